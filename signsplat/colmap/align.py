"""Similarity alignment of reconstructed cameras to ground truth, and the camera errors after it.

A reconstruction (COLMAP, or a camera solve) lives in its own frame and scale. We find the
similarity ``x_gt = s * A @ x_est + b`` (Umeyama 1991, least squares on the camera centres;
:mod:`signsplat.geometry.align`, shared with the fit's evaluation) and report per camera
the rotation error (degrees) and the centre error (metres, in the ground truth's units).
When the centres cannot fix a similarity (fewer than 3 cameras, or centres
that are coincident or collinear) the rotation ``A`` comes from the camera orientations
(chordal mean of ``R_gt_i^T R_est_i``) and ``s, b`` from the centres by least squares given ``A``.

All poses are world-to-camera (OpenCV): ``x_cam = R @ x_world + t``, R (N,3,3), t (N,3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from signsplat.geometry.align import (  # noqa: F401  (re-exported)
    Similarity, camera_centres, project_to_so3, rotation_angle_deg, umeyama)


def centres_degenerate(c: np.ndarray, min_spread: float = 0.0, rel_tol: float = 1e-3) -> bool:
    """True when (N,3) centres cannot fix a similarity: N < 3, coincident or collinear.

    ``min_spread``: centres whose RMS distance from their mean is below it count as
    coincident (in the centres' units; 0 only catches exact coincidence).
    """
    c = np.asarray(c, float)
    if len(c) < 3:
        return True
    x = c - c.mean(0)
    spread = float(np.sqrt((x**2).sum(1).mean()))
    sv = np.linalg.svd(x, compute_uv=False)
    return bool(spread <= max(min_spread, 1e-12) or sv[1] < rel_tol * sv[0])


def orientation_similarity(R_est: np.ndarray, c_est: np.ndarray, R_gt: np.ndarray,
                           c_gt: np.ndarray) -> Similarity:
    """Similarity from the orientations (rotation) and centres (scale, translation given it)."""
    A = project_to_so3(np.einsum("nji,njk->ik", np.asarray(R_gt, float), np.asarray(R_est, float)))
    ce = np.asarray(c_est, float) @ A.T
    xe, xg = ce - ce.mean(0), c_gt - c_gt.mean(0)
    denom = float((xe**2).sum())
    scale = float((xe * xg).sum() / denom) if denom > 1e-18 else 1.0
    return Similarity(scale, A, c_gt.mean(0) - scale * ce.mean(0))


@dataclass(frozen=True)
class CameraAlignment:
    """Per-camera errors after aligning estimated cameras to ground truth.

    rotation_deg (N,), centre_m (N,) in the ground truth's units; method 'umeyama' or
    'orientation' (the fallback for degenerate centres); similarity maps estimate -> truth.
    """

    similarity: Similarity
    rotation_deg: np.ndarray
    centre_m: np.ndarray
    method: str


def align_cameras(R_est, t_est, R_gt, t_gt, min_spread: float = 0.01) -> CameraAlignment:
    """Align estimated cameras (R (N,3,3), t (N,3)) to ground truth ones, N >= 1 matching rows.

    Umeyama on the centres unless they are degenerate: fewer than 3, collinear, or ground-truth
    centres within ``min_spread`` (metres, RMS) of each other; then the orientation fallback.
    """
    R_est, R_gt = np.asarray(R_est, float), np.asarray(R_gt, float)
    c_est, c_gt = camera_centres(R_est, t_est), camera_centres(R_gt, t_gt)
    if len(c_est) == 0:
        raise ValueError("align_cameras needs at least one camera")
    if centres_degenerate(c_est) or centres_degenerate(c_gt, min_spread):
        sim, method = orientation_similarity(R_est, c_est, R_gt, c_gt), "orientation"
    else:
        sim, method = umeyama(c_est, c_gt), "umeyama"
    # a camera R_e seen from the aligned frame has rotation R_e @ A^T
    R_aligned = R_est @ sim.rotation.T
    rot = rotation_angle_deg(R_aligned, R_gt)
    centre = np.linalg.norm(sim.apply(c_est) - c_gt, axis=1)
    return CameraAlignment(sim, rot, centre, method)
