"""Sequence bookkeeping shared by both fit modes: which frames are fitted, gap filling.

A frame is *fitted* when at least ``min_keypoints`` observations (summed over views) survive
cleaning. Other frames are *interpolated* (SLERP of every joint rotation, linear for the rest)
between the nearest fitted frames on both sides, or *missing* (held at the nearest fitted frame)
at the ends of the sequence. Values are always finite.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import roma
import torch

from signsplat.fit.cameras import Rig

ROTATION_BLOCKS = ("global_orient", "body_pose", "jaw_pose", "leye_pose", "reye_pose",
                   "left_hand_pose", "right_hand_pose")

FITTED, INTERPOLATED, MISSING = "fitted", "interpolated", "missing"


@dataclass
class FitResult:
    """Output of a fit.

    params: block -> (T,k) float64 (flat hand poses); rig: fitted cameras; frames (T,) int;
    provenance (T,) str; num_keypoints (T,) int observations used per frame;
    camera_status (V,) str; seconds: part -> wall-clock seconds; log: free-form counters.
    """

    params: dict[str, np.ndarray]
    rig: Rig
    frames: np.ndarray
    provenance: np.ndarray
    num_keypoints: np.ndarray
    camera_status: list[str]
    seconds: dict[str, float] = field(default_factory=dict)
    log: dict[str, float] = field(default_factory=dict)


def contiguous_triplets(frames: np.ndarray) -> np.ndarray:
    """(T-2,) bool: frames t, t+1, t+2 are consecutive frame numbers."""
    f = np.asarray(frames)
    if len(f) < 3:
        return np.zeros(0, dtype=bool)
    return (f[1:-1] - f[:-2] == 1) & (f[2:] - f[1:-1] == 1)


def fitted_mask(obs: np.ndarray, min_keypoints: int) -> tuple[np.ndarray, np.ndarray]:
    """obs (V,T,133,3) -> (fitted (T,) bool, count (T,) int of observations with score > 0)."""
    count = (obs[..., 2] > 0).sum(axis=(0, 2))
    return count >= max(int(min_keypoints), 1), count


def fill_gaps(params: dict[str, np.ndarray], fitted: np.ndarray
              ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Replace the parameters of unfitted frames; returns (params, provenance (T,) str).

    Needs at least one fitted frame. Rotations (axis-angle blocks) are SLERPed per joint.
    """
    fitted = np.asarray(fitted, bool)
    T = len(fitted)
    idx = np.nonzero(fitted)[0]
    if len(idx) == 0:
        raise ValueError("no fitted frame to fill gaps from")
    prov = np.where(fitted, FITTED, MISSING).astype(object)
    out = {k: np.array(v, dtype=np.float64, copy=True) for k, v in params.items()}
    for t in np.nonzero(~fitted)[0]:
        before = idx[idx < t]
        after = idx[idx > t]
        if len(before) and len(after):
            a, b = before[-1], after[0]
            s = (t - a) / (b - a)
            for k, v in out.items():
                if k in ROTATION_BLOCKS:
                    r0 = torch.as_tensor(v[a].reshape(-1, 3))
                    r1 = torch.as_tensor(v[b].reshape(-1, 3))
                    v[t] = roma.rotvec_slerp(r0, r1, torch.tensor([s], dtype=r0.dtype)
                                             )[0].numpy().reshape(-1)
                else:
                    v[t] = (1 - s) * v[a] + s * v[b]
            prov[t] = INTERPOLATED
        else:
            src = before[-1] if len(before) else after[0]
            for v in out.values():
                v[t] = v[src]
    return out, prov.astype(str)
