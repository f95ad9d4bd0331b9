"""Batch benchmark (issue 26): dataset-sized synthetic batches on the laptop profile and on
the local SLURM cluster, and the dry-run DAG build time up to 1,000 sequences.

Sheets come from `signsplat sheet synth` (signers x sentences; bodies, appearances, gloss
sentences and 1-6 cameras vary; every scene is the tiny one: 64 px, 4 frames). Each run goes
from simulation through perception and the SMPL-X fit (the simulator's keypoints, a few steps)
to a short avatar (`--avatar-steps`, default 20) and its evaluation, for every sequence:

- ``local``: the laptop profile (profiles/default, local executor, `--cores 2`);
- ``slurm``: the shipped profiles/slurm through the local single-node cluster
  (workflow/cluster/local-slurm.sh must be running; its account and default partition given on
  the command line, first status check after 2 s).

Per run: wall seconds; CPU seconds (local: Snakemake and every job, from the OS; slurm:
Snakemake's own plus sacct's TotalCPU of the run's jobs, which includes the Snakemake process
inside each job); the rules' commands' CPU seconds (benchmark files); jobs; jobs per second;
per-rule costs (signsplat.report.accounting). The shared assets (body model, gloss library)
are built once and not timed. Saved to benchmarks/results/: batch.parquet, batch_rules.parquet
and batch_dag.parquet (`snakemake -n -q` of `all` over sheets of --dag-sizes sequences).

    .venv/bin/python benchmarks/bench_batch.py [--sizes 2 8 24] [--executors local slurm]
        [--dag-sizes 24 100 1000] [--avatar-steps 20]
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
OUT = ROOT / "benchmarks" / "results"

from signsplat.report.accounting import job_costs, query_sacct, rule_costs  # noqa: E402

ACCOUNT, PARTITION = "signsplat", "main"  # what local-slurm.sh sets up


def shape(n: int) -> tuple[int, int]:
    """signers x sentences = n, as square as possible (fewer signers than sentences)."""
    signers = max(d for d in range(1, int(n ** 0.5) + 1) if n % d == 0)
    return signers, n // signers


def make_sheet(folder: Path, n: int) -> tuple[Path, list[str]]:
    signers, sentences = shape(n)
    subprocess.run([sys.executable, "-m", "signsplat", "sheet", "synth", "--signers",
                    str(signers), "--sentences", str(sentences), "--out", str(folder)],
                   cwd=ROOT, check=True, capture_output=True)
    sheet = folder / "sequences.tsv"
    names = pd.read_csv(sheet, sep="\t")["sequence"].tolist()
    return sheet, names


def run_config(work: Path, sheet: Path, avatar_steps: int) -> tuple[Path, Path]:
    results = work / "results"
    cfg = {
        "results": str(results), "sequences": str(sheet), "scenes": [],
        "fit": yaml.safe_load((ROOT / "config" / "fit_few_steps.yaml").read_text())["fit"],
        "avatar": {"upsample": {"max_rounds": 0},
                   "train": {"iterations": avatar_steps, "test_interval": 2, "test_offset": 1,
                             "log_every": 10, "checkpoint_every": 1000},
                   "eval": {"refine_steps": 0, "save_images": 1}},
    }
    path = work / "config.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return results, path


def targets(results: Path, names: list[str]) -> list[str]:
    return [str(results / n / f) for n in names
            for f in ("perception/eval.parquet", "fit/fit_eval.parquet",
                      "eval/demo/metrics.parquet")]


def slurm_args(logdir: Path) -> list[str]:
    profile = yaml.safe_load((ROOT / "profiles" / "slurm" / "config.yaml").read_text())
    defaults = {**profile["default-resources"], "slurm_account": ACCOUNT,
                "slurm_partition": PARTITION}
    return ["--workflow-profile", "profiles/slurm",
            "--default-resources", *[f"{k}={v}" for k, v in defaults.items()],
            "--slurm-init-seconds-before-status-checks", "2", "--slurm-logdir", str(logdir)]


def snakemake(args: list[str]) -> tuple[subprocess.CompletedProcess, float, float]:
    """Run Snakemake; (result, wall seconds, CPU seconds of it and its waited children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "snakemake", "--nolock", *args], cwd=ROOT,
                         capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return res, wall, cpu


