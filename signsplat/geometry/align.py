"""Similarity alignment (Umeyama 1991) and rotation distances, shared by the fit's evaluation
and the COLMAP comparison (numpy, float64).

Poses elsewhere are world-to-camera (OpenCV): ``x_cam = R @ x_world + t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Similarity:
    """``x_dst = s * R @ x_src + t``: scale ``s``, rotation ``R (3,3)``, translation ``t (3,)``."""

    s: float
    R: np.ndarray
    t: np.ndarray

    @property
    def scale(self) -> float:
        return self.s

    @property
    def rotation(self) -> np.ndarray:
        return self.R

    @property
    def translation(self) -> np.ndarray:
        return self.t

    def apply(self, x: np.ndarray) -> np.ndarray:
        """Transform points (..., 3) -> (..., 3)."""
        return self.s * np.asarray(x, float) @ self.R.T + self.t


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True,
            weights: np.ndarray | None = None) -> Similarity:
    """Least-squares similarity mapping ``src (N,3)`` onto ``dst (N,3)``, N >= 3.

    ``weights (N,)`` optional non-negative point weights. The rotation is proper (det +1) even
    when the best orthogonal map is a reflection. Degenerate inputs (all source points equal)
    give the identity rotation, scale 1 and a pure translation. Raises ValueError on shapes.
    """
    src = np.asarray(src, float)
    dst = np.asarray(dst, float)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"umeyama needs two (N,3) arrays with N >= 3, got {src.shape}, "
                         f"{dst.shape}")
    w = np.ones(len(src)) if weights is None else np.asarray(weights, float)
    w = w / max(w.sum(), 1e-12)
    mu_s, mu_d = w @ src, w @ dst
    xs, xd = src - mu_s, dst - mu_d
    cov = (xd * w[:, None]).T @ xs
    U, S, Vt = np.linalg.svd(cov)
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    var_s = float(w @ (xs ** 2).sum(1))
    if var_s <= 1e-24:
        R = np.eye(3)
    s = float(np.trace(np.diag(S) @ D) / var_s) if (with_scale and var_s > 1e-24) else 1.0
    return Similarity(s, R, mu_d - s * R @ mu_s)


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Geodesic angle between rotations ``(...,3,3)`` in degrees (accurate near 0 and 180,
    unlike arccos of the trace)."""
    rel = np.einsum("...ij,...kj->...ik", np.asarray(Ra, float), np.asarray(Rb, float))
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    skew = np.stack([rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0],
                     rel[..., 1, 0] - rel[..., 0, 1]], axis=-1)
    sin = np.linalg.norm(skew, axis=-1) / 2.0
    return np.degrees(np.arctan2(sin, cos))


def camera_centres(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """World positions of camera centres ``-R^T t``: (N,3,3), (N,3) -> (N,3)."""
    return -np.einsum("nji,nj->ni", np.asarray(R, float), np.asarray(t, float))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius) to a (3,3) matrix."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0])
    return U @ D @ Vt
