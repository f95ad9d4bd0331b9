"""The test suite's wall-clock and CPU time, this checkout beside another, in one run.

    python benchmarks/bench_test_suite.py --baseline /path/to/old/checkout \
        [--baseline-args="-q --durations=40"] [--args="-q -n 3 --dist worksteal --durations=40"]

Each checkout runs its own tests with its own library on the path (PYTHONPATH = the checkout),
with this interpreter; where the baseline pinned another version of a dependency, install that
version into a folder (`pip install --no-deps --target DIR pkg==x`) and pass it with
--baseline-path DIR (put before the checkout on the baseline's PYTHONPATH). Prints and
appends one row per run to benchmarks/results/test_suite.parquet (pytest's output of each run
goes to /tmp/signsplat-bench/test_suite-LABEL.log): label, commit, args, wall_s, cpu_user_s,
cpu_sys_s, passed, failed, skipped, load_before (1-minute load average when the run started).
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import re
import resource
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd

from _results import append_rows, commit_of  # benchmarks/_results.py

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "test_suite.parquet"
LOGS = Path("/tmp/signsplat-bench")  # each run's pytest output (durations, failures)


def _count(summary: str, word: str) -> int:
    match = re.search(rf"(\d+) {word}", summary)
    return int(match.group(1)) if match else 0


def run_suite(label: str, checkout: Path, args: list[str], path: list[str] = ()) -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([*path, str(checkout)]))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    load = os.getloadavg()[0]
    start = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", *args], cwd=checkout, env=env,
        capture_output=True, text=True, check=False,
    )
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    tail = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
    log = LOGS / f"test_suite-{label}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text(proc.stdout + proc.stderr)
    row = {
        "date": dt.date.today().isoformat(), "label": label, "commit": commit_of(checkout),
        "args": shlex.join(args), "wall_s": wall,
        "cpu_user_s": after.ru_utime - before.ru_utime,
        "cpu_sys_s": after.ru_stime - before.ru_stime,
        "passed": _count(tail, "passed"), "failed": _count(tail, "failed"),
        "errors": _count(tail, "error"), "skipped": _count(tail, "skipped"),
        "load_before": load, "summary": tail,
    }
    print(f"{label:9s} {row['commit']} wall {wall:7.1f} s  user {row['cpu_user_s']:7.1f} s  "
          f"load {load:.2f}  {tail}", flush=True)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, required=True, help="the other checkout")
    parser.add_argument("--args", default="-q -n 3 --dist worksteal --durations=40",
                        help="pytest arguments for this checkout (make test's)")
    parser.add_argument("--baseline-args", default=None,
                        help="pytest arguments for the baseline (default: --args)")
    parser.add_argument("--baseline-path", action="append", default=[],
                        help="a folder put first on the baseline's PYTHONPATH (the dependency "
                             "versions it pinned); may be repeated")
    opts = parser.parse_args()
    runs = [
        ("current", ROOT, shlex.split(opts.args), []),
        ("baseline", opts.baseline.resolve(), shlex.split(opts.baseline_args or opts.args),
         opts.baseline_path),
    ]
    rows = [run_suite(label, path, args, extra) for label, path, args, extra in runs]
    table = pd.DataFrame(rows)
    append_rows(table, OUT)
    base, cur = rows[1]["wall_s"], rows[0]["wall_s"]
    print(f"wall-clock ratio baseline / current: {base / cur:.2f}x")


if __name__ == "__main__":
    main()
