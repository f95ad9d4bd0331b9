"""The fit's optical-flow term (signsplat.fit.flow)."""

import json

import cv2
import numpy as np
import pytest
import torch
from fit_scenes import make_stage, observe, random_motion, synthetic_rig, truth_init
from scipy.interpolate import griddata

from signsplat.config import validate
from signsplat.fit import data as fit_data
from signsplat.fit.bodyfit import FitParams
from signsplat.fit.cameras import CameraParams, project
from signsplat.fit.flow import (
    FlowTargets,
    batch_positions,
    bilinear,
    flow_targets,
    flow_term,
    frame_pairs,
    match_flow,
    trusted_flow,
    visible_vertices,
)
from signsplat.fit.silhouette import MatchCache
from signsplat.fit.solver import loss_terms, make_problem, run_stage

#: the flow term's clamp (px): the schema's fit.multiview.flow.clamp_px
CLAMP = validate({}, "stages/fit.schema.yaml")["multiview"]["flow"]["clamp_px"]


def _texture(h=64, w=80, seed=0):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 1.5)
    return cv2.normalize(img, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)


def _shift(img, dx, dy):
    m = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(img, m, img.shape[::-1], flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_REFLECT)


def test_frame_pairs_follow_the_frame_numbers():
    assert frame_pairs(np.array([0, 1, 2, 4, 5]), [1]) == [(0, 1), (1, 2), (3, 4)]
    # gap 1 first, then gap 2 (frames 0 -> 2 and 2 -> 4); 1 -> 3 has no frame 3
    assert frame_pairs(np.array([0, 1, 2, 4, 5]), [2, 1]) == [(0, 1), (1, 2), (3, 4), (0, 2),
                                                             (2, 3)]
    assert frame_pairs(np.array([7]), [1]) == []
    with pytest.raises(ValueError, match="gaps"):
        frame_pairs(np.arange(3), [0])


def test_trusted_flow_measures_a_subpixel_shift_and_drops_the_rest():
    a = _texture()
    b = _shift(a, 1.5, -0.75)
    mask_a = np.zeros(a.shape, bool)
    mask_a[10:54, 10:60] = True
    mask_b = mask_a.copy()
    mask_b[:, 45:] = False  # points that land here left the person: untrusted
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    f = trusted_flow(a, b, mask_a, mask_b, dis, 0.5)
    assert f.shape == (64, 80, 2) and f.dtype == np.float32
    assert np.isnan(f[~mask_a]).all()
    assert np.isnan(f[20:40, 50:58]).all()  # lands at x >= 51.5, outside mask_b
    inner = f[16:48, 16:40]
    assert np.isfinite(inner).mean() > 0.9
    err = np.linalg.norm(inner - np.array([1.5, -0.75], np.float32), axis=-1)
    assert np.nanmedian(err) < 0.1
    # an unrelated second image: the backward flow disagrees almost everywhere
    g = trusted_flow(a, _texture(seed=1), mask_a, mask_a, dis, 0.5)
    assert np.isfinite(g).all(-1).mean() < 0.5 * np.isfinite(f).all(-1).mean()


def test_bilinear_samples_and_propagates_nan():
    f = torch.arange(2 * 2 * 3 * 4, dtype=torch.float32).reshape(2, 2, 3, 4)
    f[1, :, 2, 3] = float("nan")
    pts = torch.tensor([[1.5, 1.0], [0.0, 0.0], [3.0, 2.0], [9.0, 9.0]])
    out = bilinear(f, torch.tensor([0, 1, 0, 1]), pts)
    assert torch.allclose(out[0], torch.tensor([5.5, 17.5]))  # between x = 1 and 2, row 1
    assert torch.allclose(out[1], f[1, :, 0, 0])
    assert torch.allclose(out[2], f[0, :, 2, 3])  # the far corner, exactly
    assert torch.isnan(out[3]).all()  # clamped onto the NaN corner of field 1


