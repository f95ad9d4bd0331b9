"""Footage measures without ground truth: detection rates (a hand only where the pose shows it
in view), jitter, the table and the overlays."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from signsplat.io.tables import read_table, write_table
from signsplat.perception.quality import footage_quality, hand_visible, quality_rows

W, H = 200, 100


def _still(t=10):
    """A still signer: every point found at a fixed place; left wrist (9) below its elbow
    (7) in mid-frame, right wrist (10) near the bottom with its elbow above (hand hanging
    out of the frame)."""
    xy = np.zeros((t, 133, 2))
    xy[:, :, 0], xy[:, :, 1] = 100.0, 50.0
    xy[:, 7], xy[:, 9] = [60.0, 30.0], [60.0, 50.0]
    xy[:, 8], xy[:, 10] = [140.0, 70.0], [140.0, 95.0]
    return xy, np.ones((t, 133))


def rates(rows):
    return {(m, p): v for m, p, v, _ in rows}


def test_rates_and_hand_visibility():
    xy, sc = _still()
    assert hand_visible(xy, sc, "left_hand", (W, H), 0.5).all()
    assert not hand_visible(xy, sc, "right_hand", (W, H), 0.5).any()  # centre at y 107.5
    sc[:4, 112:133] = 0.2  # right hand missed: does not count (not visible anyway)
    sc[:5, 91:112] = 0.0  # left hand missed in half the frames
    sc[:2, [0, 1, 2, 3, 5]] = 0.0  # 6 of 11 upper-body points: body not found
    r = rates(quality_rows(xy, sc, (W, H)))
    assert r[("detection_rate", "left_hand")] == pytest.approx(0.5)
    assert np.isnan(r[("detection_rate", "right_hand")])
    assert r[("visible_rate", "right_hand")] == 0.0
    assert r[("detection_rate", "body")] == pytest.approx(0.8)
    assert r[("detection_rate", "face")] == 1.0
    assert r[("jitter_px", "face")] == 0.0


def test_jitter_is_the_median_second_difference_at_256_px():
    xy, sc = _still(12)
    xy[:, 23:91, 0] += np.where(np.arange(12) % 2, 1.0, -1.0)[:, None]  # +-1 px zigzag
    r = rates(quality_rows(xy, sc, (W, H)))
    assert r[("jitter_px", "face")] == pytest.approx(4.0 * 256 / H)
    assert r[("jitter_px", "body")] == 0.0


def test_table_over_frames_without_keypoints(tmp_path):
    from signsplat.io.images import write_png

    xy, sc = _still(6)
    frames, kp = [], []
    for f in range(6):
        write_png(tmp_path / f"images/{f}.png", np.zeros((H, W, 3), np.uint8))
        frames.append(("c", 0, f, f / 25, f"images/{f}.png", ""))
        if f < 3:  # frames 3-5 have no keypoint rows at all
            for k in range(133):
                kp.append(("c", 0, f, k, xy[f, k, 0], xy[f, k, 1], sc[f, k]))
    fr = pd.DataFrame(frames, columns=["scene", "view", "frame", "time", "image", "mask"])
    write_table(fr.astype({"view": "int32", "frame": "int32"}), tmp_path / "frames.parquet",
                "frames")
    kt = pd.DataFrame(kp, columns=["scene", "view", "frame", "kp", "x", "y", "score"])
    kt = kt.astype({"view": "int32", "frame": "int32", "kp": "int16", "x": "float32",
                    "y": "float32", "score": "float32"})
    write_table(kt, tmp_path / "kp.parquet", "keypoints")
    df = footage_quality(tmp_path / "frames.parquet", tmp_path / "kp.parquet",
                         tmp_path / "q.parquet")
    got = {(r.metric, r.part): r.value for r in df.itertuples()}
    assert got[("detection_rate", "body")] == pytest.approx(0.5)
    assert got[("detection_rate", "left_hand")] == 1.0  # visible only where found
    assert read_table(tmp_path / "q.parquet", "footage_quality").attrs["height"] == str(H)
    # overlays: the mask tinted green, found keypoints drawn, in a fresh process's tables
    import subprocess
    import sys

    from signsplat.io.images import read_rgb, write_png as png

    mask = np.zeros((H, W), np.uint8)
    mask[10:30, 10:30] = 255
    png(tmp_path / "masks/0.png", mask)
    mt = pd.DataFrame([("c", 0, f, "masks/0.png", 400, 10.0, 10.0, 30.0, 30.0, 1.0)
                       for f in range(6)],
                      columns=["scene", "view", "frame", "mask", "area", "x0", "y0", "x1", "y1",
                               "confidence"])
    write_table(mt.astype({"view": "int32", "frame": "int32", "area": "int64", "x0": "float32",
                           "y0": "float32", "x1": "float32", "y1": "float32",
                           "confidence": "float32"}), tmp_path / "masks.parquet", "masks")
    code = ("import sys; from signsplat.cli import main; sys.exit(main(sys.argv[1:]))")
    res = subprocess.run([sys.executable, "-c", code, "perception-quality", "--frames",
                          str(tmp_path / "frames.parquet"), "--masks",
                          str(tmp_path / "masks.parquet"), "--keypoints",
                          str(tmp_path / "kp.parquet"), "--out", str(tmp_path / "q2.parquet"),
                          "--overlays", str(tmp_path / "ov")], capture_output=True, text=True,
                         check=False)
    assert res.returncode == 0, res.stderr[-2000:]
    shots = sorted((tmp_path / "ov").glob("*.png"))
    assert [p.name for p in shots] == ["0000.png", "0002.png", "0003.png", "0005.png"]
    first = read_rgb(shots[0])
    assert first[20, 20, 1] > first[20, 20, 0]  # tinted green inside the mask
    assert tuple(first[50, 100]) == (255, 0, 220)  # hands at (100, 50), the right drawn last
    assert tuple(read_rgb(shots[-1])[50, 100]) == (0, 0, 0)  # frame 5 has no keypoints

