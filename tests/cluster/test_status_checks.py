"""The tests' cap on the SLURM plugin's status-check wait (tests/faults/sitecustomize.py),
checked in a fresh interpreter, as Snakemake would start, without a cluster."""

import subprocess
import sys

from .slurm_helpers import STATUS_CHECK_MAX, slurm_env

# The wait the plugin asks for after a check that found nothing finished, read back.
PROBE = """
import snakemake_executor_plugin_slurm as plugin
executor = object.__new__(plugin.Executor)
executor.next_seconds_between_status_checks = 52
print(executor.next_seconds_between_status_checks)
"""


def _wait(env: dict) -> float:
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                         check=False)
    assert out.returncode == 0, out.stderr
    return float(out.stdout)


def test_status_check_wait_is_capped_only_where_the_tests_ask():
    assert _wait(slurm_env()) == STATUS_CHECK_MAX
    env = slurm_env()
    del env["SIGNSPLAT_TEST_STATUS_CHECK_MAX"]
    assert _wait(env) == 52
