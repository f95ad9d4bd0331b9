"""Camera initialisation that does not assume the rig (config ``fit.multiview.camera_init: auto``).

The images give two kinds of evidence about where the cameras are:

- the body itself: each view's head/torso keypoints against the same points of the rest body
  (PnP; :mod:`signsplat.fit.cameras`), which places a camera in the body's frame but is only as
  good as the rest body resembles the signer, and weak when the torso is small in the image;
- the same keypoint seen by several views in the same frame: a 2D-2D correspondence. Over a
  clip the moving arms and hands give hundreds of them, spread in depth. Two views' relative
  pose follows from their essential matrix (known intrinsics), further views are registered by
  PnP against the points triangulated so far, and a bundle adjustment refines all of them
  (:func:`reconstruct_rig`, "sfm"). A body seen from afar fills a small angle, where two
  views leave the rotation angle nearly free (bas-relief); three or more views fix it jointly:
  an affine factorisation of the tracks common to them, upgraded to scaled orthographic
  cameras and refined in perspective (:func:`affine_rig`, "affine"). Neither needs a body
  model or a guess of the rig; the result is brought into the body's frame and scale by a
  similarity mapping the triangulated head/torso keypoints of the first frames onto the rest
  body's (which also tells a mirror-image reconstruction: its left and right are exchanged).

Every source gives a hypothesis (a camera per view it can place); the configured arc
(``camera_prior``) is one more. The observations are split in two halves (a checkerboard over
frames and keypoints): hypotheses are estimated on one and scored on the other, held out
(:func:`heldout_errors`: held-out keypoints triangulated by the hypothesis' other cameras must
reproject onto their detections). The best whole rig wins. A view no hypothesis places
consistently is reported ``unplaced`` (a warning; the fit then ignores its keypoints and keeps
its camera fixed), never NaN.

Shapes: ``V`` views, ``T`` frames, 133 keypoints; observations ``obs (V,T,133,3)`` (x, y px and
a confidence, 0 = unseen); cameras world-to-camera ``R (V,3,3)``, ``t (V,3)``.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from signsplat.fit.cameras import (pnp, pnp_ransac, projection_matrices, rig_prior,
                                   triangulate)
from signsplat.geometry.align import rotation_angle_deg, umeyama

log = logging.getLogger(__name__)

#: Candidate sources in the order they are preferred on a tie (names of the hypotheses).
SOURCES = ("affine", "sfm", "pnp_ransac", "pnp", "prior")

#: Keypoints the reconstruction and the scores use: body, feet, hands and 8 of the 68 face
#: points (chin, nose tip, eye and mouth corners). All 68 would outnumber the rest two to
#: one, and a small, nearly flat patch fits many wrong two-view geometries to a pixel.
TRACK_KEYPOINTS = tuple(range(0, 23)) + tuple(23 + k for k in (8, 30, 36, 39, 42, 45, 48, 54)) \
    + tuple(range(91, 133))


@dataclass
class RigHypotheses:
    """What :func:`initial_rig` tried and chose (for the log and the tables).

    ``R``, ``t``: the chosen cameras; ``status (V,)``: the source of each view's camera
    (one of :data:`SOURCES`, ``no_detections`` or ``unplaced``); ``winner``: the best whole rig
    (a source name); ``scores``: held-out median px of every whole rig tried; ``view_px (V,)``:
    each chosen camera's held-out error (NaN: too few testable points).
    """

    R: np.ndarray
    t: np.ndarray
    status: list[str]
    winner: str
    scores: dict[str, float] = field(default_factory=dict)
    view_px: np.ndarray | None = None
    #: every whole-rig hypothesis tried: name -> (R, t)
    rigs: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    #: views turned around (:func:`turn_views`): view -> (px before, after); of the winner,
    #: or with :func:`place_cameras` of every placement that led to it
    turned: dict[int, tuple[float, float]] = field(default_factory=dict)
    #: views left in place that the other side fits a little better: view -> (px, px there)
    doubtful: dict[int, tuple[float, float]] = field(default_factory=dict)


def placed_views(status: list[str]) -> list[int]:
    """The views whose camera the initialisation placed (not ``no_detections``, not
    ``unplaced``), from :attr:`RigHypotheses.status` or the fit's camera status."""
    return [v for v, st in enumerate(status) if st not in ("no_detections", "unplaced")]


def inlier_threshold_px(init_cfg: dict, height) -> float:
    """The initialisation's inlier distance in pixels: ``init.threshold`` times the median
    image height of the views."""
    return init_cfg["threshold"] * float(np.median(np.asarray(height, float)))


# --- observations as tracks -----------------------------------------------------------------

