"""The anchored avatar model: posing, per-part bounds, displacements, switches, finite extremes."""

import math

import pytest

import roma
import torch
from avatar_scenes import SIZES, random_smplx, rig

from signsplat.avatar.checkpoint import build_model
from signsplat.avatar.config import avatar_config
from signsplat.avatar.model import frame_quats, sh_degree_at, wxyz_to_xyzw, xyzw_to_wxyz
from signsplat.render import rasterization

CFG = {"upsample": {"edge_length": 0.08, "face_area": 3e-3}}


def _model(body, **over):
    cfg = avatar_config({**CFG, **over})
    return build_model(body, torch.zeros(1, 10), cfg), cfg


def _pose(model, body, params, sh=0):
    out = body(**params)
    return model(out.v_shaped, out.vertices, out.transforms, params.get("transl"), sh)


def test_rest_pose_puts_points_on_the_mesh(tiny_body):
    model, _ = _model(tiny_body)
    g = _pose(model, tiny_body, {"betas": torch.zeros(1, 10)})
    expect = (tiny_body.v_template[model.anchors] * model.bary_fixed[..., None]).sum(1)
    torch.testing.assert_close(g.means[0], expect, atol=1e-6, rtol=0)  # zero-init displacement
    assert g.colors.shape == (1, model.num_points, 1, 3)
    torch.testing.assert_close(g.quats[0].norm(dim=-1), torch.ones(model.num_points))


def test_global_rotation_moves_means_and_turns_gaussians(tiny_body):
    model, _ = _model(tiny_body)
    with torch.no_grad():
        model.quat.copy_(torch.nn.functional.normalize(torch.randn_like(model.quat), dim=-1))
    rotvec = torch.tensor([[0.3, -1.1, 0.4]])
    g0 = _pose(model, tiny_body, {"global_orient": torch.zeros(1, 3)})
    g1 = _pose(model, tiny_body, {"global_orient": rotvec})
    R = roma.rotvec_to_rotmat(rotvec[0])
    root = tiny_body.rest_joints[0]
    torch.testing.assert_close(g1.means[0], (g0.means[0] - root) @ R.T + root, atol=1e-5, rtol=0)
    r0 = roma.unitquat_to_rotmat(wxyz_to_xyzw(g0.quats[0]))
    r1 = roma.unitquat_to_rotmat(wxyz_to_xyzw(g1.quats[0]))
    torch.testing.assert_close(r1, R @ r0, atol=1e-4, rtol=0)


def test_scales_bounded_per_part_and_displacement_bounded(tiny_body):
    model, cfg = _model(tiny_body)
    with torch.no_grad():
        model.scale_raw.fill_(50.0)
        model.disp_net.head.bias.fill_(100.0)
        g = _pose(model, tiny_body, {"betas": torch.zeros(1, 10)})
    bound = model.scale_max_per_point()
    assert bool((g.scales[0] <= bound[:, None] + 1e-6).all())
    hands = model.part_group() == 2
    assert float(g.scales[0][hands].max()) <= cfg.model.scale_max.hands + 1e-6
    assert float(g.scales[0][~hands].max()) > cfg.model.scale_max.hands  # body allows more
    d = g.displacement.norm(dim=-1)
    vparts = model.part_group()[: model.num_vertices]
    lim = torch.tensor([cfg.model.displacement_limit.body, cfg.model.displacement_limit.head,
                        cfg.model.displacement_limit.hands])[vparts]
    assert bool((d <= lim + 1e-6).all()) and float(d.min()) > 0.5 * float(lim.min())
    # displacement moves original vertices along their normals; points follow their anchors
    # (posed in the rest pose: the posed points are the canonical ones)
    moved = (g.means[0] - model.canonical_points()).norm(dim=-1)
    assert float(moved[: model.num_vertices].min()) > 0


def test_pose_dependent_switch_removes_omega(tiny_body):
    on, _ = _model(tiny_body)
    off, _ = _model(tiny_body, model={"pose_dependent": False})
    assert on.omega is not None and off.omega is None
    assert not any(n.startswith("omega") for n, _ in off.named_parameters())
    with torch.no_grad():  # make Omega's heads non-zero: attributes then depend on the pose
        on.omega.head.weight.normal_(0, 0.5)
    p = random_smplx(2, seed=3, scale=0.5)
    a = _pose(on, tiny_body, {k: v[:1] for k, v in p.items()})
    b = _pose(on, tiny_body, {k: v[1:] for k, v in p.items()})
    assert not torch.allclose(a.opacities, b.opacities)
    a = _pose(off, tiny_body, {k: v[:1] for k, v in p.items()})
    b = _pose(off, tiny_body, {k: v[1:] for k, v in p.items()})
    torch.testing.assert_close(a.opacities, b.opacities)
    torch.testing.assert_close(a.scales, b.scales)


