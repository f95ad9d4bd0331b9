"""The workflow through a real SLURM scheduler (a single-node cluster on this machine, see
conftest.py) with the shipped profile (profiles/slurm): the tiny multi-view sequence end to end
(every rule of the default run has a job in it), every job a SLURM job with what it asked
for, the perception group one SLURM job, outputs equal to the local run's, an injected crash
retried, and a cancelled job redone cleanly. (How the profile groups two sequences' perception
is checked by the dry run in tests/test_batch.py.)"""

import json
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
import torch
import yaml

from signsplat.io.atomic import is_temporary
from signsplat.io.images import read_rgb
from signsplat.report.accounting import query_sacct

from workflow_runs import (TINY_THREADS, proxy_body, shared_once, snakemake, tiny_config,
                           tiny_local_run)

from .slurm_helpers import (ACCOUNT, PARTITION, ROOT, fault_env, logged_jobs, slurm_args,
                            slurm_env)

pytestmark = [pytest.mark.cluster, pytest.mark.slow]

# The crash injected into the SLURM run: fit_smplx of tiny dies after its first file.
FAULT = "fail-once:fit:/tiny/fit:1"


def _slurm_run(work: Path, body: Path) -> dict:
    work.mkdir(parents=True, exist_ok=True)
    cfg = tiny_config(work, body=body, single_view=False)
    t0 = time.time()
    res = snakemake("--configfile", str(cfg), *TINY_THREADS, *slurm_args(work / "slurm_logs"),
                    env=fault_env(FAULT, work / "fault"))
    log = res.stdout + res.stderr
    assert res.returncode == 0, log[-6000:]
    return {"work": str(work), "log": log, "seconds": time.time() - t0}


@pytest.fixture(scope="module")
def slurm_run(slurm_cluster, tmp_path_factory):
    """The tiny multi-view sequence through the local cluster (once per session), with
    fit_smplx made to crash once."""
    body = proxy_body(tmp_path_factory)
    run = shared_once(tmp_path_factory, "slurm_run", lambda work: _slurm_run(work, body))
    work, log = Path(run["work"]), run["log"]
    run_id = re.search(r"SLURM run ID: (\S+)", log).group(1)
    sacct = query_sacct(name=run_id)
    assert sacct is not None, "sacct failed"
    heads = sacct[sacct["step"] == ""].set_index("job")
    return SimpleNamespace(work=work, results=work / "results", log=log, jobs=logged_jobs(log),
                           sacct=sacct, heads=heads, marks=work / "fault",
                           seconds=run["seconds"])


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    """The two tiny sequences run locally (once per session, tests/workflow_runs.py), of
    which the SLURM run has the multi-view one."""
    work = tiny_local_run(tmp_path_factory)
    return SimpleNamespace(work=work, results=work / "results")


def _wildcard_values(job):
    return "_".join(job["wildcards"].values())


def test_every_rule_ran_as_a_slurm_job_with_what_it_asked_for(slurm_run):
    jobs = [j for j in slurm_run.jobs if j["rule"] != "all"]
    assert all(not j["local"] for j in jobs), [j["rule"] for j in jobs if j["local"]]
    rules = {j["rule"] for j in jobs}
    assert {"body_model", "gloss_library", "simulate", "segment", "detect_keypoints",
            "perception_eval", "fit_smplx", "colmap_compare", "train_avatar",
            "evaluate_avatar", "stitch_video", "report"} <= rules
    heads = slurm_run.heads
    for job in jobs:
        if job["in_group"]:
            continue
        comment = f"rule_{job['rule']}" + (f"_wildcards_{_wildcard_values(job)}"
                                           if job["wildcards"] else "")
        mine = heads[heads["comment"] == comment]
        done = mine[mine["state"] == "COMPLETED"]
        assert len(done) == 1, (comment, mine[["state"]])
        got = done.iloc[0]
        want = job["resources"]
        assert got["account"] == ACCOUNT
        assert got["partition"] == want["slurm_partition"], comment
        assert got["req_mem_mb"] == float(want["mem_mb"]), comment
        assert got["time_limit_min"] == float(want["runtime"]), comment
        assert got["alloc_cpus"] == job["threads"], comment
        if want.get("gpu"):
            assert f"gres/gpu={want['gpu']}" in got["req_tres"], comment
    # the shipped profile's choices reached SLURM: avatar jobs on the GPU partition with a
    # GPU, the rest on this cluster's default partition
    on_gpu = set(heads[heads["partition"] == "gpu"]["comment"].str.extract(r"rule_(\w+?)_wild")[0])
    assert on_gpu == {"train_avatar", "evaluate_avatar"}
    assert set(heads["partition"]) == {"gpu", PARTITION}


