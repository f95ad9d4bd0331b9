"""The fused per-point attributes (signsplat/avatar/attributes.py): the Numba kernel against the
PyTorch formulas, values and gradients."""

import pytest
import torch

from signsplat.avatar.attributes import point_attributes, point_attributes_torch


def _inputs(b=2, p=40, r=3, heads=True, gain=True, dtype=torch.float32, seed=0):
    g = torch.Generator().manual_seed(seed)

    def rnd(*shape, scale=1.0):
        return (torch.randn(*shape, generator=g, dtype=dtype) * scale).requires_grad_()

    x = dict(scale_raw=rnd(p, 3), quat=rnd(p, 4), opacity_raw=rnd(p), sh_dc=rnd(p, 3),
             sh_rest=rnd(p, r, 3, scale=0.3),
             heads=rnd(b, p, 11, scale=0.2) if heads else None,
             gain=(1 + rnd(b, p, 3, scale=0.3)).detach().requires_grad_() if gain else None,
             q_blend=rnd(b, p, 4))
    smax = torch.rand(p, generator=g, dtype=dtype) * 0.02 + 0.004
    return x, smax


@pytest.mark.parametrize("heads,gain,r", [(True, True, 3), (False, True, 3), (True, False, 0),
                                          (False, False, 8)])
def test_kernel_matches_the_torch_formulas(heads, gain, r):
    x, smax = _inputs(r=r, heads=heads, gain=gain)
    y = {k: (v.detach().clone().requires_grad_() if v is not None else None)
         for k, v in x.items()}
    out_k = point_attributes(**x, smax=smax, smin=2e-4)
    out_t = point_attributes_torch(**y, smax=smax, smin=2e-4)
    g = torch.Generator().manual_seed(9)
    loss_k = loss_t = 0.0
    for a, b in zip(out_k, out_t):
        torch.testing.assert_close(a, b)
        w = torch.randn(a.shape, generator=g)
        loss_k = loss_k + (a * w).sum()
        loss_t = loss_t + (b * w).sum()
    loss_k.backward()
    loss_t.backward()
    for k, v in x.items():
        if v is not None:
            torch.testing.assert_close(v.grad, y[k].grad, msg=k)


def test_gradcheck_in_float64():
    x, smax = _inputs(b=2, p=5, r=3, dtype=torch.float64)
    names = list(x)
    assert torch.autograd.gradcheck(
        lambda *t: point_attributes(**dict(zip(names, t)), smax=smax, smin=2e-4),
        tuple(x[n] for n in names))


def test_outputs_are_unit_quaternions_and_bounded_scales():
    x, smax = _inputs(b=3, p=100)
    scales, quats, opac, colors = point_attributes(**x, smax=smax, smin=2e-4)
    torch.testing.assert_close(quats.norm(dim=-1), torch.ones(3, 100))
    assert bool((scales > 2e-4).all() and (scales < smax[:, None]).all())
    assert bool(((opac > 0) & (opac < 1)).all()) and colors.shape == (3, 100, 4, 3)
