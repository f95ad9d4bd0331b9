"""What each stage costs: wall time, CPU time and peak memory per job and per rule, from the
Snakemake ``benchmark:`` files and, for a run on SLURM, from the scheduler's accounting
(``sacct``: elapsed, CPU time, MaxRSS, and what the job asked for) beside them.

A benchmark file is matched to its rule by the rules' benchmark patterns, which the workflow
passes (``{"train_avatar": {"benchmark": "results/_benchmarks/{scene}/train_avatar_{variant}.tsv",
"log": "results/_logs/{scene}/train_avatar_{variant}.log"}, ...}``). It is matched to a SLURM
job step by two facts:

- snakemake-executor-plugin-slurm (2.x) submits each job with the comment
  ``rule_<rule>_wildcards_<values joined by _>`` (``rule_<rule>`` without wildcards) and a group
  job with ``rule_<group>_<its rules joined by _>``; every rule of a job runs as one numbered
  step (``<job>.0``, ``.1``, ...);
- the step's command line (sacct's SubmitLine) names the jobs it ran:
  ``--target-jobs <rule>:<wildcard>=<value>,...``. Group jobs share one comment, so when two run
  at the same time this is what tells their steps apart;
- the rule's command writes its log file while it runs, inside that step, so the log's last
  modification lies within the step's start and end. (Not the benchmark file's: Snakemake's
  main process touches a job's outputs and benchmark file when it learns the job ended.)

Times from sacct are whole seconds; memory is MB (2^20 bytes). A step's CPU time and MaxRSS
include the Snakemake process that runs the rule inside the job (about 1.5 s and 200-250 MB
here), which the benchmark (the rule's command alone) does not.
"""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.io.tables import Table, register_table
from signsplat.report.collect import benchmark_files

SACCT_FIELDS = ("JobID", "JobName", "Comment", "Partition", "Account", "ReqMem", "Timelimit",
                "AllocCPUS", "ReqTRES", "State", "ExitCode", "Start", "End", "ElapsedRaw",
                "TotalCPU", "MaxRSS", "WorkDir", "SubmitLine")

JOB_COSTS = register_table(Table(
    "job_costs",
    "One row per benchmarked job of a run: the Snakemake benchmark figures and, when the job "
    "ran on SLURM, the sacct figures of the step that ran it (signsplat.report.accounting).",
    {
        "rule": "str rule name (the benchmark file stem when no pattern matched)",
        "wildcards": "str the job's wildcards as name=value, comma-separated ('' without)",
        "seconds": "float64 wall-clock seconds of the rule's command (benchmark `s`)",
        "cpu_seconds": "float64 CPU seconds of the command and its children (benchmark "
                       "`cpu_time`)",
        "max_rss_mb": "float64 peak resident memory, MB (benchmark `max_rss`)",
        "slurm_job": "str SLURM job id of the step ('' when not run on SLURM or not found)",
        "partition": "str SLURM partition",
        "req_mem_mb": "float64 memory the SLURM job asked for, MB",
        "time_limit_min": "float64 the SLURM job's time limit, minutes",
        "alloc_cpus": "float64 CPUs allocated to the SLURM job",
        "slurm_elapsed_s": "float64 elapsed seconds of the step (sacct ElapsedRaw)",
        "slurm_cpu_s": "float64 CPU seconds of the step (sacct TotalCPU)",
        "slurm_max_rss_mb": "float64 peak resident memory of the step, MB (sacct MaxRSS)",
        "job_elapsed_s": "float64 elapsed seconds of the whole SLURM job (with its start-up)",
    },
))

RULE_COSTS = register_table(Table(
    "rule_costs",
    "Per rule, the sums (time) and maxima (memory) of job_costs: what each stage costs.",
    {
        "rule": "str rule name",
        "jobs": "int64 benchmarked jobs of the rule",
        "seconds": "float64 summed wall-clock seconds (benchmark)",
        "cpu_seconds": "float64 summed CPU seconds (benchmark)",
        "max_rss_mb": "float64 largest peak resident memory, MB (benchmark)",
        "slurm_jobs": "int64 jobs matched to a SLURM step",
        "slurm_elapsed_s": "float64 summed elapsed seconds of those steps (sacct)",
        "slurm_cpu_s": "float64 summed CPU seconds of those steps (sacct)",
        "slurm_max_rss_mb": "float64 largest MaxRSS of those steps, MB (sacct)",
        "req_mem_mb": "float64 largest memory request of the rule's SLURM jobs, MB",
    },
))