def test_perception_ran_as_one_slurm_job(slurm_run):
    members = [j for j in slurm_run.jobs if j["in_group"]]
    assert {j["rule"] for j in members} == {"segment", "detect_keypoints", "perception_eval"}
    scenes = {j["wildcards"]["scene"] for j in members}
    assert scenes == {"tiny"}
    heads = slurm_run.heads
    groups = heads[heads["comment"].str.startswith("rule_perception")]
    assert len(groups) == len(scenes)
    assert not heads["comment"].str.match(r"rule_(segment|detect_keypoints|perception_eval)_")\
        .any(), "a perception rule ran as its own SLURM job"
    steps = slurm_run.sacct[slurm_run.sacct["step"].str.fullmatch(r"\d+")]
    want_cpus = max(j["threads"] for j in members)
    want_mem = max(float(j["resources"]["mem_mb"]) for j in members)
    want_time = sum(float(j["resources"]["runtime"]) for j in members) / len(scenes)
    seen = set()
    for job_id, g in groups.iterrows():
        assert g["state"] == "COMPLETED"
        mine = steps[steps["job"] == job_id]
        assert len(mine) == 3 and (mine["state"] == "COMPLETED").all()  # one step per rule
        # the three rules of one chain run one after the other: the CPUs of one rule, the
        # memory of the largest, the time of all three
        assert g["alloc_cpus"] == want_cpus and g["req_mem_mb"] == want_mem
        assert g["time_limit_min"] == want_time
        text = next((slurm_run.work / "slurm_logs").rglob(f"{job_id}.log")).read_text()
        ran = re.findall(r"^localrule (\w+):\n(?:    .*\n)*?    wildcards: scene=(\w+)", text,
                         re.M)
        assert sorted(r for r, _ in ran) == ["detect_keypoints", "perception_eval", "segment"]
        assert len({s for _, s in ran}) == 1
        seen |= {s for _, s in ran}
    assert seen == scenes


def test_a_job_that_crashed_once_was_retried_and_the_run_completed(slurm_run):
    reached = json.loads((slurm_run.marks / "reached").read_text())
    assert (slurm_run.marks / "failed").exists() and len(reached["written"]) == 1
    heads = slurm_run.heads
    fits = heads[heads["comment"] == "rule_fit_smplx_wildcards_tiny"]
    crashed = fits.loc[reached["slurm_job_id"]]
    assert crashed["state"] == "FAILED"
    later = fits[fits.index.astype(int) > int(reached["slurm_job_id"])]
    assert list(later["state"]) == ["COMPLETED"]
    assert "Trying to restart" in slurm_run.log
    fit = slurm_run.results / "tiny" / "fit"
    assert (fit / "smplx_fit.parquet").is_file() and (fit / "fit_eval.parquet").is_file()
    assert not [p for p in slurm_run.results.rglob("*") if is_temporary(p)]


