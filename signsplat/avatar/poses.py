"""Held-out poses from the training frames' fine-tuning (no test image is used).

Training fine-tunes the SMPL-X parameters of the training frames together with the Gaussians
(``train.finetune_smplx``), so the texture is learned on poses that differ a little from the
fit's. A held-out frame is never rendered in training and keeps the fit's pose, which then
disagrees with the texture by what the fine-tuning moved its neighbours. The fit's error changes
slowly over time (the fit smooths its poses, and much of the error is a fixed offset per vertex),
so the correction of a held-out frame is estimated by interpolating, linearly in the frame
number, the corrections (fine-tuned minus fitted parameters) of the nearest training frames
before and after it; at the ends of the sequence the nearest training frame's correction is used.

Corrections are differences of the parameter vectors themselves (axis-angle, metres,
expression coefficients), the space the fine-tuning moved them in; no rotation is converted, so
an axis-angle near pi or a pose in gimbal lock is carried the same as any other. This is
``eval.heldout_pose: interpolated``; ``fit`` renders the fit's pose as it is.
"""

from __future__ import annotations

import numpy as np
import torch


def interpolation_weights(frames: np.ndarray, known: np.ndarray) -> torch.Tensor:
    """(F, F) matrix W with W[i, j] the weight of frame ``j``'s correction in frame ``i``'s.

    ``frames``: (F,) frame numbers; ``known``: (F,) bool, frames whose correction is known (the
    training frames). A known frame weights only itself; an unknown one its nearest known
    neighbours before and after, linearly in the frame number (the nearest one alone at the
    ends). With no known frame the matrix is zero (no correction)."""
    frames = np.asarray(frames, dtype=np.float64)
    known = np.asarray(known, dtype=bool)
    if frames.shape != known.shape or frames.ndim != 1:
        raise ValueError(f"frames {frames.shape} and known {known.shape} must be equal 1-D shapes")
    n = len(frames)
    w = np.zeros((n, n))
    idx = np.flatnonzero(known)
    if not len(idx):
        return torch.zeros(n, n)
    order = idx[np.argsort(frames[idx], kind="stable")]
    kf = frames[order]
    for i in range(n):
        if known[i]:
            w[i, i] = 1.0
            continue
        pos = int(np.searchsorted(kf, frames[i]))
        if pos == 0 or pos == len(kf):
            w[i, order[min(pos, len(kf) - 1)]] = 1.0
            continue
        a, b = order[pos - 1], order[pos]
        span = frames[b] - frames[a]
        t = 0.5 if span <= 0 else (frames[i] - frames[a]) / span
        w[i, a] += 1.0 - t
        w[i, b] += t
    return torch.from_numpy(w).float()


def carry_corrections(fitted: dict[str, torch.Tensor], tuned: dict[str, torch.Tensor],
                      frames: np.ndarray, train: np.ndarray) -> dict[str, torch.Tensor]:
    """Per-frame blocks (F, k) for every frame: the training frames' tuned values as they are,
    the others their fitted values plus the interpolated correction of the training frames.

    ``fitted`` and ``tuned``: block name -> (F, k) tensors (blocks shared over the sequence,
    such as ``betas`` with one row, are returned tuned and unchanged); ``train``: (F,) bool.
    Non-finite corrections (a frame whose fit had no value) count as zero."""
    train = np.asarray(train, dtype=bool)
    w = interpolation_weights(frames, train)  # no weight on a held-out frame's own delta
    out = {}
    for name, t in tuned.items():
        f = fitted.get(name)
        if f is None or t.shape[0] != len(frames) or f.shape != t.shape:
            out[name] = t
            continue
        f = f.to(t)
        delta = torch.nan_to_num(t - f, nan=0.0, posinf=0.0, neginf=0.0)
        keep = torch.as_tensor(train, device=t.device)[:, None]
        out[name] = torch.where(keep, t, f + w.to(t) @ delta)
    return out