_SLURM_COLUMNS = ["slurm_job", "partition", "req_mem_mb", "time_limit_min", "alloc_cpus",
                  "slurm_elapsed_s", "slurm_cpu_s", "slurm_max_rss_mb", "job_elapsed_s"]


# --- sacct's formats ----------------------------------------------------------------------------

def parse_duration(text: str) -> float:
    """Seconds of a SLURM duration: ``[D-]HH:MM:SS``, ``MM:SS.fff``, ``MM:SS`` (TotalCPU) or
    ``Timelimit``'s forms; NaN for empty, ``UNLIMITED`` or ``INVALID``."""
    text = (text or "").strip()
    if not text or not text[0].isdigit():
        return float("nan")
    days = 0
    if "-" in text:
        d, text = text.split("-", 1)
        days = int(d)
    parts = [float(p) for p in text.split(":")]
    while len(parts) < 3:
        parts.insert(0, 0.0)
    h, m, s = parts[-3:]
    return days * 86400 + h * 3600 + m * 60 + s


def parse_mem_mb(text: str) -> float:
    """MB of a SLURM memory figure (``781176K``, ``4000M``, ``2G``, ``4000Mn``); NaN if empty."""
    m = re.fullmatch(r"\s*([\d.]+)([KMGT]?)[nc]?\s*", text or "")
    if not m:
        return float("nan")
    scale = {"": 1 / 2**20, "K": 1 / 1024, "M": 1, "G": 1024, "T": 2**20}[m.group(2)]  # "": bytes
    return float(m.group(1)) * scale


def _time(text: str) -> pd.Timestamp:
    try:
        return pd.Timestamp(text)
    except (ValueError, TypeError):
        return pd.NaT


def target_key(rule: str, wildcards: dict) -> str:
    """One Snakemake job as ``rule:name=value,...`` (names sorted), to compare a benchmarked
    job with the ``--target-jobs`` of the SLURM step that ran it."""
    return f"{rule}:" + ",".join(f"{k}={v}" for k, v in sorted(wildcards.items()))


def target_jobs(submit_line: str) -> tuple[str, ...]:
    """The jobs a Snakemake command line runs (its ``--target-jobs`` entries, as
    ``target_key``); empty when the line names none (or sacct has no SubmitLine)."""
    try:  # quotes kept: Snakemake double-quotes a value that holds a comma
        words = shlex.split(submit_line or "", posix=False)
    except ValueError:  # an unbalanced quote: a line cut short
        return ()
    if "--target-jobs" not in words:
        return ()
    out = []
    for word in words[words.index("--target-jobs") + 1:]:
        if word.startswith("-"):
            break
        rule, _, wcs = word.strip("'").partition(":")
        pairs = re.findall(r'(\w+)=("[^"]*"|[^,]*)', wcs)
        out.append(target_key(rule, {k: v.strip('"') for k, v in pairs}))
    return tuple(out)


def sacct_table(lines: list[str], fields: tuple[str, ...] = SACCT_FIELDS) -> pd.DataFrame:
    """Rows of ``sacct --parsable2 --noheader --format=<fields>`` as a table: one row
    per job and per step (``step`` = '' for the job itself, else ``batch``, ``extern``, 0, 1...);
    ``targets`` are the jobs a step's command line names (``target_jobs``)."""
    rows = []
    for line in lines:
        if not line.strip():
            continue
        # the last field may hold '|' itself (a command line)
        f = dict(zip(fields, line.split("|", len(fields) - 1)))
        job, _, step = f["JobID"].partition(".")
        rows.append({
            "job": job, "step": step, "name": f["JobName"], "comment": f["Comment"],
            "partition": f["Partition"], "account": f["Account"],
            "req_mem_mb": parse_mem_mb(f["ReqMem"]),
            "time_limit_min": parse_duration(f["Timelimit"]) / 60,
            "alloc_cpus": float(f["AllocCPUS"]) if f["AllocCPUS"].isdigit() else np.nan,
            "req_tres": f["ReqTRES"], "state": f["State"].split(" ")[0],
            "exit_code": f["ExitCode"], "start": _time(f["Start"]), "end": _time(f["End"]),
            "elapsed_s": float(f["ElapsedRaw"]) if f["ElapsedRaw"].isdigit() else np.nan,
            "cpu_s": parse_duration(f["TotalCPU"]), "max_rss_mb": parse_mem_mb(f["MaxRSS"]),
            "workdir": f.get("WorkDir", ""),
            "targets": target_jobs(f.get("SubmitLine", "")) if step else (),
        })
    return pd.DataFrame(rows, columns=[
        "job", "step", "name", "comment", "partition", "account", "req_mem_mb",
        "time_limit_min", "alloc_cpus", "req_tres", "state", "exit_code", "start", "end",
        "elapsed_s", "cpu_s", "max_rss_mb", "workdir", "targets"])


