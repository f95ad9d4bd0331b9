"""Model contracts: RTMW-shaped models load unchanged; wrong models fail with shapes shown."""

from __future__ import annotations

import numpy as np
import pytest

from signsplat.perception.contracts import (KeypointSpec, ModelContractError, SegmenterSpec,
                                            load_keypointer, load_segmenter)
from signsplat.perception.keypoints import detect_batch


def test_rtmw_shaped_model_loads_with_defaults(models):
    model = load_keypointer(KeypointSpec(str(models["rtmw"])))
    assert model.input_size == (384, 288)
    assert not model.dynamic_batch  # RTMW files have batch 1: one crop per call
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, (256, 320, 3), dtype=np.uint8) for _ in range(3)]
    boxes = [np.array([40.0, 20, 200, 250]), None, np.array([0.0, 0, 320, 256])]
    xy, score = detect_batch(model, KeypointSpec(str(models["rtmw"])), images, boxes)
    assert xy.shape == (3, 133, 2) and score.shape == (3, 133)
    assert np.all((score >= 0) & (score <= 1))
    assert np.all(score[1] == 0) and np.all(np.isnan(xy[1]))
    ok = score[0] > 0
    assert ok.any()
    # decoded points lie inside the padded crop around the box
    assert np.all(xy[0][ok, 0] >= 40 - 0.7 * 160 - 1) and np.all(xy[0][ok, 0] <= 200 + 0.7 * 160)


def test_wrong_keypoint_count_fails_with_expected_and_found(models):
    with pytest.raises(ModelContractError) as err:
        load_keypointer(KeypointSpec(str(models["rtm17"])))
    msg = str(err.value)
    assert "rtm17.onnx" in msg and "expected (?, 133, 576)" in msg and "found (1, 17, 576)" in msg


def test_wrong_split_ratio_fails(models):
    with pytest.raises(ModelContractError, match=r"expected \(\?, 133, 864\)"):
        load_keypointer(KeypointSpec(str(models["rtmw"]), split_ratio=3.0))


def test_configured_size_must_match_static_model(models):
    with pytest.raises(ModelContractError, match=r"found \(1, 3, 384, 288\)"):
        load_keypointer(KeypointSpec(str(models["rtmw"]), input_size=(256, 192)))


def test_segmenter_given_as_keypoint_model_fails(models):
    with pytest.raises(ModelContractError, match="SimCC"):
        load_keypointer(KeypointSpec(str(models["bright_seg"]), input_size=(64, 64)))


def test_keypoint_model_given_as_segmenter_fails(models):
    with pytest.raises(ModelContractError, match=r"expected \(\?, 1, \?, \?\)"):
        load_segmenter(SegmenterSpec(str(models["rtmw"]), input_size=(384, 288)))


def test_missing_and_corrupt_model_files_name_the_file(tmp_path):
    with pytest.raises(ModelContractError, match="nothere.onnx: segmentation model file not found"):
        load_segmenter(SegmenterSpec(str(tmp_path / "nothere.onnx")))
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not an onnx file at all")
    with pytest.raises(ModelContractError, match="bad.onnx: not a loadable ONNX"):
        load_keypointer(KeypointSpec(str(bad)))


def test_dynamic_batch_model_runs_batches(models):
    seg = load_segmenter(SegmenterSpec(str(models["bright_seg"]), input_size=(64, 64)))
    assert seg.dynamic_batch
    (alpha,) = seg.run(np.zeros((5, 3, 64, 64), np.float32))
    assert alpha.shape == (5, 1, 64, 64)
    kp = load_keypointer(KeypointSpec(str(models["tiny_kp"])))
    assert kp.dynamic_batch and kp.input_size == (64, 48)
    sx, sy = kp.run(np.zeros((4, 3, 64, 48), np.float32))
    assert sx.shape == (4, 133, 96) and sy.shape == (4, 133, 128)


def test_sessions_use_the_threads_asked_for_and_do_not_spin(models):
    """Two pool threads for a two-thread stage, which sleep between parallel sections: spinning
    takes the cores that other jobs on the machine need (benchmarks/bench_perception_threads.py)."""
    from signsplat.perception.contracts import open_session

    opts = open_session(models["rtmw"], threads=2).get_session_options()
    assert opts.intra_op_num_threads == 2 and opts.inter_op_num_threads == 1
    assert opts.get_session_config_entry("session.intra_op.allow_spinning") == "0"
