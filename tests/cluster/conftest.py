"""Fixtures of the cluster tests: a single-node SLURM cluster on this machine
(workflow/cluster/local-slurm.sh), started here when it is not already running (`make test`
starts it first) and stopped again at the end; the tests skip, saying why, where it cannot run
(no root, no packages: `make slurm-packages`). Where it must run (.ci/run sets
SIGNSPLAT_REQUIRE_CLUSTER=1 when root and apt-get are there) they fail instead."""

import os
import subprocess

import pytest

from workflow_runs import locked

from .slurm_helpers import SCRIPT, USERS, alive

REQUIRED = os.environ.get("SIGNSPLAT_REQUIRE_CLUSTER") == "1"


@pytest.fixture(scope="session")
def slurm_cluster():
    """The local cluster, running. Started when not running yet, and then stopped when the
    last test process using it (pytest-xdist workers, parallel sessions) is done."""
    with locked(USERS / "lock"):
        if subprocess.run([str(SCRIPT), "status"], capture_output=True).returncode != 0:
            start = subprocess.run([str(SCRIPT), "start"], capture_output=True, text=True,
                                   timeout=300)
            if start.returncode == 2:  # no root, or the packages are missing
                why = f"no local SLURM cluster: {start.stderr.strip()}"
                if REQUIRED:
                    pytest.fail(f"{why} (SIGNSPLAT_REQUIRE_CLUSTER=1)")
                pytest.skip(why)
            assert start.returncode == 0, \
                f"local-slurm.sh start failed:\n{start.stdout}\n{start.stderr}"
            (USERS / "started").write_text("")
        (USERS / str(os.getpid())).write_text("")
    try:
        yield
    finally:
        with locked(USERS / "lock"):
            (USERS / str(os.getpid())).unlink(missing_ok=True)
            others = [p for p in USERS.iterdir() if p.name.isdigit() and alive(int(p.name))]
            if not others and (USERS / "started").exists():
                subprocess.run([str(SCRIPT), "stop"], capture_output=True, timeout=300)
                (USERS / "started").unlink()