def query_sacct(since: datetime | None = None, name: str | None = None,
                sacct: str = "sacct") -> pd.DataFrame | None:
    """This user's SLURM jobs and steps (since ``since``, default 2 days ago; of job name
    ``name`` when given), or None when sacct is missing or fails (no SLURM, or accounting
    storage disabled)."""
    exe = shutil.which(sacct)
    if exe is None:
        return None
    since = since or datetime.now() - timedelta(days=2)
    # an older sacct without SubmitLine is asked again without it (matching then goes by time)
    for fields in (SACCT_FIELDS, SACCT_FIELDS[:-1]):
        cmd = [exe, "--parsable2", "--noheader", f"--format={','.join(fields)}",
               f"--starttime={since:%Y-%m-%dT%H:%M:%S}", "--endtime=now"]
        if name:
            cmd.append(f"--name={name}")
        try:
            out = subprocess.run(cmd, capture_output=True, text=True, timeout=60,
                                 check=True).stdout
        except subprocess.CalledProcessError:
            continue  # sacct answered with an error (an unknown field, or no accounting)
        except (subprocess.SubprocessError, OSError):
            return None  # it did not answer: asking again would only wait again
        return sacct_table(out.splitlines(), fields)
    return None


# --- benchmark files ----------------------------------------------------------------------------

def _segments(pattern: str) -> list[tuple[str, str | None, str | None]]:
    """A Snakemake file pattern as (literal text, wildcard name, its constraint) pieces;
    constraints may hold braces (``{n,\\d{2}}``)."""
    out, i, lit = [], 0, ""
    while i < len(pattern):
        if pattern[i] != "{":
            lit += pattern[i]
            i += 1
            continue
        depth, j = 0, i
        while j < len(pattern):
            depth += {"{": 1, "}": -1}.get(pattern[j], 0)
            if depth == 0:
                break
            j += 1
        name, _, constraint = pattern[i + 1:j].partition(",")
        out.append((lit, name.strip(), constraint or None))
        lit, i = "", j + 1
    out.append((lit, None, None))
    return out


def _pattern_regex(pattern: str) -> tuple[re.Pattern, list[str]]:
    rx, names = "", []
    for lit, name, constraint in _segments(pattern):
        rx += re.escape(lit)
        if name:
            rx += f"(?P<{name}>{constraint})" if constraint and name not in names \
                else (f"(?P={name})" if name in names else f"(?P<{name}>[^/]+?)")
            names.append(name)
    return re.compile(rx + r"\Z"), list(dict.fromkeys(names))


def _fill(pattern: str, wildcards: dict[str, str]) -> str:
    return "".join(lit + (wildcards[name] if name else "")
                   for lit, name, _ in _segments(pattern))


def _literal_length(pattern: str) -> int:
    return sum(len(lit) for lit, _, _ in _segments(pattern))


def _match_rule(rel: str, patterns: dict[str, str]) -> tuple[str, dict[str, str]]:
    """(rule, wildcards) of a benchmark file path relative to ``_benchmarks``; the pattern
    with the longest literal text wins when several match."""
    best = None
    for rule, pattern in patterns.items():
        rx, names = _pattern_regex(pattern)
        m = rx.match(rel)
        if m:
            literal = _literal_length(pattern)
            if best is None or literal > best[0]:
                best = (literal, rule, {n: m.group(n) for n in names})
    if best is None:
        return Path(rel).stem, {}
    return best[1], best[2]


