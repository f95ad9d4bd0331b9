"""A stage holds the cameras of views whose keypoints agree across the views
(``hold_cameras_within_px`` of a stage; the fit's ``camera_init_px_view<v>``)."""

import numpy as np
import pytest
import torch
from fit_scenes import (make_stage, observe, random_motion, render_masks, synthetic_rig,
                         truth_init)
from scipy.ndimage import binary_dilation

from signsplat.config import validate
from signsplat.fit.bodyfit import FitParams
from signsplat.fit.cameras import CameraParams
from signsplat.fit.multiview import fit_multiview
from signsplat.fit.solver import make_problem, run_stage


def _scene(kpm, T=2, V=3):
    """Keypoints without error, masks two pixels too large: the mask terms pull the cameras
    (and the body) away from where the keypoints put them. The fit starts at the truth."""
    gt = random_motion(T, seed=3)
    rig = synthetic_rig(V, arc=120)
    obs = observe(kpm, gt, rig)
    masks = binary_dilation(render_masks(kpm, gt, rig), np.ones((1, 1, 5, 5), bool))
    init = truth_init(gt)
    return rig, obs, masks, init


@pytest.mark.parametrize("solver", [
    {"optimizer": "adam", "iterations": 30, "lr": 0.01},
    {"optimizer": "lbfgs", "iterations": 8, "lr": 1.0},
], ids=["adam", "lbfgs"])
def test_a_view_whose_keypoints_agree_keeps_its_camera(kpm, solver):
    """View 1 (0.1 px at the initialisation) keeps its camera to the bit, view 2 (2 px)
    moves; without the measurement, view 1 moves too. View 0 is the fixed reference."""
    rig, obs, masks, init = _scene(kpm)
    stage = make_stage(name="sil", groups=("root", "body", "cameras"), sigma_px=5,
                       silhouette={"inside": 300.0, "cover": 300.0},
                       hold_cameras_within_px=0.5, **solver)
    cfg = validate({}, "stages/fit.schema.yaml")
    moved = {}
    for view_px in ([0.0, 0.1, 2.0], None):
        problem = make_problem(kpm, obs, cfg, np.arange(obs.shape[1]), masks=masks,
                               view_px=view_px)
        assert problem.held_views(stage) == ([0, 1] if view_px else [])
        params = FitParams(obs.shape[1], 10, 10, init=init)
        cams = CameraParams(rig, fixed=[0])
        run_stage(problem, params, cams, stage)
        step = torch.cat([cams.rotvec, cams.dt], 1).detach().abs().amax(1)
        assert torch.isfinite(step).all()
        moved[view_px is not None] = step.tolist()
    assert moved[True][1] == 0.0 and moved[True][2] > 1e-5
    assert moved[False][1] > 1e-5 and moved[False][2] > 1e-5


def test_the_hold_reads_only_stages_that_move_cameras(kpm):
    cfg = validate({}, "stages/fit.schema.yaml")
    problem = make_problem(kpm, np.zeros((3, 2, 133, 3)), cfg, view_px=[0.2, np.nan, 0.7])
    with_cameras = make_stage(name="a", iterations=1, lr=0.01, groups=("body", "cameras"),
                              hold_cameras_within_px=0.5)
    without = make_stage(name="b", iterations=1, lr=0.01, groups=("body",),
                         hold_cameras_within_px=0.5)
    unset = make_stage(name="c", iterations=1, lr=0.01, groups=("body", "cameras"))
    assert problem.held_views(with_cameras) == [0]  # an unmeasured view (NaN) moves
    assert problem.held_views(without) == [] and problem.held_views(unset) == []
    with pytest.raises(ValueError, match="hold_cameras_within_px needs a gradient"):
        make_stage(name="d", iterations=1, lr=1.0, groups=("cameras",), optimizer="lm",
                   hold_cameras_within_px=0.5)


def test_the_default_silhouette_stage_holds_agreeing_cameras():
    stages = validate({}, "stages/fit.schema.yaml")["multiview"]["stages"]
    holding = [s["name"] for s in stages if "hold_cameras_within_px" in s]
    assert holding == ["silhouette"]


def test_the_fit_log_names_held_views_but_never_a_fixed_camera(kpm):
    """Keypoints without error agree in every view; the reference camera is fixed anyway, so
    the log lists the other views only."""
    T, V = 2, 3
    gt = random_motion(T, seed=4)
    rig = synthetic_rig(V, arc=120)
    obs = observe(kpm, gt, rig)
    cfg = validate({"multiview": {"stages": [
        {"name": "root", "iterations": 10, "lr": 0.05, "groups": ["root"], "warm_start": True},
        {"name": "cams", "iterations": 3, "lr": 0.01, "groups": ["root", "cameras"],
         "hold_cameras_within_px": 0.5}]}}, "stages/fit.schema.yaml")
    res = fit_multiview(kpm, obs, np.arange(T), rig.K, rig.width, rig.height, cfg)
    ref = res.log["reference_view"]
    assert max(res.log[f"camera_init_px_view{v}"] for v in range(V)) < 0.5
    assert res.log["cameras_held"]["cams"] == [v for v in range(V) if v != ref]
