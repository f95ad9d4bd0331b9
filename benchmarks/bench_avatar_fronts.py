"""The avatar's accuracy-versus-time front before and after a change, measured side by side.

Trains and evaluates the settings of the workflow's `sweep` target (ground-truth SMPL-X; the
`demo` point, which needs the fit, is left out) with two checkouts, one after the other on this
machine, and writes their fronts to ``benchmarks/results/avatar_fronts.parquet`` (table
``avatar_fronts``) and ``.png``; the report shows them when the file exists.

    python benchmarks/bench_avatar_fronts.py --old 0289f30          # old vs this checkout
    python benchmarks/bench_avatar_fronts.py --old 0289f30 --collect-only   # table again

Both commits are checked out with ``git worktree`` under ``--work`` and run with this
checkout's Python environment (each imports its own ``signsplat`` from its folder). Each job
has the sweep's two threads and the jobs run one at a time (``--cores``, default 2).
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from datetime import date
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

OUT = ROOT / "benchmarks" / "results" / "avatar_fronts.parquet"


def git(*args: str, cwd: Path = ROOT) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True,
                          text=True).stdout.strip()


def checkout(commit: str, work: Path, label: str) -> Path:
    """A worktree of ``commit`` (so that edits to this checkout do not reach a run); the one
    already under ``work`` when it holds that commit."""
    src = work / f"src-{label}"
    if not src.exists():
        git("worktree", "add", "--detach", str(src), commit)
    elif git("rev-parse", "HEAD", cwd=src) != commit:
        raise SystemExit(f"{src} holds another commit than {commit[:10]}: remove it "
                         f"(git worktree remove {src}) or pass another --work")
    return src


def run_record(work: Path, label: str, rev: str, collect_only: bool) -> dict:
    """The commit and date of ``label``'s run: written when it runs, read back by
    ``--collect-only`` (so that a rebuilt table keeps what actually ran, and when)."""
    path = work / label / "run.json"
    if collect_only:
        if not path.exists():
            raise SystemExit(f"{path} not found: run without --collect-only first")
        return json.loads(path.read_text())
    record = {"commit": git("rev-parse", rev), "measured": date.today().isoformat()}
    if path.exists() and json.loads(path.read_text())["commit"] != record["commit"]:
        # Snakemake would take that commit's finished outputs as this one's (a new worktree
        # has no record of the code that wrote them) and the table would carry the wrong label
        raise SystemExit(f"{path.parent} holds the runs of another commit than "
                         f"{record['commit'][:10]}: remove {path.parent} or pass another --work")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(record))
    return record


def sweep_points(src: Path, results: Path) -> list[tuple[str, str]]:
    """(scene, variant) of the sweep's trainings in ``src``'s workflow, the demo left out."""
    dry = subprocess.run([sys.executable, "-m", "snakemake", "-n", "-F", "sweep", "--config",
                          f"results={results}"], cwd=src, capture_output=True, text=True)
    if dry.returncode != 0:
        raise SystemExit(f"{src}: dry run of `sweep` failed:\n{dry.stdout[-2000:]}"
                         f"{dry.stderr[-2000:]}")
    found = re.findall(r"rule train_avatar:\n(?:    .*\n)*?    wildcards: scene=(\w+), "
                       r"variant=(\w+)", dry.stdout + dry.stderr)
    return sorted({p for p in found if p[1] != "demo"})


def run(src: Path, results: Path, points: list[tuple[str, str]], cores: int) -> float:
    targets = [str(results / s / "eval" / v / "metrics.parquet") for s, v in points]
    print(f"{src}: {', '.join(v for _, v in points)}", flush=True)
    t0 = time.time()
    res = subprocess.run([sys.executable, "-m", "snakemake", *targets, "--cores", str(cores),
                          "--config", f"results={results}"], cwd=src)
    if res.returncode != 0:
        raise SystemExit(f"{src}: the sweep's trainings failed (exit {res.returncode})")
    return time.time() - t0


def setting(variant: str) -> str:
    """The sweep's name of a point: the changed axis and value, or ``centre``."""
    m = re.fullmatch(r"sw_(iterations|resolution|max_points)(\d+)", variant)
    return f"{m.group(1)} {m.group(2)}" if m else "centre"


def collect(runs: list[tuple[str, str, Path, Path, list[tuple[str, str]]]], measured: str):
    import pandas as pd

    from signsplat.report.plots import avatar_fronts
    from signsplat.report.runs import FRONTS_TABLE, fronts_table, write_parquet

    rows = []
    for label, commit, _, _, points in runs:
        for scene, variant in points:
            rows.append({"code": label, "commit": commit[:10], "measured": measured,
                         "scene": scene, "variant": variant, "setting": setting(variant)})
    df = fronts_table(pd.DataFrame(rows), {r[0]: r[3] for r in runs})
    write_parquet(df, OUT, FRONTS_TABLE.name)
    avatar_fronts(df, OUT.with_suffix(".png"))
    print(df[["code", "setting", "psnr", "ssim", "hand_psnr", "seconds", "points",
              "pareto_psnr"]].to_string(index=False))
    print(f"wrote {OUT} and {OUT.with_suffix('.png')}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--old", required=True, help="the commit before the change")
    p.add_argument("--new", default="HEAD", help="the commit after it (default: this checkout)")
    p.add_argument("--work", default="/tmp/signsplat-fronts", help="worktrees and results")
    p.add_argument("--cores", type=int, default=2)
    p.add_argument("--collect-only", action="store_true",
                   help="only read the finished runs under --work and write the table")
    a = p.parse_args(argv)
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    runs, records = [], []
    for label, rev in (("before", a.old), ("after", a.new)):
        record = run_record(work, label, rev, a.collect_only)
        src = checkout(record["commit"], work, label)
        results = work / label / "results"
        runs.append((label, record["commit"], src, results, sweep_points(src, results)))
        records.append(record)
    measured = ", ".join(sorted({r["measured"] for r in records}))
    if not a.collect_only:
        for label, _, src, results, points in runs:  # one after the other: each has the cores
            seconds = run(src, results, points, a.cores)
            print(f"{label}: {seconds:.0f} s", flush=True)
    collect(runs, measured)
    return 0


if __name__ == "__main__":
    sys.exit(main())
