"""How make test's workers share the suite: long modules first (used by conftest.py)."""

from __future__ import annotations

import os

# Modules whose tests take long (a costly module fixture or long runs), with their rough cost
# in seconds on one core (from make test's --durations): make test's workers start on these,
# longest first, so no long test is left for the end of the run. A module with a `slow` test
# and no entry here counts 30 s.
HEAVY = {
    # the cluster tests mostly wait for SLURM jobs (their CPU is spent outside the worker)
    "tests/cluster/test_slurm.py": 360,
    # the session's tiny run (tests/workflow_runs.py) counts where it is first asked for
    "tests/test_workflow.py": 200, "tests/test_batch.py": 60, "tests/fit/test_fit.py": 100,
    "tests/perception/test_shipped_models.py": 60, "tests/perception/test_train.py": 60,
    "tests/render/test_raster_gradcheck.py": 30, "tests/perception/test_stages.py": 30,
    "tests/test_device.py": 30, "tests/fit/test_flow.py": 30, "tests/fit/test_silhouette.py": 30,
    "tests/perception/test_contracts.py": 20, "tests/body/test_appearance.py": 20,
    "tests/stitch/test_metrics.py": 20,
}


def workers(config) -> int:
    """make test's worker count (pytest-xdist ``-n``; 1 without it)."""
    n = getattr(config.option, "numprocesses", None)
    if isinstance(n, int) and n > 1:
        return n
    try:
        return int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    except ValueError:
        return 1


def lanes(groups: list[list], costs: list[float], n: int) -> list:
    """The items of ``groups`` (one list per test module, in collection order) reordered for
    ``n`` workers that each start on a contiguous ``len // n`` share and steal from the end of
    each other's queue (pytest-xdist's worksteal). Modules with a cost (> 0) go to the front of
    the shares, longest first, each to the share with the least cost so far, each kept whole
    (its module fixture is built once); the other tests fill every share up to its size."""
    total = sum(len(g) for g in groups)
    shares: list[list] = [[] for _ in range(n)]
    load = [0.0] * n
    for cost, _, group in sorted(((c, k, g) for k, (g, c) in enumerate(zip(groups, costs))
                                  if c > 0), key=lambda t: (-t[0], t[1])):
        i = min(range(n), key=lambda j: (load[j], j))
        shares[i].extend(group)
        load[i] += cost
    light = [item for g, c in zip(groups, costs) if c <= 0 for item in g]
    for i, share in enumerate(shares):
        take = max(0, total // n - len(share)) if i < n - 1 else len(light)
        share.extend(light[:take])
        light = light[take:]
    return [item for share in shares for item in share]
