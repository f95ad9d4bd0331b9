"""The keypoint model's body with MediaPipe's hands (perception.keypoints.hands: mediapipe):
which hands are taken, what stays the model's, degenerate inputs; on real frames with ground
truth when the pretrained models are fetched."""

from __future__ import annotations

import numpy as np
import pytest

from signsplat.body.joints import KP_LEFT_HAND, KP_RIGHT_HAND
from signsplat.config import REPO_ROOT, validate
from signsplat.perception.hands import take_hands

LEFT, RIGHT = list(KP_LEFT_HAND), list(KP_RIGHT_HAND)
BOX = (0.0, 0.0, 100.0, 200.0)  # person size 200 px
BOTH = ("left", "right")


def _take(xy, sc, hxy, hsc, boxes, sides=BOTH):
    return take_hands(xy, sc, hxy, hsc, boxes, min_score=0.3, reach=0.1, sides=sides)


def _frames(n=3, seed=0):
    """Model keypoints and a hand landmarker's that agree on the wrists (within 5 px) and
    differ on the fingers by a known offset."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(20, 180, (n, 133, 2)).astype(np.float32)
    sc = np.full((n, 133), 0.6, np.float32)
    hxy = np.full((n, 133, 2), np.nan, np.float32)
    hsc = np.zeros((n, 133), np.float32)
    for wrist, hand in ((9, LEFT), (10, RIGHT)):
        hxy[:, hand] = xy[:, hand] + 7.0
        hxy[:, hand[0]] = xy[:, wrist] + 5.0
        hsc[:, hand] = 0.95
    return xy, sc, hxy, hsc


def test_fingers_are_taken_and_the_wrist_and_scores_stay_the_models():
    xy, sc, hxy, hsc = _frames()
    out, osc, taken = _take(xy, sc, hxy, hsc, [BOX] * 3)
    assert taken == {"left": 3, "right": 3}
    for hand in (LEFT, RIGHT):
        np.testing.assert_array_equal(out[:, hand[1:]], hxy[:, hand[1:]])
        np.testing.assert_array_equal(out[:, hand[0]], xy[:, hand[0]])  # the root
    body = [k for k in range(133) if k not in LEFT[1:] + RIGHT[1:]]
    np.testing.assert_array_equal(out[:, body], xy[:, body])
    np.testing.assert_array_equal(osc, sc)  # the fit's weights stay the model's


def test_only_the_configured_sides_are_taken():
    """hand_sides [right]: the right fingers are the landmarker's, the left stay the model's;
    an unknown side is an error naming the known ones."""
    xy, sc, hxy, hsc = _frames()
    out, _, taken = _take(xy, sc, hxy, hsc, [BOX] * 3, sides=("right",))
    assert taken == {"right": 3}
    np.testing.assert_array_equal(out[:, RIGHT[1:]], hxy[:, RIGHT[1:]])
    np.testing.assert_array_equal(out[:, LEFT], xy[:, LEFT])
    with pytest.raises(ValueError, match="known: \\['left', 'right'\\]"):
        _take(xy, sc, hxy, hsc, [BOX] * 3, sides=("middle",))


def test_a_hand_on_the_other_sides_wrist_is_not_taken():
    """Sides exchanged (a view from behind labelled the other way round): each landmarker
    hand lies at the model's other wrist, so neither is taken."""
    xy, sc, hxy, hsc = _frames()
    xy[:, 9] = (20.0, 100.0)
    xy[:, 10] = (80.0, 100.0)
    hxy[:, LEFT[0]] = xy[:, 10]
    hxy[:, RIGHT[0]] = xy[:, 9]
    out, _, taken = _take(xy, sc, hxy, hsc, [BOX] * 3)
    assert taken == {"left": 0, "right": 0}
    np.testing.assert_array_equal(out, xy)


def test_reach_scales_with_the_person():
    xy, sc, hxy, hsc = _frames(n=2)
    hxy[:, RIGHT[0]] = xy[:, 10] + (15.0, 0.0)  # 15 px: inside 0.1 x 200, outside 0.1 x 100
    boxes = [BOX, (0.0, 0.0, 100.0, 100.0)]
    _, _, taken = _take(xy, sc, hxy, hsc, boxes)
    assert taken["right"] == 1


def test_unsure_hands_and_unsure_wrists_are_not_taken():
    xy, sc, hxy, hsc = _frames()
    hsc[0, LEFT] = 0.2  # the landmarker's hand not found
    sc[1, 10] = 0.1  # the model's right wrist unsure
    _, _, taken = _take(xy, sc, hxy, hsc, [BOX] * 3)
    assert taken == {"left": 2, "right": 2}


