"""Camera initialisation that does not assume the rig (config ``fit.multiview.camera_init: auto``).

The images give two kinds of evidence about where the cameras are:

- the body itself: each view's head/torso keypoints against the same points of the rest body
  (PnP; :mod:`signsplat.fit.cameras`), which places a camera in the body's frame but is only as
  good as the rest body resembles the signer;
- the same keypoint seen by several views in the same frame: a 2D-2D correspondence. Over a
  clip the moving arms and hands give hundreds of them, spread in depth. Two views' relative pose
  follows from their essential matrix (known intrinsics), further views are registered by PnP
  against the points triangulated so far, and a bundle adjustment refines all of them
  (:func:`reconstruct_rig`, "sfm"). This needs no body model and no guess of the rig; the
  result is brought into the body's frame (and scale) by a similarity that maps the
  triangulated head/torso keypoints of the first frames onto the rest body's.

Every source gives a hypothesis (a camera per view it can place); the configured arc
(``camera_prior``) is one more. The observations are split in two halves (a checkerboard over
frames and keypoints): hypotheses are estimated on one and scored on the other, held out
(:func:`heldout_errors`: held-out keypoints triangulated from the hypothesis' cameras must
reproject onto their detections). The best whole rig wins, then single views may switch to
another hypothesis' camera where that lowers their held-out error clearly. A view no
hypothesis places consistently is reported ``unplaced`` (a warning; the fit then ignores its
keypoints and keeps its camera fixed), never NaN.

Shapes: ``V`` views, ``T`` frames, 133 keypoints; observations ``obs (V,T,133,3)`` (x, y px and
a confidence, 0 = unseen); cameras world-to-camera ``R (V,3,3)``, ``t (V,3)``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from signsplat.fit.cameras import (pnp, pnp_ransac, projection_matrices, rig_prior,
                                   triangulate)
from signsplat.geometry.align import umeyama

log = logging.getLogger(__name__)

#: Candidate sources in the order they are preferred on a tie (names of the hypotheses).
SOURCES = ("sfm", "pnp_ransac", "pnp", "prior")

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
        xc = X @ R[v].T + t[v]
        front = xc[:, 2] > 1e-6
        uvp = (xc[:, :2] / np.where(front, xc[:, 2], 1.0)[:, None]) * K[v, [0, 1], [0, 1]] \
            + K[v, :2, 2]
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


def bundle_adjust(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray, uv: np.ndarray,
                  w: np.ndarray, views: list[int], fixed: int, loss_px: float,
                  max_nfev: int = 60) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Refine the cameras ``views`` (all but ``fixed``) and the points ``X (N,3)`` on the
    observations ``uv (V,N,2)``, ``w (V,N)`` (> 0 = used) with a robust (soft-L1, scale
    ``loss_px``) reprojection error (scipy least squares, sparse Jacobian). The scale gauge is
    held by the distance of the first free camera's centre from the fixed one. Returns
    (R, t, X) with the refined entries replaced."""
    from scipy.optimize import least_squares
    from scipy.sparse import lil_matrix

    free = [v for v in views if v != fixed]
    vi, pi = np.nonzero(w[views] > 0)
    vi = np.asarray(views)[vi]
    npts = len(X)
    if not free or 2 * len(vi) < 6 * len(free) + 3 * npts:
        return R, t, X
    col = {v: i for i, v in enumerate(free)}
    nc = 6 * len(free)
    R0 = R.copy()
    obs = uv[vi, pi]
    sw = np.sqrt(w[vi, pi])
    C = -np.einsum("vji,vj->vi", R, t)
    ref_dist = float(np.linalg.norm(C[free[0]] - C[fixed])) if free else 1.0

    def unpack(x):
        Rs, ts = R.copy(), t.copy()
        for v in free:
            k = 6 * col[v]
            Rs[v] = _rodrigues(x[k:k + 3]) @ R0[v]
            ts[v] = t[v] + x[k + 3:k + 6]
        return Rs, ts, x[nc:].reshape(npts, 3)

    def fun(x):
        Rs, ts, P = unpack(x)
        xc = np.einsum("nij,nj->ni", Rs[vi], P[pi]) + ts[vi]
        z = np.maximum(xc[:, 2], 1e-3)
        u = K[vi, 0, 0] * xc[:, 0] / z + K[vi, 0, 2]
        v = K[vi, 1, 1] * xc[:, 1] / z + K[vi, 1, 2]
        res = (np.stack([u, v], 1) - obs) * sw[:, None]
        Cs = -Rs[free[0]].T @ ts[free[0]] + Rs[fixed].T @ ts[fixed]
        gauge = 10.0 * loss_px * (np.linalg.norm(Cs) - ref_dist) / max(ref_dist, 1e-9)
        return np.concatenate([res.reshape(-1), [gauge]])

    A = lil_matrix((2 * len(vi) + 1, nc + 3 * npts), dtype=np.int8)
    rows = np.arange(len(vi))
    for r in (0, 1):
        for k in range(3):
            A[2 * rows + r, nc + 3 * pi + k] = 1
        for v in free:
            sel = rows[vi == v]
            for k in range(6):
                A[2 * sel + r, 6 * col[v] + k] = 1
    for k in range(6):
        A[2 * len(vi), 6 * col[free[0]] + k] = 1
    x0 = np.concatenate([np.zeros(nc), X.reshape(-1)])
    sol = least_squares(fun, x0, jac_sparsity=A, loss="soft_l1", f_scale=loss_px,
                        x_scale="jac", method="trf", tr_solver="lsmr", max_nfev=max_nfev)
    Rs, ts, P = unpack(sol.x)
    return Rs, ts, P


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

    def retriangulate(weights):
        P = projection_matrices(K[reg], R[reg], t[reg])
        X, ok = robust_triangulate(P, uv[reg], weights[reg], threshold_px)
        # reject tracks the registered views do not agree on
        e = reprojection_errors(K[reg], R[reg], t[reg], uv[reg], weights[reg] * ok[None],
                                leave_one_out=False)
        bad = np.nanmax(np.where(np.isfinite(e), e, 0.0), axis=0) > 3 * threshold_px
        return X, ok & ~bad

    X, ok = retriangulate(wa)
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
        wb = w * ok[None]
        for _ in range(2):  # the second pass without the observations the first left far off
            R, t, Xb = bundle_adjust(K, R, t, X[ok], uv[:, ok], wb[:, ok], views, seed.a,
                                     threshold_px)
            X = X.copy()
            X[ok] = Xb
            e = reprojection_errors(K, R, t, uv, wb * ok[None], leave_one_out=False)
            wb = np.where(np.isfinite(e) & (e > 3 * threshold_px), 0.0, wb)
        X, ok = retriangulate(w)
    return Reconstruction(R, t, reg, X, ok, (seed.a, seed.b))


