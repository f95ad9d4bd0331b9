"""The shipped default models (models/*.onnx) on held-out synthetic scenes against the issue-4
targets (mask IoU >= 0.97, body PCK@0.05 >= 0.95, hands PCK@0.05 >= 0.85), and hard cases:
no person, an occluded hand, a hand outside the image."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import onnx
import pytest

from signsplat.body.joints import KP_BODY, KP_LEFT_HAND
from signsplat.perception.cli import perception_config, specs
from signsplat.perception.contracts import load_keypointer, load_segmenter
from signsplat.perception.evaluate import mask_iou
from signsplat.io.images import read_mask, read_rgb
from signsplat.perception.keypoints import box_from_mask, detect_batch
from signsplat.perception.segment import mask_stats, segment_batch

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parent / "data"
FRAMES = ["single_v00_f0040", "studio6_v01_f0030"]
BODY, LEFT_HAND = list(KP_BODY), list(KP_LEFT_HAND)


@pytest.fixture(scope="module")
def held_out(tmp_path_factory, shipped, proxy_body_path, gloss_library_path):
    """Accuracy rows of both stages on freshly simulated evaluation scenes (config/scenes:
    'single' 40 frames, 'studio6' its whole 60 frames x 6 views, as the workflow evaluates it:
    its first frames are the hardest for the right hand, 0.79 over the first 8 against 0.87 over
    all 60), which training never sees."""
    import pandas as pd

    from signsplat.config import load_scene, validate
    from signsplat.perception.evaluate import accuracy
    from signsplat.perception.stages import detect_sequence, segment_sequence
    from signsplat.synth.simulate import simulate_scene

    seg, _, kp, _ = shipped
    root = tmp_path_factory.mktemp("held_out")
    body, glosses = proxy_body_path, gloss_library_path
    rows = []
    for name, frames in (("single", 40), ("studio6", 60)):
        spec = load_scene(ROOT / "config" / "scenes" / f"{name}.yaml")
        spec.update(name=name, max_frames=frames)
        spec = validate(spec, "scene.schema.yaml", name)
        sim, out = root / name / "sim", root / name / "perception"
        simulate_scene(spec, body, glosses, sim, threads=2, progress=False)
        segment_sequence(sim / "frames.parquet", out, seg, 2, progress=False)
        detect_sequence(sim / "frames.parquet", out / "masks.parquet", out / "keypoints.parquet",
                        kp, 2, progress=False)
        rows.append(accuracy(sim, out))
    df = pd.concat(rows, ignore_index=True)
    return {(r["scene"], r["metric"], r["part"]): r["value"] for _, r in df.iterrows()}


@pytest.fixture(scope="module")
def shipped():
    seg, kp = specs(perception_config(None))
    seg = type(seg)(**{**seg.__dict__, "path": str(ROOT / seg.path)})
    kp = type(kp)(**{**kp.__dict__, "path": str(ROOT / kp.path)})
    return seg, load_segmenter(seg, 2), kp, load_keypointer(kp, 2)


def _frame(name):
    gt = np.load(DATA / f"{name}_gt.npz")
    return read_rgb(DATA / f"{name}.png"), read_mask(DATA / f"{name}_mask.png"), gt["xy"], gt["visible"]


@pytest.mark.parametrize("name", ["segmenter.onnx", "keypoints.onnx", "keypoints_wide.onnx"])
def test_shipped_files_size_opset_dynamic_batch(name):
    path = ROOT / "models" / name
    assert path.stat().st_size <= 10 * 2**20
    model = onnx.load(str(path))
    assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) >= 17
    batch = model.graph.input[0].type.tensor_type.shape.dim[0]
    assert batch.dim_param and not batch.dim_value  # symbolic batch axis


@pytest.mark.parametrize("name", FRAMES)
def test_accuracy_on_held_out_frames(shipped, name):
    seg, smodel, kp, kmodel = shipped
    img, gt_mask, gt_xy, vis = _frame(name)
    (alpha,) = segment_batch(smodel, seg, [img])
    st = mask_stats(alpha, seg.threshold)
    assert mask_iou(st["mask"], gt_mask) > 0.93
    xy, score = detect_batch(kmodel, kp, [img], [st["box"]])
    box = box_from_mask(gt_mask)
    thr = 0.05 * max(box[2] - box[0], box[3] - box[1])
    err = np.linalg.norm(xy[0] - gt_xy, axis=1)
    body = [k for k in BODY if vis[k]]
    assert np.mean(np.nan_to_num(err[body], nan=np.inf) <= thr) >= 0.8
    assert np.all((score >= 0) & (score <= 1))


def _case(scene, metric, part, target):
    return pytest.param(scene, metric, part, target, id=f"{scene}-{metric}-{part}")


TARGETS = [
    _case("single", "pck@0.05", "left_hand", 0.85),
    _case("single", "mask_iou", "all", 0.97),
    _case("studio6", "mask_iou", "all", 0.97),
    _case("single", "pck@0.05", "body", 0.95),
    _case("studio6", "pck@0.05", "body", 0.95),
    _case("studio6", "pck@0.05", "left_hand", 0.85),
    _case("single", "pck@0.05", "right_hand", 0.85),
    _case("studio6", "pck@0.05", "right_hand", 0.85),
]


@pytest.mark.parametrize("scene,metric,part,target", TARGETS)
def test_held_out_scenes_against_the_issue_targets(held_out, scene, metric, part, target):
    assert held_out[(scene, metric, part)] >= target


def test_held_out_levels_the_shipped_models_reach(held_out):
    """Beyond the issue's bars: the face and the mean pixel errors of the shipped models (the
    models before the retrain had face PCK 0.95 and body / left-hand errors of 7 px on
    'studio6'; the first ones IoU 0.93, body PCK 0.40 and hands near 0 on 'single')."""
    for scene in ("single", "studio6"):
        assert held_out[(scene, "pck@0.05", "face")] >= 0.98
        assert held_out[(scene, "mean_px_error", "face")] < 4.0
        assert held_out[(scene, "mean_px_error", "body")] < 5.0
        assert held_out[(scene, "mean_px_error", "left_hand")] < 4.0
        assert held_out[(scene, "mean_px_error", "right_hand")] < 9.0


def test_held_out_masks_hold_the_true_area(held_out):
    """At the configured threshold the shipped segmenter's masks hold as many pixels as the
    simulator's, within 1 % (an outline half a pixel out biases the fit's mask terms; at the
    old threshold 0.5 they held 1.1-1.5 % more: models/README.md)."""
    for scene in ("single", "studio6"):
        assert abs(held_out[(scene, "mask_area_bias", "all")]) < 0.01


def test_no_person_gives_empty_mask_and_zero_scores(shipped):
    seg, smodel, kp, kmodel = shipped
    grey = np.full((256, 256, 3), 200, np.uint8)
    img, gt_mask, _, _ = _frame("single_v00_f0040")
    strip = img[:, :40][:, ~gt_mask[:, :40].any(0)]  # person-free columns of a textured frame
    textured = np.ascontiguousarray(np.tile(strip, (1, 256 // strip.shape[1] + 1, 1))[:, :256])
    for frame in (grey, textured):
        (alpha,) = segment_batch(smodel, seg, [frame])
        st = mask_stats(alpha, seg.threshold)
        assert st["area"] < kp.min_area
    xy, score = detect_batch(kmodel, kp, [grey], [None])
    assert np.all(score == 0) and np.all(np.isnan(xy))


@pytest.fixture(scope="module")
def wide(shipped):
    """The `wide` detectors' keypoint model (the shipped one adapted to other rigs)."""
    kp = shipped[2]
    kp = dataclasses.replace(kp, path=str(ROOT / "models" / "keypoints_wide.onnx"))
    return kp, load_keypointer(kp, 2)


