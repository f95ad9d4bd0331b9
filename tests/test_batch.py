"""Batch runs (issue 9): the slurm profile's resources, caching, resume after a kill.

These drive the real workflow through Snakemake on the tiny scene (2 views x 4 frames).
The shared assets (body model, gloss library) are built once and copied into each run's
results folder, so each test only runs what it is about.
"""

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

from signsplat.io.tables import read_table

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def snakemake(*args, timeout=900, **kw):
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "--nolock", *args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout, **kw)


@pytest.fixture(scope="module")
def assets(tmp_path_factory):
    """Body model and gloss library written once, by the workflow's own rules."""
    results = tmp_path_factory.mktemp("assets_results")
    cfg = tmp_path_factory.mktemp("assets_cfg") / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(results), "sequences": None,
                                   "scenes": ["tiny"]}))
    res = snakemake(str(results / "_assets" / "body_model.npz"),
                    str(results / "_assets" / "gloss_library.parquet"), "--configfile", str(cfg))
    assert res.returncode == 0, res.stderr[-3000:]
    return results / "_assets"


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


def test_slurm_profile_dry_run_gives_every_job_its_resources(tmp_path):
    res = snakemake("-n", "--workflow-profile", "workflow/profiles/slurm", "--config",
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


def test_killed_run_resumes_with_no_partial_outputs(tmp_path, assets):
    results, cfg = _setup(tmp_path, assets, {"tK": _tiny(7)})
    target = _sim_targets(results, ["tK"])
    cmd = [sys.executable, "-m", "snakemake", "--cores", "2", "--nolock", *target,
           "--configfile", str(cfg)]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    images = results / "tK" / "sim" / "images"
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if images.exists() and any(images.rglob("*.png")):
            break
        time.sleep(0.05)
    killed = proc.poll() is None
    if killed:
        os.killpg(proc.pid, signal.SIGKILL)  # a crash, not a polite stop
    proc.wait()
    frames = results / "tK" / "sim" / "frames.parquet"
    if killed and frames.exists():
        # the job can reach its end between the first image and the kill (a fast machine
        # writes the tiny scene's 8 images in a few ms): the table is written last, so every
        # image it lists must then be complete
        for rel in read_table(frames, "frames")["image"]:
            assert (frames.parent / rel).stat().st_size > 0, rel
    res = snakemake(*target, "--configfile", str(cfg), "--rerun-incomplete")
    assert res.returncode == 0, res.stderr[-3000:]
    df = read_table(frames, "frames")
    assert len(df) == 2 * 4
    for rel in df["image"]:
        assert (frames.parent / rel).stat().st_size > 0
    leftovers = [p for p in results.rglob("*") if ".tmp" in p.name]
    assert not leftovers, leftovers
