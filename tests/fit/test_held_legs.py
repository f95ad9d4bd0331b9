"""Legs no view sees keep the rest pose (config ``fit.hold_unseen_legs``)."""

import numpy as np
import pytest
import torch
from fit_scenes import (make_stage, observe, random_motion, render_masks, synthetic_rig,
                         truth_init)

from signsplat.config import validate
from signsplat.fit import objective as obj
from signsplat.fit.bodyfit import FitParams
from signsplat.fit.cameras import CameraParams
from signsplat.fit.solver import _sanitize_grads, make_problem, run_stage

LEFT_HIP, RIGHT_HIP = 0, 3  # body_pose offsets of the hips' axis-angles (joints 1, 2)


def _leg_keypoints(side: str) -> list[int]:
    return list(obj.LEG_SIDES[side][1])


def test_unseen_legs_are_the_sides_without_a_leg_observation():
    obs = torch.zeros(2, 3, 133, 3)
    assert obj.unseen_legs(obs) == ["left", "right"]
    obs[1, 2, 15, 2] = 0.4  # one left ankle in one view and frame
    assert obj.unseen_legs(obs) == ["right"]
    obs[0, 0, 22, 2] = 0.9  # one right heel
    assert obj.unseen_legs(obs) == []
    held = obj.held_pose_mask(["right"])
    # right hip, knee, ankle, foot: joints 2, 5, 8, 11 -> body_pose values 3-5, 12-14, ...
    assert torch.nonzero(held)[:, 0].tolist() == [3, 4, 5, 12, 13, 14, 21, 22, 23, 30, 31, 32]


def test_a_leg_point_outside_its_image_is_not_seen():
    """A pose model's guess of a knee below the frame does not release the leg, once the
    images' sizes are known."""
    obs = torch.zeros(2, 3, 133, 3)
    sizes = [(160, 120), (200, 100)]
    knee, ankle = _leg_keypoints("left")[:2]
    obs[0, 1, knee] = torch.tensor([50.0, 130.0, 0.9])  # below view 0's 120 rows
    obs[1, 2, ankle] = torch.tensor([-3.0, 50.0, 0.9])  # left of view 1
    obs[1, 0, knee] = torch.tensor([60.0, 110.0, 0.9])  # below view 1's 100 rows
    assert obj.unseen_legs(obs) == ["right"]  # sizes unknown: every point counts
    assert obj.unseen_legs(obs, sizes) == ["left", "right"]
    obs[0, 2, knee] = torch.tensor([159.4, 119.4, 0.5])  # the corner pixel of view 0
    assert obj.unseen_legs(obs, sizes) == ["right"]


def test_make_problem_holds_only_unseen_legs_and_only_when_asked(kpm):
    cfg = validate({}, "stages/fit.schema.yaml")
    obs = np.zeros((2, 3, 133, 3))
    obs[..., :5, 2] = 1.0  # a face, no legs
    assert make_problem(kpm, obs, cfg).legs_held == ["left", "right"]
    obs[0, 1, _leg_keypoints("left")[0], 2] = 1.0
    assert make_problem(kpm, obs, cfg).legs_held == ["right"]
    obs[0, 1, _leg_keypoints("right")[-1], 2] = 1.0
    assert make_problem(kpm, obs, cfg).held_pose is None
    off = validate({"hold_unseen_legs": False}, "stages/fit.schema.yaml")
    assert make_problem(kpm, np.zeros((2, 3, 133, 3)), off).held_pose is None
    obs[0, 1, _leg_keypoints("left")[0], 1] = 300.0  # the left knee below a 256-row image
    assert make_problem(kpm, obs, cfg).legs_held == []
    assert make_problem(kpm, obs, cfg, image_sizes=[(256, 256)] * 2).legs_held == ["left"]


