"""The COLMAP comparison of one simulated sequence by this checkout and another, side by side.

    python benchmarks/bench_colmap.py --baseline /path/to/old/checkout [--scene studio6] \\
        [--results results] [--threads 1] [--work /tmp/signsplat-bench-colmap]

Both checkouts run `python -m signsplat colmap-compare` on the sequence's simulated images
(`<results>/<scene>/sim`) at the same time, each with `--threads` threads (default 1, as the
workflow's rule), started in their own folder so that each imports its own `signsplat`, with
the config's defaults of each checkout. Prints and appends one row per checkout to
`benchmarks/results/colmap_time.parquet`: date, label, commit, scene, threads, `wall_s` (the
command's wall clock), `sum_row_s` (the table's seconds summed over its COLMAP rows) and
`same_table` (whether every column but the times equals the baseline's: the change left the
reconstructions as they were). Compare the two rows of one run, not seconds across runs.
"""

from __future__ import annotations

import argparse
import datetime as dt
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

from _results import append_rows, commit_of  # benchmarks/_results.py

ROOT = Path(__file__).resolve().parents[1]
TIMES = ("seconds", "cpu_seconds", "ply")


def start(checkout: Path, sim: Path, out: Path, threads: int) -> subprocess.Popen:
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "signsplat", "colmap-compare",
           "--frames", str(sim / "frames.parquet"), "--cameras", str(sim / "cameras.parquet"),
           "--out", str(out / "colmap_compare.parquet"), "--ply", str(out / "points.ply"),
           "--ply-dir", str(out / "ply"), "--threads", str(threads)]
    with open(out / "colmap_compare.log", "w") as log:  # the child keeps its own handle
        return subprocess.Popen(cmd, cwd=checkout, stdout=log, stderr=subprocess.STDOUT)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--baseline", type=Path, required=True, help="the checkout to compare with")
    p.add_argument("--scene", default="studio6", help="a simulated multi-view sequence")
    p.add_argument("--results", type=Path, default=ROOT / "results")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--work", type=Path, default=Path("/tmp/signsplat-bench-colmap"))
    args = p.parse_args(argv)
    sim = (args.results / args.scene / "sim").resolve()
    if not (sim / "frames.parquet").exists():
        raise SystemExit(f"{sim}/frames.parquet not found: simulate {args.scene} first")
    checkouts = {"baseline": args.baseline.resolve(), "current": ROOT}
    t0 = time.perf_counter()
    procs = {k: start(c, sim, args.work / k, args.threads) for k, c in checkouts.items()}
    walls = {}
    while len(walls) < len(procs):  # each one's wall clock when it ends
        for label, proc in procs.items():
            if label not in walls and proc.poll() is not None:
                walls[label] = time.perf_counter() - t0
        time.sleep(0.1)
    tables = {}
    for label, proc in procs.items():
        if proc.returncode != 0:
            raise SystemExit(f"{label}: colmap-compare failed, see "
                             f"{args.work / label / 'colmap_compare.log'}")
        tables[label] = pd.read_parquet(args.work / label / "colmap_compare.parquet")
    keep = [c for c in tables["baseline"].columns if c not in TIMES]
    same = tables["baseline"][keep].equals(tables["current"].reindex(columns=keep))
    rows = []
    for label, checkout in checkouts.items():
        t = tables[label]
        rows.append({"date": dt.datetime.now().isoformat(timespec="minutes"), "label": label,
                     "commit": commit_of(checkout), "scene": args.scene,
                     "threads": args.threads, "wall_s": round(walls[label], 2),
                     "sum_row_s": round(float(t.loc[t["method"] != "smplx_camera_solve",
                                                    "seconds"].sum()), 2),
                     "same_table": bool(same)})
    rows = pd.DataFrame(rows)
    print(rows.to_string(index=False))
    print(f"baseline / current wall clock: {walls['baseline'] / walls['current']:.2f}x")
    append_rows(rows, ROOT / "benchmarks" / "results" / "colmap_time.parquet")
    return 0


if __name__ == "__main__":
    sys.exit(main())