def test_the_keypoint_graphs_stay_finite_on_noise(shipped, wide):
    """A noise crop drives some heatmaps far below zero; the graphs' outputs stay finite
    (the shipped file exported before the peak finder was made stable returned a NaN row)."""
    x = np.random.default_rng(0).normal(size=(2, 3, 256, 192)).astype(np.float32)
    for kmodel in (shipped[3], wide[1]):
        for out in kmodel.run(x):
            assert np.isfinite(out).all()


def test_the_wide_keypoint_model_on_held_out_frames(shipped, wide):
    """The adapted model still finds the body on the studio framing it started from."""
    seg, smodel, _, _ = shipped
    kp, kmodel = wide
    for name in FRAMES:
        img, gt_mask, gt_xy, vis = _frame(name)
        (alpha,) = segment_batch(smodel, seg, [img])
        xy, score = detect_batch(kmodel, kp, [img], [mask_stats(alpha, seg.threshold)["box"]])
        box = box_from_mask(gt_mask)
        err = np.linalg.norm(xy[0] - gt_xy, axis=1)
        body = [k for k in BODY if vis[k]]
        thr = 0.05 * max(box[2] - box[0], box[3] - box[1])
        assert np.mean(np.nan_to_num(err[body], nan=np.inf) <= thr) >= 0.8, name
        assert np.all((score >= 0) & (score <= 1))