def test_visible_vertices_hides_the_farther_point_of_a_cell():
    uv = torch.tensor([[[[10.2, 10.3], [10.9, 10.8], [30.0, 5.0], [-3.0, 4.0], [50.0, 50.0]]]])
    z = torch.tensor([[[2.0, 2.5, 3.0, 2.0, 0.01]]])
    vis = visible_vertices(uv, z, 40, 40)
    # same 2 px cell, 0.5 m behind: hidden; out of the image or behind the near plane: not seen
    assert vis.tolist() == [[[True, False, True, False, False]]]
    assert visible_vertices(uv, z, 40, 40, tolerance_m=1.0)[0, 0, 1]


def _scene(kpm, T=2, V=3, seed=3):
    gt = random_motion(T, seed=seed)
    rig = synthetic_rig(V, arc=120)
    inputs = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in gt.items()
              if k not in ("leye_pose", "reye_pose")}
    with torch.no_grad():
        verts = kpm.model(**inputs).vertices
    K, R, t = (torch.as_tensor(x, dtype=torch.float32) for x in (rig.K, rig.R, rig.t))
    return gt, rig, verts, K, R, t


def _true_flow(verts, K, R, t, W, H, pairs):
    """Flow targets built from the true motion of the visible vertices (nearest vertex)."""
    uv, z = project(verts, K, R, t)
    vis = visible_vertices(uv, z, W, H)
    gy, gx = np.mgrid[0:H, 0:W]
    fields, idx = [], []
    for v in range(K.shape[0]):
        for a, b in pairs:
            m = vis[v, a].numpy()
            p = uv[v, a][m].numpy()
            motion = (uv[v, b] - uv[v, a])[m].numpy()
            f = griddata(p, motion, (gx, gy), method="nearest").astype(np.float32)
            far = griddata(p, np.zeros(len(p)), (gx, gy), method="linear")
            f[np.isnan(far)] = np.nan  # outside the body's projection: untrusted
            fields.append(f.transpose(2, 0, 1))
            idx.append((v, a, b))
    idx = torch.as_tensor(np.array(idx))
    return FlowTargets(torch.as_tensor(np.stack(fields)), idx[:, 0], idx[:, 1], idx[:, 2], W, H)


def test_flow_term_is_lowest_at_the_true_motion_and_pulls_towards_it(kpm):
    _gt, rig, verts, K, R, t = _scene(kpm)
    W, H = int(rig.width[0]), int(rig.height[0])
    targets = _true_flow(verts, K, R, t, W, H, [(0, 1)])
    frames = torch.arange(2)
    at_truth = flow_term(*project(verts, K, R, t), targets, frames, CLAMP)
    shift = torch.zeros(2, 1, 3)
    shift.data[1, 0] = torch.tensor([0.02, -0.015, 0.0])
    shift.requires_grad_(True)
    off = flow_term(*project(verts + shift, K, R, t), targets, frames, CLAMP)
    assert float(at_truth) < 0.1 * K.shape[0]
    assert float(off.detach()) > 20 * float(at_truth) + 1.0
    off.backward()
    # a small step against the gradient brings frame 1 back: it points along the offset
    assert float(shift.grad[1, 0] @ shift.detach()[1, 0]) > 0
    # a batch holding only one frame of the pair has nothing to follow
    one = flow_term(*project(verts[:1], K, R, t), targets, torch.tensor([0]), CLAMP)
    assert float(one) == 0.0