def align_to_body(rec: Reconstruction, kp_neutral: np.ndarray, T: int, K_num: int,
                  body_keypoints, frames: int) -> tuple[np.ndarray, np.ndarray] | None:
    """The reconstruction's cameras in the rest body's frame and scale: the similarity that
    maps the median of its triangulated ``body_keypoints`` over the first ``frames`` frames
    that have them onto ``kp_neutral (133,3)`` (Umeyama). None with fewer than 4 points."""
    idx = np.asarray(body_keypoints)
    X = rec.X.reshape(T, K_num, 3)[:, idx]
    ok = rec.ok.reshape(T, K_num)[:, idx]
    rows = np.nonzero(ok.sum(1) >= 4)[0][:frames]
    if not len(rows):
        return None
    with np.errstate(all="ignore"):
        med = np.nanmedian(np.where(ok[rows][..., None], X[rows], np.nan), axis=0)
    good = np.isfinite(med).all(1)
    if good.sum() < 4:
        return None
    sim = umeyama(med[good], kp_neutral[idx][good], with_scale=True)
    if not np.isfinite(sim.s) or sim.s <= 0:
        return None
    Rn = np.einsum("vij,kj->vik", rec.R, sim.R)  # R R_s^T
    tn = sim.s * rec.t - np.einsum("vij,j->vi", Rn, sim.t)
    return Rn, tn


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
INIT_SOURCES = {"auto": SOURCES, "sfm": ("sfm", "prior"), "pnp": ("pnp", "prior"),
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
    thr = ic["threshold"] * float(np.median(H))
    chest = kp_neutral[[5, 6]].mean(0)
    prior = rig_prior(K, width, height, V, cfg["camera_prior"]["arc_degrees"],
                      cfg["camera_prior"]["distance"], chest)
    cands: list[dict[str, tuple[np.ndarray, np.ndarray]]] = [{} for _ in range(V)]
    for v in live:
        cands[v]["prior"] = (prior.R[v], prior.t[v])
        if "pnp" in order or "pnp_ransac" in order:
            pn = body_pnp(kp_neutral, est_all[v], K[v], H[v], cfg)
            cands[v].update({k: x for k, x in pn.items() if k in order})
    if "sfm" in order and len(live) >= 2:
        uv_e, w_e = tracks(est)
        rec = reconstruct_rig(uv_e, w_e, K, thr, min_points=ic["min_points"])
        aligned = align_to_body(rec, kp_neutral, T, o.shape[2], PNP_KEYPOINTS,
                                cfg["init_frames"]) if rec.registered.sum() >= 2 else None
        if aligned is not None:
            for v in np.nonzero(rec.registered)[0]:
                cands[v]["sfm"] = (aligned[0][v], aligned[1][v])
        log.info("camera init (sfm): %d of %d views registered", int(rec.registered.sum()),
                 len(live))
    scores: dict[str, float] = {}
    best = None
    for name in order:
        rig = _assemble(cands, name, order, prior)
        if rig is None:
            continue
        px = heldout_errors(K, rig[0], rig[1], uv_t, w_t, limit, robust_px=thr)
        scores[name] = rig_score(px, live, limit)
        log.info("camera init: hypothesis %r (%s) -> held-out %.2f px (per view %s)", name,
                 ",".join(rig[2]), scores[name], np.round(px, 2).tolist())
        if best is None or scores[name] < scores[best[0]]:
            best = (name, rig, px)
    if best is None:  # no view with detections
        return RigHypotheses(prior.R.copy(), prior.t.copy(), ["no_detections"] * V, "none",
                             scores, np.full(V, np.nan))
    winner, (R, t, status), px = best
    R, t, status = R.copy(), t.copy(), list(status)
    for _ in range(2 if mode == "auto" else 0):  # single views may switch to another source
        changed = False
        for v in live:
            for name, (Rc, tc) in cands[v].items():
                if name == status[v]:
                    continue
                R2, t2 = R.copy(), t.copy()
                R2[v], t2[v] = Rc, tc
                px2 = heldout_errors(K, R2, t2, uv_t, w_t, limit, robust_px=thr)
                if np.isfinite(px2[v]) and (not np.isfinite(px[v]) or
                                            px2[v] < ic["switch_margin"] * px[v]):
                    R, t, px = R2, t2, px2
                    status[v] = name
                    changed = True
        if not changed:
            break
    for v in live:
        if not np.isfinite(px[v]) or px[v] > limit[v]:
            log.warning("camera init: view %d cannot be placed (held-out error %.1f px, limit "
                        "%.1f px; sources tried %s): its keypoints are left out of the fit "
                        "and its camera (from %s) is held fixed", v, px[v], limit[v],
                        sorted(cands[v]), status[v])
            status[v] = "unplaced"
    log.info("camera init: winner %r, views %s", winner, status)
    return RigHypotheses(R, t, status, winner, scores, px)
