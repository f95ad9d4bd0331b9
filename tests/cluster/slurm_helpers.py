"""Helpers of the cluster tests (tests/cluster): the local SLURM cluster's script and
names, Snakemake runs with the shipped slurm profile, the fault hook's environment, and what a
Snakemake log says about its jobs. The two tiny sequences' config, Snakemake runs and the
run-once machinery are shared with the other workflow tests (tests/workflow_runs.py)."""

import os
import re
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "workflow" / "cluster" / "local-slurm.sh"
FAULTS = ROOT / "tests" / "faults"  # the test-only fault hook (sitecustomize.py)
ACCOUNT = "signsplat"  # the account local-slurm.sh creates
PARTITION = "main"     # its default partition; the shipped profile says "cpu"
USERS = Path("/tmp/signsplat-slurm-users")  # one file per test process using the cluster


def alive(pid: int) -> bool:
    return Path(f"/proc/{pid}").exists()


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


# At most this many seconds between two status checks (tests/faults/sitecustomize.py says why).
STATUS_CHECK_MAX = 3


def slurm_env(**extra: str) -> dict:
    """The environment of a Snakemake run on the local cluster: the test hooks
    (tests/faults/sitecustomize.py) on PYTHONPATH, status checks at most STATUS_CHECK_MAX s
    apart, and ``extra``."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(FAULTS)]),
            "SIGNSPLAT_TEST_STATUS_CHECK_MAX": str(STATUS_CHECK_MAX), **extra}


def fault_env(spec: str, folder: Path) -> dict:
    """``slurm_env`` that also arms the fault hook with ``spec`` (``action:stage:match:after``);
    its markers go to ``folder``."""
    return slurm_env(SIGNSPLAT_TEST_FAULT=spec, SIGNSPLAT_TEST_FAULT_DIR=str(folder))


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
