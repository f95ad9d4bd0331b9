"""Hand joint limits: Euler conversion, gimbal lock, clamping and the bounded parameterisation."""

import math

import numpy as np
import pytest
import roma
import torch
from scipy.spatial.transform import Rotation

from signsplat.body import hand_limits as hl

ORDERS = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]


@pytest.mark.parametrize("order", ORDERS)
def test_euler_matches_scipy_and_round_trips(order):
    g = torch.Generator().manual_seed(1)
    e = (torch.rand(500, 3, generator=g, dtype=torch.float64) - 0.5) * 2
    e = e * torch.tensor([math.pi, math.pi / 2 * 0.999, math.pi], dtype=torch.float64)
    aa = hl.euler_to_axis_angle(e, order)
    ref = Rotation.from_euler(order, e.numpy()).as_rotvec()
    np.testing.assert_allclose(aa.numpy(), ref, atol=1e-9)
    back = hl.axis_angle_to_euler(aa, order)
    np.testing.assert_allclose(back.numpy(), e.numpy(), atol=1e-6)


@pytest.mark.parametrize("order", ORDERS)
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_gimbal_lock_finite_values_and_gradients(order, dtype):
    e = torch.tensor([[0.3, math.pi / 2, 0.2], [0.0, -math.pi / 2, 0.0], [1.0, math.pi / 2, -1.0],
                      [0.0, 0.0, 0.0], [-2.0, -math.pi / 2, 0.5]], dtype=dtype, requires_grad=True)
    back = hl.axis_angle_to_euler(hl.euler_to_axis_angle(e, order), order)
    (back * torch.arange(1, 4, dtype=dtype)).sum().backward()
    assert torch.isfinite(back).all()
    assert torch.isfinite(e.grad).all()
    # the recovered angles describe the same rotation
    r1 = roma.euler_to_rotmat(order, e.detach().double())
    r2 = roma.euler_to_rotmat(order, back.detach().double())
    tol = 1e-5 if dtype == torch.float32 else 1e-8
    assert (r1 - r2).abs().max() < 10 * tol ** 0.5


def test_locked_axes_and_ranges_are_data():
    lim = hl.hand_limits("left")
    assert lim.lo.shape == lim.hi.shape == lim.locked.shape == (15, 3)
    names = list(lim.names)
    # PIP/DIP joints flex about one axis only; MCP flex + abduct, no twist; thumb CMC all three
    for f in ("index", "middle", "ring", "pinky"):
        for k in (2, 3):
            assert lim.locked[names.index(f"{f}{k}")].tolist() == [True, True, False]
        assert lim.locked[names.index(f"{f}1")].tolist() == [True, False, False]
    assert not lim.locked[names.index("thumb1")].any()
    assert (lim.lo <= 0).all() and (lim.hi >= 0).all()
    assert np.all(lim.lo[lim.locked] == 0) and np.all(lim.hi[lim.locked] == 0)
    assert lim.num_free == int((~lim.locked).sum()) == 22


def test_flexion_signs_left_negative_right_positive_about_z():
    ang = torch.zeros(15, 3, dtype=torch.float64)
    ang[0, 2] = 0.5  # index1 flexion
    left = hl.anatomical_to_axis_angle(ang, hl.hand_limits("left")).reshape(15, 3)
    right = hl.anatomical_to_axis_angle(ang, hl.hand_limits("right")).reshape(15, 3)
    np.testing.assert_allclose(left[0].numpy(), [0, 0, -0.5], atol=1e-12)
    np.testing.assert_allclose(right[0].numpy(), [0, 0, 0.5], atol=1e-12)
    # the left index tip (along +x at rest) moves towards the palm (-y)
    tip = roma.rotvec_to_rotmat(left[0]) @ torch.tensor([1.0, 0, 0], dtype=torch.float64)
    assert tip[1] < -0.4


