"""The multi-view fit on the generalisation suite (issue 29): simulate -> perception -> fit for
every suite scene with the workflow's default config, then one table and one figure.

Usage: python benchmarks/fit_suite.py [--scenes g00 issue29 ...] [--results results/suite]
       [--cores 2] [--keypoints detected|ground_truth] [--detectors shipped|wide] [--collect-only]
       [--out benchmarks/results/fit_suite.parquet]

The scenes are config/scenes/suite/*.yaml (`signsplat suite-scenes` writes them from
config/scenes/suite/grid.yaml; this script writes them when the sheet is missing). Snakemake
runs the workflow's own rules (`--keep-going`: a scene that fails is a row saying so) with
`--config sequences=config/scenes/suite/sequences.tsv results=<results>`; keypoints are the
perception stage's (detected) unless `--keypoints ground_truth`. Writes
benchmarks/results/fit_suite.parquet (table `fit_suite`, signsplat/report/fit_suite.py) and
fit_suite.svg, and prints the Done-when summary and the wall-clock time of the run. The machine
is usually shared: seconds are indicative.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import yaml

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from signsplat.io.tables import table_metadata, write_table  # noqa: E402
from signsplat.report.fit_suite import (plot_suite, scene_row, suite_table,  # noqa: E402
                                        summarise)

SUITE = REPO / "config" / "scenes" / "suite"


def run_workflow(scenes: list[str], results: Path, cores: int, keypoints: str,
                 detectors: str = "shipped") -> int:
    targets = [str(results / s / "fit" / "fit_eval.parquet") for s in scenes]
    config = [f"sequences={SUITE / 'sequences.tsv'}", f"results={results}"]
    if keypoints != "detected":
        config.append(f"fit={json.dumps({'keypoints': keypoints})}")
    if detectors != "shipped":
        config.append(f"perception={json.dumps({'detectors': {'synthetic': detectors}})}")
    cmd = [sys.executable, "-m", "snakemake", "--cores", str(cores), "--keep-going",
           "--rerun-triggers", "mtime", "--config", *config, "--", *targets]
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    print(" ".join(cmd), flush=True)
    return subprocess.call(cmd, cwd=REPO, env=env)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="*", help="suite scene names (default: all)")
    p.add_argument("--results", default="results/suite")
    p.add_argument("--cores", type=int, default=2)
    p.add_argument("--keypoints", default="detected", choices=["detected", "ground_truth"])
    p.add_argument("--detectors", default="shipped", choices=["shipped", "wide"],
                   help="the synthetic scenes' detectors (wide: the keypoint model adapted to "
                        "other rigs, models/README.md); give each choice its own --results and "
                        "--out")
    p.add_argument("--collect-only", action="store_true", help="only read finished results")
    p.add_argument("--out", default="benchmarks/results/fit_suite.parquet")
    a = p.parse_args()
    if not (SUITE / "sequences.tsv").exists():
        subprocess.check_call([sys.executable, "-m", "signsplat", "suite-scenes"], cwd=REPO)
    sheet = [ln.split("\t")[:3] for ln in (SUITE / "sequences.tsv").read_text().splitlines()[1:]]
    specs = {name: yaml.safe_load((REPO / spec).read_text()) for name, _, spec in sheet}
    scenes = a.scenes or list(specs)
    unknown = sorted(set(scenes) - set(specs))
    if unknown:
        sys.exit(f"unknown suite scene(s) {unknown}; known {sorted(specs)}")
    results = (REPO / a.results).resolve()
    t0 = time.perf_counter()
    if not a.collect_only:
        code = run_workflow(scenes, results, a.cores, a.keypoints, a.detectors)
        print(f"snakemake exit code {code}", flush=True)
    wall = time.perf_counter() - t0
    rows = [scene_row(results, s, specs[s], a.keypoints) for s in scenes]
    df = suite_table(rows)
    out = REPO / a.out
    meta = {"keypoints": a.keypoints, "detectors": a.detectors, "wall_seconds": f"{wall:.0f}",
            "results": str(results)}
    if a.collect_only and out.exists():  # the run's own wall clock and notes stay (also
        # from a table written before a column was added)
        meta = {**table_metadata(pq.read_table(out, columns=["scene"])),
                "keypoints": a.keypoints, "results": str(results)}
        wall = float(meta.get("wall_seconds", 0))
    write_table(df, out, "fit_suite", metadata=meta)
    plot_suite(df, out.with_suffix(".svg"))
    cols = ["scene", "cameras", "arc_deg", "image", "frames", "camera_rotation_deg",
            "camera_centre_m", "body_mpjpe_mm", "hands_mpjpe_mm", "camera_init", "unplaced",
            "doubtful", "mask_turned", "mask_kept", "cameras_held", "fit_seconds",
            "meets_target", "status"]
    with_pd_options = __import__("pandas").option_context("display.width", 200,
                                                          "display.max_columns", 20)
    with with_pd_options:
        print(df[cols].to_string(index=False, float_format=lambda x: f"{x:.3g}"))
    s = summarise(df)
    print(json.dumps({k: v for k, v in s.items() if k != "two_camera"}, indent=1))
    print("two-camera scenes:", json.dumps(s["two_camera"]))
    print(f"this run: {wall / 3600:.2f} h wall clock ({len(scenes)} scenes); pipeline seconds "
          f"summed from the benchmark files: {s['pipeline_hours']:.2f} h; wrote {out}")


if __name__ == "__main__":
    main()
