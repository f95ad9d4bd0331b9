"""benchmarks/segmenter_threshold.py: area bias and wrong pixels of the masks by threshold."""

import cv2
import numpy as np
from benchmark_scripts import load_benchmark

from signsplat.io.tables import read_table
from signsplat.perception.contracts import SegmenterSpec, load_segmenter


def test_group_rows_measure_the_masks_against_the_scenes_own(models, scene_factory, tmp_path):
    group_rows = load_benchmark("segmenter_threshold").group_rows
    group = tmp_path / "group"
    sim = scene_factory(group, views=2, frames=3)
    spec = SegmenterSpec(str(models["bright_seg"]), input_size=(64, 64), batch_size=4)
    model = load_segmenter(spec)
    thresholds = [0.3, 0.5, 0.9]
    rows = group_rows(group, model, spec, thresholds, every=1)
    assert [r["threshold"] for r in rows] == thresholds
    assert all(r["frames"] == 6 and r["group"] == "group" for r in rows)
    bias = [r["area_bias"] for r in rows]
    assert bias == sorted(bias, reverse=True)  # a higher threshold never adds pixels
    assert all(r["wrong_fraction"] >= abs(r["area_bias"]) for r in rows)

    # the same images against truths one pixel smaller: the masks are now larger than the truth
    frames = read_table(sim / "frames.parquet", "frames")
    for rel in frames["mask"]:
        mask = cv2.imread(str(sim / rel), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(sim / rel), cv2.erode(mask, np.ones((3, 3), np.uint8)))
    eroded = group_rows(group, model, spec, thresholds, every=1)
    assert all(e["area_bias"] > r["area_bias"] for e, r in zip(eroded, rows))
    assert group_rows(group, model, spec, [0.5], every=2)[0]["frames"] == 4  # frames 0 and 2
