"""Fixtures of the fit tests: the keypoint model of the proxy body (tests/conftest.py) and the
same numerics for every test (helpers: fit_scenes.py)."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _same_numerics_whatever_ran_before():
    """Every fit test with torch's deterministic kernels (what run_fit asks for), on one thread
    (tests/conftest.py), restored afterwards. Both are process-wide: other tests in the same
    pytest-xdist worker (a CLI run with --threads 2, a fit through run_fit) changed them for the
    tests that came after, so a fit's last digits, and a bound near its figure, depended on the
    order the worker happened to run the tests in."""
    from signsplat.device import make_deterministic

    deterministic = torch.are_deterministic_algorithms_enabled()
    warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    make_deterministic()
    yield
    torch.use_deterministic_algorithms(deterministic, warn_only=warn_only)


@pytest.fixture
def torch_threads():
    """``torch_threads(n)`` sets torch's thread count for the rest of the test; the count from
    before is restored afterwards."""
    before = torch.get_num_threads()
    yield torch.set_num_threads
    torch.set_num_threads(before)


@pytest.fixture(scope="session")
def kpm(proxy_body_path):
    from signsplat.fit.bodyfit import load_keypoint_model

    return load_keypoint_model(proxy_body_path, 10, 10, "cpu")