@pytest.mark.parametrize("views", [1, 3])
def test_fits_pass_the_image_sizes_to_the_hold(kpm, views):
    """Single- and multi-view fits hold a leg whose points all lie outside the images, and
    release one with a point inside."""
    from signsplat.fit.multiview import fit_multiview
    from signsplat.fit.singleview import fit_singleview

    T = 3
    gt = random_motion(T, seed=5)
    rig = synthetic_rig(views, arc=0 if views == 1 else 120)
    obs = observe(kpm, gt, rig)
    legs = _leg_keypoints("left") + _leg_keypoints("right")
    obs[:, :, legs, 0] = 128.0
    obs[:, :, legs, 1] = 300.0  # guessed below the 256-row images
    obs[:, :, legs, 2] = 0.9
    obs[0, 1, _leg_keypoints("right")[0], 1] = 250.0  # one right knee inside view 0
    stage = {"iterations": 3, "lr": 0.01, "sigma_px": 100}
    if views == 1:
        cfg = validate({"singleview": {
            "hypothesis_iterations": 3,
            "init_stages": [{"name": "body", "groups": ["root", "body"], **stage}],
            "refine_stages": [{"name": "refine", "groups": ["root", "body"], **stage}]}},
            "stages/fit.schema.yaml")
        res = fit_singleview(kpm, obs[0], np.arange(T), rig.K[0], 256, 256, cfg)
    else:
        cfg = validate({"multiview": {"stages": [
            {"name": "body", "groups": ["root", "body", "cameras"], **stage}]}},
            "stages/fit.schema.yaml")
        res = fit_multiview(kpm, obs, np.arange(T), rig.K, rig.width, rig.height, cfg)
    assert res.log["legs_held"] == ["left"]


def test_a_held_value_gets_no_gradient(kpm):
    """What keeps a held leg still inside an Adam or L-BFGS stage, not only at its end."""
    cfg = validate({}, "stages/fit.schema.yaml")
    problem = make_problem(kpm, np.zeros((1, 2, 133, 3)), cfg)
    params = FitParams(2, 10, 10)
    params.body_pose.grad = torch.ones_like(params.body_pose)
    params.transl.grad = torch.full_like(params.transl, float("nan"))
    _sanitize_grads([params.body_pose, params.transl], problem, params)
    held = problem.held_pose
    assert torch.all(params.body_pose.grad[:, held] == 0)
    assert torch.all(params.body_pose.grad[:, ~held] == 1)
    assert torch.all(params.transl.grad == 0)


def _spread_scene(kpm, T=2, V=3):
    """The truth's legs spread (hips abducted 0.3 rad); its masks show them, its keypoints of
    the legs are not observed; the fit starts at the truth with the legs at rest."""
    gt = random_motion(T, seed=7)
    gt["body_pose"] = gt["body_pose"].copy()
    gt["body_pose"][:, LEFT_HIP + 2] = 0.3
    gt["body_pose"][:, RIGHT_HIP + 2] = -0.3
    rig = synthetic_rig(V, arc=120)
    obs = observe(kpm, gt, rig)
    obs[:, :, _leg_keypoints("left") + _leg_keypoints("right"), 2] = 0.0
    init = truth_init(gt)
    init["body_pose"] = gt["body_pose"].copy()
    init["body_pose"][:, [LEFT_HIP + 2, RIGHT_HIP + 2]] = 0.0
    return gt, rig, obs, render_masks(kpm, gt, rig), init


@pytest.mark.parametrize("solver", [
    {"optimizer": "adam", "iterations": 40, "lr": 0.01},
    {"optimizer": "lbfgs", "iterations": 10, "lr": 1.0},
], ids=["adam", "lbfgs"])
def test_masks_do_not_move_a_leg_no_keypoint_shows(kpm, solver):
    """The masks would spread the legs (they do with the setting off); held, the legs end
    the stage at the rest pose to the bit while the rest of the body is fitted."""
    _, rig, obs, masks, init = _spread_scene(kpm)
    stage = make_stage(name="sil", groups=("root", "body"),
                       silhouette={"inside": 100.0, "cover": 100.0}, **solver)
    moved = {}
    for hold in (True, False):
        cfg = validate({"hold_unseen_legs": hold}, "stages/fit.schema.yaml")
        params = FitParams(obs.shape[1], 10, 10, init=init)
        problem = make_problem(kpm, obs, cfg, np.arange(obs.shape[1]), masks=masks)
        before = params.body_pose.detach().clone()
        run_stage(problem, params, CameraParams(rig, fixed=list(range(rig.num_views))), stage)
        after = params.body_pose.detach()
        legs = obj.held_pose_mask(["left", "right"])
        moved[hold] = float((after[:, legs] - before[:, legs]).abs().max())
        assert torch.isfinite(after).all()
        if hold:
            assert torch.equal(after[:, legs], torch.zeros_like(after[:, legs]))
            assert float((after[:, ~legs] - before[:, ~legs]).abs().max()) > 1e-4
    assert moved[True] == 0.0 and moved[False] > 0.02
