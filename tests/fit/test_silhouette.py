"""The mask (silhouette) terms of the multi-view fit: targets, gradients, hard cases, wiring."""

import json

import cv2
import numpy as np
import pandas as pd
import pytest
import torch
from fit_scenes import (make_stage, mesh_vertices, observe, random_motion, render_masks,
                         synthetic_rig, truth_init)

from signsplat.config import validate
from signsplat.errors import InputError
from signsplat.fit import data as fit_data
from signsplat.fit.bodyfit import FitParams
from signsplat.fit.cameras import CameraParams, project
from signsplat.fit.silhouette import (
    MatchCache,
    _outside_rows,
    mask_contour,
    silhouette_terms,
    targets_from_masks,
)
from signsplat.fit.solver import Stage, loss_terms, make_problem, run_stage, stage_config


def _t(a):
    return torch.as_tensor(np.asarray(a), dtype=torch.float32)


def test_contour_and_targets():
    m = np.zeros((2, 1, 32, 40), bool)
    m[0, 0, 8:20, 10:30] = True  # a rectangle inside the image
    m[1, 0, 20:, 5:15] = False
    m[1, 0, 20:32, 5:15] = True  # touches the bottom border
    c = mask_contour(m[0, 0], 1000)
    # the rectangle's outline: one point on each pixel edge between inside and outside
    assert len(c) == 2 * 20 + 2 * 12
    assert ((c[:, 0] == 9.5) | (c[:, 0] == 29.5) | (c[:, 1] == 7.5) | (c[:, 1] == 19.5)).all()
    c1 = mask_contour(m[1, 0], 1000)
    assert (c1[:, 1] < 31).all()  # the image border is not silhouette
    assert len(mask_contour(m[0, 0], 10)) == 10
    tg = targets_from_masks(m)
    assert tg.valid.tolist() == [[True], [True]]
    assert float(tg.outside[0, 0, 10, 15]) < 0  # inside
    assert abs(float(tg.outside[0, 0, 8, 5]) - 4.5) < 0.1  # 4.5 px left of the outline
    assert float(tg.outside[0, 0, 8, 10]) == -0.5 and float(tg.outside[0, 0, 8, 9]) == 0.5
    empty = targets_from_masks(np.zeros((1, 2, 8, 8), bool))
    assert not empty.valid.any() and all(len(c) == 0 for c in empty.contours)
    with pytest.raises(ValueError, match="views, frames"):
        targets_from_masks(np.zeros((8, 8), bool))


def test_outside_maps_of_a_batch_are_its_views_and_frames():
    """(view, frame) rows of the outside-distance maps, view-major like the projections; the
    whole sequence in order is the maps themselves (no copy)."""
    m = np.zeros((2, 3, 16, 16), bool)
    for v in range(2):
        for f in range(3):
            m[v, f, 2 + 3 * f:8 + 3 * f, 2 + 5 * v:8 + 5 * v] = True
    tg = targets_from_masks(m)
    whole = _outside_rows(tg, torch.arange(3))
    assert whole.data_ptr() == tg.outside.data_ptr()
    some = _outside_rows(tg, torch.tensor([2, 0]))
    want = torch.stack([tg.outside[v * 3 + f] for v in range(2) for f in (2, 0)])
    assert torch.equal(some, want) and not torch.equal(some, tg.outside[:4])


def _three_view_scene(kpm):
    """Two frames of a known motion seen by three cameras: targets from rendered masks."""
    T, V = 2, 3
    gt = random_motion(T, seed=3)
    rig = synthetic_rig(V, arc=120)
    tg = targets_from_masks(render_masks(kpm, gt, rig))
    return mesh_vertices(kpm, gt), _t(rig.K), _t(rig.R), _t(rig.t), tg, torch.arange(T), V


def test_terms_are_lowest_at_the_truth_and_pull_towards_it(kpm):
    verts, K, R, t, tg, frames, V = _three_view_scene(kpm)
    inside0, cover0 = silhouette_terms(verts, kpm.model.faces, K, R, t, tg, frames)
    shift = torch.tensor([0.03, -0.02, 0.0], requires_grad=True)
    inside, cover = silhouette_terms(verts + shift, kpm.model.faces, K, R, t, tg, frames)
    # at the truth: contour pixels ~1 px from the nearest outline vertex (the mesh spacing)
    assert float(inside0) < 0.05 and float(cover0) < 2.0 * V
    assert float(inside.detach()) > max(1.0, 100 * float(inside0))
    assert float(cover.detach()) > 5 * float(cover0)
    (inside + cover).backward()
    # the gradient points away from the truth: a small step against it reduces the shift
    assert float(shift.grad @ shift.detach()) > 0


