"""Cost accounting: benchmark files named by their rules, and each job matched to the SLURM
step that ran it (sacct lines as sacct prints them: --parsable2 --noheader)."""

import os
from datetime import datetime

import numpy as np
import pandas as pd
import pytest

from signsplat.report import accounting as A

BENCH_HEADER = "s\th:m:s\tmax_rss\tmax_vms\tmax_uss\tmax_pss\tio_in\tio_out\tmean_load\tcpu_time\n"
R = "results"
PATTERNS = {  # as the report rule passes them (wildcard constraints included)
    "body_model": {"benchmark": f"{R}/_benchmarks/body_model.tsv",
                   "log": f"{R}/_logs/body_model.log"},
    "segment": {"benchmark": f"{R}/_benchmarks/{{scene,[A-Za-z0-9_-]+}}/segment.tsv",
                "log": f"{R}/_logs/{{scene,[A-Za-z0-9_-]+}}/segment.log"},
    "detect_keypoints": {"benchmark": f"{R}/_benchmarks/{{scene}}/detect_keypoints.tsv",
                         "log": f"{R}/_logs/{{scene}}/detect_keypoints.log"},
    "train_avatar": {"benchmark": f"{R}/_benchmarks/{{scene}}/train_avatar_{{variant}}.tsv",
                     "log": f"{R}/_logs/{{scene}}/train_avatar_{{variant}}.log"},
    "evaluate_avatar": {"benchmark": f"{R}/_benchmarks/{{scene}}/evaluate_{{variant}}.tsv",
                        "log": f"{R}/_logs/{{scene}}/evaluate_{{variant}}.log"},
}


def _job(root, rel, seconds, cpu, rss, log_time):
    bench = root / "_benchmarks" / f"{rel}.tsv"
    bench.parent.mkdir(parents=True, exist_ok=True)
    bench.write_text(BENCH_HEADER + f"{seconds}\t0:00:01\t{rss}\t0\t0\t0\t0\t0\t0\t{cpu}\n")
    log = root / "_logs" / f"{rel}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    log.write_text("done\n")
    t = datetime.fromisoformat(log_time).timestamp()
    os.utime(log, (t, t))
    os.utime(bench, (t + 30, t + 30))  # Snakemake's main process touches it later


def _line(job, name, comment, state, start, end, elapsed, cpu="00:01.000", rss="",
          partition="main", mem="2000M", limit="01:15:00", cpus="2", tres="", submit=""):
    return "|".join([job, name, comment, partition, "signsplat", mem, limit, cpus, tres, state,
                     "0:0", start, end, str(elapsed), cpu, rss, "/repo", submit])


