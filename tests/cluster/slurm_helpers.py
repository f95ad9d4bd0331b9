"""Helpers of the cluster tests (tests/cluster): the local SLURM cluster's script and
names, Snakemake runs with the shipped slurm profile, the fault hook's environment, the two
tiny sequences' config, and what a Snakemake log says about its jobs."""

import contextlib
import fcntl
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "workflow" / "cluster" / "local-slurm.sh"
FAULTS = ROOT / "tests" / "faults"  # the test-only fault hook (sitecustomize.py)
ACCOUNT = "signsplat"  # the account local-slurm.sh creates
PARTITION = "main"     # its default partition; the shipped profile says "cpu"
USERS = Path("/tmp/signsplat-slurm-users")  # one file per test process using the cluster


@contextlib.contextmanager
def locked(path: Path):
    """An exclusive lock on ``path`` (made if missing) while the block runs."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        yield


def alive(pid: int) -> bool:
    return Path(f"/proc/{pid}").exists()


def shared_once(tmp_path_factory, name: str, make):
    """``make(folder) -> JSON-able value``, computed once per test session even with
    pytest-xdist workers (the others wait and reuse it)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of one session
    done = root / f"{name}.json"
    with locked(root / f"{name}.lock"):
        if not done.exists():
            try:
                value = {"value": make(root / name)}
            except Exception as exc:  # noqa: BLE001 - kept for the other workers, re-raised
                value = {"error": f"{type(exc).__name__}: {exc}"}
                done.write_text(json.dumps(value))
                raise
            done.write_text(json.dumps(value))
    value = json.loads(done.read_text())
    if "error" in value:
        raise AssertionError(f"{name} failed in another test process: {value['error']}")
    return value["value"]


def slurm_args(logdir: Path) -> list[str]:
    """Snakemake options for the local cluster: the shipped workflow profile, with the account
    and default partition of this cluster given on the command line (a command-line
    --default-resources replaces the profile's whole entry, so its other values are repeated
    from the profile file), faster first status checks, SLURM logs kept in ``logdir``."""
    profile = yaml.safe_load((ROOT / "profiles" / "slurm" / "config.yaml").read_text())
    defaults = {**profile["default-resources"], "slurm_account": ACCOUNT,
                "slurm_partition": PARTITION}
    return ["--workflow-profile", "profiles/slurm",
            "--default-resources", *[f"{k}={v}" for k, v in defaults.items()],
            "--slurm-init-seconds-before-status-checks", "2",
            "--slurm-logdir", str(logdir), "--slurm-keep-successful-logs"]


def snakemake(*args, timeout=1800, env=None, **kw):
    cmd = [sys.executable, "-m", "snakemake", "--nolock", *args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env=env, **kw)


def fault_env(spec: str, folder: Path) -> dict:
    """The environment that arms the fault hook (tests/faults/sitecustomize.py) with ``spec``
    (``action:stage:match:after``); its markers go to ``folder``."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(FAULTS)]),
            "SIGNSPLAT_TEST_FAULT": spec, "SIGNSPLAT_TEST_FAULT_DIR": str(folder)}


def tiny_config(work: Path, name: str = "config.yaml") -> Path:
    """Two tiny sequences end to end: `tiny` (config/scenes/tiny.yaml: 2 views x 4 frames) and
    `tiny1` (1 view, another body, appearance, gloss and seed: the single-view fit), with the
    smallest fit, avatar (4 steps) and stitching settings; results and report under ``work``."""
    spec = yaml.safe_load((ROOT / "config" / "scenes" / "tiny.yaml").read_text())
    spec.update(seed=11, cameras={**spec["cameras"], "count": 1},
                signer={"betas": [-0.3, 0.2] + [0.0] * 8, "appearance_seed": 3},
                motion={**spec["motion"], "glosses": ["SCHOOL"]})
    (work / "tiny1.yaml").write_text(yaml.safe_dump(spec))
    (work / "sequences.tsv").write_text(
        f"sequence\tsource\tspec\ntiny1\tsynthetic\t{work / 'tiny1.yaml'}\n")
    cfg = {
        "results": str(work / "results"), "sequences": str(work / "sequences.tsv"),
        "scenes": ["tiny"],
        "fit": yaml.safe_load((ROOT / "config" / "fit_few_steps.yaml").read_text())["fit"],
        "avatar": {"upsample": {"max_rounds": 0},
                   "train": {"iterations": 4, "test_interval": 2, "test_offset": 1,
                             "log_every": 2, "checkpoint_every": 50},
                   "eval": {"refine_steps": 0, "save_images": 2},
                   "strategy": {"refine_start": 1, "refine_every": 2, "refine_stop": 4}},
        "stitch": {"sentences": ["Why are you sad?"], "size": 64},
        "report": {"html": str(work / "report" / "index.html")},
    }
    path = work / name
    path.write_text(yaml.safe_dump(cfg))
    return path


def _pairs(text: str) -> dict[str, str]:
    return dict(p.split("=", 1) for p in text.split(", ") if "=" in p)


def logged_jobs(log: str) -> list[dict]:
    """The jobs a Snakemake run printed (one entry per job id): rule, whether local, whether
    in a group job, wildcards, threads and resources."""
    jobs = {}
    for m in re.finditer(r"^( *)(local)?rule (\w+):\n((?:\1 {4}.*\n)+)", log, re.M):
        fields = dict(re.findall(r"^ +(\w+): (.*)$", m.group(4), re.M))
        jobs[fields["jobid"]] = {
            "rule": m.group(3), "local": bool(m.group(2)), "in_group": bool(m.group(1)),
            "wildcards": _pairs(fields.get("wildcards", "")),
            "threads": int(fields.get("threads", 1)),
            "resources": _pairs(fields.get("resources", "")),
        }
    return list(jobs.values())
