"""The SMPL-X fit of one finished sequence by this checkout and another, side by side.

    python benchmarks/bench_fit.py --baseline /path/to/old/checkout --scene clip \\
        --configfile config/config.yaml config/footage.yaml [--results results] [--threads 1] \\
        [--one-at-a-time] [--set sequences=config/scenes/suite/sequences.tsv] \\
        [--work /tmp/signsplat-bench-fit]

Both checkouts' workflows fit the sequence from the same inputs: the sequence's `frames`, `sim`
and `perception` folders and the results' `_assets` are linked into `--work/<label>`, and the
two `fit_smplx` jobs run at the same time, each with `--threads` threads (default 1: one core
each), or with `--one-at-a-time` the baseline's and then this checkout's, each alone (what
threads gain shows only so), Snakemake started in each checkout so that each imports its own
`signsplat`. A run stops before fitting if anything but the fit (and the body model) would run.

Prints and appends one row per checkout to `benchmarks/results/fit_time.parquet`: date, label,
commit, scene, threads, `runs` (side by side or one at a time), `wall_s` (the rule's own
benchmark seconds), `fit_s` and the fit's stages (`stage_<name>_s`, the fit log's seconds), the
fit log's evaluation figures (`eval_*`) and `max_param_diff`, the largest absolute difference
of any SMPL-X parameter from the baseline's fit (0: the change left the fit as it was). The
machine's speed varies from day to day: compare the two rows of one run, not seconds across
runs.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from _results import append_rows, commit_of  # benchmarks/_results.py

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results" / "fit_time.parquet"
INPUTS = ("frames", "sim", "perception")  # a sequence's folders the fit reads


def prepare(results: Path, scene: str, work: Path) -> None:
    """``work`` with hard links to the sequence's inputs and the shared assets (same mtimes,
    so the workflow takes them as up to date); no fit."""
    if work.exists():
        shutil.rmtree(work)
    found = [d for d in INPUTS if (results / scene / d).is_dir()]
    if "perception" not in found and "sim" not in found:
        raise SystemExit(f"{results / scene}: no perception or sim folder; run the workflow "
                         f"up to the fit first (snakemake {results / scene}/fit/fit_eval.parquet)")
    for d in found:
        shutil.copytree(results / scene / d, work / scene / d, copy_function=os.link)
    if (results / "_assets").is_dir():
        shutil.copytree(results / "_assets", work / "_assets", copy_function=os.link)


def snakemake(checkout: Path, work: Path, scene: str, args, dry: bool) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "snakemake", "--nolock", "--cores", str(args.threads),
           "--set-threads", f"fit_smplx={args.threads}", "--rerun-triggers", "mtime",
           "--configfile", *args.configfile, "--config", f"results={work}", *args.set, "--",
           str(work / scene / "fit" / "fit_eval.parquet")]
    if dry:
        cmd.insert(3, "-n")
    return subprocess.Popen(cmd, cwd=checkout, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def check_plan(checkout: Path, work: Path, scene: str, args) -> None:
    out = snakemake(checkout, work, scene, args, dry=True).communicate()[0]
    jobs = set(re.findall(r"^(\w+)\s+\d+$", out, re.M)) - {"total"}
    if "fit_smplx" not in jobs or jobs - {"fit_smplx", "body_model"}:
        hint = ""
        if re.search(r"Updated input files: models/", out):
            # a fresh checkout's (git worktree's) committed models are newer than the outputs
            hint = (f"\n{checkout}: its models/ files are newer than the linked outputs (a "
                    "fresh checkout?); if they are the same models, make them older: find "
                    f"{checkout}/models -maxdepth 1 -type f -exec touch -d 2000-01-01 {{}} +")
        raise SystemExit(f"{checkout}: the workflow would run {sorted(jobs) or 'nothing'}, "
                         f"not only the fit:\n{out[-3000:]}{hint}")


def fit_row(work: Path, scene: str) -> tuple[dict, pd.DataFrame]:
    fit = work / scene / "fit"
    log = json.loads((fit / "fit_log.json").read_text())
    bench = pd.read_csv(work / "_benchmarks" / scene / "fit_smplx.tsv", sep="\t")
    row = {"wall_s": float(bench["s"].iloc[0]), "fit_s": float(log["seconds"]["total"])}
    row.update({f"stage_{k}_s": float(v) for k, v in log["seconds"].items() if k != "total"})
    row.update({f"eval_{k.replace('/', '_')}": float(v) for k, v in log.get("eval", {}).items()
                if isinstance(v, (int, float))})
    return row, pd.read_parquet(fit / "smplx_fit.parquet")


def max_difference(a: pd.DataFrame, b: pd.DataFrame) -> float:
    """Largest absolute difference of the numeric (and array) columns the two fits share."""
    if len(a) != len(b):
        return float("inf")
    worst = 0.0
    for col in sorted(set(a.columns) & set(b.columns)):
        try:
            x = np.stack(a[col].map(lambda v: np.asarray(v, float)).to_numpy())
            y = np.stack(b[col].map(lambda v: np.asarray(v, float)).to_numpy())
        except (TypeError, ValueError):
            continue  # text columns
        if x.shape != y.shape:
            return float("inf")
        worst = max(worst, float(np.nanmax(np.abs(x - y))) if x.size else 0.0)
    return worst


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--baseline", type=Path, required=True, help="the checkout to compare with")
    p.add_argument("--scene", required=True, help="a sequence of the sheet, perceived already")
    p.add_argument("--results", type=Path, default=ROOT / "results")
    p.add_argument("--configfile", nargs="+", default=["config/config.yaml"])
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                   help="more --config values for both workflows (e.g. the sequences sheet)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--one-at-a-time", action="store_true",
                   help="run the baseline's fit, then this checkout's, each alone with every "
                        "thread (as `make demo` runs the studio6 fit: --threads 2), instead of "
                        "both at once")
    p.add_argument("--work", type=Path, default=Path("/tmp/signsplat-bench-fit"))
    args = p.parse_args(argv)
    checkouts = {"baseline": args.baseline.resolve(), "current": ROOT}
    base_cache, cache = checkouts["baseline"] / "models" / "cache", ROOT / "models" / "cache"
    if cache.is_dir() and not base_cache.exists():
        base_cache.symlink_to(cache)  # the fetched models, which a fresh worktree lacks
        print(f"linked {base_cache} -> {cache}")
    work = {label: (args.work / label).resolve() for label in checkouts}
    commits = {label: commit_of(c) for label, c in checkouts.items()}  # what runs, not what is
    for label, checkout in checkouts.items():
        prepare(args.results.resolve(), args.scene, work[label])
        check_plan(checkout, work[label], args.scene, args)

    def finish(label: str, proc: subprocess.Popen) -> None:
        out = proc.communicate()[0]
        if proc.returncode != 0:
            raise SystemExit(f"{checkouts[label]}: the fit failed (exit {proc.returncode}); "
                             f"log {work[label]}/_logs/{args.scene}/fit_smplx.log\n{out[-2000:]}")

    if args.one_at_a_time:
        for label, c in checkouts.items():
            finish(label, snakemake(c, work[label], args.scene, args, dry=False))
    else:
        procs = {label: snakemake(c, work[label], args.scene, args, dry=False)
                 for label, c in checkouts.items()}
        for label, proc in procs.items():
            finish(label, proc)
    rows, fits = [], {}
    for label in checkouts:
        row, fits[label] = fit_row(work[label], args.scene)
        rows.append({"date": dt.date.today().isoformat(), "label": label,
                     "commit": commits[label], "scene": args.scene,
                     "threads": args.threads,
                     "runs": "one at a time" if args.one_at_a_time else "side by side", **row})
    for row in rows:
        row["max_param_diff"] = max_difference(fits[row["label"]], fits["baseline"])
    df = pd.DataFrame(rows)
    print(df.set_index("label").T.to_string())
    base, cur = df.set_index("label").loc["baseline"], df.set_index("label").loc["current"]
    print(f"fit seconds baseline / current: {base['fit_s'] / cur['fit_s']:.2f}x "
          f"(wall {base['wall_s'] / cur['wall_s']:.2f}x); largest parameter difference "
          f"{cur['max_param_diff']:.3g}")
    append_rows(df, OUT)
    print(f"appended to {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