def test_degenerate_inputs_stay_finite_and_take_nothing():
    """No person, NaN everywhere, no frames: no crash, nothing taken, no NaN added."""
    xy, sc, hxy, hsc = _frames()
    hxy[:] = np.nan
    hsc[:] = np.nan
    out, osc, taken = _take(xy, sc, hxy, hsc, [None, BOX, BOX])
    assert taken == {"left": 0, "right": 0}
    assert np.isfinite(out).all() and np.isfinite(osc).all()
    xy[1, :] = np.nan
    _, _, taken = _take(xy, sc, *_frames()[2:], [BOX] * 3)
    assert taken == {"left": 2, "right": 2}  # the frame whose model wrist is NaN is left
    empty = np.zeros((0, 133, 2), np.float32), np.zeros((0, 133), np.float32)
    out, osc, taken = _take(*empty, *empty, [])
    assert out.shape == (0, 133, 2) and taken == {"left": 0, "right": 0}


CFG = validate({}, "stages/perception.schema.yaml")
MP = validate({"keypoints": {"hands": "mediapipe"}}, "stages/perception.schema.yaml")
CACHE = REPO_ROOT / CFG["pretrained"]["cache"]


def _fetched() -> bool:
    from signsplat.perception.detectors import detector_files

    return all((REPO_ROOT / p).is_file() for p in detector_files(MP, "shipped")["keypoints"])


@pytest.mark.skipif(not _fetched(), reason=f"pretrained models not fetched into {CACHE} "
                    "(make models)")
@pytest.mark.parametrize("crop", ["model", "pose"])
@pytest.mark.parametrize("name", ["studio6_v01_f0030", "single_v00_f0040"])
def test_landmarker_hands_beat_the_models_on_synthetic_ground_truth(name, crop):
    """The shipped model with MediaPipe's hands against the shipped model alone, on simulated
    frames with ground truth: the fingers closer to the truth, the rest unchanged, whether the
    landmarker looks in the model's hand crops or the pose's."""
    import dataclasses

    from signsplat.io.images import read_mask, read_rgb
    from signsplat.perception.detectors import detector_specs
    from signsplat.perception.keypoints import box_from_mask
    from signsplat.perception.stages import open_keypointer

    data = REPO_ROOT / "tests" / "perception" / "data"
    cfg = {**MP, "pretrained": {**MP["pretrained"], "cache": str(CACHE)},
           "keypoints": {**MP["keypoints"], "model": str(REPO_ROOT / "models/keypoints.onnx"),
                         "hand_crop": crop}}
    _, spec = detector_specs(cfg, "shipped", "cpu")
    assert spec.hands.face is False and spec.crop == crop  # the landmarker's face is not run
    image = read_rgb(data / f"{name}.png")
    box = box_from_mask(read_mask(data / f"{name}_mask.png"))
    both = open_keypointer(spec, 1).detect([image], [box], [0])
    alone = open_keypointer(dataclasses.replace(spec.base), 1).detect([image], [box], [0])
    gt = np.load(data / f"{name}_gt.npz")
    fingers = [k for hand in (LEFT, RIGHT) for k in hand[1:] if gt["visible"][k]]
    err = {n: np.linalg.norm(xy[0][fingers] - gt["xy"][fingers], axis=1).mean()
           for n, (xy, _) in (("both", both), ("alone", alone))}
    # measured (both / alone): pose crops 1.8 / 6.7 and 1.8 / 2.3 px, model crops 1.7 / 6.7
    # and 1.8 / 2.3 px
    assert err["both"] < min(err["alone"], 2.5), err
    rest = [k for k in range(133) if k not in fingers and k not in LEFT + RIGHT]
    np.testing.assert_array_equal(both[0][0][rest], alone[0][0][rest])


@pytest.mark.skipif(not _fetched(), reason=f"pretrained models not fetched into {CACHE} "
                    "(make models)")
def test_the_landmarker_looks_only_for_the_hands_on_its_sides():
    """hand_sides [right] (what keypoints.hands `dominant` asks for a right-handed signer):
    the landmarker runs for the right hand alone and finds it where it finds it with both."""
    from signsplat.io.images import read_mask, read_rgb
    from signsplat.perception.detectors import detector_specs
    from signsplat.perception.keypoints import box_from_mask
    from signsplat.perception.stages import open_keypointer

    data = REPO_ROOT / "tests" / "perception" / "data"
    cfg = {**MP, "pretrained": {**MP["pretrained"], "cache": str(CACHE)}}
    image = read_rgb(data / "studio6_v01_f0030.png")
    box = box_from_mask(read_mask(data / "studio6_v01_f0030_mask.png"))
    found = {}
    for sides in (["left", "right"], ["right"]):
        one = {**cfg, "keypoints": {**cfg["keypoints"], "hand_sides": sides}}
        _, spec = detector_specs(one, "shipped", "cpu")
        assert spec.hands.hand_sides == tuple(sides)
        xy, sc = open_keypointer(spec.hands, 1).detect([image], [box], [0])
        found[len(sides)] = xy[0], sc[0]
    both, right = found[2], found[1]
    assert (both[1][RIGHT] > 0.3).all() and (both[1][LEFT] > 0.3).all()
    np.testing.assert_array_equal(right[0][RIGHT], both[0][RIGHT])
    assert (right[1][LEFT] == 0).all() and np.isnan(right[0][LEFT]).all()