def _split_patterns(patterns: dict) -> tuple[dict[str, str], dict[str, str]]:
    """(rule -> benchmark pattern relative to ``_benchmarks/``, rule -> log pattern) from the
    workflow's patterns: rule -> benchmark pattern, or rule -> {"benchmark": .., "log": ..}."""
    bench, logs = {}, {}
    for rule, p in patterns.items():
        b = p.get("benchmark") if isinstance(p, dict) else p
        if b and "_benchmarks/" in str(b):
            bench[rule] = str(b).split("_benchmarks/", 1)[1]
        if isinstance(p, dict) and p.get("log"):
            logs[rule] = str(p["log"])
    return bench, logs


def benchmark_jobs(bench_dir: str | Path, patterns: dict | None = None) -> pd.DataFrame:
    """One row per benchmark file (mean over its repeats): rule, wildcards, seconds,
    cpu_seconds, max_rss_mb; ``values`` (the wildcard values in pattern order, for matching
    SLURM comments), ``target`` (``target_key``, for matching a step's command line) and
    ``written`` (when the job's command last wrote its log; the benchmark file's modification
    time when the rule has no log pattern or the log is missing)."""
    bench_dir = Path(bench_dir)
    patterns, logs = _split_patterns(patterns or {})
    rows = []
    for f, means in benchmark_files(bench_dir):
        rule, wc = _match_rule(f.relative_to(bench_dir).as_posix(), patterns)
        written = f
        if rule in logs:
            try:
                log = Path(_fill(logs[rule], wc))
            except KeyError:
                log = None
            if log is not None and log.is_file():
                written = log
        rows.append({"rule": rule, "wildcards": ",".join(f"{k}={v}" for k, v in wc.items()),
                     **means, "values": list(wc.values()), "target": target_key(rule, wc),
                     "written": pd.Timestamp(datetime.fromtimestamp(written.stat().st_mtime))})
    return pd.DataFrame(rows, columns=["rule", "wildcards", "seconds", "cpu_seconds",
                                       "max_rss_mb", "values", "target", "written"])


# --- matching -----------------------------------------------------------------------------------

def slurm_comment(rule: str, values: list[str]) -> str:
    """The comment snakemake-executor-plugin-slurm gives a (non-group) job of ``rule``."""
    wc = "_".join(values).replace("/", "_")
    return f"rule_{rule}_wildcards_{wc}" if wc else f"rule_{rule}"


def _is_group_of(comment: str, rule: str) -> bool:
    return "_wildcards_" not in comment and comment.startswith("rule_") and \
        re.search(rf"_{re.escape(rule)}(_|$)", comment) is not None


def match_slurm(jobs: pd.DataFrame, sacct: pd.DataFrame | None,
                workdir: str | None = None, slack_s: float = 2.0) -> pd.DataFrame:
    """``jobs`` (benchmark_jobs) with the sacct figures of the step that ran each job.

    Candidates are the steps of the SLURM jobs whose comment is the job's own (or a group
    job's that names its rule), in ``workdir`` when given, that ran this very job by their
    command line (steps whose command line sacct did not give stay candidates); of the steps
    whose start and end bracket ``written`` (within ``slack_s``), the one ending closest to it
    wins.
    """
    out = jobs.copy()
    for col in _SLURM_COLUMNS:
        out[col] = "" if col in ("slurm_job", "partition") else np.nan
    if sacct is None or not len(sacct) or not len(jobs):
        return out
    heads = sacct[sacct["step"] == ""].set_index("job")
    if workdir:
        heads = heads[(heads["workdir"] == "") | (heads["workdir"] == str(workdir))]
    steps = sacct[sacct["step"].str.fullmatch(r"\d+") & sacct["job"].isin(heads.index)]
    slack = pd.Timedelta(seconds=slack_s)
    for i, row in jobs.iterrows():
        own = slurm_comment(row["rule"], row["values"])
        ok = [j for j, c in heads["comment"].items() if c == own or _is_group_of(c, row["rule"])]
        ran_it = steps["targets"].map(lambda t: not t or row["target"] in t)
        cand = steps[steps["job"].isin(ok) & ran_it & (steps["start"] - slack <= row["written"])
                     & (steps["end"] + slack >= row["written"])]
        if not len(cand):
            continue
        step = cand.loc[(cand["end"] - row["written"]).abs().idxmin()]
        head = heads.loc[step["job"]]
        out.loc[i, "slurm_job"] = f"{step['job']}.{step['step']}"
        out.loc[i, "partition"] = head["partition"]
        for col in ("req_mem_mb", "time_limit_min", "alloc_cpus"):
            out.loc[i, col] = head[col]
        out.loc[i, "slurm_elapsed_s"] = step["elapsed_s"]
        out.loc[i, "slurm_cpu_s"] = step["cpu_s"]
        out.loc[i, "slurm_max_rss_mb"] = step["max_rss_mb"]
        out.loc[i, "job_elapsed_s"] = head["elapsed_s"]
    return out