def patterns(results: Path) -> dict:
    """Rule -> benchmark / log patterns (as the report rule gets them), for this layout."""
    r = str(results)
    per_scene = {"simulate": "simulate", "segment": "segment",
                 "detect_keypoints": "detect_keypoints", "perception_eval": "perception_eval",
                 "fit_smplx": "fit_smplx", "train_avatar": "train_avatar_{variant}",
                 "evaluate_avatar": "evaluate_{variant}"}
    return {rule: {"benchmark": f"{r}/_benchmarks/{{scene}}/{stem}.tsv",
                   "log": f"{r}/_logs/{{scene}}/{stem}.log"} for rule, stem in per_scene.items()}


def one_run(executor: str, n: int, work: Path, assets: Path, avatar_steps: int) -> tuple[dict, pd.DataFrame]:
    sheet, names = make_sheet(work / "sheet", n)
    results, cfg = run_config(work, sheet, avatar_steps)
    shutil.copytree(assets, results / "_assets")
    for p in (results / "_assets").iterdir():
        os.utime(p)
    args = [*targets(results, names), "--configfile", str(cfg)]
    args += ["--cores", "2"] if executor == "local" else slurm_args(work / "slurm_logs")
    res, wall, cpu = snakemake(args)
    if res.returncode != 0:
        raise SystemExit(f"{executor} run of {n} sequences failed:\n{res.stderr[-4000:]}")
    sacct = None
    slurm_jobs, slurm_elapsed = 0, float("nan")
    if executor == "slurm":
        run_id = re.search(r"SLURM run ID: (\S+)", res.stdout + res.stderr).group(1)
        time.sleep(2)  # the last job's accounting record
        sacct = query_sacct(name=run_id)
        heads = sacct[sacct["step"] == ""]
        slurm_jobs = len(heads)
        slurm_elapsed = float(heads["elapsed_s"].sum())
        cpu += float(heads["cpu_s"].sum())
    jobs = job_costs(results, patterns(results), sacct if sacct is not None else False)
    cams = [yaml.safe_load((work / "sheet" / "scenes" / f"{m}.yaml").read_text())["cameras"]
            ["count"] for m in names]
    row = {"executor": executor, "sequences": n, "views": int(sum(cams)),
           "jobs": len(jobs), "slurm_jobs": slurm_jobs, "slurm_job_elapsed_s": slurm_elapsed,
           "wall_s": wall, "cpu_s": cpu, "command_cpu_s": float(jobs["cpu_seconds"].sum()),
           "command_wall_s": float(jobs["seconds"].sum()),
           "jobs_per_s": len(jobs) / wall, "avatar_steps": avatar_steps,
           # the machine's 5-minute load average at the end (2 cores: above ~2 it was shared)
           "load_avg_5min": os.getloadavg()[1], "date": date.today().isoformat()}
    per_rule = rule_costs(jobs).assign(executor=executor, sequences=n)
    return row, per_rule