def test_far_pose_renders_finite(tiny_body):
    """Joint rotations near 180 degrees everywhere (far outside any training pose)."""
    model, _ = _model(tiny_body, model={"sh_degree": 1})
    g = torch.Generator().manual_seed(7)
    params = {k: torch.zeros(1, n) for k, n in SIZES.items()}
    for k in ("body_pose", "left_hand_pose", "right_hand_pose", "global_orient", "jaw_pose"):
        rv = torch.randn(1, SIZES[k] // 3, 3, generator=g)
        params[k] = (rv / rv.norm(dim=-1, keepdim=True) * (math.pi - 1e-3)).reshape(1, -1)
    params["transl"] = torch.tensor([[0.0, 0.0, 0.5]])
    out = _pose(model, tiny_body, params, sh=1)
    for t in (out.means, out.quats, out.scales, out.opacities, out.colors):
        assert bool(torch.isfinite(t).all())
    vm, K = rig(2, 24)
    img, alpha, _ = rasterization(out.means[0], out.quats[0], out.scales[0], out.opacities[0],
                                  out.colors[0], vm, K, 24, 24, sh_degree=1,
                                  backgrounds=torch.ones(2, 3))
    assert bool(torch.isfinite(img).all()) and bool(torch.isfinite(alpha).all())
    # gradients stay finite too
    img.sum().backward()
    assert all(bool(torch.isfinite(p.grad).all()) for p in model.parameters() if p.grad is not None)


def test_sh_schedule():
    assert sh_degree_at(10, 100, 2, 0.75) == 0
    assert sh_degree_at(74, 100, 2, 0.75) == 0
    assert sh_degree_at(75, 100, 2, 0.75) == 2
    assert sh_degree_at(99, 100, 0, 0.75) == 0


def test_displacement_cached_without_autograd_until_a_weight_changes(tiny_body):
    model, _ = _model(tiny_body)
    with torch.no_grad():
        model.disp_net.head.weight.normal_(0, 0.5)
        a = model.displacement()
        assert model.displacement() is a  # reused while rendering
        model.disp_net.head.weight.mul_(2.0)  # an in-place update (as the optimiser does)
        b = model.displacement()
    assert b is not a and not torch.allclose(a, b)
    c = model.displacement()  # with autograd: always recomputed, differentiable
    assert c.requires_grad
    torch.testing.assert_close(c.detach(), b)


def test_displacement_learns_from_its_zero_start(tiny_body):
    """The displacement network's head starts at zero (no displacement); a loss on the
    displacement must still reach its weights, or training never moves it off zero."""
    model, _ = _model(tiny_body)
    assert float(model.disp_net.head.weight.abs().max()) == 0.0
    d = model.displacement()
    assert float(d.abs().max()) == 0.0
    (d * torch.randn_like(d)).sum().backward()
    grad = model.disp_net.head.weight.grad
    assert grad is not None and bool(torch.isfinite(grad).all())
    assert float(grad.abs().max()) > 1e-4


def test_flat_init_puts_discs_in_the_surface(tiny_body):
    flat, cfg = _model(tiny_body)
    ball, _ = _model(tiny_body, model={"flat_init": 0.0})
    g = _pose(flat, tiny_body, {"betas": torch.zeros(1, 10)})
    from signsplat.avatar.model import vertex_normals
    n = (vertex_normals(tiny_body.v_template[None], flat.faces)[0][flat.anchors]
         * flat.bary_fixed[..., None]).sum(1)
    n = n / n.norm(dim=-1, keepdim=True)
    R = roma.unitquat_to_rotmat(wxyz_to_xyzw(g.quats[0]))
    thin_axis = R[torch.arange(len(n)), :, g.scales[0].argmin(-1)]
    ok = n.norm(dim=-1) > 0.5
    assert float((thin_axis[ok] * n[ok]).sum(-1).abs().min().detach()) > 0.99  # thin along n
    ratio = g.scales[0].min(-1).values / g.scales[0].max(-1).values
    assert float(ratio.max()) < 0.5
    gb = _pose(ball, tiny_body, {"betas": torch.zeros(1, 10)})
    torch.testing.assert_close(gb.scales[0].min(-1).values, gb.scales[0].max(-1).values)


def test_frame_quats_is_roma_gram_schmidt_then_markley():
    """The per-vertex LBS frame's quaternion: the same values and gradients as roma's
    special_gramschmidt + rotmat_to_unitquat, on every branch of Markley's method (rotations
    near the identity and near half-turns about x, y and z) and on blended (not orthonormal)
    frames."""
    g = torch.Generator().manual_seed(0)
    axes = torch.eye(3, dtype=torch.float64)
    rv = torch.cat([0.3 * torch.randn(40, 3, generator=g, dtype=torch.float64),
                    *[3.1 * axes[i] + 0.05 * torch.randn(40, 3, generator=g, dtype=torch.float64)
                      for i in range(3)]])
    r = roma.rotvec_to_rotmat(rv)
    blended = 0.6 * r + 0.4 * r[torch.randperm(len(r), generator=g)]
    m = torch.stack([r, blended]).requires_grad_()  # (2, 160, 3, 3)
    eye = torch.eye(3, dtype=torch.float64)

    def oracle(x):
        return xyzw_to_wxyz(roma.rotmat_to_unitquat(roma.special_gramschmidt(x + 1e-6 * eye)))

    want = oracle(m)
    got = frame_quats(m)
    assert got.shape == (2, 160, 4)
    # every branch of Markley's method is exercised (largest diagonal candidate: w, x, y, z)
    w, x, y, z = want.detach().abs().unbind(-1)
    branch = torch.stack([x, y, z, w]).argmax(0)
    assert set(branch.flatten().tolist()) == {0, 1, 2, 3}
    torch.testing.assert_close(got, want, rtol=0, atol=1e-12)
    probe = torch.randn(got.shape, generator=g, dtype=torch.float64)
    g_got, = torch.autograd.grad((got * probe).sum(), m)
    g_want, = torch.autograd.grad((want * probe).sum(), m)
    torch.testing.assert_close(g_got, g_want, rtol=1e-9, atol=1e-10)


@pytest.mark.parametrize("on", ["vertices", "points"])
def test_pose_net_runs_over_the_vertices_or_the_points(tiny_body, on):
    """model.pose_net_on: Omega's sequence is the mesh vertices (its residuals interpolated to
    the points) or every point; either way a zero-initialised head leaves the canonical model
    and, once trained, moves the Gaussians and takes gradients."""
    model, _ = _model(tiny_body, model={"pose_net_on": on})
    params = random_smplx(2, seed=4)
    seen = []
    forward = model.omega.forward
    model.omega.forward = lambda x: seen.append(tuple(x.shape)) or forward(x)
    g0 = _pose(model, tiny_body, params)
    length = model.num_vertices if on == "vertices" else model.num_points
    assert model.num_vertices != model.num_points
    assert seen == [(2, 6, length)]
    torch.nn.init.normal_(model.omega.head.weight, std=0.5)
    g1 = _pose(model, tiny_body, params)
    torch.testing.assert_close(g1.means, g0.means)  # Omega never moves the points
    assert float((g1.scales - g0.scales).abs().max()) > 1e-4
    assert float((g1.quats - g0.quats).abs().max()) > 1e-4
    (g1.scales.sum() + g1.colors.sum()).backward()
    assert all(p.grad is not None and float(p.grad.abs().max()) > 0
               for p in model.omega.trunk.parameters())


def test_conv_net_head_is_a_linear_layer_per_point():
    """The networks' head (a 1x1 convolution in the trunk's layout) is the linear layer applied
    to every point's trunk features, in value and gradient."""
    from signsplat.avatar.model import ConvNet1d

    torch.manual_seed(0)
    net = ConvNet1d(6, 8, (3, 4, 1), kernel=5, layers=2)
    torch.nn.init.normal_(net.head.weight)
    torch.nn.init.normal_(net.head.bias)
    x = torch.randn(2, 6, 40, dtype=torch.float64)
    net = net.double()
    heads = net(x)
    assert [h.shape for h in heads] == [(2, 40, 3), (2, 40, 4), (2, 40, 1)]
    ref = torch.nn.functional.linear(net.trunk(x).transpose(1, 2), net.head.weight,
                                     net.head.bias)
    torch.testing.assert_close(torch.cat(heads, -1), ref, rtol=0, atol=1e-12)
    w = torch.randn(2, 40, 8, dtype=torch.float64)
    grads = torch.autograd.grad((torch.cat(heads, -1) * w).sum(), list(net.parameters()))
    ref_grads = torch.autograd.grad((ref * w).sum(), list(net.parameters()))
    for a, b in zip(grads, ref_grads):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-10)
