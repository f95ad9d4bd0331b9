"""Camera refinement (train.refine_cameras): parameterisation, gauge, and that training with it
pulls perturbed cameras back towards the ones the images were rendered with."""

import dataclasses
import math

import numpy as np
import roma
import torch
from avatar_scenes import look_at
from test_avatar_train import _cfg, scene  # noqa: F401  (module fixture)

from signsplat.avatar.cameras import CameraRefinement
from signsplat.avatar.train import AvatarTrainer, cameras_refined


def _rig():
    return torch.stack([look_at((2.0 * math.sin(a), 1.0, 2.0 * math.cos(a)))
                        for a in (0.0, 0.8, -0.8)])


def test_disabled_refinement_is_the_identity_and_learns_nothing():
    vm = _rig()
    cams = CameraRefinement(vm, torch.tensor([0.0, 1.0, 0.0]), [0, 1, 2], enabled=False)
    assert torch.equal(cams.viewmats(), vm)
    assert not cams.raw.requires_grad


def test_corrections_are_rigid_zero_mean_and_skip_held_out_views():
    vm = _rig()
    cams = CameraRefinement(vm, torch.tensor([0.0, 1.0, 0.0]), [0, 1], enabled=True)
    torch.testing.assert_close(cams.viewmats(), vm)  # zero at the start
    with torch.no_grad():
        cams.raw.copy_(torch.randn(3, 6) * 0.05)
    d = cams.delta()
    torch.testing.assert_close(d[:2].sum(0), torch.zeros(6), atol=1e-6, rtol=0)
    assert torch.equal(d[2], torch.zeros(6))  # view 2 is held out: never corrected
    out = cams.viewmats()
    torch.testing.assert_close(out[2], vm[2])
    R = out[:, :3, :3]
    torch.testing.assert_close(R @ R.transpose(1, 2), torch.eye(3).expand(3, 3, 3), atol=1e-5,
                               rtol=0)
    # the same correction added to every training camera is a rigid motion of the whole world:
    # the gauge removes it
    with torch.no_grad():
        cams.raw.add_(torch.tensor([0.1, -0.2, 0.05, 0.3, 0.0, -0.1]))
    torch.testing.assert_close(cams.viewmats(), out, atol=1e-6, rtol=0)


def test_gradients_are_finite_at_zero_and_at_large_angles():
    vm = _rig()
    cams = CameraRefinement(vm, torch.tensor([0.0, 1.0, 0.0]), [0, 1, 2], enabled=True)
    for value in (0.0, math.pi - 1e-4, math.pi):
        with torch.no_grad():
            cams.raw.zero_()
            cams.raw[0, 0] = value
        cams.raw.grad = None
        cams.viewmats().sum().backward()
        assert torch.isfinite(cams.raw.grad).all(), value


def _angle_deg(a, b):
    r = a[:3, :3] @ b[:3, :3].T
    return float(torch.rad2deg(roma.rotmat_geodesic_distance(r, torch.eye(3))))


def _centre_err(a, b):
    ca = -a[:3, :3].T @ a[:3, 3]
    cb = -b[:3, :3].T @ b[:3, 3]
    return float((ca - cb).norm())


def test_training_pulls_perturbed_cameras_back(scene):  # noqa: F811
    body, data = scene
    true = data.viewmats.clone()
    # turn camera 1 by 3 degrees about the subject (so it sees the subject shifted ~1.5 px)
    turn = torch.eye(4)
    turn[:3, :3] = roma.rotvec_to_rotmat(torch.tensor([0.0, math.radians(3.0), 0.0]))
    centre = torch.tensor([0.0, 1.0, 0.0])
    turn[:3, 3] = centre - turn[:3, :3] @ centre
    bad = true.clone()
    bad[1] = true[1] @ turn
    noisy = dataclasses.replace(data, viewmats=bad)
    before = _angle_deg(bad[1] @ torch.linalg.inv(bad[0]), true[1] @ torch.linalg.inv(true[0]))
    cfg = _cfg(train={"iterations": 60, "color_init": "constant", "refine_cameras": True,
                      "lr_cameras": 3e-3, "finetune_smplx": False})
    assert cameras_refined(cfg)
    tr = AvatarTrainer(body, noisy, cfg)
    tr.run(progress=False)
    got = tr.viewmats.detach()
    assert torch.isfinite(got).all()
    after = _angle_deg(got[1] @ torch.linalg.inv(got[0]), true[1] @ torch.linalg.inv(true[0]))
    assert after < 0.6 * before, (before, after)
    log = tr.log_rows[-1]
    assert log["camera_rotation_deg_max"] > 0.5
    # the auto setting follows the SMPL-X source: ground-truth cameras stay fixed; the default
    # (false) never refines
    gt = _cfg(train={"smplx_source": "ground_truth", "refine_cameras": "auto"})
    assert not cameras_refined(gt)
    assert cameras_refined(_cfg(train={"smplx_source": "fitted", "refine_cameras": "auto"}))
    assert not cameras_refined(_cfg(train={"smplx_source": "fitted"}))
    assert np.isfinite([r["loss"] for r in tr.log_rows]).all()


def test_camera_corrections_stay_fixed_after_the_stop_step(scene):  # noqa: F811
    body, data = scene
    cfg = _cfg(train={"iterations": 6, "color_init": "constant", "refine_cameras": True,
                      "lr_cameras": 3e-3, "refine_cameras_stop": 3})
    tr = AvatarTrainer(body, data, cfg)
    seen = []
    for _ in range(6):
        tr.train_step()
        seen.append(tr.cameras.raw.detach().clone())
    # refined up to the stop step (each step moves them), frozen after it
    assert not torch.equal(seen[1], seen[2])
    for later in seen[3:]:
        assert torch.equal(later, seen[2])
    assert tr.cameras.raw.grad is None
    # the rest of the model still trains past the stop
    colours = tr.model.sh_dc.detach().clone()
    tr.train_step()
    assert not torch.equal(colours, tr.model.sh_dc.detach())
