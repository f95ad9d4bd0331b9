"""Batch runs (issue 9): the slurm profile's resources, caching, resume after a kill.

These drive the real workflow through Snakemake on the tiny scene (2 views x 4 frames).
The shared assets (body model, gloss library) come from the session's tiny run and are
copied into each run's results folder, so each test only runs what it is about.
"""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml
from workflow_runs import snakemake as run_snakemake
from workflow_runs import tiny_local_run

from signsplat.io.atomic import is_temporary
from signsplat.io.tables import read_table

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def snakemake(*args, timeout=900, **kw):
    return run_snakemake("--cores", "2", *args, timeout=timeout, **kw)


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    """Body model and gloss library, as the workflow's own rules wrote them in the session's
    tiny run (tests/workflow_runs.py)."""
    return tiny_local_run(tmp_path_factory) / "results" / "_assets"


def _setup(tmp_path, assets, scenes):
    results = tmp_path / "results"
    shutil.copytree(assets, results / "_assets")
    for p in (results / "_assets").iterdir():
        os.utime(p)  # newer than anything: the copies count as up to date
    sheet = tmp_path / "sequences.tsv"
    rows = ["sequence\tsource\tspec"]
    for name, spec in scenes.items():
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(spec))
        rows.append(f"{name}\tsynthetic\t{path}")
    sheet.write_text("\n".join(rows) + "\n")
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(results), "sequences": str(sheet),
                                   "scenes": []}))
    return results, cfg


def _tiny(seed=7):
    spec = yaml.safe_load((ROOT / "config" / "scenes" / "tiny.yaml").read_text())
    spec["seed"] = seed
    return spec


def _sim_targets(results, names):
    return [str(results / n / "sim" / "frames.parquet") for n in names]


PERCEPTION = {"segment", "detect_keypoints", "perception_eval"}  # profiles/slurm's group


def test_slurm_profile_dry_run_gives_every_job_its_resources(tmp_path):
    res = snakemake("-n", "--workflow-profile", "profiles/slurm", "--config",
                    f"results={tmp_path}")
    assert res.returncode == 0, res.stderr[-3000:] + res.stdout[-3000:]
    jobs = re.findall(r"^(?:local)?rule (\w+):\n(.*?)(?=\n\n)", res.stdout, re.S | re.M)
    assert jobs, res.stdout[-2000:]
    seen = set()
    for rule, body in jobs:
        if rule == "all":
            continue
        seen.add(rule)
        match = re.search(r"resources: (.*)", body)
        assert match, f"job of rule {rule} declares no resources"
        res_text = match.group(1)
        for key in ("mem_mb=", "runtime=", "slurm_partition="):
            assert key in res_text, f"rule {rule}: {key} missing in {res_text}"
        if rule in ("train_avatar", "evaluate_avatar"):
            assert "gpu=1" in res_text and "slurm_partition=gpu" in res_text
    assert {"body_model", "simulate"} <= seen
    # the perception rules are not jobs of their own: one group job per sequence holds them
    assert not seen & PERCEPTION, seen & PERCEPTION
    groups = re.split(r"^.*Group job perception .*$", res.stdout, flags=re.M)[1:]
    scenes = []
    for group in groups:
        members = re.findall(r"^ {4}rule (\w+):\n(?: {8}.*\n)*? {8}wildcards: scene=(\w+)",
                             group, re.M)
        assert sorted(r for r, _ in members) == sorted(PERCEPTION), members
        assert len({s for _, s in members}) == 1, members
        scenes.append(members[0][1])
    assert sorted(scenes) == ["single", "studio6"]  # the default run's two sequences


def test_unchanged_rerun_does_nothing_and_one_changed_sequence_reruns_alone(tmp_path, assets):
    results, cfg = _setup(tmp_path, assets, {"tA": _tiny(7), "tB": _tiny(8)})
    targets = _sim_targets(results, ["tA", "tB"])
    res = snakemake(*targets, "--configfile", str(cfg))
    assert res.returncode == 0, res.stderr[-3000:]
    res = snakemake("-n", *targets, "--configfile", str(cfg))
    assert "Nothing to be done" in res.stdout + res.stderr
    # change one sequence's parameters: only its simulate job is planned
    spec = _tiny(9)
    (tmp_path / "tB.yaml").write_text(yaml.safe_dump(spec))
    res = snakemake("-n", *targets, "--configfile", str(cfg))
    assert res.returncode == 0
    planned = " ".join(re.findall(r"^\s+output: (.*)$", res.stdout, re.M))
    assert "tB/sim/frames.parquet" in planned and "tA/sim" not in planned


FAULTS = ROOT / "tests" / "faults"  # test-only hook (sitecustomize.py): see its docstring


def test_killed_run_resumes_with_no_partial_outputs(tmp_path, assets):
    """The simulate stage is made to hang after its third finished file (the fault hook);
    the run is killed (SIGKILL to Snakemake and the stage) while the stage's outputs are
    incomplete; `--rerun-incomplete` then completes them, with no temporary file left."""
    results, cfg = _setup(tmp_path, assets, {"tK": _tiny(7)})
    target = _sim_targets(results, ["tK"])
    marks = tmp_path / "fault"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(FAULTS)]),
           "SIGNSPLAT_TEST_FAULT": "block:simulate:/tK/:3", "SIGNSPLAT_TEST_FAULT_DIR": str(marks)}
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "--nolock", *target,
           "--configfile", str(cfg)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, env=env)
    reached = marks / "reached"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and not reached.exists():
        time.sleep(0.05)
    assert reached.exists(), f"the stage never reached its third file (exit {proc.poll()})"
    stage = json.loads(reached.read_text())
    # mid-stage: the stage process is alive, 3 of its 16 files are done, its table is not
    os.kill(stage["pid"], 0)
    assert proc.poll() is None
    sim = results / "tK" / "sim"
    frames = sim / "frames.parquet"
    finished = [p for p in sim.rglob("*.png") if not is_temporary(p)]
    assert len(stage["written"]) == 3 and len(finished) == 3, (stage, finished)
    assert not frames.exists()
    assert [p for p in sim.rglob("*") if is_temporary(p)], "no file was being written"
    os.killpg(proc.pid, signal.SIGKILL)  # a crash, not a polite stop
    assert proc.wait(timeout=60) == -signal.SIGKILL
    for _ in range(100):  # the stage was in the same process group: gone too
        if not Path(f"/proc/{stage['pid']}").exists():
            break
        time.sleep(0.05)
    assert not Path(f"/proc/{stage['pid']}").exists()
    assert not frames.exists() and len([p for p in sim.rglob("*.png")]) < 2 * 4 * 2
    # resume without the fault: the incomplete outputs are redone
    res = snakemake(*target, "--configfile", str(cfg), "--rerun-incomplete")
    assert res.returncode == 0, res.stderr[-3000:]
    df = read_table(frames, "frames")
    assert len(df) == 2 * 4
    for rel in df["image"]:
        assert (frames.parent / rel).stat().st_size > 0
    leftovers = [p for p in results.rglob("*") if is_temporary(p)]
    assert not leftovers, leftovers
