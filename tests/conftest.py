"""Session-wide assets shared by every test package: the procedural proxy body model and the
synthetic gloss library, each built once per test session (once for all of make test's
workers: tests/workflow_runs.shared_once)."""

from __future__ import annotations

from pathlib import Path

import pytest
from workflow_runs import proxy_body, shared_once


def _write_gloss_library(folder: Path) -> str:
    from signsplat.synth.glosses import write_gloss_library

    folder.mkdir(parents=True, exist_ok=True)
    write_gloss_library(folder / "glosses.parquet", seed=0, fps=25.0)
    return str(folder / "glosses.parquet")


@pytest.fixture(scope="session")
def proxy_body_path(tmp_path_factory):
    """The proxy SMPL-X body (seed 0) written once as an official-layout ``.npz``."""
    return proxy_body(tmp_path_factory)


@pytest.fixture(scope="session")
def gloss_library_path(tmp_path_factory):
    """The synthetic gloss library (seed 0, 25 fps) written once as a Parquet table."""
    return Path(shared_once(tmp_path_factory, "gloss_library", _write_gloss_library))


@pytest.fixture(scope="session")
def gloss_library(gloss_library_path):
    """The synthetic library as clips, read once (tests must not modify the clips)."""
    from signsplat.motion.clips import load_gloss_library

    return load_gloss_library(gloss_library_path)


@pytest.fixture(scope="session")
def tiny_body_path(tmp_path_factory):
    """The stand-in body of tests/standins.py written once as a model file."""
    from standins import tiny_body_arrays

    from signsplat.body.model_file import write_model_file

    return write_model_file(tmp_path_factory.mktemp("tiny_body") / "body.npz",
                            tiny_body_arrays())


@pytest.fixture
def tiny_body(tiny_body_path):
    """The stand-in body as a :class:`~signsplat.body.model.BodyModel` (a fresh one per test)."""
    from signsplat.body.model import BodyModel

    return BodyModel.from_file(tiny_body_path)


def pytest_collection_modifyitems(config, items):
    """Long tests first on make test's workers (:data:`HEAVY`, :func:`lanes`); a single
    process keeps the collection order."""
    from scheduling import HEAVY, lanes, workers

    n = workers(config)
    if n < 2:
        return
    groups: dict[str, list] = {}
    for item in items:
        groups.setdefault(item.nodeid.split("::")[0], []).append(item)
    costs = [HEAVY.get(path, 30.0 if any(i.get_closest_marker("slow") for i in g) else 0.0)
             for path, g in groups.items()]
    items[:] = lanes(list(groups.values()), costs, n)


@pytest.fixture(autouse=True)
def _one_thread():
    """Every test on one thread of torch and of Numba unless it sets its own (restored after
    it): make test's workers already keep every core busy, and a second thread pool in each
    of them only adds waiting and spinning on the shared cores."""
    import numba
    import torch

    from signsplat.device import set_threads

    before = torch.get_num_threads(), numba.get_num_threads()
    set_threads(1)
    yield
    numba.set_num_threads(before[1])  # Numba first: see signsplat.device.set_threads
    torch.set_num_threads(before[0])


@pytest.fixture(autouse=True)
def _autograd_left_on():
    """A test that leaves autograd switched off for its process fails (the tests after it on
    the same worker would fail instead, far from the cause); grad mode is restored."""
    import torch

    yield
    if not torch.is_grad_enabled():
        torch.set_grad_enabled(True)
        pytest.fail("this test left torch's grad mode off for the rest of the process")