def test_flow_matches_are_kept_until_due_and_stay_finite_in_hard_cases(kpm):
    _gt, rig, verts, K, R, t = _scene(kpm)
    W, H = int(rig.width[0]), int(rig.height[0])
    targets = _true_flow(verts, K, R, t, W, H, [(0, 1)])
    frames = torch.arange(2)
    uv, z = project(verts, K, R, t)
    fresh = match_flow(uv, z, targets, frames)
    assert fresh.count > 1000 and torch.isfinite(fresh.motion).all()
    few = match_flow(uv, z, targets, frames, max_vertices=100)
    per_pair = torch.bincount(few.pair, minlength=targets.num_pairs)
    assert int(per_pair.max()) <= 100 and int(per_pair.min()) >= 50
    assert set(few.vertex.tolist()) <= set(fresh.vertex.tolist())
    cache = MatchCache(every=3)
    flow_term(uv, z, targets, frames, CLAMP, cache=cache)
    first = cache.matches
    flow_term(uv + 1.0, z, targets, frames, CLAMP, cache=cache)
    assert cache.matches is first  # kept: not due
    flow_term(uv, z, targets, frames, CLAMP, cache=cache)
    flow_term(uv, z, targets, frames, CLAMP, cache=cache)
    assert cache.matches is not first  # re-chosen on the 4th call
    # empty frames (all flow untrusted), points behind the camera, NaN projections
    empty = FlowTargets(torch.full_like(targets.flow, float("nan")), targets.view, targets.a,
                        targets.b, W, H)
    assert float(flow_term(uv, z, empty, frames, CLAMP)) == 0.0
    bad_uv = uv.clone()
    bad_uv[:, 1, :100] = float("nan")
    val = flow_term(bad_uv, torch.where(torch.rand_like(z) < 0.1, -z, z), targets, frames,
                    CLAMP)
    assert torch.isfinite(val)


def _matches_of_every_pair_at_once(uv, z, targets, frames, max_vertices):
    """match_flow as one computation over every view's pairs (the reference: the function
    works view by view on the fit's threads)."""
    la, lb = batch_positions(frames, targets.a), batch_positions(frames, targets.b)
    sel = torch.nonzero((la >= 0) & (lb >= 0)).flatten()
    vis = visible_vertices(uv, z, targets.width, targets.height)
    view, a = targets.view[sel], la[sel]
    keep = vis[view, a] & vis[view, lb[sel]]
    step = torch.div(keep.sum(1, keepdim=True) + max_vertices - 1, max_vertices,
                     rounding_mode="floor")
    keep = keep & ((keep.cumsum(1) - 1) % step.clamp(min=1) == 0)
    s_idx, n_idx = torch.nonzero(keep, as_tuple=True)
    f = bilinear(targets.flow, sel[s_idx], uv[view[s_idx], a[s_idx], n_idx])
    ok = torch.isfinite(f).all(-1)
    return sel[s_idx[ok]], n_idx[ok], f[ok]


@pytest.mark.parametrize("threads", [1, 2])
def test_flow_matches_view_by_view_equal_every_pair_at_once(kpm, threads, torch_threads):
    _gt, rig, verts, K, R, t = _scene(kpm, T=3)
    W, H = int(rig.width[0]), int(rig.height[0])
    targets = _true_flow(verts, K, R, t, W, H, [(0, 1), (1, 2), (0, 2)])
    uv, z = project(verts, K, R, t)
    frames = torch.arange(3)
    torch_threads(threads)
    got = match_flow(uv, z, targets, frames, max_vertices=150)
    pair, vertex, motion = _matches_of_every_pair_at_once(uv, z, targets, frames, 150)
    assert got.count > 1000 and len(set(got.pair.tolist())) == 9
    assert torch.equal(got.pair, pair) and torch.equal(got.vertex, vertex)
    assert torch.equal(got.motion, motion)


def test_stage_chooses_the_flow_vertices_every_flow_rematch_every_steps(kpm, monkeypatch):
    import signsplat.fit.flow as flow_module

    gt, rig, verts, K, R, t = _scene(kpm, seed=4)
    W, H = int(rig.width[0]), int(rig.height[0])
    targets = _true_flow(verts, K, R, t, W, H, [(0, 1)])
    calls = []
    real = flow_module.match_flow
    monkeypatch.setattr(flow_module, "match_flow",
                        lambda *a, **k: calls.append(1) or real(*a, **k))
    init = truth_init(gt)
    problem = make_problem(kpm, observe(kpm, gt, rig), validate({}, "stages/fit.schema.yaml"),
                           np.arange(2), flow=targets)
    for every, want in ((None, 7), (3, 3)):
        calls.clear()
        extra = {} if every is None else {"flow_rematch_every": every}
        stage = make_stage(name="flow", iterations=7, lr=0.001, groups=("root",), smooth=False,
                           flow=10.0, rematch_every=1, **extra)
        run_stage(problem, FitParams(2, 10, 10, init=init), CameraParams(rig, fixed=[0, 1, 2]),
                  stage)
        assert len(calls) == want, (every, len(calls))  # steps 0, 3 and 6 with every 3


