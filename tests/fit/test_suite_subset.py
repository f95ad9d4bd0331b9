"""Three small generated suite scenes through the workflow (simulate -> perception -> fit with
detected keypoints), collected into the fit_suite table: the suite's plumbing end to end.
The full suite is a benchmark (benchmarks/fit_suite.py), not a test."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from signsplat.report.fit_suite import scene_row, suite_table, summarise
from signsplat.synth.suite import generate_suite, write_suite

ROOT = Path(__file__).resolve().parents[2]

GRID = {
    "seed": 3, "scenes": 3, "uneven": {"azimuth": 0.3, "distance": 0.1, "height": 0.1},
    "axes": {
        "rig": [{"count": 2, "arc": 60, "spacing": "even"},
                {"count": 3, "arc": 100, "spacing": "uneven"},
                {"count": 4, "arc": 360, "spacing": "even"}],
        "distance": [2.0, 2.5, 3.0], "framing": [1.4], "height": [[1.4, 1.3]],
        "image": [[112, 96]], "clip": [5], "betas": [[0.5, -0.5]],
        "effects": [["lighting", {"background": {"kind": "solid", "color": [0.8, 0.8, 0.8]}}],
                    ["lighting", "camera_jitter"]],
        "glosses": [["HELLO", "BOOK"]],
    },
}

FAST_FIT = {"multiview": {"init": {"frames": 5}, "stages": [
    {"name": "root", "iterations": 15, "lr": 0.05, "groups": ["root"], "warm_start": True,
     "parts": {"left_hand": 0, "right_hand": 0, "limbs": 0}, "smooth": False, "sigma_px": 100},
    {"name": "body_cameras", "iterations": 25, "lr": 0.02,
     "groups": ["root", "body", "betas", "cameras"], "lr_scale": {"cameras": 0.3},
     "parts": {"left_hand": 0, "right_hand": 0, "palms": 1}, "sigma_px": 100}]}}


@pytest.mark.slow
def test_three_scene_subset_runs_and_is_tabulated(tmp_path):
    scenes = generate_suite(GRID)
    assert sorted(s["cameras"]["count"] for s in scenes.values()) == [2, 3, 4]
    write_suite(scenes, tmp_path / "suite", "test grid")
    cfg = {"results": str(tmp_path / "results"), "scenes": [],
           "sequences": str(tmp_path / "suite" / "sequences.tsv"), "fit": FAST_FIT}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(cfg))
    targets = [str(tmp_path / "results" / n / "fit" / "fit_eval.parquet") for n in scenes]
    res = subprocess.run([sys.executable, "-m", "snakemake", "--cores", "2", "--nolock",
                          "--configfile", str(tmp_path / "config.yaml"), "--", *targets],
                         cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    df = suite_table([scene_row(tmp_path / "results", n, s) for n, s in scenes.items()])
    assert (df["status"] == "ok").all(), df[["scene", "status"]]
    cols = ["camera_rotation_deg", "camera_centre_m", "body_mpjpe_mm", "fit_seconds"]
    assert np.isfinite(df[cols].to_numpy()).all()
    assert (df["camera_init"] != "").all() and (df["pipeline_seconds"] > 0).all()
    s = summarise(df)
    assert s["scenes"] == 3 and s["multi_camera_scenes"] == 2 and s["failed_or_nan"] == 0