@pytest.mark.parametrize("batch", [[0, 1], [1]], ids=["sequence", "second_frame"])
def test_inside_term_is_the_mean_over_every_vertex_in_the_image(kpm, batch):
    """The inside term samples again, with gradient, only the vertices outside the outline;
    its value and gradients (vertices, cameras) are those of the plain mean over every vertex
    in the image, the vertices inside clamped to 0. Frame 1 of view 2 has an empty mask: it
    counts nothing."""
    verts, K, R, t, tg, _, V = _three_view_scene(kpm)
    tg.valid[2, 1] = False
    tg.outside[2 * 2 + 1] = 50.0  # far outside everywhere: only the validity keeps it out
    frames = torch.tensor(batch)
    moved = verts[frames] + torch.tensor([0.03, -0.02, 0.01])
    leaves = [x.clone().requires_grad_(True) for x in (moved, R, t)]
    inside, _ = silhouette_terms(leaves[0], kpm.model.faces, K, leaves[1], leaves[2], tg, frames)
    grads = torch.autograd.grad(inside, leaves)

    ref_leaves = [x.clone().requires_grad_(True) for x in (moved, R, t)]
    uv, z = project(ref_leaves[0], K, ref_leaves[1], ref_leaves[2])
    H, W = tg.height, tg.width
    B = len(frames)
    grid = (uv / uv.new_tensor([W - 1, H - 1]) * 2 - 1).reshape(V * B, 1, -1, 2)
    d = torch.nn.functional.grid_sample(_outside_rows(tg, frames), grid, align_corners=True,
                                        padding_mode="border").reshape(V, B, -1)
    w = ((z > 0.05) & (uv[..., 0] > 1) & (uv[..., 0] < W - 2) & (uv[..., 1] > 1)
         & (uv[..., 1] < H - 2) & tg.valid[:, frames][..., None]).float()
    ref = ((d.clamp(0, 10) ** 2 * w).sum(-1) / w.sum(-1).clamp(min=1)).sum() / B
    ref_grads = torch.autograd.grad(ref, ref_leaves)
    assert float(ref.detach()) > 1.0  # the moved body is partly outside
    assert float(inside.detach()) == pytest.approx(float(ref.detach()), rel=1e-5)
    for g, r in zip(grads, ref_grads):
        assert torch.allclose(g, r, rtol=1e-4, atol=1e-6 * float(r.abs().max()))


def test_the_outline_is_not_pulled_inwards(kpm):
    """Both terms are lowest for the true body, not for one half a pixel thinner: masks mark
    the pixels whose centre the person covers, so the outline lies half a pixel outside the
    outermost mask pixels' centres. (Measured from those centres, the terms preferred a body
    about 2 % smaller in these 96-pixel images.)"""
    T, V = 1, 3
    gt = random_motion(T, seed=3)
    rig = synthetic_rig(V, arc=120, size=96)
    tg = targets_from_masks(render_masks(kpm, gt, rig, supersample=4))
    verts = mesh_vertices(kpm, gt)
    centre = verts.mean(1, keepdim=True)
    K, R, t = _t(rig.K), _t(rig.R), _t(rig.t)
    scales = [0.97, 0.98, 0.99, 1.0, 1.01, 1.02]
    totals = []
    for s in scales:
        inside, cover = silhouette_terms(centre + s * (verts - centre), kpm.model.faces, K, R, t,
                                         tg, torch.arange(T))
        totals.append(float(inside) + float(cover))
    assert scales[int(np.argmin(totals))] == 1.0, dict(zip(scales, totals))


def test_match_cache_reuses_matches_until_it_is_due(kpm):
    verts, K, R, t, tg, frames, _ = _three_view_scene(kpm)
    faces = kpm.model.faces
    moved = verts + torch.tensor([0.03, -0.02, 0.0])
    cache = MatchCache(every=2)
    first = silhouette_terms(verts, faces, K, R, t, tg, frames, cache=cache)
    assert [float(a) for a in first] == [float(a) for a in
                                         silhouette_terms(verts, faces, K, R, t, tg, frames)]
    kept = cache.matches
    # second call: the matches of the truth are kept for the moved body
    _, cover_kept = silhouette_terms(moved, faces, K, R, t, tg, frames, cache=cache)
    assert cache.matches is kept
    _, cover_fresh = silhouette_terms(moved, faces, K, R, t, tg, frames)
    assert float(cover_kept) != float(cover_fresh)
    # third call: due, re-matched - the same as a fresh matching
    _, cover_third = silhouette_terms(moved, faces, K, R, t, tg, frames, cache=cache)
    assert cache.matches is not kept and float(cover_third) == float(cover_fresh)
    # other frames are re-matched at once
    kept = cache.matches
    silhouette_terms(moved[:1], faces, K, R, t, tg, frames[:1], cache=cache)
    assert cache.matches is not kept and cache.matches.frames.tolist() == [0]