def test_the_report_shows_sacct_beside_the_benchmark_files(slurm_run):
    tables = slurm_run.work / "report" / "tables"
    per_job = pd.read_csv(next(tables.glob("runtimes_*Jobs_on_SLURM*.tsv")), sep="\t")
    per_rule = pd.read_csv(next(tables.glob("runtimes_*Cost_per_rule*.tsv")), sep="\t")
    # every benchmarked job matched the SLURM step that ran it (the report's own benchmark
    # file is written after the report, so it is not in this first report)
    assert (per_rule["slurm_jobs"] == per_rule["jobs"]).all(), per_rule
    assert len(per_job) == per_rule["jobs"].sum() == len(set(per_job["slurm_job"]))
    heads = slurm_run.heads
    for _, row in per_job.iterrows():
        job, step = str(row["slurm_job"]).split(".")
        assert heads.loc[job, "state"] == "COMPLETED"
        # the step ran the rule's command: it lasted at least as long (sacct: whole seconds)
        assert row["slurm_elapsed_s"] >= np.floor(row["seconds"]) - 1, row
        assert row["slurm_max_rss_mb"] > 0 and row["slurm_cpu_s"] > 0
    assert set(per_job["rule"]) >= {"simulate", "segment", "train_avatar", "stitch_video"}


# --- outputs equal a local run's -----------------------------------------------------------------

TIME_LIKE = re.compile(r"seconds|_ms|fps|^s$", re.I)


def _drop_times(df: pd.DataFrame) -> pd.DataFrame:
    """A table without what measures time: columns named so, and in long tables (metric /
    value) the rows of such metrics."""
    df = df.drop(columns=[c for c in df.columns if TIME_LIKE.search(str(c))])
    if "metric" in df.columns:
        df = df[~df["metric"].astype(str).str.contains(TIME_LIKE)]
    return df.reset_index(drop=True)


def _drop_time_keys(obj):
    if isinstance(obj, dict):
        return {k: _drop_time_keys(v) for k, v in obj.items() if not TIME_LIKE.search(str(k))}
    if isinstance(obj, list):
        return [_drop_time_keys(v) for v in obj]
    return obj


def _same_checkpoint(a: Path, b: Path) -> None:
    ca = torch.load(a, map_location="cpu", weights_only=False)
    cb = torch.load(b, map_location="cpu", weights_only=False)

    def cmp(x, y, where):
        if isinstance(x, dict):
            keys = [k for k in x if not TIME_LIKE.search(str(k))]
            assert keys == [k for k in y if not TIME_LIKE.search(str(k))], where
            for k in keys:
                cmp(x[k], y[k], f"{where}/{k}")
        elif isinstance(x, (list, tuple)):
            assert len(x) == len(y), where
            for i, (u, v) in enumerate(zip(x, y)):
                cmp(u, v, f"{where}[{i}]")
        elif torch.is_tensor(x):
            torch.testing.assert_close(x, y, rtol=0, atol=0, msg=where)
        elif isinstance(x, float) and np.isnan(x):
            assert np.isnan(y), where
        else:
            assert x == y, where

    cmp(ca, cb, str(a.name))


def _video_frames(path: Path) -> np.ndarray:
    import cv2

    cap = cv2.VideoCapture(str(path))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return np.stack(frames).astype(np.int16)


def test_outputs_equal_a_local_run(local_run, slurm_run):
    # (local_run first: under pytest-xdist the other worker runs the SLURM run meanwhile
    # for the tests that need only it)
    a, b = slurm_run.results, local_run.results
    skip = ("_logs", "_benchmarks")
    files_a = {p.relative_to(a) for p in a.rglob("*") if p.is_file() and p.relative_to(a).parts[0] not in skip}
    files_b = {p.relative_to(b) for p in b.rglob("*") if p.is_file() and p.relative_to(b).parts[0] not in skip}
    # the local run has the single-view sequence too
    files_b = {rel for rel in files_b if rel.parts[0] in {"_assets", "tiny"}}
    assert {rel.parts[0] for rel in files_a} == {"_assets", "tiny"}
    assert files_a == files_b, files_a ^ files_b
    kinds = {}
    for rel in sorted(files_a):
        pa, pb, suffix = a / rel, b / rel, rel.suffix
        kinds[suffix] = kinds.get(suffix, 0) + 1
        if suffix == ".parquet":
            pd.testing.assert_frame_equal(_drop_times(pd.read_parquet(pa)),
                                          _drop_times(pd.read_parquet(pb)), obj=str(rel))
        elif suffix == ".png":
            diff = np.abs(read_rgb(pa).astype(np.int16) - read_rgb(pb).astype(np.int16))
            assert diff.max() <= 1, (rel, diff.max())
        elif suffix == ".mp4":
            fa, fb = _video_frames(pa), _video_frames(pb)
            assert fa.shape == fb.shape and np.abs(fa - fb).mean() < 0.5, rel
        elif suffix == ".json":
            assert _drop_time_keys(json.loads(pa.read_text())) == \
                _drop_time_keys(json.loads(pb.read_text())), rel
        elif suffix == ".pt":
            _same_checkpoint(pa, pb)
        else:
            assert pa.read_bytes() == pb.read_bytes(), rel
    # the comparison covered every kind of output
    assert {".parquet", ".png", ".mp4", ".json", ".pt", ".ply", ".npz"} <= set(kinds), kinds