def test_flow_targets_from_images_of_a_moving_texture():
    a = _texture(64, 64)
    imgs = np.stack([a, _shift(a, 1.0, 0.0), _shift(a, 2.0, 0.0)])[None]  # (1,3,H,W)
    masks = np.zeros(imgs.shape, bool)
    masks[..., 8:56, 8:56] = True
    masks[0, 2] = False  # an empty frame: its pairs are left out
    tg = flow_targets(imgs, masks, np.array([0, 1, 2]), gaps=(1, 2), consistency_px=0.5,
                      preset="medium")
    assert tg.num_pairs == 1 and (int(tg.a[0]), int(tg.b[0])) == (0, 1)
    f = tg.flow[0, :, 20:40, 20:40]
    assert float(torch.nanmedian((f[0] - 1.0).abs())) < 0.1
    with pytest.raises(ValueError, match="preset"):
        flow_targets(imgs, masks, np.arange(3), (1,), 0.5, preset="slow")
    with pytest.raises(ValueError, match="views, frames"):
        flow_targets(imgs[0], masks[0], np.arange(3), (1,), 0.5, "medium")


def test_flow_stage_fixes_the_motion_between_frames_without_keypoints(kpm):
    """Keypoints weighted 0: the flow term alone brings frame 1's offset relative to frame 0
    down (it cannot see where both frames are, only how the body moved between them)."""
    gt, rig, verts, K, R, t = _scene(kpm, seed=4)
    W, H = int(rig.width[0]), int(rig.height[0])
    targets = _true_flow(verts, K, R, t, W, H, [(0, 1)])
    init = truth_init(gt)
    init["transl"] = gt["transl"] + np.array([[0.0, 0.0, 0.0], [0.02, -0.015, 0.01]])
    params = FitParams(2, 10, 10, init=init)
    cams = CameraParams(rig, fixed=list(range(3)))
    cfg = validate({}, "stages/fit.schema.yaml")
    problem = make_problem(kpm, observe(kpm, gt, rig), cfg, np.arange(2), flow=targets)
    off = {"body": 0, "feet": 0, "face": 0, "left_hand": 0, "right_hand": 0}
    stage = make_stage(name="flow", iterations=60, lr=0.002, groups=("root",), parts=off,
                       smooth=False, flow=10.0, rematch_every=5)

    def rel(p):
        return np.linalg.norm(np.diff(p, axis=0) - np.diff(gt["transl"], axis=0))

    before = rel(init["transl"])
    run_stage(problem, params, cams, stage)
    assert rel(params.transl.detach().numpy()) < 0.3 * before
    terms = loss_terms(problem, params, cams, stage)
    assert "flow" in terms and float(terms["data"].detach()) == 0.0


def test_flow_stage_rules(kpm):
    with pytest.raises(ValueError, match="not lm"):
        make_stage(name="j", iterations=1, lr=1.0, groups=("root",), optimizer="lm", flow=1.0)
    assert not make_stage(name="z", iterations=1, lr=0.1, groups=("root",)).uses_flow
    assert make_stage(name="f", iterations=1, lr=0.1, groups=["root"], flow=5).flow == 5.0
    gt = random_motion(2, seed=6)
    rig = synthetic_rig(2)
    problem = make_problem(kpm, observe(kpm, gt, rig), validate({}, "stages/fit.schema.yaml"))
    stage = make_stage(name="needs_images", iterations=1, lr=0.1, groups=("root",), flow=1.0)
    with pytest.raises(ValueError, match="needs_images.*no images"):
        loss_terms(problem, FitParams(2, 10, 10), CameraParams(rig), stage)