@pytest.fixture
def run(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    root = tmp_path / R
    _job(root, "body_model", 26.1, 6.4, 526.0, "2026-11-26T06:47:10.5")
    _job(root, "tiny/segment", 2.2, 1.0, 288.0, "2026-11-26T06:48:11.2")
    _job(root, "tiny/detect_keypoints", 2.2, 1.0, 290.0, "2026-11-26T06:48:17.9")
    _job(root, "tiny1/segment", 2.7, 1.1, 300.0, "2026-11-26T06:47:49.3")
    _job(root, "tiny/train_avatar_demo", 9.6, 6.1, 996.0, "2026-11-26T06:50:01.0")
    _job(root, "tiny/evaluate_demo", 8.0, 5.0, 900.0, "2026-11-26T07:30:00.0")  # not on SLURM
    group = "rule_perception_detect_keypoints_perception_eval_segment"
    lines = [
        _line("1", "u1", "rule_body_model", "COMPLETED", "2026-11-26T06:46:40",
              "2026-11-26T06:47:14", 34, mem="4000M", limit="00:20:00", cpus="1"),
        _line("1.batch", "batch", "", "COMPLETED", "2026-11-26T06:46:40",
              "2026-11-26T06:47:14", 34, rss="231832K"),
        _line("1.0", "python3.11", "", "COMPLETED", "2026-11-26T06:46:44",
              "2026-11-26T06:47:12", 28, cpu="00:13.246", rss="1233M"),
        # another job at the same time (1 CPU each), ending nearer body_model's log time
        _line("2", "u1", "rule_gloss_library", "COMPLETED", "2026-11-26T06:46:40",
              "2026-11-26T06:47:12", 32, cpus="1"),
        _line("2.0", "python3.11", "", "COMPLETED", "2026-11-26T06:46:45",
              "2026-11-26T06:47:11", 26),
        # two group jobs with the same comment: which sequence each ran is only in time
        _line("5", "u1", group, "COMPLETED", "2026-11-26T06:47:40", "2026-11-26T06:48:03", 23),
        _line("5.0", "python3.11", "", "COMPLETED", "2026-11-26T06:47:43",
              "2026-11-26T06:47:50", 7, cpu="00:02.967", rss="474904K"),
        _line("5.1", "python3.11", "", "COMPLETED", "2026-11-26T06:47:50",
              "2026-11-26T06:47:55", 5),
        _line("6", "u1", group, "COMPLETED", "2026-11-26T06:48:04", "2026-11-26T06:48:28", 24),
        _line("6.0", "python3.11", "", "COMPLETED", "2026-11-26T06:48:07",
              "2026-11-26T06:48:12", 5, cpu="00:02.743", rss="492546K"),
        _line("6.1", "python3.11", "", "COMPLETED", "2026-11-26T06:48:12",
              "2026-11-26T06:48:18", 6, cpu="00:02.813", rss="535601K"),
        # a crashed first attempt, then the retry that wrote the files
        _line("9", "u1", "rule_train_avatar_wildcards_tiny_demo", "FAILED",
              "2026-11-26T06:49:00", "2026-11-26T06:49:20", 20, partition="gpu",
              mem="6000M", limit="02:00:00", tres="billing=2,cpu=2,gres/gpu=1,mem=6000M"),
        _line("9.0", "python3.11", "", "FAILED", "2026-11-26T06:49:03",
              "2026-11-26T06:49:19", 16),
        _line("11", "u1", "rule_train_avatar_wildcards_tiny_demo", "COMPLETED",
              "2026-11-26T06:49:45", "2026-11-26T06:50:04", 19, partition="gpu",
              mem="6000M", limit="02:00:00"),
        _line("11.0", "python3.11", "", "COMPLETED", "2026-11-26T06:49:48",
              "2026-11-26T06:50:02", 14, cpu="01:02:03", rss="1.5G"),
    ]
    return root, A.sacct_table(lines)


def test_sacct_formats():
    assert A.parse_duration("00:13.246") == pytest.approx(13.246)
    assert A.parse_duration("01:02:03") == 3723
    assert A.parse_duration("1-00:00:10") == 86410
    assert A.parse_duration("02:00:00") == 7200
    assert np.isnan(A.parse_duration("UNLIMITED")) and np.isnan(A.parse_duration(""))
    assert A.parse_mem_mb("781176K") == pytest.approx(781176 / 1024)
    assert A.parse_mem_mb("4000M") == 4000 and A.parse_mem_mb("1.5G") == 1536
    assert A.parse_mem_mb("4000Mn") == 4000 and np.isnan(A.parse_mem_mb(""))


def test_benchmark_files_are_named_by_their_rules(run):
    root, _ = run
    jobs = A.benchmark_jobs(root / "_benchmarks", PATTERNS).set_index(["rule", "wildcards"])
    assert set(jobs.index) == {
        ("body_model", ""), ("segment", "scene=tiny"), ("segment", "scene=tiny1"),
        ("detect_keypoints", "scene=tiny"), ("train_avatar", "scene=tiny,variant=demo"),
        ("evaluate_avatar", "scene=tiny,variant=demo")}
    assert jobs.loc[("train_avatar", "scene=tiny,variant=demo"), "values"] == ["tiny", "demo"]
    # without patterns: the file stem
    assert "train_avatar_demo" in set(A.benchmark_jobs(root / "_benchmarks")["rule"])


def test_each_job_is_matched_to_the_step_that_ran_it(run):
    root, sacct = run
    jobs = A.job_costs(root, PATTERNS, sacct).set_index(["rule", "wildcards"])
    got = jobs["slurm_job"].to_dict()
    assert got == {("body_model", ""): "1.0",
                   ("segment", "scene=tiny1"): "5.0",      # the earlier group job
                   ("segment", "scene=tiny"): "6.0",
                   ("detect_keypoints", "scene=tiny"): "6.1",
                   ("train_avatar", "scene=tiny,variant=demo"): "11.0",  # the retry
                   ("evaluate_avatar", "scene=tiny,variant=demo"): ""}
    body = jobs.loc[("body_model", "")]
    assert body["req_mem_mb"] == 4000 and body["time_limit_min"] == 20
    assert body["slurm_cpu_s"] == pytest.approx(13.246) and body["slurm_max_rss_mb"] == 1233
    assert body["slurm_elapsed_s"] == 28 and body["job_elapsed_s"] == 34
    train = jobs.loc[("train_avatar", "scene=tiny,variant=demo")]
    assert train["partition"] == "gpu" and train["slurm_cpu_s"] == 3723
    assert train["slurm_max_rss_mb"] == 1536
    assert np.isnan(jobs.loc[("evaluate_avatar", "scene=tiny,variant=demo"), "slurm_cpu_s"])


def _step_line(job, start, end, target):
    submit = ("srun -n1 --cpu-bind=q --cpus-per-task=1 /repo/.venv/bin/python -m snakemake "
              f"--snakefile /repo/Snakefile --target-jobs {target} --allowed-rules segment "
              "--cores all --wrap-a|pipe")  # a '|' inside the last field
    return _line(job, "python", "", "COMPLETED", start, end, 9, submit=submit)


def test_group_jobs_at_the_same_time_are_told_apart_by_their_command_lines(tmp_path,
                                                                           monkeypatch):
    monkeypatch.chdir(tmp_path)
    root = tmp_path / R
    # two sequences' perception groups side by side: by time alone both logs are nearest to 8.0
    _job(root, "tiny2/segment", 8.0, 1.0, 300.0, "2026-11-26T07:00:09.2")
    _job(root, "tiny3/segment", 8.0, 1.0, 300.0, "2026-11-26T07:00:08.9")
    group = "rule_perception_detect_keypoints_perception_eval_segment"
    head = dict(state="COMPLETED", start="2026-11-26T06:59:58", end="2026-11-26T07:00:12",
                elapsed=14)
    lines = [_line("7", "u1", group, **head), _line("8", "u1", group, **head),
             _step_line("7.0", "2026-11-26T07:00:00", "2026-11-26T07:00:10",
                        "segment:scene=tiny2"),
             _step_line("8.0", "2026-11-26T07:00:00", "2026-11-26T07:00:09",
                        "'segment:scene=tiny3'")]
    sacct = A.sacct_table(lines)
    assert sacct["targets"].tolist() == [(), (), ("segment:scene=tiny2",),
                                         ("segment:scene=tiny3",)]
    jobs = A.job_costs(root, PATTERNS, sacct).set_index("wildcards")
    assert jobs["slurm_job"].to_dict() == {"scene=tiny2": "7.0", "scene=tiny3": "8.0"}


def test_the_jobs_a_command_line_runs():
    line = ("srun -n1 python -m snakemake --target-jobs 'train_avatar:scene=tiny,variant=demo' "
            'stitch:sentence="a,b" --allowed-rules train_avatar stitch')
    assert A.target_jobs(line) == ("train_avatar:scene=tiny,variant=demo", "stitch:sentence=a,b")
    assert A.target_jobs("sbatch --wrap 'python -m snakemake --target-jobs 'x") == ()
    assert A.target_jobs("") == () and A.target_key("r", {"b": 1, "a": 2}) == "r:a=2,b=1"


def test_rule_costs_sum_time_and_take_the_largest_memory(run):
    root, sacct = run
    jobs = A.job_costs(root, PATTERNS, sacct)
    rules = A.rule_costs(jobs).set_index("rule")
    seg = rules.loc["segment"]
    assert seg["jobs"] == 2 and seg["slurm_jobs"] == 2
    assert seg["seconds"] == pytest.approx(4.9) and seg["cpu_seconds"] == pytest.approx(2.1)
    assert seg["max_rss_mb"] == 300
    assert seg["slurm_cpu_s"] == pytest.approx(2.967 + 2.743)
    assert seg["slurm_max_rss_mb"] == pytest.approx(492546 / 1024)
    assert rules.loc["evaluate_avatar", "slurm_jobs"] == 0
    assert list(rules.columns) == list(A.RULE_COSTS.columns)[1:]
    assert rules["cpu_seconds"].is_monotonic_decreasing


def test_cost_tables_without_slurm_leave_out_the_scheduler_columns(run):
    root, _ = run
    tables = A.cost_tables(root, PATTERNS, sacct=False)
    assert len(tables) == 1
    caption, df = tables[0]
    assert "no SLURM accounting" in caption
    assert list(df.columns) == ["rule", "jobs", "seconds", "cpu_seconds", "max_rss_mb"]
    tables = A.cost_tables(root, PATTERNS, sacct=run[1])
    assert "5 of 6 jobs found" in tables[0][0] and len(tables[1][1]) == 5


def test_a_missing_sacct_means_no_slurm_figures(run, monkeypatch):
    monkeypatch.setattr(A.shutil, "which", lambda name: None)
    assert A.query_sacct() is None
    root, _ = run
    jobs = A.job_costs(root, PATTERNS)  # asks sacct: there is none
    assert (jobs["slurm_job"] == "").all() and len(jobs) == 6
    assert isinstance(jobs, pd.DataFrame)