# --- scancel of a running job -------------------------------------------------------------------

def test_cancelled_job_then_rerun_completes_with_no_partial_files(slurm_run, tmp_path):
    """simulate of a third sequence hangs mid-stage (the fault hook) inside its SLURM job;
    `scancel` stops it there, the stage process included; Snakemake reports the failure and
    removes the job's outputs; a rerun completes the sequence with no temporary file left.
    (`--retries 0`: the profile's one retry would resubmit the cancelled job by itself.)"""
    results = tmp_path / "results"
    shutil.copytree(slurm_run.results / "_assets", results / "_assets")
    spec = yaml.safe_load((ROOT / "config" / "scenes" / "tiny.yaml").read_text())
    spec["seed"] = 23
    (tmp_path / "tC.yaml").write_text(yaml.safe_dump(spec))
    (tmp_path / "sequences.tsv").write_text(f"sequence\tsource\tspec\ntC\tsynthetic\t"
                                            f"{tmp_path / 'tC.yaml'}\n")
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(results), "scenes": [],
                                   "sequences": str(tmp_path / "sequences.tsv")}))
    target = str(results / "tC" / "sim" / "frames.parquet")
    marks = tmp_path / "fault"
    args = [target, "--configfile", str(cfg), *slurm_args(tmp_path / "slurm_logs")]
    proc = subprocess.Popen([sys.executable, "-m", "snakemake", "--nolock", *args,
                             "--retries", "0"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=fault_env("block:simulate:/tC/:3", marks))
    try:
        deadline = time.time() + 600
        while time.time() < deadline and proc.poll() is None and not (marks / "reached").exists():
            time.sleep(0.2)
        assert (marks / "reached").exists(), proc.poll()
        stage = json.loads((marks / "reached").read_text())
        job = stage["slurm_job_id"]
        state = subprocess.run(["squeue", "-h", "-j", job, "-o", "%T"], capture_output=True,
                               text=True).stdout.strip()
        sim = results / "tC" / "sim"
        assert state == "RUNNING" and not (sim / "frames.parquet").exists()
        assert [p for p in sim.rglob("*") if is_temporary(p)], "no file was being written"
        subprocess.run(["scancel", job], check=True)
        out, _ = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:  # a failed assertion above: stop Snakemake and its job
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    assert proc.returncode != 0 and f"SLURM-job '{job}' failed" in out, out[-3000:]
    for _ in range(300):  # the stage process went with its job (SIGKILL after KillWait)
        if not Path(f"/proc/{stage['pid']}").exists():
            break
        time.sleep(0.1)
    assert not Path(f"/proc/{stage['pid']}").exists(), "the stage outlived its cancelled job"
    cancelled = query_sacct(name=re.search(r"SLURM run ID: (\S+)", out).group(1))
    assert cancelled.set_index("job").loc[job].query("step == ''")["state"].iloc[0] \
        == "CANCELLED"
    # the cancelled job's outputs were removed: nothing partial is left to be mistaken
    assert not (sim / "images").exists() and not [p for p in sim.rglob("*") if is_temporary(p)]
    res = snakemake(*args, env=slurm_env())
    assert res.returncode == 0, (res.stdout + res.stderr)[-4000:]
    frames = pd.read_parquet(sim / "frames.parquet")
    assert len(frames) == 2 * 4 and all((sim / r).stat().st_size > 0 for r in frames["image"])
    assert not [p for p in results.rglob("*") if is_temporary(p)]