def tracks(obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """obs (V,T,K,3) -> (uv (V,N,2), w (V,N)) with N = T*K tracks (a keypoint in a frame)."""
    V, T, K = obs.shape[:3]
    return obs[..., :2].reshape(V, T * K, 2), obs[..., 2].reshape(V, T * K)


def heldout_split(T: int, K: int) -> np.ndarray:
    """(T,K) bool: the held-out half, a checkerboard over frames and keypoints (every frame and
    every keypoint type is in both halves)."""
    return (np.arange(T)[:, None] + np.arange(K)[None]) % 2 == 1


def robust_triangulate(P: np.ndarray, uv: np.ndarray, w: np.ndarray, threshold_px: float,
                       rounds: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """DLT triangulation (:func:`signsplat.fit.cameras.triangulate`) that drops, per track,
    the observations reprojecting farther than ``3 threshold_px`` and solves again
    (``rounds`` times): one view's wrong detection (a swapped side, a hand taken for the other)
    does not drag the point. P (V,3,4), uv (V,N,2), w (V,N). Returns (X (N,3), ok (N,))."""
    X, ok = triangulate(P, uv, w, min_views=2)
    for _ in range(rounds):
        xc = np.einsum("vij,nj->vni", P[:, :, :3], X) + P[:, None, :, 3]
        z = xc[..., 2]
        proj = xc[..., :2] / np.where(np.abs(z) > 1e-9, z, 1e-9)[..., None]
        err = np.linalg.norm(proj - uv, axis=-1)
        keep = (w > 0) & (z > 0) & (err <= 3 * threshold_px)
        # keep the two best views of a track that would otherwise lose too many
        few = ok & (keep.sum(0) < 2) & ((w > 0).sum(0) >= 2)
        if few.any():
            e = np.where(w[:, few] > 0, err[:, few], np.inf)
            best2 = np.argsort(e, axis=0)[:2]
            k2 = np.zeros_like(keep[:, few])
            np.put_along_axis(k2, best2, True, axis=0)
            keep[:, few] = k2 & (w[:, few] > 0)
        w2 = np.where(keep, w, 0.0)
        X2, ok2 = triangulate(P, uv, w2, min_views=2)
        X = np.where(ok2[:, None], X2, X)
        ok = ok | ok2
        w = w2
    return X, ok


# --- scoring ----------------------------------------------------------------------------------

def project_points(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
    """One camera's projection of points X (...,3): (pixels (...,2), in front of it (...))."""
    xc = X @ R.T + t
    front = xc[..., 2] > 1e-6
    uv = xc[..., :2] / np.where(front, xc[..., 2], 1.0)[..., None] * K[[0, 1], [0, 1]] + K[:2, 2]
    return uv, front


def reprojection_errors(K: np.ndarray, R: np.ndarray, t: np.ndarray, uv: np.ndarray,
                        w: np.ndarray, leave_one_out: bool = True,
                        active: np.ndarray | None = None,
                        robust_px: float | None = None) -> np.ndarray:
    """Per observation: pixel distance between the detection and the track triangulated by the
    cameras (V,...), reprojected (V,N) (NaN: not seen, or not triangulable).

    Only the ``active (V,)`` views (default all) triangulate. With ``leave_one_out`` a track
    seen by 3 or more active views is triangulated, for each active view, from the other active
    views only (a wrong camera cannot pull the point towards itself); a track seen by 2 active
    views is triangulated from both. Points behind a camera count as about the image's
    diagonal (a hypothesis with the body behind a camera is wrong). With ``robust_px`` the
    points are triangulated by :func:`robust_triangulate` with that threshold."""
    V, N = w.shape
    active = np.ones(V, bool) if active is None else np.asarray(active, bool)

    def tri(P_, uv_, w_):
        if robust_px is None:
            return triangulate(P_, uv_, w_, min_views=2)
        return robust_triangulate(P_, uv_, w_, robust_px)

    P = projection_matrices(K, R, t)
    seen = w > 0
    wa = np.where(active[:, None], w, 0.0) * seen
    nseen = (wa > 0).sum(0)
    err = np.full((V, N), np.nan)
    big = 2.0 * float(np.max(np.abs(K[:, :2, 2]))) * 1.5  # about the image diagonal

    def project_into(v, X, ok):
        uvp, front = project_points(K[v], R[v], t[v], X)
        e = np.linalg.norm(uvp - uv[v], axis=-1)
        return np.where(ok & seen[v], np.where(front, e, big), np.nan)

    X, ok = tri(P, uv, wa)
    for v in range(V):
        e = project_into(v, X, ok)
        own = active[v] and seen[v].any()
        multi = seen[v] & ((nseen - (wa[v] > 0)) >= 2) if own else np.zeros(N, bool)
        if leave_one_out and multi.any():
            others = wa.copy()
            others[v] = 0.0
            Xo, oko = tri(P, uv[:, multi], others[:, multi])
            Xm = np.zeros((N, 3))
            Xm[multi] = Xo
            okm = np.zeros(N, bool)
            okm[multi] = oko
            e = np.where(multi, project_into(v, Xm, okm), e)
        err[v] = e
    return err


def _medians(e: np.ndarray, min_points: int) -> np.ndarray:
    out = np.full(len(e), np.nan)
    for v in range(len(e)):
        ev = e[v][np.isfinite(e[v])]
        if len(ev) >= min_points:
            out[v] = float(np.median(ev))
    return out


def heldout_errors(K, R, t, uv, w, limit_px: np.ndarray | None = None,
                   min_points: int = 8, robust_px: float | None = None) -> np.ndarray:
    """(V,) median held-out reprojection error per view (px; NaN with fewer than
    ``min_points`` testable observations). See :func:`reprojection_errors`.

    With ``limit_px (V,)``, views above their limit are taken out of the triangulation one at a
    time (the worst first, while 3 or more views remain) and measured against the others: one
    camera with garbage detections or a wrong pose does not spoil the other views' scores.
    ``robust_px``: see :func:`reprojection_errors`."""
    V = len(w)
    active = (w > 0).any(1)
    while True:
        med = _medians(reprojection_errors(K, R, t, uv, w, active=active, robust_px=robust_px),
                       min_points)
        if limit_px is None or active.sum() <= 2:
            return med
        over = active & ~(med <= limit_px)  # NaN counts as over
        if not over.any():
            return med
        worst = max(np.nonzero(over)[0], key=lambda v: np.inf if np.isnan(med[v]) else med[v])
        active = active.copy()
        active[worst] = False
        if V < 3:
            return med


def rig_score(view_px: np.ndarray, views: list[int], limit_px: np.ndarray) -> float:
    """One number for a whole rig: the mean of its views' held-out medians, each capped at its
    view's limit (a view no hypothesis places, or one without testable keypoints, then costs
    every hypothesis the same)."""
    if not views:
        return float("inf")
    vals = np.where(np.isfinite(view_px), np.minimum(view_px, limit_px), limit_px)[views]
    return float(np.mean(vals))


# --- two views --------------------------------------------------------------------------------

def normalised(uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixel coordinates (N,2) -> normalised image coordinates (N,2) of intrinsics K."""
    return np.stack([(uv[:, 0] - K[0, 2] - K[0, 1] * (uv[:, 1] - K[1, 2]) / K[1, 1]) / K[0, 0],
                     (uv[:, 1] - K[1, 2]) / K[1, 1]], -1)


@dataclass
class PairPose:
    """Relative pose of view ``b`` w.r.t. view ``a`` (``x_b = R x_a + t``, |t| = 1)."""

    a: int
    b: int
    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray  # indices of the tracks used (inliers, in front of both cameras)
    parallax_deg: float  # median angle between the two rays of the inliers

    @property
    def quality(self) -> float:
        """Inliers, discounted when the baseline is too small to fix depth (< 4 degrees)."""
        return len(self.inliers) * min(1.0, self.parallax_deg / 4.0)


def relative_pose(xa: np.ndarray, xb: np.ndarray, Ka: np.ndarray, Kb: np.ndarray,
                  threshold_px: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray,
                                                               np.ndarray, float] | None:
    """Relative pose from 2D-2D correspondences with known intrinsics: the essential matrix
    (OpenCV's MAGSAC, with local optimisation) and the cheirality test.

    xa, xb (N,2) pixels. Returns (R, t unit, inlier mask (N,), median parallax degrees) or None
    (fewer than 8 points or no solution)."""
    if len(xa) < 8:
        return None
    na, nb = normalised(xa, Ka), normalised(xb, Kb)
    f = 0.5 * (Ka[0, 0] + Kb[0, 0])
    cv2.setRNGSeed(seed)
    try:
        E, mask = cv2.findEssentialMat(na, nb, np.eye(3), method=cv2.USAC_MAGSAC, prob=0.9999,
                                       threshold=threshold_px / f)
    except cv2.error:
        return None
    if E is None or mask is None or E.shape[0] < 3:
        return None
    best = None
    for i in range(0, E.shape[0] - 2, 3):
        try:
            n, R, tt, m = cv2.recoverPose(E=E[i:i + 3], points1=na, points2=nb,
                                          cameraMatrix=np.eye(3), mask=mask.copy())
        except cv2.error:
            continue
        if best is None or n > best[0]:
            best = (n, R, tt.reshape(3), m.reshape(-1) > 0)
    if best is None or best[0] < 8:
        return None
    _, R, tt, inl = best
    # parallax: angle between the two rays of each inlier
    ra = np.c_[na[inl], np.ones(inl.sum())]
    rb = np.c_[nb[inl], np.ones(inl.sum())] @ R  # ray b in a's frame
    cos = (ra * rb).sum(1) / (np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1))
    parallax = float(np.degrees(np.median(np.arccos(np.clip(cos, -1, 1)))))
    return R, tt, inl, parallax


# --- several views ----------------------------------------------------------------------------

def _rodrigues(v: np.ndarray) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(v, np.float64).reshape(3, 1))[0]


def _skew(v: np.ndarray) -> np.ndarray:
    """(...,3) -> (...,3,3) cross-product matrices."""
    z = np.zeros(v.shape[:-1])
    return np.stack([np.stack([z, -v[..., 2], v[..., 1]], -1),
                     np.stack([v[..., 2], z, -v[..., 0]], -1),
                     np.stack([-v[..., 1], v[..., 0], z], -1)], -2)


def bundle_adjust(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray, uv: np.ndarray,
                  w: np.ndarray, views: list[int], fixed: int, loss_px: float,
                  iterations: int = 50) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refine the cameras ``views`` (all but ``fixed``) and the points ``X (N,3)`` on the
    observations ``uv (V,N,2)``, ``w (V,N)`` (> 0 = used, the weight) with a robust (Huber,
    scale ``loss_px``) reprojection error: Levenberg-Marquardt with analytic Jacobians, the
    points eliminated per step (Schur complement), rotations updated on the left
    (``R <- exp(d) R``). The fixed camera holds the gauge; the damping holds the scale.
    Returns (R, t, X) with the refined entries replaced."""
    R, t, X = R.copy(), t.copy(), np.asarray(X, float).copy()
    free = [v for v in views if v != fixed]
    w = np.where((w[views] > 0).sum(0) >= 2, w, 0.0)  # a point seen once has no depth
    ci, pi = np.nonzero(w[views] > 0)
    ci = np.asarray(views)[ci]
    if not free or len(ci) < 6:
        return R, t, X
    col = -np.ones(len(R), int)
    col[free] = np.arange(len(free))
    nc, N = 6 * len(free), len(X)
    obs, wt = uv[ci, pi], w[ci, pi]
    fx, fy = K[ci, 0, 0], K[ci, 1, 1]
    cx, cy = K[ci, 0, 2], K[ci, 1, 2]

    def residuals(R_, t_, X_):
        xc = np.einsum("nij,nj->ni", R_[ci], X_[pi]) + t_[ci]
        z = np.maximum(xc[:, 2], 1e-6)
        r = np.stack([fx * xc[:, 0] / z + cx, fy * xc[:, 1] / z + cy], 1) - obs
        return r, xc, z

    def cost(r):
        e = np.linalg.norm(r, axis=1)
        huber = np.where(e <= loss_px, 0.5 * e ** 2, loss_px * (e - 0.5 * loss_px))
        return float((wt * huber).sum())

    r, xc, z = residuals(R, t, X)
    current = cost(r)
    lam = 1e-3
    for _ in range(iterations):
        e = np.linalg.norm(r, axis=1)
        irls = wt * np.where(e <= loss_px, 1.0, loss_px / np.maximum(e, 1e-12))
        Jxc = np.zeros((len(ci), 2, 3))
        Jxc[:, 0, 0], Jxc[:, 0, 2] = fx / z, -fx * xc[:, 0] / z ** 2
        Jxc[:, 1, 1], Jxc[:, 1, 2] = fy / z, -fy * xc[:, 1] / z ** 2
        JX = np.einsum("nij,njk->nik", Jxc, R[ci])  # (n,2,3)
        Jc = np.concatenate([-np.einsum("nij,njk->nik", Jxc, _skew(xc - t[ci])), Jxc], 2)
        Hpp = np.zeros((N, 3, 3))
        np.add.at(Hpp, pi, irls[:, None, None] * np.einsum("nki,nkj->nij", JX, JX))
        gp = np.zeros((N, 3))
        np.add.at(gp, pi, irls[:, None] * np.einsum("nki,nk->ni", JX, r))
        Hcc = np.zeros((nc, nc))
        gc = np.zeros(nc)
        Hcp = np.zeros((N, nc, 3))
        for v in free:
            m = ci == v
            k = 6 * col[v]
            Jm, rm, im = Jc[m], r[m], irls[m]
            Hcc[k:k + 6, k:k + 6] = np.einsum("n,nki,nkj->ij", im, Jm, Jm)
            gc[k:k + 6] = np.einsum("n,nki,nk->i", im, Jm, rm)
            np.add.at(Hcp[:, k:k + 6], pi[m], im[:, None, None] *
                      np.einsum("nki,nkj->nij", Jm, JX[m]))
        improved = False
        for _ in range(6):
            Hpp_d = Hpp + lam * (np.eye(3) * np.maximum(np.einsum("nii->ni", Hpp), 1e-9)[:, :, None])
            det = np.linalg.det(Hpp_d)
            okp = np.abs(det) > 1e-18
            inv = np.zeros_like(Hpp_d)
            inv[okp] = np.linalg.inv(Hpp_d[okp])
            B = Hcp @ inv  # (N,nc,3)
            S = Hcc + lam * np.diag(np.maximum(np.diag(Hcc), 1e-9)) \
                - B.transpose(1, 0, 2).reshape(nc, -1) @ Hcp.transpose(1, 0, 2).reshape(nc, -1).T
            rhs = gc - B.transpose(1, 0, 2).reshape(nc, -1) @ gp.reshape(-1)
            try:
                dc = -np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            dp = -(inv @ (gp + (dc @ Hcp))[:, :, None])[:, :, 0]
            R2, t2 = R.copy(), t.copy()
            for v in free:
                k = 6 * col[v]
                R2[v] = _rodrigues(dc[k:k + 3]) @ R[v]
                t2[v] = t[v] + dc[k + 3:k + 6]
            X2 = X + dp
            r2, xc2, z2 = residuals(R2, t2, X2)
            c2 = cost(r2)
            if np.isfinite(c2) and c2 < current:
                R, t, X, r, xc, z = R2, t2, X2, r2, xc2, z2
                improved = current - c2 > 1e-10 * current
                current = c2
                lam = max(lam / 3, 1e-9)
                break
            lam *= 10
        if not improved:
            break
    return R, t, X


@dataclass
class Reconstruction:
    """Cameras placed from 2D-2D correspondences alone (arbitrary world frame and scale)."""

    R: np.ndarray  # (V,3,3); identity where not registered
    t: np.ndarray  # (V,3)
    registered: np.ndarray  # (V,) bool
    X: np.ndarray  # (N,3) triangulated tracks
    ok: np.ndarray  # (N,) bool: X is valid
    seed_pair: tuple[int, int] = (-1, -1)


def reconstruct_rig(uv: np.ndarray, w: np.ndarray, K: np.ndarray, threshold_px: float,
                    min_points: int = 12, bundle: bool = True) -> Reconstruction:
    """Incremental reconstruction of the cameras from keypoint tracks (no body model).

    uv (V,N,2), w (V,N) tracks (only w > 0 used); K (V,3,3); ``threshold_px`` the inlier
    distance. The pair with the most inliers at a sufficient baseline seeds the rig (essential
    matrix); the view sharing the most triangulated tracks is registered next (PnP-RANSAC),
    and so on; a bundle adjustment refines the cameras and points at the end. Views that share
    fewer than ``min_points`` tracks stay unregistered.
    """
    V, N = w.shape
    R = np.tile(np.eye(3), (V, 1, 1))
    t = np.zeros((V, 3))
    reg = np.zeros(V, bool)
    seen = w > 0
    pairs: list[PairPose] = []
    for a in range(V):
        for b in range(a + 1, V):
            common = np.nonzero(seen[a] & seen[b])[0]
            if len(common) < min_points:
                continue
            rp = relative_pose(uv[a, common], uv[b, common], K[a], K[b], threshold_px)
            if rp is None or rp[2].sum() < min_points:
                continue
            pairs.append(PairPose(a, b, rp[0], rp[1], common[rp[2]], rp[3]))
    empty = Reconstruction(R, t, reg, np.zeros((N, 3)), np.zeros(N, bool))
    if not pairs:
        return empty
    seed = max(pairs, key=lambda p: p.quality)
    log.info("camera init (sfm): seed pair %d-%d, %d inliers, parallax %.1f deg", seed.a,
             seed.b, len(seed.inliers), seed.parallax_deg)
    R[seed.b], t[seed.b] = seed.R, seed.t
    reg[[seed.a, seed.b]] = True
    wa = np.zeros_like(w)
    wa[:, seed.inliers] = w[:, seed.inliers]
    return _complete(uv, w, K, R, t, reg, seed.a, threshold_px, min_points, bundle,
                     seed_weights=wa, seed_pair=(seed.a, seed.b))


def _complete(uv, w, K, R, t, reg, fixed: int, threshold_px: float, min_points: int,
              bundle: bool = True, seed_weights=None, seed_pair=(-1, -1),
              loose_px: float | None = None) -> Reconstruction:
    """Register the remaining views by PnP-RANSAC against the tracks the registered ones
    triangulate (the view sharing the most first), then bundle-adjust (two passes, the second
    without the observations the first leaves far off; camera ``fixed`` holds the gauge).
    ``loose_px``: the seed cameras are approximate (affine); bundle-adjust them first with this
    robust scale."""
    R, t, reg = R.copy(), t.copy(), reg.copy()
    seen = w > 0
    if loose_px is not None and reg.sum() >= 2:
        views = list(np.nonzero(reg)[0])
        ws = np.where(reg[:, None], w, 0.0)
        X0, ok0 = triangulate(projection_matrices(K, R, t), uv, ws, min_views=2)
        for scale in (loose_px, threshold_px):
            R, t, Xb = bundle_adjust(K, R, t, X0[ok0], uv[:, ok0], ws[:, ok0], views, fixed,
                                     scale)
            X0 = X0.copy()
            X0[ok0] = Xb

    def retriangulate(weights):
        P = projection_matrices(K[reg], R[reg], t[reg])
        X, ok = robust_triangulate(P, uv[reg], weights[reg], threshold_px)
        # keep the tracks that at least two registered views agree on
        e = reprojection_errors(K[reg], R[reg], t[reg], uv[reg], weights[reg] * ok[None],
                                leave_one_out=False)
        agree = (np.where(np.isfinite(e), e, np.inf) <= 3 * threshold_px).sum(0) >= 2
        return X, ok & agree

    X, ok = retriangulate(w if seed_weights is None else seed_weights)
    while not reg.all():
        best = None
        for v in np.nonzero(~reg)[0]:
            m = ok & seen[v]
            if m.sum() < min_points:
                continue
            sol = pnp_ransac(X[m], uv[v, m], K[v], 2 * threshold_px, iterations=500)
            if sol is None:
                continue
            n_in = sol[3] * m.sum()
            if n_in >= min_points and (best is None or n_in > best[0]):
                best = (n_in, v, sol[0], sol[1])
        if best is None:
            break
        _, v, R[v], t[v] = best
        reg[v] = True
        X, ok = retriangulate(w)
    if bundle and reg.sum() >= 2:
        views = list(np.nonzero(reg)[0])
        wb = w * ok[None] * reg[:, None]
        for _ in range(2):  # the second pass without the observations the first left far off
            R, t, Xb = bundle_adjust(K, R, t, X[ok], uv[:, ok], wb[:, ok], views, fixed,
                                     threshold_px)
            X = X.copy()
            X[ok] = Xb
            e = reprojection_errors(K, R, t, uv, wb * ok[None], leave_one_out=False)
            wb = np.where(np.isfinite(e) & (e > 3 * threshold_px), 0.0, wb)
        X, ok = retriangulate(w)
    return Reconstruction(R, t, reg, X, ok, seed_pair)


def affine_factorization(uv: np.ndarray, w: np.ndarray, K: np.ndarray, views: list[int],
                         min_tracks: int = 20) -> list[tuple[np.ndarray, np.ndarray]]:
    """Cameras of ``views`` from tracks seen by all of them, as scaled orthographic cameras
    (Tomasi-Kanade factorisation and the metric upgrade for known intrinsics).

    A body seen from afar fills a small angle: two views' essential matrix then leaves the
    rotation angle free (bas-relief), and one view's PnP of a small, nearly flat torso is
    weak; three or more affine views fix the rotations jointly, without local minima, up to
    a mirror image (Necker). Returns both mirror solutions as (R (V,3,3), t (V,3)) with
    identity/zero for views not in ``views``; the world is the tracks' centroid and scale is
    arbitrary. Empty when fewer than 3 views or ``min_tracks`` common tracks.
    """
    sol = _factorise(uv, w, K, views, min_tracks)
    if sol is None:
        return []
    M, mean, _ = sol
    return _metric_upgrade(M, mean, w.shape[0], views)


def _factorise(uv, w, K, views, min_tracks: int):
    """Rank-3 factorisation of the centred normalised tracks common to ``views``: (M (2n,3),
    per-view means (n,2), per-view rms residual in px) or None."""
    if len(views) < 3:
        return None
    common = np.nonzero((w[views] > 0).all(0))[0]
    if len(common) < min_tracks:
        return None
    xn = np.stack([normalised(uv[v, common], K[v]) for v in views])  # (n,M,2)
    mean = xn.mean(1)
    W = (xn - mean[:, None]).transpose(0, 2, 1).reshape(2 * len(views), -1)
    U, S, Vt = np.linalg.svd(W, full_matrices=False)
    M = U[:, :3] * np.sqrt(S[:3])
    res = (W - M @ (np.sqrt(S[:3])[:, None] * Vt[:3])).reshape(len(views), 2, -1)
    f = np.array([K[v, 0, 0] for v in views])
    rms = np.sqrt((res ** 2).sum(1).mean(1)) * f
    return M, mean, rms


def _metric_upgrade(M: np.ndarray, mean: np.ndarray, V: int, views: list[int]
                    ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Scaled orthographic cameras from the affine factor ``M``: L = Q Q^T solves
    m1 L m1 = m2 L m2, m1 L m2 = 0 per view (rows of equal length, orthogonal) with the first
    view's scale 1; both mirror images (Q and Q diag(1, 1, -1))."""
    def row(a, b):
        return np.array([a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[0] * b[2] + a[2] * b[0],
                         a[1] * b[1], a[1] * b[2] + a[2] * b[1], a[2] * b[2]])
    A, rhs = [], []
    for i in range(len(views)):
        m1, m2 = M[2 * i], M[2 * i + 1]
        A += [row(m1, m1) - row(m2, m2), row(m1, m2)]
        rhs += [0.0, 0.0]
    A.append(row(M[0], M[0]))
    rhs.append(1.0)
    ell = np.linalg.lstsq(np.asarray(A), np.asarray(rhs), rcond=None)[0]
    L = np.array([[ell[0], ell[1], ell[2]], [ell[1], ell[3], ell[4]], [ell[2], ell[4], ell[5]]])
    evals, evecs = np.linalg.eigh(L)
    if evals.max() <= 0:
        return []
    Q = evecs @ np.diag(np.sqrt(np.clip(evals, 1e-9 * evals.max(), None)))
    out = []
    for mirror in (1.0, -1.0):
        Qm = Q @ np.diag([1.0, 1.0, mirror])
        R = np.tile(np.eye(3), (V, 1, 1))
        t = np.zeros((V, 3))
        for i, v in enumerate(views):
            a, b = M[2 * i] @ Qm, M[2 * i + 1] @ Qm
            s_ = 0.5 * (np.linalg.norm(a) + np.linalg.norm(b))
            r1 = a / np.linalg.norm(a)
            r2 = b - (b @ r1) * r1
            r2 /= np.linalg.norm(r2)
            Rv = np.stack([r1, r2, np.cross(r1, r2)])
            U2, _, Vt2 = np.linalg.svd(Rv)
            R[v] = U2 @ Vt2
            depth = 1.0 / max(s_, 1e-9)
            t[v] = np.r_[mean[i] * depth, depth]
        out.append((R, t))
    return out


def affine_rig(uv: np.ndarray, w: np.ndarray, K: np.ndarray, threshold_px: float,
               min_points: int = 12) -> list[Reconstruction]:
    """Reconstructions seeded by :func:`affine_factorization` (both mirror images): the views
    sharing the most tracks are factorised (dropping the view with the fewest observations
    until enough tracks are common to all), the others registered by PnP against the
    triangulated tracks, and all refined by bundle adjustment (perspective)."""
    V, N = w.shape
    views = [v for v in range(V) if (w[v] > 0).sum() >= min_points]
    sols = []
    while len(views) >= 3:
        fac = _factorise(uv, w, K, views, 20)
        if fac is None:  # too few tracks common to all: drop the view seeing the fewest
            views.remove(min(views, key=lambda v: (w[v] > 0).sum()))
            continue
        rms = fac[2]
        worst = int(np.argmax(rms))
        others = np.delete(rms, worst)
        if len(views) > 3 and rms[worst] > max(3 * np.median(others), 2 * threshold_px):
            views.pop(worst)  # a view the others' affine structure does not explain
            continue
        sols = _metric_upgrade(fac[0], fac[1], V, views)
        break
    out = []
    for R, t in sols:
        reg = np.zeros(V, bool)
        reg[views] = True
        out.append(_complete(uv, w, K, R, t, reg, views[0], threshold_px, min_points,
                             loose_px=10 * threshold_px))
    return out


def mirrored(rec: Reconstruction, uv: np.ndarray, w: np.ndarray, K: np.ndarray,
             threshold_px: float, min_points: int) -> Reconstruction:
    """The other branch of a reconstruction's depth reversal (Necker): the scene reflected in
    depth and each camera turned accordingly (``R' = diag(1,1,-1) R diag(1,1,-1)``), which an
    affine camera cannot tell from the original, then refined in perspective. Near-affine
    views (a body far away) leave the two nearly as good on the images; the body's own shape
    (the face in front, left and right labelled) tells them apart (:func:`align_to_body`)."""
    D = np.diag([1.0, 1.0, -1.0])
    c = np.median(rec.X[rec.ok], axis=0) if rec.ok.any() else np.zeros(3)
    R = np.einsum("ij,vjk,kl->vil", D, rec.R, D)
    # each camera keeps the image and the depth of the scene's centre c (reflected about c)
    xc = np.einsum("vij,j->vi", rec.R, c) + rec.t
    t = xc * [1.0, 1.0, 1.0] - np.einsum("vij,j->vi", R, c)
    views = list(np.nonzero(rec.registered)[0])
    reg = np.zeros(len(R), bool)
    reg[views] = True
    return _complete(uv, w, K, R, t, reg, views[0], threshold_px, min_points,
                     loose_px=10 * threshold_px)


def align_to_body(rec: Reconstruction, kp_neutral: np.ndarray, T: int, K_num: int,
                  body_keypoints, frames: int
                  ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """The reconstruction's cameras in the rest body's frame and scale: the similarity that
    maps the median of its triangulated ``body_keypoints`` over the first ``frames`` frames
    that have them onto ``kp_neutral (133,3)`` (Umeyama). Returns (R, t, rms residual of the
    alignment relative to the body points' spread); None with fewer than 4 points. A mirror
    image of the body (left and right exchanged) aligns badly: the residual tells."""
    idx = np.asarray(body_keypoints)
    X = rec.X.reshape(T, K_num, 3)[:, idx]
    ok = rec.ok.reshape(T, K_num)[:, idx]
    rows = np.nonzero(ok.sum(1) >= 4)[0][:frames]
    if not len(rows):
        return None
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(np.where(ok[rows][..., None], X[rows], np.nan), axis=0)
    good = np.isfinite(med).all(1)
    if good.sum() < 4:
        return None
    sim = umeyama(med[good], kp_neutral[idx][good], with_scale=True)
    if not np.isfinite(sim.s) or sim.s <= 0:
        return None
    dst = kp_neutral[idx][good]
    resid = float(np.sqrt(((sim.apply(med[good]) - dst) ** 2).sum(1).mean())
                  / max(np.sqrt(((dst - dst.mean(0)) ** 2).sum(1).mean()), 1e-9))
    Rn = np.einsum("vij,kj->vik", rec.R, sim.R)  # R R_s^T
    tn = sim.s * rec.t - np.einsum("vij,j->vi", Rn, sim.t)
    return Rn, tn, resid


# --- left and right exchanged ----------------------------------------------------------------

#: Left/right pairs of the 68 face landmarks (iBUG order): jaw, brows, nostrils, eyes, mouth.
_FACE_PAIRS = ([(i, 16 - i) for i in range(8)] + [(17 + i, 26 - i) for i in range(5)]
               + [(31, 35), (32, 34), (36, 45), (37, 44), (38, 43), (39, 42), (40, 47),
                  (41, 46), (48, 54), (49, 53), (50, 52), (55, 59), (56, 58), (60, 64),
                  (61, 63), (65, 67)])


def mirror_index() -> np.ndarray:
    """(133,) each COCO-WholeBody keypoint's left/right counterpart (itself on the midline)."""
    m = np.arange(133)
    for a, b in ((1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (15, 16),
                 (17, 20), (18, 21), (19, 22)):
        m[a], m[b] = b, a
    for a, b in _FACE_PAIRS:
        m[23 + a], m[23 + b] = 23 + b, 23 + a
    m[91:112], m[112:133] = np.arange(112, 133), np.arange(91, 112)
    return m


def _swap_evidence(K, R, t, obs, threshold_px, views) -> np.ndarray:
    """(V,T) ratio of the median distance of each view-frame's body and hand detections to the
    other views' points with the sides exchanged, over as labelled (inf: not testable, or
    already close as labelled)."""
    V, T = obs.shape[:2]
    mirror = mirror_index()
    test = np.r_[np.arange(5, 17), np.arange(91, 133)]
    uv, w = tracks(obs)
    P = projection_matrices(K, R, t)
    ratio = np.full((V, T), np.inf)
    for v in views:
        others = [u for u in views if u != v]
        if len(others) < 2:
            continue
        X, ok = robust_triangulate(P[others], uv[others], w[others], threshold_px)
        X, ok = X.reshape(T, 133, 3), ok.reshape(T, 133)
        proj, front = project_points(K[v], R[v], t[v], X)
        front &= ok
        o = obs[v]
        as_is = np.linalg.norm(o[:, test, :2] - proj[:, test], axis=-1)
        swapped = np.linalg.norm(o[:, test, :2] - proj[:, mirror[test]], axis=-1)
        both = (o[:, test, 2] > 0) & front[:, test] & front[:, mirror[test]]
        for f in range(T):
            m = both[f]
            if m.sum() < 6:
                continue
            a, b = np.median(as_is[f][m]), np.median(swapped[f][m])
            if a > 2 * threshold_px:
                ratio[v, f] = b / a
    return ratio


def side_swaps(K: np.ndarray, R: np.ndarray, t: np.ndarray, obs: np.ndarray,
               threshold_px: float, views=None) -> np.ndarray:
    """(V,T) bool: the view-frames whose detections have left and right exchanged (a detector
    seeing a signer from behind often takes the back for the front).

    Each view's body and hand keypoints are compared with the points the other views
    triangulate (robustly), as labelled and with every left/right pair exchanged; a view-frame
    is swapped when exchanged they land at less than half the distance, and farther than
    ``2 threshold_px`` as labelled. One view at a time, the one with the strongest evidence
    first, is repaired before the others are tested again (its exchanged sides would
    otherwise make the others' points look exchanged). ``views``: the trusted cameras."""
    V, T = obs.shape[:2]
    views = list(range(V)) if views is None else list(views)
    out = np.zeros((V, T), bool)
    for _ in range(len(views)):
        cur = exchange_sides(obs, out)
        ratio = _swap_evidence(K, R, t, cur, threshold_px, views)
        cand = (ratio < 0.5) & ~out
        if not cand.any():
            break
        # the view with the strongest evidence (a truly exchanged view-frame matches the
        # others' points almost exactly once exchanged)
        strength = np.where(cand, 0.5 - ratio, 0.0).sum(1)
        v = int(np.argmax(strength))
        out[v] |= cand[v]
    return out


def exchange_sides(obs: np.ndarray, swaps: np.ndarray) -> np.ndarray:
    """obs (V,T,133,3) with the left/right labels of the view-frames ``swaps (V,T)`` exchanged."""
    out = obs.copy()
    v, f = np.nonzero(swaps)
    out[v, f] = obs[v, f][:, mirror_index()]
    return out


# --- views placed on the wrong side of the signer -------------------------------------------

def refine_view(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray, uv: np.ndarray,
                threshold_px: float, rounds: int = 3) -> tuple[np.ndarray, np.ndarray, float]:
    """One camera's pose refined on fixed points X (N,3) and their detections uv (N,2)
    (OpenCV's Levenberg-Marquardt ``solvePnPRefineLM``), leaving out after each round the
    points farther than ``3 threshold_px``. Returns (R, t, median px over all N points)."""
    obj = np.ascontiguousarray(X, np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(uv, np.float64).reshape(-1, 1, 2)
    rvec = cv2.Rodrigues(np.asarray(R, np.float64))[0]
    tvec = np.asarray(t, np.float64).reshape(3, 1).copy()
    keep = np.ones(len(obj), bool)
    for _ in range(rounds):
        rvec, tvec = cv2.solvePnPRefineLM(obj[keep], img[keep], K, None, rvec, tvec)
        proj, front = project_points(K, cv2.Rodrigues(rvec)[0], tvec.reshape(3), X)
        err = np.where(front, np.linalg.norm(proj - uv, axis=-1), np.inf)
        near = err <= 3 * threshold_px
        if near.sum() < 12:
            break
        keep = near
    return cv2.Rodrigues(rvec)[0], tvec.reshape(3), float(np.median(err))


def turned_around(R: np.ndarray, t: np.ndarray, centre: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """A camera moved half a turn about the vertical (world y) through ``centre``: the same
    view of the signer from the other side."""
    Q = np.diag([-1.0, 1.0, -1.0])
    c = np.asarray(centre, float)
    C = Q @ (-R.T @ t - c) + c
    R2 = R @ Q
    return R2, -R2 @ C


def _view_error(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray, ok: np.ndarray,
                obs_v: np.ndarray) -> float:
    """Median over frames of one camera's median distance from its detections obs_v (T,133,3)
    to the points X (T,133,3) (``ok``: triangulated), each frame taken as labelled or with its
    sides exchanged, whichever is closer (the fit exchanges such view-frames back)."""
    proj, front = project_points(K, R, t, X)
    mirror = mirror_index()
    seen = obs_v[..., 2] > 0
    frames = []
    for f in range(len(obs_v)):
        best = np.inf
        for idx in (np.arange(133), mirror):
            m = seen[f] & ok[f, idx]
            if m.sum() >= 4:
                e = np.where(front[f, idx][m],
                             np.linalg.norm(obs_v[f, m, :2] - proj[f, idx][m], axis=-1), np.inf)
                best = min(best, float(np.median(e)))
        if np.isfinite(best):
            frames.append(best)
    return float(np.median(frames)) if frames else np.inf


def turn_views(K: np.ndarray, R: np.ndarray, t: np.ndarray, obs: np.ndarray, views: list[int],
               threshold_px: float, margin: float, centre: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, dict[int, tuple[float, float]],
                          dict[int, tuple[float, float]]]:
    """Views placed on the wrong side of the signer, turned around.

    Seen from behind with left and right labelled the other way round, a body's keypoints look
    like a (mirrored) front view, so a reconstruction can place such a camera facing the front,
    and its bundle adjustment, which moves the points too, stays there. Against the points the
    other views triangulate the wrong side is no minimum: each view is refined on them from its
    pose and from that pose turned half a turn about the vertical through ``centre``. A
    refined pose more than 90 degrees from the view's own is a candidate when its error
    (:func:`_view_error`, which allows every frame its sides exchanged, so a true back view
    with exchanged labels keeps its side) is below ``margin`` times the view's; the candidate
    with the largest gain is taken, then the others are tried again, one view at a time.
    Smaller corrections are left to the fit: on biased detections they lead towards the
    keypoints' optimum, away from the true rig (docs/fit.md).

    obs (V,T,133,3): the observations the rig was estimated on. Returns (R, t, turned,
    doubtful): ``turned`` {view: (error px before, after)}; ``doubtful`` {view: (error px,
    error px on the other side)} for the views left where they are although the other side
    fits their detections better, by less than the margin (``margin`` 0: neither is looked
    for)."""
    R, t = np.array(R, float), np.array(t, float)
    T = obs.shape[1]
    uv, w = tracks(obs)
    turned: dict[int, tuple[float, float]] = {}
    doubtful: dict[int, tuple[float, float]] = {}
    while margin > 0:
        P = projection_matrices(K, R, t)
        errs, pts = {}, {}
        for v in views:
            others = [u for u in views if u != v]
            if v in turned or len(others) < 2:
                continue
            X, ok = robust_triangulate(P[others], uv[others], w[others], threshold_px)
            m = ok & (w[v] > 0)
            if m.sum() < 12:
                continue
            pts[v] = (X.reshape(T, 133, 3), ok.reshape(T, 133), X[m], uv[v, m])
            errs[v] = _view_error(K[v], R[v], t[v], *pts[v][:2], obs[v])
        best = None  # (ratio, view, R, t, error)
        doubtful = {}
        for v in errs:
            for start in ((R[v], t[v]), turned_around(R[v], t[v], centre)):
                Rn, tn, _ = refine_view(K[v], *start, *pts[v][2:], threshold_px)
                if rotation_angle_deg(Rn, R[v]) <= 90.0:
                    continue
                e = _view_error(K[v], Rn, tn, *pts[v][:2], obs[v])
                if e < errs[v]:
                    doubtful[v] = (errs[v], min(e, doubtful.get(v, (0, np.inf))[1]))
                if e < margin * errs[v] and (best is None or e / errs[v] < best[0]):
                    best = (e / errs[v], v, Rn, tn, e)
        if best is None:
            break
        _, v, R[v], t[v], e = best
        turned[v] = (errs[v], e)
    return R, t, turned, doubtful


# --- the body: PnP of the rest body's head and torso ----------------------------------------

#: Keypoints that move rigidly with the head and torso: nose, eyes, ears, shoulders, hips, face.
PNP_KEYPOINTS = tuple(range(0, 7)) + (11, 12) + tuple(range(23, 91))


def median_observation(obs_v: np.ndarray, frames: int) -> np.ndarray:
    """Per-keypoint median over the first ``frames`` frames that observe it.

    obs_v (T,133,3) of one view -> (133,3): x, y and the fraction of those frames observing it.
    """
    out = np.zeros((obs_v.shape[1], 3))
    for k in range(obs_v.shape[1]):
        ok = np.nonzero(obs_v[:, k, 2] > 0)[0][:frames]
        if len(ok):
            out[k, :2] = np.median(obs_v[ok, k, :2], axis=0)
            out[k, 2] = len(ok) / frames
    return out


def pooled_correspondences(kp_neutral: np.ndarray, obs_v: np.ndarray, frames: int,
                           min_score: float) -> tuple[np.ndarray, np.ndarray]:
    """Rest-body points and their detections over the first ``frames`` observed frames of
    one view (head/torso keypoints with score >= ``min_score``): (N,3), (N,2)."""
    idx = np.asarray(PNP_KEYPOINTS)
    seen = np.nonzero((obs_v[:, idx, 2] > 0).any(1))[0][:frames]
    o = obs_v[seen][:, idx]  # (F,K,3)
    m = o[..., 2] >= min_score
    return np.broadcast_to(kp_neutral[idx], o[..., :3].shape)[m], o[..., :2][m]


def body_pnp(kp_neutral: np.ndarray, obs_v: np.ndarray, K: np.ndarray, height: float,
             cfg: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Candidates of one view from the rest body's head/torso keypoints (config
    ``fit.multiview``): ``pnp`` against the median of the first ``init_frames`` frames' detections,
    ``pnp_ransac`` on every confident detection of those frames. Either may be missing."""
    out = {}
    idx = np.asarray(PNP_KEYPOINTS)
    med = median_observation(obs_v, cfg["init_frames"])
    m = med[idx, 2] > 0
    if m.sum() >= cfg["pnp_min_points"]:
        sol = pnp(kp_neutral[idx][m], med[idx][m][:, :2], K)
        if sol is not None and sol[2] <= cfg["pnp_max_rms_px"] and \
                np.linalg.norm(sol[1]) <= cfg["pnp_max_distance_m"]:
            out["pnp"] = (sol[0], sol[1])
    X, x = pooled_correspondences(kp_neutral, obs_v, cfg["init_frames"], cfg["ransac_min_score"])
    rs = pnp_ransac(X, x, K, cfg["ransac_threshold"] * float(height))
    if rs is not None and rs[3] >= cfg["ransac_min_inliers"] and \
            np.linalg.norm(rs[1]) <= cfg["pnp_max_distance_m"]:
        out["pnp_ransac"] = (rs[0], rs[1])
    return out


# --- choosing ---------------------------------------------------------------------------------

def init_frames(obs: np.ndarray, count: int) -> np.ndarray:
    """Indices of at most ``count`` frames, evenly spaced over those with observations."""
    busy = np.nonzero((obs[..., 2] > 0).sum((0, 2)) > 0)[0]
    if len(busy) <= count:
        return busy
    return busy[np.unique(np.linspace(0, len(busy) - 1, count).round().astype(int))]


#: which sources each ``camera_init`` uses, in the order of preference on a tie
INIT_SOURCES = {"auto": SOURCES, "sfm": ("affine", "sfm", "prior"), "pnp": ("pnp", "prior"),
                "rig_prior": ("prior",)}


def _assemble(cands, first: str, order, prior) -> tuple[np.ndarray, np.ndarray,
                                                        list[str]] | None:
    """The rig of source ``first``, other sources (in ``order``) where it places no camera,
    the prior's camera for views without detections; None when ``first`` places none."""
    V = len(cands)
    R, t, st = prior.R.copy(), prior.t.copy(), ["no_detections"] * V
    used = False
    for v in range(V):
        for name in (first, *order):
            if name in cands[v]:
                R[v], t[v] = cands[v][name]
                st[v] = name
                used = used or name == first
                break
    return (R, t, st) if used else None


def choose_rig(scores: dict[str, float], order, prior_margin: float) -> str:
    """The winning whole rig: the lowest held-out score (ties: the earlier in ``order``),
    except that the configured arc ("prior") stays unless the best score is below
    ``prior_margin`` times the prior's. Detector bias makes even the true rig score somewhat
    worse than the keypoints' own optimum, so a small gain is no evidence against the prior."""
    best = min(scores, key=lambda n: (scores[n], order.index(n)))
    if "prior" in scores and best != "prior" and \
            not scores[best] < prior_margin * scores["prior"]:
        log.info("camera init: keeping the configured rig ('prior', %.2f px): the best other "
                 "hypothesis %r (%.2f px) is not below %.2f x its error", scores["prior"],
                 best, scores[best], prior_margin)
        return "prior"
    return best


def _like_body(source: str, residual: float, bound: float) -> bool:
    """Whether a reconstruction's alignment onto the rest body (:func:`align_to_body`'s
    residual) is within ``bound``; a warning when it is not."""
    if residual <= bound:
        return True
    log.warning("camera init (%s): rejected, its points do not match the body's shape "
                "(alignment residual %.2f > max_body_residual %.2f): its geometry is likely "
                "wrong", source, residual, bound)
    return False


def initial_rig(kp_neutral: np.ndarray, obs: np.ndarray, K: np.ndarray, width, height,
                cfg: dict) -> RigHypotheses:
    """Cameras without ground truth and without assuming the rig (see the module docstring).

    kp_neutral (133,3): the rest body's keypoints; obs (V,T,133,3) cleaned observations; K
    (V,3,3); cfg the validated ``fit.multiview`` section (``camera_init`` auto, sfm, pnp or
    rig_prior; ``init`` settings). World frame: the rest body's (y up, the signer facing +z).
    """
    V = obs.shape[0]
    K = np.asarray(K, float)
    H = np.asarray(height, float)
    ic = cfg["init"]
    mode = cfg["camera_init"]
    order = INIT_SOURCES[mode]
    sel = init_frames(obs, ic["frames"])
    o = obs[:, sel]
    T = len(sel)
    held = heldout_split(T, o.shape[2])
    est_all = o.copy()  # the estimation half (every keypoint: the rest body's PnP)
    est_all[:, held, 2] = 0
    off = np.setdiff1d(np.arange(o.shape[2]), TRACK_KEYPOINTS)
    est, test = est_all.copy(), o.copy()
    est[:, :, off, 2] = 0
    test[:, ~held, 2] = 0
    test[:, :, off, 2] = 0
    uv_t, w_t = tracks(test)
    live = [v for v in range(V) if (obs[v, ..., 2] > 0).any()]
    limit = ic["unplaced_fraction"] * H
    thr = inlier_threshold_px(ic, H)
    chest = kp_neutral[[5, 6]].mean(0)
    prior = rig_prior(K, width, height, V, cfg["camera_prior"]["arc_degrees"],
                      cfg["camera_prior"]["distance"], chest)
    cands: list[dict[str, tuple[np.ndarray, np.ndarray]]] = [{} for _ in range(V)]
    for v in live:
        cands[v]["prior"] = (prior.R[v], prior.t[v])
        if "pnp" in order or "pnp_ransac" in order:
            pn = body_pnp(kp_neutral, est_all[v], K[v], H[v], cfg)
            cands[v].update({k: x for k, x in pn.items() if k in order})
    uv_e, w_e = tracks(est)
    if "sfm" in order and len(live) >= 2:
        rec = reconstruct_rig(uv_e, w_e, K, thr, min_points=ic["min_points"])
        aligned = None
        if rec.registered.sum() >= 2:
            for branch in (rec, mirrored(rec, uv_e, w_e, K, thr, ic["min_points"])):
                al = align_to_body(branch, kp_neutral, T, o.shape[2], PNP_KEYPOINTS,
                                   cfg["init_frames"])
                log.info("camera init (sfm): %s branch, body alignment residual %s",
                         "first" if branch is rec else "depth-reversed",
                         "none" if al is None else f"{al[2]:.2f}")
                if al is not None and (aligned is None or al[2] < aligned[2]):
                    aligned, rec_used = al, branch
            rec = rec_used if aligned is not None else rec
        if aligned is not None and not _like_body("sfm", aligned[2], ic["max_body_residual"]):
            aligned = None
        if aligned is not None:
            for v in np.nonzero(rec.registered)[0]:
                cands[v]["sfm"] = (aligned[0][v], aligned[1][v])
        log.info("camera init (sfm): %d of %d views registered", int(rec.registered.sum()),
                 len(live))
    if "affine" in order and len(live) >= 3:
        best_aff = None
        for rec in affine_rig(uv_e, w_e, K, thr, min_points=ic["min_points"]):
            al = align_to_body(rec, kp_neutral, T, o.shape[2], PNP_KEYPOINTS,
                               cfg["init_frames"])
            if al is not None and (best_aff is None or al[2] < best_aff[1][2]):
                best_aff = (rec, al)
        if best_aff is not None and not _like_body("affine", best_aff[1][2],
                                                   ic["max_body_residual"]):
            best_aff = None
        if best_aff is not None:
            rec, al = best_aff
            for v in np.nonzero(rec.registered)[0]:
                cands[v]["affine"] = (al[0][v], al[1][v])
            log.info("camera init (affine): %d of %d views registered, body alignment "
                     "residual %.2f", int(rec.registered.sum()), len(live), al[2])
    scores: dict[str, float] = {}
    tried: dict[str, tuple] = {}
    for name in order:
        rig = _assemble(cands, name, order, prior)
        if rig is None:
            continue
        px = heldout_errors(K, rig[0], rig[1], uv_t, w_t, limit, robust_px=thr)
        scores[name] = rig_score(px, live, limit)
        tried[name] = (rig, px)
        log.info("camera init: hypothesis %r (%s) -> held-out %.2f px (per view %s)", name,
                 ",".join(rig[2]), scores[name], np.round(px, 2).tolist())
    rigs = {name: (rig[0], rig[1]) for name, (rig, _) in tried.items()}
    if not scores:  # no view with detections
        return RigHypotheses(prior.R.copy(), prior.t.copy(), ["no_detections"] * V, "none",
                             scores, np.full(V, np.nan))
    winner = choose_rig(scores, order, ic["prior_margin"])
    (R, t, status), px = tried[winner]
    R, t, turned, doubtful = turn_views(K, R, t, est, live, thr, ic["turn_margin"], chest)
    status = list(status)
    for v, (before, after) in turned.items():
        log.info("camera init: view %d turned around (it was placed facing the other side of "
                 "the signer): %.2f -> %.2f px from the other views' points", v, before, after)
    for v, (here, there) in doubtful.items():
        log.warning("camera init: view %d may face the signer from the other side: its "
                    "detections lie %.2f px from the other views' points there and %.2f px "
                    "where it is placed, not below init.turn_margin (%.2f) times that, so it "
                    "stays, unless its person masks decide otherwise once the body is fitted "
                    "(init.mask_side_margin); check its overlays", v, there, here,
                    ic["turn_margin"])
    if turned:
        px = heldout_errors(K, R, t, uv_t, w_t, limit, robust_px=thr)
    for v in live:
        if not np.isfinite(px[v]) or px[v] > limit[v]:
            log.warning("camera init: view %d cannot be placed (held-out error %.1f px, limit "
                        "%.1f px; sources tried %s): its keypoints are left out of the fit "
                        "and its camera (from %s) is held fixed", v, px[v], limit[v],
                        sorted(cands[v]), status[v])
            status[v] = "unplaced"
    log.info("camera init: winner %r, views %s", winner, status)
    return RigHypotheses(R, t, status, winner, scores, px, rigs, turned, doubtful)


def place_cameras(kp_neutral: np.ndarray, obs: np.ndarray, K: np.ndarray, width, height,
                  cfg: dict) -> RigHypotheses:
    """The multi-view fit's camera initialisation: :func:`initial_rig`, and with
    ``repair_sides``:

    - views left unplaced are tried once more with their left and right exchanged in every
      frame (a detector that sees the signer from behind labels the whole view the other way
      round, and no camera matches such a view); the retry is kept when it places more views;
    - then once more without the view-frames whose left and right the placed cameras show to
      be exchanged (:func:`side_swaps`), when they are more than 2 % of all.

    Same arguments as :func:`initial_rig`. (The fit finds the exchanged view-frames again from
    the cameras returned and exchanges them back in what it fits.) The result's ``turned``
    holds the views turned in the placements that led to it: a turn in the first placement
    can decide the path to the last, which then needs none."""
    hyp = initial_rig(kp_neutral, obs, K, width, height, cfg)
    if not cfg["repair_sides"]:
        return hyp
    turned = dict(hyp.turned)
    lost = [v for v, s in enumerate(hyp.status) if s == "unplaced"]
    if lost:
        whole = np.zeros(obs.shape[:2], bool)
        whole[lost] = True
        flipped = exchange_sides(obs, whole)
        retry = initial_rig(kp_neutral, flipped, K, width, height, cfg)
        if len(placed_views(retry.status)) > len(placed_views(hyp.status)):
            log.info("camera init: view(s) %s placed with their left and right exchanged",
                     [v for v in lost if retry.status[v] != "unplaced"])
            hyp, obs = retry, flipped
            turned.update(retry.turned)
    swaps = side_swaps(np.asarray(K, float), hyp.R, hyp.t, obs,
                       inlier_threshold_px(cfg["init"], height), views=placed_views(hyp.status))
    if swaps.sum() > 0.02 * swaps.size:
        log.info("camera init: left and right exchanged in %d view-frames; placing the cameras "
                 "again without them", int(swaps.sum()))
        hyp = initial_rig(kp_neutral, exchange_sides(obs, swaps), K, width, height, cfg)
    return replace(hyp, turned={**turned, **hyp.turned})