def dag_time(n: int, work: Path) -> dict:
    sheet, _ = make_sheet(work / f"dag{n}", n)
    args = ["-n", "-q", "--cores", "2", "--config", f"sequences={sheet}", "scenes=[]",
            f"results={work / f'dag{n}_results'}"]
    best = None
    for _ in range(2):
        res, wall, cpu = snakemake(args)
        if res.returncode != 0:
            raise SystemExit(f"dry run of {n} sequences failed:\n{res.stderr[-3000:]}")
        best = min(best or (wall, cpu), (wall, cpu))
    out = subprocess.run([sys.executable, "-m", "snakemake", "-n", "--nolock", *args[2:]],
                         cwd=ROOT, capture_output=True, text=True).stdout
    total = re.search(r"^total\s+(\d+)", out, re.M)
    return {"sequences": n, "jobs": int(total.group(1)) if total else -1,
            "wall_s": best[0], "cpu_s": best[1], "date": date.today().isoformat()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sizes", type=int, nargs="+", default=[2, 8, 24])
    parser.add_argument("--executors", nargs="+", default=["local", "slurm"],
                        choices=["local", "slurm"])
    parser.add_argument("--dag-sizes", type=int, nargs="*", default=[24, 100, 1000])
    parser.add_argument("--avatar-steps", type=int, default=20)
    parser.add_argument("--append", action="store_true",
                        help="keep the runs already in batch.parquet / batch_rules.parquet "
                             "(those of other sizes or executors) and add these")
    args = parser.parse_args()
    if "slurm" in args.executors and subprocess.run(
            [str(ROOT / "workflow" / "cluster" / "local-slurm.sh"), "status"],
            capture_output=True).returncode != 0:
        raise SystemExit("the local SLURM cluster is not running: "
                         "workflow/cluster/local-slurm.sh start")
    OUT.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        tmp = Path(tmp)
        dag = pd.DataFrame([dag_time(n, tmp) for n in args.dag_sizes])
        if len(dag):
            dag.to_parquet(OUT / "batch_dag.parquet", index=False)
            print("dry run (snakemake -n -q, all targets), best of 2:")
            print(dag.to_string(index=False))
        # shared assets, built once by the workflow's own rules, not timed
        sheet, names = make_sheet(tmp / "assets" / "sheet", 1)
        results, cfg = run_config(tmp / "assets", sheet, args.avatar_steps)
        res, _, _ = snakemake([str(results / "_assets" / "body_model.npz"),
                               str(results / "_assets" / "gloss_library.parquet"),
                               "--configfile", str(cfg), "--cores", "2"])
        assert res.returncode == 0, res.stderr[-3000:]
        rows, rules = [], []
        if args.append and (OUT / "batch.parquet").exists():
            done = pd.read_parquet(OUT / "batch.parquet")
            new_runs = {(e, n) for e in args.executors for n in args.sizes}
            keep = [(e, n) not in new_runs for e, n in zip(done["executor"], done["sequences"])]
            rows = done[keep].drop(columns=["marginal_wall_s_per_sequence"],
                                   errors="ignore").to_dict("records")
            old_rules = pd.read_parquet(OUT / "batch_rules.parquet")
            rules = [old_rules[[(e, n) not in new_runs for e, n in
                                zip(old_rules["executor"], old_rules["sequences"])]]]
        for n in args.sizes:
            for executor in args.executors:
                row, per_rule = one_run(executor, n, tmp / f"{executor}{n}",
                                        results / "_assets", args.avatar_steps)
                print(f"{executor:>5} {n:>3} sequences: {row['wall_s']:7.1f} s wall, "
                      f"{row['cpu_s']:7.1f} s CPU, {row['jobs']} jobs, "
                      f"{row['jobs_per_s']:.3f} jobs/s", flush=True)
                rows.append(row)
                rules.append(per_rule)
                save(rows, rules)  # after every run: a stopped benchmark keeps what it measured
    print(save(rows, rules).to_string(index=False))


def save(rows: list[dict], rules: list[pd.DataFrame]) -> pd.DataFrame:
    """Write batch.parquet (with the wall time each added sequence costs, per executor) and
    batch_rules.parquet; returns the batch table."""
    table = pd.DataFrame(rows)
    for _, g in table.groupby("executor"):
        g = g.sort_values("sequences")
        table.loc[g.index, "marginal_wall_s_per_sequence"] = (
            g["wall_s"].diff() / g["sequences"].diff()).values
    table.to_parquet(OUT / "batch.parquet", index=False)
    pd.concat(rules, ignore_index=True).to_parquet(OUT / "batch_rules.parquet", index=False)
    return table

if __name__ == "__main__":
    main()
