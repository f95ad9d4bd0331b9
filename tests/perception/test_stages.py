"""The segment / detect_keypoints stages and perception_eval on a fake simulated scene."""

from __future__ import annotations

import json

import numpy as np
import pytest

from signsplat.errors import InputError
from signsplat.io.tables import read_table
from signsplat.perception.cli import detect_keypoints, perception_eval, segment
from signsplat.perception.contracts import KeypointSpec, SegmenterSpec
from signsplat.io.images import read_mask
from signsplat.perception.stages import detect_sequence, segment_sequence


def _specs(models):
    return (SegmenterSpec(str(models["bright_seg"]), input_size=(64, 64), batch_size=4),
            KeypointSpec(str(models["tiny_kp"]), batch_size=4))


def test_segment_and_keypoints_over_a_sequence(models, fake_scene, tmp_path):
    seg, kp = _specs(models)
    out = tmp_path / "perception"
    report = segment_sequence(fake_scene / "frames.parquet", out, seg, progress=False)
    masks = read_table(out / "masks.parquet", "masks")
    assert len(masks) == 6 and report.frames == 6
    for _, r in masks.iterrows():
        pred = read_mask(out / r["mask"])
        gt = read_mask(fake_scene / f"masks/{r['view']:02d}/{r['frame']:04d}.png")
        assert (pred & gt).sum() / max((pred | gt).sum(), 1) > 0.95 or not gt.any()
        assert r["area"] == pred.sum()
    # the frame with no person: empty mask, NaN box, confidence 0
    empty = masks[(masks["view"] == 1) & (masks["frame"] == 2)].iloc[0]
    assert empty["area"] == 0 and np.isnan(empty["x0"]) and empty["confidence"] == 0
    full = masks[masks["area"] > 0]
    assert np.all(full["confidence"] > 0.5) and np.all(full["x1"] > full["x0"])

    kp_report = detect_sequence(fake_scene / "frames.parquet", out / "masks.parquet",
                                out / "keypoints.parquet", kp, progress=False)
    kps = read_table(out / "keypoints.parquet", "keypoints")
    assert len(kps) == 6 * 133 and kp_report.frames == 6
    assert kps["score"].between(0, 1).all()
    nobody = kps[(kps["view"] == 1) & (kps["frame"] == 2)]
    assert np.all(nobody["score"] == 0) and nobody["x"].isna().all()


def test_corrupt_and_missing_images_name_the_file_and_keep_other_outputs(models, fake_scene,
                                                                         tmp_path):
    seg, kp = _specs(models)
    (fake_scene / "images/00/0001.png").write_bytes(b"\x89PNG garbage")
    (fake_scene / "images/01/0000.png").unlink()
    out = tmp_path / "perception"
    with pytest.raises(InputError) as err:
        segment_sequence(fake_scene / "frames.parquet", out, seg, progress=False)
    msg = str(err.value)
    assert "images/00/0001.png" in msg and "images/01/0000.png" in msg
    assert "not found" in msg and "corrupt" in msg
    written = sorted(p.relative_to(out).as_posix() for p in (out / "masks").rglob("*.png"))
    assert written == ["masks/00/0000.png", "masks/00/0002.png", "masks/01/0001.png",
                       "masks/01/0002.png"]
    assert len(read_table(out / "masks.parquet", "masks")) == 4
    # skip mode: a warning, the stage goes on and keypoints cover the readable frames
    report = segment_sequence(fake_scene / "frames.parquet", out, seg, skip_bad_frames=True,
                              progress=False)
    assert report.frames == 4 and len(report.bad_frames) == 2
    kr = detect_sequence(fake_scene / "frames.parquet", out / "masks.parquet",
                         out / "keypoints.parquet", kp, skip_bad_frames=True, progress=False)
    assert kr.frames == 4


def test_cli_stages_and_eval_table(models, fake_scene, tmp_path, capsys):
    cfg = json.dumps({
        "segmenter": {"model": str(models["bright_seg"]), "input_size": [64, 64]},
        "keypoints": {"model": str(models["tiny_kp"])},
        "eval": {"speed_frames": 4},
    })
    out = tmp_path / "perception"
    assert segment(["--frames", str(fake_scene / "frames.parquet"), "--out-dir", str(out),
                    "--config-json", cfg, "--quiet", "--timings", str(out / "t_seg.parquet")]) == 0
    assert detect_keypoints(["--frames", str(fake_scene / "frames.parquet"), "--masks",
                             str(out / "masks.parquet"), "--out", str(out / "keypoints.parquet"),
                             "--config-json", cfg, "--quiet",
                             "--timings", str(out / "t_kp.parquet")]) == 0
    assert perception_eval(["--sim-dir", str(fake_scene), "--perception-dir", str(out),
                            "--out", str(out / "eval.parquet"), "--config-json", cfg,
                            "--timings", f"segment={out / 't_seg.parquet'}",
                            f"keypoints={out / 't_kp.parquet'}"]) == 0
    ev = read_table(out / "eval.parquet", "perception_eval")
    printed = capsys.readouterr().out
    assert "mask_iou" in printed and "pck@0.05" in printed
    iou = ev[ev["metric"] == "mask_iou"]["value"].iloc[0]
    assert iou > 0.95  # the brightness segmenter is right on bright-on-dark figures
    parts = set(ev[ev["metric"] == "pck@0.05"]["part"])
    assert parts == {"body", "feet", "face", "left_hand", "right_hand"}
    fps = ev[(ev["metric"] == "fps") & (ev["part"] == "total")]["value"].iloc[0]
    assert fps > 0 and np.isfinite(fps)
    assert set(ev[ev["metric"] == "stage_fps"]["part"]) == {"segment", "keypoints", "total"}
    # a random keypoint model is far from the truth: PCK must show it
    assert ev[ev["metric"] == "pck@0.05"]["value"].max() < 0.5


def test_cli_reports_a_bad_config_value(models, fake_scene, tmp_path):
    from signsplat.config import ConfigError

    with pytest.raises(ConfigError, match="threshold"):
        segment(["--frames", str(fake_scene / "frames.parquet"), "--out-dir", str(tmp_path),
                 "--config-json", json.dumps({"segmenter": {"threshold": 2}})])
