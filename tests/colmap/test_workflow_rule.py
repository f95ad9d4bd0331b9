"""The colmap_compare rule through Snakemake, on a rendered rig staged as simulator output.

A throw-away Snakefile includes only common.smk and colmap.smk, so the rule's inputs (the
simulator's and the fit's files) are staged by hand instead of being produced upstream.
"""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

import signsplat.colmap.compare  # noqa: F401  (registers the colmap_compare table)
from signsplat.io.tables import read_table, write_table

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_rule_runs_for_multiview_scenes_only(textured_rig, tmp_path):
    for name, count in (("rig8", 4), ("mono", 1)):
        spec = {"cameras": {"count": count}, "motion": {"glosses": ["HELLO"]}}
        (tmp_path / f"{name}.yaml").write_text(yaml.safe_dump(spec))
    (tmp_path / "sequences.tsv").write_text(
        "sequence\tsource\tspec\n"
        f"rig8\tsynthetic\t{tmp_path / 'rig8.yaml'}\nmono\tsynthetic\t{tmp_path / 'mono.yaml'}\n")
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(
        {"results": "results", "sequences": str(tmp_path / "sequences.tsv"), "scenes": []}))
    (tmp_path / "Snakefile").write_text(
        f'configfile: "{tmp_path / "config.yaml"}"\n'
        f'include: "{ROOT / "workflow/rules/common.smk"}"\n'
        f'include: "{ROOT / "workflow/rules/colmap.smk"}"\n'
        "rule all:\n    input: expand(rules.colmap_compare.output.table,"
        " scene=PLAN.multiview_scenes)\n    default_target: True\n")
    # stage 4 views of the rig as simulator output (first frame only; the default settings
    # make 2 runs x 3 settings) and a fit that reproduces the truth
    sim, fit = tmp_path / "results/rig8/sim", tmp_path / "results/rig8/fit"
    shutil.copytree(textured_rig / "images", sim / "images")
    frames = read_table(textured_rig / "frames.parquet", "frames")
    keep = (frames["frame"] == 0) & (frames["view"] % 2 == 0)
    write_table(frames[keep].assign(scene="rig8"), sim / "frames.parquet", "frames")
    cams = read_table(textured_rig / "cameras.parquet", "cameras")
    cams = cams[cams["view"] % 2 == 0].assign(scene="rig8")
    write_table(cams, sim / "cameras.parquet", "cameras")
    write_table(cams.assign(fit_status="pnp"), fit / "cameras_fit.parquet", "cameras",
                metadata={"mode": "multiview", "keypoints": "ground_truth"})
    pd.DataFrame({"scene": "rig8", "mode": "multiview", "keypoints": "ground_truth",
                  "metric": ["seconds"], "part": ["all"], "value": [3.0], "unit": ["s"],
                  "seconds_total": [3.0], "seconds_per_frame": [3.0]}).to_parquet(
        fit / "fit_eval.parquet")
    res = subprocess.run([sys.executable, "-m", "snakemake", "-s", str(tmp_path / "Snakefile"),
                          "-d", str(tmp_path), "--cores", "2", "--nolock"],
                         capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    out = tmp_path / "results/rig8/colmap"
    df = read_table(out / "colmap_compare.parquet", "colmap_compare")
    assert not (tmp_path / "results/mono/colmap").exists()  # single view: no comparison
    assert set(df["method"]) == {"colmap_static_frame_0", "colmap_sequence",
                                 "smplx_camera_solve"}
    assert df["seconds"].notna().all()
    fit_row = df[df["method"] == "smplx_camera_solve"].iloc[0]
    assert fit_row["rot_error_deg"] < 1e-6 and fit_row["seconds"] == 3.0
    ok = df[df["setting"] == "known_intrinsics"]
    assert (ok["registered"] >= 3).all() and (ok["rot_error_deg"] < 1.0).all()
    assert (out / "points.ply").exists() and any((out / "ply").iterdir())
    log = (tmp_path / "results/_logs/rig8/colmap_compare.log").read_text()
    assert "Keeping successful reconstruction" in log or "Elapsed time" in log  # pycolmap's log
    assert (tmp_path / "results/_benchmarks/rig8/colmap_compare.tsv").exists()
    assert json.loads(df.attrs["config"])["settings"][0]["name"] == "known_intrinsics"
    assert np.isfinite(df["seconds"]).all()
