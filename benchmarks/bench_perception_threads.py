"""The perception stages (shipped segmenter and keypointer, two threads) on one simulated
sequence, this checkout beside another, alone and beside a busy core, in one run.

    python benchmarks/bench_perception_threads.py --baseline /path/to/old/checkout \
        [--sim results/studio6/sim] [--repeats 2] [--threads 2]

A busy core stands for what shares the machine with a perception job: the other sequence's
jobs in `make demo`, other users' jobs on a shared node. Each measurement is a fresh process
(PYTHONPATH = the checkout, this interpreter) that segments the sequence's frames and detects
their keypoints; the checkouts alternate within each repeat. Prints and appends one row per
measurement to benchmarks/results/perception_threads.parquet: date, label, commit, condition,
repeat, images, wall_s, cpu_s (the process's user + system time).
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd

from _results import append_rows, commit_of  # benchmarks/_results.py

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "perception_threads.parquet"

# Run in the measured checkout: its own signsplat, its own copy of the shipped models.
CHILD = """
import json, resource, sys, time
from pathlib import Path
import pandas as pd
from signsplat.perception.cli import perception_config, specs
from signsplat.perception.stages import detect_sequence, segment_sequence
checkout, sim, out = (Path(a) for a in sys.argv[1:4])
threads = int(sys.argv[4])
seg, kp = specs(perception_config(None))
seg = type(seg)(**{**seg.__dict__, "path": str(checkout / seg.path)})
kp = type(kp)(**{**kp.__dict__, "path": str(checkout / kp.path)})
r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
segment_sequence(sim / "frames.parquet", out, seg, threads, progress=False)
detect_sequence(sim / "frames.parquet", out / "masks.parquet", out / "keypoints.parquet", kp,
                threads, progress=False)
r1 = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({"wall_s": time.perf_counter() - t0,
                  "cpu_s": r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime,
                  "images": len(pd.read_parquet(sim / "frames.parquet"))}))
"""

BUSY = "import time\nwhile True: pass\n"


def measure(checkout: Path, sim: Path, threads: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout))
    with tempfile.TemporaryDirectory(prefix="signsplat-bench-") as out:
        proc = subprocess.run([sys.executable, "-c", CHILD, str(checkout), str(sim),
                               str(Path(out) / "perception"), str(threads)],
                              cwd=checkout, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{checkout}: the perception run failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--baseline", type=Path, required=True, help="the checkout to compare with")
    p.add_argument("--sim", type=Path, default=ROOT / "results" / "studio6" / "sim",
                   help="a simulated sequence's folder (frames.parquet and images)")
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--threads", type=int, default=2)
    a = p.parse_args(argv)
    if not (a.sim / "frames.parquet").is_file():
        raise SystemExit(f"{a.sim / 'frames.parquet'} not found: simulate the sequence first "
                         f"(snakemake {a.sim / 'frames.parquet'}) or pass --sim")
    checkouts = {"current": ROOT, "baseline": a.baseline.resolve()}
    commits = {label: commit_of(c) for label, c in checkouts.items()}
    rows = []
    for condition in ("alone", "beside a busy core"):
        busy = (subprocess.Popen([sys.executable, "-c", BUSY])
                if condition != "alone" else None)
        try:
            for repeat in range(a.repeats):
                for label, checkout in checkouts.items():
                    row = {"date": dt.date.today().isoformat(), "label": label,
                           "commit": commits[label], "condition": condition, "repeat": repeat,
                           "threads": a.threads, "sim": str(a.sim),
                           **measure(checkout, a.sim, a.threads)}
                    rows.append(row)
                    print(f"{condition:19s} {label:8s} {row['commit']}  wall {row['wall_s']:6.1f} s"
                          f"  cpu {row['cpu_s']:6.1f} s  ({row['images']} images)", flush=True)
        finally:
            if busy is not None:
                busy.kill()
                busy.wait()
    df = pd.DataFrame(rows)
    means = df.groupby(["condition", "label"])[["wall_s", "cpu_s"]].mean().unstack("label")
    for condition in means.index:
        wall, cpu = means.loc[condition, "wall_s"], means.loc[condition, "cpu_s"]
        print(f"{condition}: wall baseline / current {wall['baseline'] / wall['current']:.2f}x, "
              f"CPU {cpu['baseline'] / cpu['current']:.2f}x")
    append_rows(df, OUT)
    print(f"appended to {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