@pytest.mark.skipif(not _fetched(), reason=f"pretrained models not fetched into {CACHE} "
                    "(make models)")
def test_the_model_s_hand_crops_skip_what_they_cannot_place():
    """hand_crop `model`: the landmarker runs in the crop of the keypoint model's own hand
    points, and not where those points are missing, unsure or all in one place (no crop can
    be made there); points far outside the image give no hand and no NaN."""
    from signsplat.io.images import read_mask, read_rgb
    from signsplat.perception.hands import hands_in_model_crops
    from signsplat.perception.keypoints import box_from_mask
    from signsplat.perception.pretrained.graphs import HAND_LMK
    from signsplat.perception.pretrained.keypointer import MediaPipeSpec, MediaPipeWholeBody
    from signsplat.perception.stages import open_keypointer
    from signsplat.perception.detectors import specs

    data = REPO_ROOT / "tests" / "perception" / "data"
    image = read_rgb(data / "studio6_v01_f0030.png")
    box = box_from_mask(read_mask(data / "studio6_v01_f0030_mask.png"))
    _, kp = specs({**CFG, "keypoints": {**CFG["keypoints"],
                                         "model": str(REPO_ROOT / "models/keypoints.onnx")}},
                  "cpu")
    xy, sc = open_keypointer(kp, 1).detect([image], [box], [0])
    pre = {**CFG["pretrained"], "cache": str(CACHE)}
    landmarker = MediaPipeWholeBody(MediaPipeSpec.from_config(pre, "cpu"), 1, models=(HAND_LMK,))
    n = 5
    xy, sc = np.repeat(xy, n, axis=0), np.repeat(sc, n, axis=0)
    xy[1, RIGHT[3]] = np.nan  # one missing point
    sc[2, RIGHT] = 0.1  # unsure
    xy[3, RIGHT] = xy[3, RIGHT[0]]  # all in one place
    xy[4, RIGHT] += 1e5  # far outside the image
    hxy, hsc = hands_in_model_crops(landmarker, [image] * n, xy, sc, ("right",),
                                    min_score=0.3, min_presence=0.5)
    assert hxy.shape == (n, 133, 2) and hsc.shape == (n, 133)
    assert np.isfinite(hxy[0, RIGHT]).all() and (hsc[0, RIGHT] >= 0.5).all()
    assert np.isnan(hxy[1:, RIGHT]).all() and (hsc[1:, RIGHT] == 0).all()
    assert np.isnan(hxy[:, LEFT]).all()  # a side not asked for is not looked for


@pytest.mark.skipif(not _fetched(), reason=f"pretrained models not fetched into {CACHE} "
                    "(make models)")
def test_the_keypoints_table_says_how_many_frames_took_the_landmarker_s_fingers(tmp_path):
    """The keypoint stage with MediaPipe's right fingers writes the keypointer, its models and
    its count of frames taken into the table's metadata (the report's perception section
    shows them)."""
    import shutil

    import pandas as pd

    from signsplat.io.tables import read_table, write_table
    from signsplat.perception.detectors import detector_specs
    from signsplat.perception.stages import detect_sequence, segment_sequence

    data = REPO_ROOT / "tests" / "perception" / "data"
    (tmp_path / "images").mkdir()
    shutil.copy(data / "studio6_v01_f0030.png", tmp_path / "images" / "0000.png")
    frames = pd.DataFrame([dict(scene="s", view=0, frame=0, time=0.0,
                                image="images/0000.png", mask="")])
    write_table(frames.astype({"view": "int32", "frame": "int32"}),
                tmp_path / "frames.parquet", "frames")
    cfg = {**MP, "pretrained": {**MP["pretrained"], "cache": str(CACHE)},
           "keypoints": {**MP["keypoints"], "model": str(REPO_ROOT / "models/keypoints.onnx"),
                         "hand_sides": ["right"]},
           "segmenter": {**MP["segmenter"], "model": str(REPO_ROOT / "models/segmenter.onnx")}}
    seg, spec = detector_specs(cfg, "shipped", "cpu")
    segment_sequence(tmp_path / "frames.parquet", tmp_path / "p", seg, 1, progress=False)
    detect_sequence(tmp_path / "frames.parquet", tmp_path / "p" / "masks.parquet",
                    tmp_path / "k.parquet", spec, 1, progress=False)
    meta = read_table(tmp_path / "k.parquet", "keypoints").attrs
    assert meta["source"] == "onnx+mediapipe" and str(CACHE) in meta["model"]
    assert meta["note"] == "MediaPipe's hands (crop: model) taken in 1 of 1 frames (right)"