def test_hard_cases_stay_finite(kpm):
    """Empty masks (no person), vertices behind the camera, a degenerate (zero-area) mesh."""
    T, V = 2, 2
    gt = random_motion(T, seed=4)
    rig = synthetic_rig(V, arc=90)
    masks = render_masks(kpm, gt, rig)
    masks[:, 1] = False  # frame 1: nobody in any view
    tg = targets_from_masks(masks)
    verts = mesh_vertices(kpm, gt).clone()
    K, R, t = _t(rig.K), _t(rig.R), _t(rig.t)
    cases = {"behind": verts - 10.0 * R[0, 2],  # pushed behind camera 0
             "collapsed": torch.zeros_like(verts) + verts[:, :1]}  # every vertex in one point
    for name, x in cases.items():
        x = x.clone().requires_grad_(True)
        inside, cover = silhouette_terms(x, kpm.model.faces, K, R, t, tg, torch.arange(T))
        (inside + cover).backward()
        assert torch.isfinite(inside) and torch.isfinite(cover), name
        assert torch.isfinite(x.grad).all(), name
        assert float(x.grad[1].abs().sum()) == 0.0, name  # the empty frame pulls nothing
    nothing = targets_from_masks(np.zeros((V, T, 256, 256), bool))
    inside, cover = silhouette_terms(verts, kpm.model.faces, K, R, t, nothing, torch.arange(T))
    assert float(inside) == 0.0 and float(cover) == 0.0


@pytest.mark.parametrize("solver", [
    {"optimizer": "adam", "iterations": 60, "lr": 0.002},
    {"optimizer": "adam", "iterations": 60, "lr": 0.002, "rematch_every": 5},
    {"optimizer": "lbfgs", "iterations": 15, "lr": 1.0},
], ids=["adam", "adam_rematch5", "lbfgs"])
def test_silhouette_stage_recovers_an_offset_without_keypoints(kpm, solver):
    """Keypoints weighted 0: the masks alone move a body started 3 cm off back towards the
    truth (a sign or projection error would push it away), with every optimizer the terms
    allow."""
    T, V = 2, 3
    gt = random_motion(T, seed=5)
    rig = synthetic_rig(V, arc=120)
    masks = render_masks(kpm, gt, rig)
    obs = observe(kpm, gt, rig)
    init = truth_init(gt)
    init["transl"] = gt["transl"] + np.array([0.03, 0.02, -0.02])
    params = FitParams(T, 10, 10, init=init)
    cams = CameraParams(rig, fixed=list(range(V)))
    cfg = validate({}, "stages/fit.schema.yaml")
    problem = make_problem(kpm, obs, cfg, np.arange(T), masks=masks)
    off = {"body": 0, "feet": 0, "face": 0, "left_hand": 0, "right_hand": 0}
    stage = make_stage(name="sil", groups=("root",), parts=off,
                       silhouette={"inside": 100.0, "cover": 100.0}, **solver)
    before = np.linalg.norm(init["transl"] - gt["transl"], axis=1).mean()
    run_stage(problem, params, cams, stage)
    after = np.linalg.norm(params.transl.detach().numpy() - gt["transl"], axis=1).mean()
    assert after < 0.4 * before
    terms = loss_terms(problem, params, cams, stage)
    assert {"silhouette_inside", "silhouette_cover"} <= set(terms)
    assert float(terms["data"].detach()) == 0.0


def test_stage_rules_and_missing_masks(kpm):
    with pytest.raises(ValueError, match="not lm"):
        make_stage(name="j", iterations=1, lr=1.0, groups=("root",), optimizer="lm",
                   silhouette={"cover": 1.0})
    with pytest.raises(ValueError, match="unknown silhouette term"):  # past the schema
        Stage.from_config({**stage_config(name="s", iterations=1, lr=0.1, groups=["root"]),
                           "silhouette": {"outline": 1.0}})
    assert not make_stage(name="z", iterations=1, lr=0.1, groups=("root",),
                          silhouette={"inside": 0.0}).uses_silhouette
    T, V = 2, 2
    gt = random_motion(T, seed=6)
    rig = synthetic_rig(V)
    problem = make_problem(kpm, observe(kpm, gt, rig), validate({}, "stages/fit.schema.yaml"))
    params = FitParams(T, 10, 10)
    stage = make_stage(name="needs_masks", iterations=1, lr=0.1, groups=("root",),
                       silhouette={"inside": 1.0})
    with pytest.raises(ValueError, match="needs_masks.*no person masks"):
        loss_terms(problem, params, CameraParams(rig), stage)