def job_costs(results: str | Path, patterns: dict | None = None,
              sacct: pd.DataFrame | None | bool = True) -> pd.DataFrame:
    """The ``job_costs`` table of a results folder. ``sacct``: True = ask sacct (jobs since
    the oldest benchmark file, in this working directory), a table = use it, None/False = no
    SLURM figures."""
    jobs = benchmark_jobs(Path(results) / "_benchmarks", patterns)
    if sacct is True:
        since = None
        if len(jobs):
            oldest = jobs["written"].min() - pd.Timedelta(seconds=jobs["seconds"].max() + 3600)
            since = oldest.to_pydatetime()
        sacct = query_sacct(since)
        matched = match_slurm(jobs, sacct, workdir=os.getcwd())
    else:
        matched = match_slurm(jobs, sacct if isinstance(sacct, pd.DataFrame) else None)
    return matched.drop(columns=["values", "target", "written"])[list(JOB_COSTS.columns)]


def rule_costs(jobs: pd.DataFrame) -> pd.DataFrame:
    """The ``rule_costs`` table of a ``job_costs`` table, most expensive rule (CPU) first."""
    if not len(jobs):
        return pd.DataFrame(columns=list(RULE_COSTS.columns))
    on_slurm = jobs["slurm_job"] != ""
    g = jobs.assign(on_slurm=on_slurm).groupby("rule", sort=False)
    out = pd.DataFrame({
        "jobs": g.size(),
        "seconds": g["seconds"].sum(min_count=1),
        "cpu_seconds": g["cpu_seconds"].sum(min_count=1),
        "max_rss_mb": g["max_rss_mb"].max(),
        "slurm_jobs": g["on_slurm"].sum(),
        "slurm_elapsed_s": g["slurm_elapsed_s"].sum(min_count=1),
        "slurm_cpu_s": g["slurm_cpu_s"].sum(min_count=1),
        "slurm_max_rss_mb": g["slurm_max_rss_mb"].max(),
        "req_mem_mb": g["req_mem_mb"].max(),
    }).reset_index()
    out["jobs"] = out["jobs"].astype("int64")
    out["slurm_jobs"] = out["slurm_jobs"].astype("int64")
    return out.sort_values("cpu_seconds", ascending=False, na_position="last",
                           ignore_index=True)[list(RULE_COSTS.columns)]


def cost_tables(results: str | Path, patterns: dict | None = None,
                sacct: pd.DataFrame | None | bool = True) -> list[tuple[str, pd.DataFrame]]:
    """The report's cost tables: per rule, and per job when jobs ran on SLURM (the per-job
    benchmark figures alone are the report's "Jobs" table)."""
    jobs = job_costs(results, patterns, sacct)
    if not len(jobs):
        return []
    on_slurm = jobs["slurm_job"] != ""
    note = (f"{int(on_slurm.sum())} of {len(jobs)} jobs found in SLURM's accounting (sacct)"
            if on_slurm.any() else "no SLURM accounting for these jobs (not run on SLURM, or "
            "sacct unavailable)")
    per_rule = rule_costs(jobs).round(2)
    if not on_slurm.any():
        per_rule = per_rule[["rule", "jobs", "seconds", "cpu_seconds", "max_rss_mb"]]
    tables = [(f"Cost per rule: benchmark files; {note}", per_rule)]
    if on_slurm.any():
        tables.append(("Jobs on SLURM: benchmark beside sacct", jobs[on_slurm].round(2)))
    return tables