def test_read_grey_images(tmp_path):
    from signsplat.errors import InputError
    from signsplat.io.images import write_png

    rgb = np.zeros((16, 24, 3), np.uint8)
    rgb[..., 1] = 200
    write_png(tmp_path / "a.png", rgb)
    write_png(tmp_path / "small.png", rgb[:8])
    import pandas as pd

    df = pd.DataFrame({"view": [0, 1], "frame": [3, 9], "image_path": [str(tmp_path / "a.png")] * 2})
    out = fit_data.read_grey_images(df, np.array([3, 4]), [24, 24], [16, 16], "frames.parquet")
    assert out.shape == (2, 2, 16, 24) and out.dtype == np.uint8
    assert abs(int(out[0, 0, 0, 0]) - round(0.587 * 200)) <= 1 and out[1].max() == 0
    bad = df.assign(image_path=[str(tmp_path / "small.png")] * 2)
    with pytest.raises(InputError, match="small.png"):
        fit_data.read_grey_images(bad, np.array([3]), [24, 24], [16, 16], "frames.parquet")


def test_cli_reads_images_only_for_a_flow_stage(tmp_path, kpm, proxy_body_path, capsys):
    """A flow stage needs --frames (error names the stage and the flag); the fit then runs."""
    from test_fit import FAST_MV, _write_inputs

    from signsplat.cli import main

    d = _write_inputs(tmp_path, kpm)
    masks = tmp_path / "masks.parquet"
    import pandas as pd

    m = np.zeros((256, 256), np.uint8)
    m[40:220, 60:200] = 255
    (tmp_path / "m").mkdir()
    cv2.imwrite(str(tmp_path / "m/p.png"), m)
    pd.DataFrame({"view": [0, 0, 0, 1, 1, 1], "frame": [0, 1, 2] * 2,
                  "mask": ["m/p.png"] * 6}).to_parquet(masks)
    cfg = json.loads(json.dumps(FAST_MV))
    for st in cfg["multiview"]["stages"]:
        st["iterations"] = 3
    cfg["multiview"]["stages"].append({"name": "fl", "iterations": 2, "lr": 0.001,
                                       "groups": ["root"], "flow": 10})
    args = ["fit", "--keypoints", str(d / "kp.parquet"), "--calibration",
            str(d / "cameras.parquet"), "--body", str(proxy_body_path), "--masks", str(masks),
            "--config-json", json.dumps(cfg)]
    assert main(args + ["--out-dir", str(tmp_path / "a")]) == 2
    err = capsys.readouterr().err
    assert "['fl']" in err and "--frames" in err
    assert main(args + ["--frames", str(d / "frames.parquet"), "--out-dir",
                        str(tmp_path / "b")]) == 0
    assert (tmp_path / "b" / "smplx_fit.parquet").is_file()


def test_single_view_fit_refuses_the_multi_view_terms(tmp_path, kpm, proxy_body_path, capsys):
    from test_fit import _write_inputs

    from signsplat.cli import main

    d = _write_inputs(tmp_path, kpm)
    cfg = {"singleview": {"refine_stages": [{"name": "fl", "iterations": 1, "lr": 0.001,
                                             "groups": ["root"], "flow": 1}]}}
    args = ["fit", "--keypoints", str(d / "kp.parquet"), "--calibration",
            str(d / "cameras.parquet"), "--frames", str(d / "frames.parquet"), "--body",
            str(proxy_body_path), "--view", "0", "--config-json", json.dumps(cfg),
            "--out-dir", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "fit.singleview" in err and "['fl']" in err and "multi-view" in err
    assert not (tmp_path / "o" / "smplx_fit.parquet").exists()
