"""Motion figures of a stitched track: per join, frames of the transition, peak joint angular
velocity and jerk (issue 7, ``stitch_eval``; bone lengths and render speed need the body model
and the renderer and are measured by the rendering stage).

Angular velocity of a joint is the geodesic angle between its rotations in consecutive
frames times fps (deg/s); jerk is the third finite difference of the joint angle path
(deg/s^3), computed from the relative rotations to the window's first frame.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from signsplat.motion.stitching import ROTATION_BLOCKS, TRANSITION


def _rotations(params: dict[str, np.ndarray], lo: int, hi: int) -> np.ndarray:
    """(T, J, 3) axis-angles of every rotation block in frames lo..hi-1."""
    parts = [np.asarray(params[b][lo:hi], np.float64).reshape(hi - lo, -1, 3)
             for b in ROTATION_BLOCKS if b in params]
    return np.concatenate(parts, axis=1)


def angular_speed(rots: np.ndarray, fps: float) -> np.ndarray:
    """Per-frame-step angular speed (T-1, J) in deg/s of axis-angles (T, J, 3)."""
    T, J, _ = rots.shape
    if T < 2:
        return np.zeros((0, J))
    a = Rotation.from_rotvec(rots[:-1].reshape(-1, 3))
    b = Rotation.from_rotvec(rots[1:].reshape(-1, 3))
    return np.degrees((b * a.inv()).magnitude()).reshape(T - 1, J) * fps


def angular_jerk(rots: np.ndarray, fps: float) -> np.ndarray:
    """Jerk magnitude (T-3, J) in deg/s^3: third difference of the rotation vectors relative
    to the first frame (small-angle log map, adequate within a join window)."""
    T, J, _ = rots.shape
    if T < 4:
        return np.zeros((0, J))
    r0 = Rotation.from_rotvec(np.repeat(rots[:1], T, 0).reshape(-1, 3))
    rel = (Rotation.from_rotvec(rots.reshape(-1, 3)) * r0.inv()).as_rotvec().reshape(T, J, 3)
    d3 = np.diff(np.degrees(rel), n=3, axis=0) * fps ** 3
    return np.linalg.norm(d3, axis=-1)


def join_metrics(track: dict[str, np.ndarray], fps: float, margin: int = 2) -> pd.DataFrame:
    """One row per join between consecutive glosses of a stitched track.

    Args:
        track: output of :func:`signsplat.motion.stitching.stitch_clips` (blocks, ``label``,
            ``gloss_index``).
        fps: frame rate.
        margin: frames of each gloss included around the transition.
    Returns:
        columns ``join`` (int), ``from_gloss``, ``to_gloss``, ``transition_frames``,
        ``peak_velocity_deg_s``, ``peak_jerk_deg_s3``.
    """
    labels = np.asarray(track["label"])
    idx = np.asarray(track["gloss_index"])
    rows = []
    for g in range(int(idx.max()) + 1 if len(idx) else 0):
        nxt = np.nonzero((idx == g + 1) & (labels != TRANSITION))[0]
        if not len(nxt):
            break
        cur = np.nonzero((idx == g) & (labels != TRANSITION))[0]
        tr = np.nonzero((idx == g) & (labels == TRANSITION))[0]
        lo = max(int(cur[-1]) - margin, 0)
        hi = min(int(nxt[0]) + margin + 1, len(labels))
        rots = _rotations(track, lo, hi)
        vel = angular_speed(rots, fps)
        jerk = angular_jerk(rots, fps)
        rows.append({
            "join": g, "from_gloss": str(labels[cur[-1]]), "to_gloss": str(labels[nxt[0]]),
            "transition_frames": int(len(tr)),
            "peak_velocity_deg_s": float(vel.max()) if vel.size else 0.0,
            "peak_jerk_deg_s3": float(jerk.max()) if jerk.size else 0.0,
        })
    return pd.DataFrame(rows, columns=["join", "from_gloss", "to_gloss", "transition_frames",
                                       "peak_velocity_deg_s", "peak_jerk_deg_s3"])
