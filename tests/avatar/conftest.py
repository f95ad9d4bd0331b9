"""Fixtures of the avatar tests (helpers: avatar_scenes.py)."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread():
    """Two thread pools (torch, Numba) spinning on 2 shared cores are many times slower."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        import numba

        old_nb = numba.get_num_threads()
        numba.set_num_threads(1)
    except ImportError:
        old_nb = None
    yield
    torch.set_num_threads(old)
    if old_nb is not None:
        numba.set_num_threads(old_nb)