def test_occluded_hand_gets_low_scores_not_confident_garbage(shipped):
    seg, smodel, kp, kmodel = shipped
    img, gt_mask, gt_xy, vis = _frame("single_v00_f0040")
    box = box_from_mask(gt_mask)
    xy, clean = detect_batch(kmodel, kp, [img], [box])
    hand = gt_xy[LEFT_HAND]
    assert vis[LEFT_HAND].mean() > 0.5
    x0, y0 = np.floor(hand.min(0) - 6).astype(int)
    x1, y1 = np.ceil(hand.max(0) + 6).astype(int)
    occluded = img.copy()
    occluded[max(y0, 0):y1, max(x0, 0):x1] = (90, 60, 40)  # a brown box over the hand
    _, score = detect_batch(kmodel, kp, [occluded], [box])
    assert clean[0, LEFT_HAND].mean() > 0.4
    assert score[0, LEFT_HAND].mean() < 0.5 * clean[0, LEFT_HAND].mean()
    assert score[0, LEFT_HAND].mean() < 0.3
    assert score[0, BODY].mean() > 0.5 * clean[0, BODY].mean()


def test_hand_outside_the_image(shipped):
    seg, smodel, kp, kmodel = shipped
    img, gt_mask, gt_xy, vis = _frame("single_v00_f0040")
    shift = int(256 - gt_xy[LEFT_HAND, 0].min() + 4)  # the left hand leaves on the right
    moved = np.concatenate([np.repeat(img[:, :1], shift, 1), img[:, :256 - shift]], 1)
    moved_mask = np.concatenate([np.zeros((256, shift), bool), gt_mask[:, :256 - shift]], 1)
    (alpha,) = segment_batch(smodel, seg, [np.ascontiguousarray(moved)])
    st = mask_stats(alpha, seg.threshold)
    assert mask_iou(st["mask"], moved_mask) > 0.85
    xy, score = detect_batch(kmodel, kp, [np.ascontiguousarray(moved)], [st["box"]])
    assert np.all(np.isfinite(xy[0][score[0] > 0]))
    assert score[0, LEFT_HAND].mean() < 0.3  # nothing to see there
    body_in = [k for k in BODY if vis[k] and gt_xy[k, 0] + shift < 250]
    err = np.linalg.norm(xy[0, body_in] - (gt_xy[body_in] + [shift, 0]), axis=1)
    assert np.median(np.nan_to_num(err, nan=np.inf)) < 15