def test_right_hand_is_mirror_of_left():
    g = torch.Generator().manual_seed(3)
    lim_l, lim_r = hl.hand_limits("left"), hl.hand_limits("right")
    free = torch.randn(20, lim_l.num_free, generator=g, dtype=torch.float64)
    aa_l = hl.free_to_hand_pose(free, lim_l).reshape(20, 15, 3)
    aa_r = hl.free_to_hand_pose(free, lim_r).reshape(20, 15, 3)
    np.testing.assert_allclose(aa_r.numpy(), (aa_l * torch.tensor([1.0, -1, -1])).numpy(),
                               atol=1e-12)


@pytest.mark.parametrize("side", ["left", "right"])
def test_clamp_keeps_poses_in_range_and_fixes_feasible_ones(side):
    g = torch.Generator().manual_seed(4)
    wild = torch.randn(200, 45, generator=g, dtype=torch.float64) * 1.2
    assert not hl.within_limits(wild.numpy(), side).all()
    clamped = hl.clamp_hand_pose(wild, side)
    assert hl.within_limits(clamped.numpy(), side, tol_deg=1e-3).all()
    lim = hl.hand_limits(side)
    ang = hl.axis_angle_to_anatomical(clamped, lim)
    assert ang[:, torch.as_tensor(lim.locked)].abs().max() < 1e-9
    # feasible poses are left unchanged; numpy in -> numpy out
    feasible = hl.free_to_hand_pose(torch.randn(50, lim.num_free, generator=g,
                                                dtype=torch.float64), lim).numpy()
    out = hl.clamp_hand_pose(feasible, side)
    assert isinstance(out, np.ndarray)
    np.testing.assert_allclose(out, feasible, atol=1e-9)


@pytest.mark.parametrize("side", ["left", "right"])
def test_parameterisation_round_trip_and_gradients(side):
    lim = hl.hand_limits(side)
    g = torch.Generator().manual_seed(5)
    free = torch.randn(30, lim.num_free, generator=g, dtype=torch.float64) * 2
    pose = hl.free_to_hand_pose(free, lim)
    assert hl.within_limits(pose.numpy(), lim, tol_deg=1e-6).all()
    np.testing.assert_allclose(hl.hand_pose_to_free(pose, lim).numpy(), free.numpy(), atol=1e-7)
    # a learnable module starting from the flat hand, with finite gradients everywhere
    param = hl.HandPoseParam(side, batch_size=3)
    out = param()
    assert out.shape == (3, 45) and out.abs().max() < 1e-5
    target = hl.free_to_hand_pose(free[:3].float(), lim)
    loss = ((out - target) ** 2).sum()
    loss.backward()
    assert torch.isfinite(param.free.grad).all()
    assert param.free.grad.abs().sum() > 0


def test_optimising_the_parameterisation_stays_feasible():
    lim = hl.hand_limits("left")
    param = hl.HandPoseParam(lim, batch_size=1, dtype=torch.float64)
    target = torch.full((1, 45), 2.0, dtype=torch.float64)  # far outside the limits
    opt = torch.optim.Adam(param.parameters(), lr=0.3)
    for _ in range(30):
        opt.zero_grad()
        loss = ((param() - target) ** 2).sum()
        loss.backward()
        opt.step()
    assert torch.isfinite(param.free).all()
    assert hl.within_limits(param().detach().numpy(), lim, tol_deg=1e-6).all()


def test_thumb_frame_is_a_rotation_and_mirrors():
    fl = hl.thumb_frame(hl.LEFT_THUMB_DIRECTION, "left")
    fr = hl.thumb_frame(np.array(hl.LEFT_THUMB_DIRECTION) * [-1, 1, 1], "right")
    for f in (fl, fr):
        np.testing.assert_allclose(f @ f.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(f) == pytest.approx(1.0)
    m = np.diag([-1.0, 1, 1])
    np.testing.assert_allclose(fr, m @ fl @ m, atol=1e-12)
    with pytest.raises(ValueError):
        hl.hand_limits("middle")
