"""Batch benchmark (issue 9): four small synthetic sequences through the workflow.

Runs the simulate stage of four tiny sequences (a) together with ``-j 2`` and (b) one by one,
each in a fresh results folder that shares the pre-built assets, and prints/saves the total
wall time, the per-stage time from Snakemake's ``benchmark:`` files, and the speed-up.
The target is ``simulate`` by default; pass ``--target <stage-relative path>`` to go further
(e.g. ``perception/keypoints.parquet``) once those stages are wanted in the benchmark.

    .venv/bin/python benchmarks/bench_batch.py [--target sim/frames.parquet]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results"
NAMES = ["b1", "b2", "b3", "b4"]


def snakemake(cfg: Path, targets: list[str], jobs: int) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "snakemake", "--cores", str(jobs), "--jobs", str(jobs),
                    "--nolock", *targets, "--configfile", str(cfg)],
                   cwd=ROOT, check=True, capture_output=True, text=True)
    return time.perf_counter() - t0


def setup(work: Path, assets: Path | None) -> tuple[Path, Path]:
    work.mkdir(parents=True, exist_ok=True)
    results = work / "results"
    if assets is not None:
        shutil.copytree(assets, results / "_assets")
    spec = yaml.safe_load((ROOT / "config" / "scenes" / "tiny.yaml").read_text())
    rows = ["sequence\tsource\tspec"]
    for i, name in enumerate(NAMES):
        spec["seed"] = i
        path = work / f"{name}.yaml"
        path.write_text(yaml.safe_dump(spec))
        rows.append(f"{name}\tsynthetic\t{path}")
    (work / "sequences.tsv").write_text("\n".join(rows) + "\n")
    cfg = work / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(results), "sequences": str(work / "sequences.tsv"),
                                   "scenes": []}))
    return results, cfg


def stage_times(results: Path) -> pd.DataFrame:
    rows = []
    for tsv in results.glob("_benchmarks/*/*.tsv"):
        df = pd.read_csv(tsv, sep="\t")
        rows.append({"sequence": tsv.parent.name, "stage": tsv.stem, "seconds": df["s"].iloc[0]})
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--target", default="sim/frames.parquet")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        # shared assets, built once and not timed
        results, cfg = setup(tmp / "assets", None)
        snakemake(cfg, [str(results / "_assets" / "body_model.npz"),
                        str(results / "_assets" / "gloss_library.parquet")], 2)
        assets = results / "_assets"

        results, cfg = setup(tmp / "batch", assets)
        batch = snakemake(cfg, [str(results / n / args.target) for n in NAMES], 2)
        per_stage = stage_times(results)

        one_by_one = 0.0
        results1, cfg1 = setup(tmp / "serial", assets)
        for name in NAMES:
            one_by_one += snakemake(cfg1, [str(results1 / name / args.target)], 1)

    table = pd.DataFrame([
        {"run": "batch -j 2", "sequences": len(NAMES), "wall_seconds": batch},
        {"run": "one by one -j 1", "sequences": len(NAMES), "wall_seconds": one_by_one},
    ])
    table["speedup_vs_one_by_one"] = one_by_one / table["wall_seconds"]
    OUT.mkdir(parents=True, exist_ok=True)
    table.to_parquet(OUT / "batch.parquet", index=False)
    per_stage.to_parquet(OUT / "batch_stages.parquet", index=False)
    print(table.to_string(index=False))
    print("\nper-stage seconds (batch run, from Snakemake benchmark files):")
    print(per_stage.groupby("stage")["seconds"].agg(["count", "mean", "sum"]).to_string())


if __name__ == "__main__":
    main()
