"""Barycentric interpolation (signsplat/avatar/interp.py): the Numba kernels (CPU) and the
PyTorch path (other devices) against the plain autograd formula."""

import pytest
import torch

from signsplat.avatar.interp import barycentric, barycentric_torch

PATHS = {"numba": barycentric, "torch": barycentric_torch}


def _case(b=2, v=40, p=300, d=7, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    values = torch.randn(b, v, d, generator=g, dtype=dtype)
    anchors = torch.randint(0, v, (p, 3), generator=g)
    anchors[:10] = anchors[:10, :1]  # repeated anchors (a mesh vertex's own point)
    w = torch.rand(p, 3, generator=g, dtype=dtype)
    return values, anchors, w / w.sum(1, keepdim=True)


def _plain(values, anchors, w, align=False):
    gathered = values[:, anchors]  # (B, P, 3, D)
    w = w[None].expand(values.shape[0], -1, -1)
    out = (gathered * w[..., None]).sum(2)
    if align:  # the first four channels with each anchor on its first anchor's hemisphere
        dot = (gathered[..., :4] * gathered[:, :, :1, :4]).sum(-1)
        ws = w * torch.where(dot < 0, -1.0, 1.0).to(w.dtype)
        out = torch.cat([(gathered[..., :4] * ws[..., None]).sum(2), out[..., 4:]], -1)
    return out


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("align", [False, True])
def test_values_and_gradients_match_the_plain_formula(path, align):
    values, anchors, w = _case()
    grad = torch.randn(2, 300, 7, generator=torch.Generator().manual_seed(1))
    a = [values.clone().requires_grad_(), w.clone().requires_grad_()]
    b = [values.clone().requires_grad_(), w.clone().requires_grad_()]
    out_a = PATHS[path](a[0], anchors, a[1], align)
    out_b = _plain(b[0], anchors, b[1], align)
    torch.testing.assert_close(out_a, out_b)
    out_a.backward(grad)
    out_b.backward(grad)
    torch.testing.assert_close(a[0].grad, b[0].grad)
    torch.testing.assert_close(a[1].grad, b[1].grad)


@pytest.mark.parametrize("path", PATHS)
def test_gradcheck_in_float64(path):
    values, anchors, w = _case(b=2, v=6, p=9, d=6, dtype=torch.float64)
    values.requires_grad_()
    w.requires_grad_()
    for align in (False, True):
        assert torch.autograd.gradcheck(lambda x, y: PATHS[path](x, anchors, y, align),
                                        (values, w))


def test_backward_is_the_same_for_any_thread_count():
    import numba

    values, anchors, w = _case(b=3, v=500, p=20000, d=8)
    grad = torch.randn(3, 20000, 8, generator=torch.Generator().manual_seed(2))
    old = numba.get_num_threads()
    results = []
    try:
        for threads in (1, 2, 2):
            numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
            x, y = values.clone().requires_grad_(), w.clone().requires_grad_()
            barycentric(x, anchors, y).backward(grad)
            results.append((x.grad, y.grad))
    finally:
        numba.set_num_threads(old)
    for other in results[1:]:
        assert torch.equal(results[0][0], other[0]) and torch.equal(results[0][1], other[1])


def test_vertex_lists_follow_a_change_of_the_anchors():
    values, anchors, w = _case()
    x = values.clone().requires_grad_()
    barycentric(x, anchors, w).sum().backward()
    anchors[:, 0] = 0  # in place: the cached lists must not be reused
    x2, x3 = values.clone().requires_grad_(), values.clone().requires_grad_()
    barycentric(x2, anchors, w).sum().backward()
    _plain(x3, anchors, w).sum().backward()
    torch.testing.assert_close(x2.grad, x3.grad)


def _blend(q, anchors, w):
    out = barycentric(q, anchors, w, align=True)
    return out / out.norm(dim=-1, keepdim=True)


def test_quaternions_are_blended_on_one_hemisphere():
    g = torch.Generator().manual_seed(4)
    q = torch.randn(1, 30, 4, generator=g)
    q = q / q.norm(dim=-1, keepdim=True)
    anchors = torch.randint(0, 30, (50, 3), generator=g)
    w = torch.rand(50, 3, generator=g)
    w = w / w.sum(1, keepdim=True)
    flipped = q * torch.where(torch.rand(1, 30, 1, generator=g) < 0.5, -1.0, 1.0)
    a, b = _blend(q, anchors, w), _blend(flipped, anchors, w)
    # the same rotations whatever sign each vertex's quaternion has
    same = torch.minimum((a - b).abs().amax(-1), (a + b).abs().amax(-1))
    assert float(same.max()) < 1e-5
    torch.testing.assert_close(a.norm(dim=-1), torch.ones(1, 50))
    # equal anchors: the blend is that quaternion
    one = _blend(q, torch.tensor([[3, 3, 3]]), torch.tensor([[0.2, 0.3, 0.5]]))
    torch.testing.assert_close(one[0, 0], q[0, 3])
