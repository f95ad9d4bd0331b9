"""Shared fixtures: small rendered multi-view rigs (no simulator needed)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

import synthetic_rig as rig  # noqa: E402


@pytest.fixture(scope="session")
def textured_rig(tmp_path_factory) -> Path:
    """8 views on a 90 degree arc around a textured room, 2 identical frames (static rig)."""
    out = tmp_path_factory.mktemp("textured")
    Rs, ts = rig.arc_cameras(8, 90.0)
    rig.write_rig(out, "textured", Rs, ts, rig.intrinsics(256, 256, 45.0), 256, 256,
                  rig.textured_room(), frames=2)
    return out


@pytest.fixture(scope="session")
def flat_rig(tmp_path_factory) -> Path:
    """The same rig in a textureless (uniform grey) room: nothing for SIFT to find."""
    out = tmp_path_factory.mktemp("flat")
    Rs, ts = rig.arc_cameras(6, 90.0)
    rig.write_rig(out, "flat", Rs, ts, rig.intrinsics(256, 256, 45.0), 256, 256,
                  rig.textured_room(textureless=True), frames=1)
    return out


@pytest.fixture(scope="session")
def coincident_rig(tmp_path_factory) -> Path:
    """6 cameras within ~1 mm of one centre, panning over 40 degrees (no baseline)."""
    out = tmp_path_factory.mktemp("coincident")
    rng = np.random.default_rng(0)
    centre = np.array([0.0, 1.3, 3.2])
    Rs, ts = [], []
    for a in np.radians(np.linspace(-20.0, 20.0, 6)):
        c = centre + rng.normal(0.0, 0.001, 3)
        R, t = rig.look_at(c, c + np.array([np.sin(a), -0.1, -np.cos(a)]))
        Rs.append(R)
        ts.append(t)
    rig.write_rig(out, "coincident", Rs, ts, rig.intrinsics(256, 256, 45.0), 256, 256,
                  rig.textured_room(), frames=1)
    return out
