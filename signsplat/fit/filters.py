"""Temporal filtering and outlier rejection of 2D keypoint tracks (numpy, before any fit).

Keypoint tracks are arrays ``kp (T, K, 3)`` float64 holding pixel ``x, y`` and a confidence
``score`` per frame ``t`` and keypoint ``k``. Unknown keypoints have ``score == 0``; their
``x, y`` may be NaN. Every function here returns a new array in the same layout and never lets
a NaN coordinate carry a non-zero score.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np


@dataclass
class CleanStats:
    """What the cleaning did, for the log (counts of individual keypoint observations)."""

    total: int = 0
    nan: int = 0  # x or y NaN / inf (score forced to 0)
    low_score: int = 0  # finite but score below the threshold (includes score 0)
    outliers: int = 0  # rejected by the temporal median test
    used: int = 0  # observations left with a non-zero score

    def __add__(self, other: "CleanStats") -> "CleanStats":
        return CleanStats(*(a + b for a, b in zip(self.astuple(), other.astuple())))

    def astuple(self) -> tuple[int, ...]:
        return (self.total, self.nan, self.low_score, self.outliers, self.used)


def sanitize(kp: np.ndarray, min_score: float) -> tuple[np.ndarray, CleanStats]:
    """Zero the score of NaN / non-finite / low-confidence observations; NaN coords -> 0.

    kp: (T, K, 3) float. Returns (clean copy, stats). Scores are clipped to [0, 1].
    """
    kp = np.array(kp, dtype=np.float64, copy=True)
    score = np.nan_to_num(kp[..., 2], nan=0.0, posinf=0.0, neginf=0.0)
    score = np.clip(score, 0.0, 1.0)
    bad = ~np.isfinite(kp[..., :2]).all(-1)
    low = (~bad) & (score < max(min_score, 1e-12))
    score[bad | low] = 0.0
    kp[..., :2][bad] = 0.0
    kp[..., 2] = score
    stats = CleanStats(total=int(score.size), nan=int(bad.sum()), low_score=int(low.sum()),
                       used=int((score > 0).sum()))
    return kp, stats


def reject_outliers(kp: np.ndarray, radius: int, threshold_px: float) -> tuple[np.ndarray, int]:
    """Reject observations far from the temporal median of their own track.

    For each keypoint the median of the valid positions in the window ``t-radius .. t+radius``
    (excluding ``t`` itself) is computed; an observation further than ``threshold_px`` from it is
    given score 0. Windows with fewer than 2 other valid samples test nothing.
    kp: (T, K, 3) sanitised. Returns (copy, number rejected).
    """
    kp = np.array(kp, copy=True)
    T = kp.shape[0]
    if radius <= 0 or T < 3:
        return kp, 0
    valid = kp[..., 2] > 0
    xy = np.where(valid[..., None], kp[..., :2], np.nan)
    reject = np.zeros(valid.shape, dtype=bool)
    for t in range(T):
        lo, hi = max(0, t - radius), min(T, t + radius + 1)
        others = np.concatenate([xy[lo:t], xy[t + 1:hi]], axis=0)  # (W, K, 2)
        count = np.isfinite(others[..., 0]).sum(0)
        with warnings.catch_warnings():  # all-NaN windows are expected (count test below)
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(others, axis=0)  # (K, 2)
        dist = np.linalg.norm(xy[t] - med, axis=-1)
        reject[t] = valid[t] & (count >= 2) & np.isfinite(dist) & (dist > threshold_px)
    kp[..., 2][reject] = 0.0
    return kp, int(reject.sum())


def _alpha(cutoff: np.ndarray | float, dt: np.ndarray | float) -> np.ndarray:
    tau = 1.0 / (2.0 * np.pi * np.asarray(cutoff))
    return 1.0 / (1.0 + tau / np.asarray(dt))


def one_euro(kp: np.ndarray, times: np.ndarray, min_cutoff: float, beta: float,
             d_cutoff: float = 1.0, max_gap: float = 0.25) -> np.ndarray:
    """One-Euro filter (Casiez et al. 2012) of every keypoint track, skipping unknown samples.

    The cutoff adapts to the speed of the 2D position (px/s): ``fc = min_cutoff + beta*|v|``
    (Hz). A sample with score 0 is left as is and does not advance the filter; a gap longer
    than ``max_gap`` seconds restarts the track. kp: (T, K, 3); times: (T,) seconds,
    increasing. Returns the filtered copy (scores unchanged).
    """
    kp = np.array(kp, dtype=np.float64, copy=True)
    times = np.asarray(times, dtype=np.float64)
    T, K = kp.shape[:2]
    if T != len(times):
        raise ValueError(f"one_euro: {T} frames but {len(times)} timestamps")
    x_hat = np.zeros((K, 2))
    dx_hat = np.zeros((K, 2))
    t_last = np.full(K, -np.inf)
    for t in range(T):
        valid = kp[t, :, 2] > 0
        x = kp[t, :, :2]
        dt = times[t] - t_last
        fresh = valid & ~(dt <= max_gap)  # first sample or after a long gap
        cont = valid & ~fresh
        if cont.any():
            dtc = np.maximum(dt[cont], 1e-6)[:, None]
            dx = (x[cont] - x_hat[cont]) / dtc
            a_d = _alpha(d_cutoff, dtc)
            dx_hat[cont] = a_d * dx + (1 - a_d) * dx_hat[cont]
            speed = np.linalg.norm(dx_hat[cont], axis=-1, keepdims=True)
            a = _alpha(min_cutoff + beta * speed, dtc)
            x_hat[cont] = a * x[cont] + (1 - a) * x_hat[cont]
        x_hat[fresh] = x[fresh]
        dx_hat[fresh] = 0.0
        t_last[valid] = times[t]
        kp[t, valid, :2] = x_hat[valid]
    return kp


def clean_keypoints(kp: np.ndarray, times: np.ndarray, *, min_score: float,
                    outlier_radius: int, outlier_px: float, one_euro_min_cutoff: float,
                    one_euro_beta: float, one_euro_d_cutoff: float,
                    use_filter: bool) -> tuple[np.ndarray, CleanStats]:
    """Sanitise, reject temporal outliers, then One-Euro filter one view's tracks.

    kp: (T, K, 3) pixels + score; times: (T,) seconds. Returns (clean kp, stats).
    """
    kp, stats = sanitize(kp, min_score)
    kp, n_out = reject_outliers(kp, outlier_radius, outlier_px)
    if use_filter:
        kp = one_euro(kp, times, one_euro_min_cutoff, one_euro_beta, one_euro_d_cutoff)
    stats.outliers = n_out
    stats.used = int((kp[..., 2] > 0).sum())
    return kp, stats


def clean_observations(obs: np.ndarray, times: np.ndarray, heights: np.ndarray, cfg: dict
                       ) -> tuple[np.ndarray, CleanStats]:
    """Clean every view with :func:`clean_keypoints` (NaN and low scores, temporal outliers,
    One-Euro), then raise the kept confidences to ``confidence_power``.

    obs (V,T,133,3); times (T,) seconds; heights (V,) image heights in pixels (the outlier
    threshold is a fraction of them); cfg the validated ``fit`` section. Returns the cleaned
    observations (same shape) and the summed counts.
    """
    fc = cfg["filter"]
    out = np.empty_like(obs)
    stats = CleanStats()
    for v in range(obs.shape[0]):
        out[v], st = clean_keypoints(
            obs[v], times, min_score=cfg["min_score"], outlier_radius=fc["outlier_radius"],
            outlier_px=fc["outlier_fraction"] * float(heights[v]),
            one_euro_min_cutoff=fc["min_cutoff_hz"], one_euro_beta=fc["beta"],
            one_euro_d_cutoff=fc["d_cutoff_hz"], use_filter=fc["enabled"])
        stats = stats + st
    power = float(cfg["confidence_power"])
    if power != 1.0:  # ignored keypoints keep their 0
        out[..., 2] = out[..., 2] ** power
    return out, stats