def test_read_masks(tmp_path):
    (tmp_path / "m").mkdir()
    m = np.zeros((16, 24), np.uint8)
    m[4:8, 5:9] = 255
    cv2.imwrite(str(tmp_path / "m/a.png"), m)
    cv2.imwrite(str(tmp_path / "m/small.png"), m[:8])
    pd.DataFrame({"view": [0, 1, 1], "frame": [3, 4, 9], "mask": ["m/a.png", "m/a.png", ""]}
                 ).to_parquet(tmp_path / "masks.parquet")
    out = fit_data.read_masks(tmp_path / "masks.parquet", np.array([3, 4, 5]), [24, 24], [16, 16])
    assert out.shape == (2, 3, 16, 24)
    assert out[0, 0].sum() == 16 and out[1, 1].sum() == 16
    assert out[0, 1:].sum() == 0 and out[1, 0].sum() == 0 and out[:, 2].sum() == 0
    pd.DataFrame({"view": [0], "frame": [3], "mask": ["m/small.png"]}).to_parquet(
        tmp_path / "bad.parquet")
    with pytest.raises(InputError, match="small.png"):
        fit_data.read_masks(tmp_path / "bad.parquet", np.array([3]), [24], [16])
    pd.DataFrame({"view": [2], "frame": [3], "mask": ["m/a.png"]}).to_parquet(
        tmp_path / "view.parquet")
    with pytest.raises(InputError, match="view 2"):
        fit_data.read_masks(tmp_path / "view.parquet", np.array([3]), [24, 24], [16, 16])
    with pytest.raises(InputError, match="nothere.parquet"):
        fit_data.read_masks(tmp_path / "nothere.parquet", np.array([3]), [24], [16])


def test_cli_reads_masks_only_for_a_silhouette_stage(tmp_path, kpm, proxy_body_path, capsys):
    """Without silhouette weights the masks file is never opened (a missing one is fine); with
    them, a missing file is an error naming it."""
    from test_fit import FAST_MV, _write_inputs

    from signsplat.cli import main

    d = _write_inputs(tmp_path, kpm)
    cfg = json.loads(json.dumps(FAST_MV))
    for st in cfg["multiview"]["stages"]:
        st["iterations"] = 5
    args = ["fit", "--keypoints", str(d / "kp.parquet"), "--calibration",
            str(d / "cameras.parquet"), "--frames", str(d / "frames.parquet"), "--body",
            str(proxy_body_path), "--masks", str(tmp_path / "missing_masks.parquet")]
    assert main(args + ["--config-json", json.dumps(cfg), "--out-dir", str(tmp_path / "a")]) == 0
    cfg["multiview"]["stages"].append({"name": "sil", "iterations": 2, "lr": 0.001,
                                       "groups": ["root"], "silhouette": {"cover": 10}})
    assert main(args + ["--config-json", json.dumps(cfg), "--out-dir", str(tmp_path / "b")]) == 2
    assert "missing_masks.parquet" in capsys.readouterr().err
    no_masks = [a for a in args if a not in ("--masks", str(tmp_path / "missing_masks.parquet"))]
    assert main(no_masks + ["--config-json", json.dumps(cfg), "--out-dir",
                            str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "['sil']" in err and "--masks" in err


def test_outline_points_between_vertices_are_on_the_contour(kpm):
    """At the true body the outline points lie on the body's contour up to the pixel grid, also
    where they fall between two of its vertices: matched to the contour's edges, not to the
    nearest vertex (which sits up to half an edge away)."""
    T, V = 2, 3
    gt = random_motion(T, seed=5)
    rig = synthetic_rig(V, arc=120, size=128)
    verts = mesh_vertices(kpm, gt)
    faces = kpm.model.faces
    tg = targets_from_masks(render_masks(kpm, gt, rig))
    _, cover = silhouette_terms(verts, faces, _t(rig.K), _t(rig.R), _t(rig.t), tg,
                                torch.arange(T))
    per_point = float(cover) / V  # cover sums the views and averages the frames
    # an outline point is at most half a pixel from the contour along one axis
    assert per_point < 0.12, per_point
