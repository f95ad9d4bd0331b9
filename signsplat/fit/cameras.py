"""Cameras for fitting: parametrisation, projection, and initialisation without ground truth.

Convention (OpenCV, as everywhere in SignSplat): ``x_cam = R @ x_world + t``, pixel
``u = fx * x / z + cx``, ``v = fy * y / z + cy``. A rig of ``V`` static cameras is stored as
``K (V,3,3)``, ``R (V,3,3)``, ``t (V,3)`` (numpy float64 or torch); during a solve the rotation is
``R = exp(rotvec) @ R0`` with a learnable axis-angle ``rotvec (V,3)`` around the initial ``R0``
(no singularity near the start), and optionally a learnable log focal scale per camera.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import roma
import torch


@dataclass
class Rig:
    """Static cameras of a sequence (numpy float64). width/height in pixels, (V,)."""

    K: np.ndarray  # (V,3,3)
    R: np.ndarray  # (V,3,3) world->camera
    t: np.ndarray  # (V,3) metres
    width: np.ndarray  # (V,) int
    height: np.ndarray  # (V,) int

    @property
    def num_views(self) -> int:
        return int(self.K.shape[0])

    def centres(self) -> np.ndarray:
        """Camera centres in the world, (V,3): ``C = -R^T t``."""
        return -np.einsum("vji,vj->vi", self.R, self.t)

    def select(self, views) -> "Rig":
        """The rig of the cameras ``views`` (indices or a slice), in that order."""
        return Rig(K=self.K[views], R=self.R[views], t=self.t[views], width=self.width[views],
                   height=self.height[views])


def look_at(centre: np.ndarray, target: np.ndarray, up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """World->camera ``(R, t)`` of an OpenCV camera at ``centre`` looking at ``target``.

    Image y points down, so the camera's y axis is the negated world ``up`` projected.
    """
    centre = np.asarray(centre, float)
    z = np.asarray(target, float) - centre
    z /= np.linalg.norm(z)
    up = np.asarray(up, float)
    x = np.cross(z, up)  # image right; y = z x x then points down
    if np.linalg.norm(x) < 1e-8:  # looking straight up or down
        x = np.cross(z, np.array([0.0, 0.0, 1.0]))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def intrinsics_from_fov(width: int, height: int, fov_degrees: float) -> np.ndarray:
    """Approximate ``K (3,3)``: vertical field of view, square pixels, centred principal point.

    Pixel centres are integers, so the image centre is ``((w-1)/2, (h-1)/2)``.
    """
    f = 0.5 * height / np.tan(np.radians(fov_degrees) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


def project(points: torch.Tensor, K: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
            min_depth: float = 1e-3) -> tuple[torch.Tensor, torch.Tensor]:
    """Project world points into every camera.

    points (B,N,3) metres; K (V,3,3); R (V,3,3); t (V,3).
    Returns ``uv (V,B,N,2)`` pixels and ``depth (V,B,N)`` metres. Depth is clamped to
    ``min_depth`` in the division so points behind a camera stay finite (callers mask them).
    """
    V, B, N = R.shape[0], points.shape[0], points.shape[1]
    # one matrix product (V*3,3) @ (3,B*N), laid out (V,3,B,N) so that x, y and z are whole
    # blocks; unbind, not three slices: its backward stacks the gradients instead of filling a
    # zero tensor of the whole (V,3,B,N) per slice
    xc = torch.addmm(t.reshape(V * 3, 1), R.reshape(V * 3, 3), points.reshape(B * N, 3).T)
    x, y, z = xc.reshape(V, 3, B, N).unbind(1)
    zc = z.clamp_min(min_depth)
    x = x / zc
    y = y / zc
    u = K[:, 0, 0, None, None] * x + K[:, 0, 1, None, None] * y + K[:, 0, 2, None, None]
    v = K[:, 1, 1, None, None] * y + K[:, 1, 2, None, None]
    return torch.stack([u, v], dim=-1), z


class CameraParams(torch.nn.Module):
    """Learnable extrinsics (and optional focal scale) of a rig around an initial guess.

    ``fixed`` views keep their initial extrinsics (the gauge: the reference camera fixes the
    world frame). Call the module to get ``(K, R, t)`` tensors (V,3,3), (V,3,3), (V,3).
    """

    def __init__(self, rig: Rig, fixed: list[int] | tuple[int, ...] = (), refine_focal: bool = False,
                 dtype=torch.float32, device: torch.device | str = "cpu"):
        super().__init__()
        V = rig.num_views
        kw = dict(dtype=dtype, device=device)
        self.register_buffer("K0", torch.as_tensor(rig.K, **kw))
        self.register_buffer("R0", torch.as_tensor(rig.R, **kw))
        self.register_buffer("t0", torch.as_tensor(rig.t, **kw))
        mask = torch.ones(V, 1, **kw)
        for v in fixed:
            mask[v] = 0.0
        self.register_buffer("free", mask)
        self.rotvec = torch.nn.Parameter(torch.zeros(V, 3, **kw))
        self.dt = torch.nn.Parameter(torch.zeros(V, 3, **kw))
        self.log_focal = torch.nn.Parameter(torch.zeros(V, 1, **kw), requires_grad=refine_focal)
        self.width = rig.width
        self.height = rig.height

    def forward(self) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        dR = roma.rotvec_to_rotmat(self.rotvec * self.free)
        R = dR @ self.R0
        t = self.t0 + self.dt * self.free
        scale = torch.exp(self.log_focal)[:, :, None]  # (V,1,1)
        K = self.K0.clone()
        K[:, :2, :2] = self.K0[:, :2, :2] * scale
        return K, R, t

    def to_rig(self) -> Rig:
        with torch.no_grad():
            K, R, t = self()
        return Rig(K=K.double().cpu().numpy(), R=R.double().cpu().numpy(),
                   t=t.double().cpu().numpy(), width=np.asarray(self.width),
                   height=np.asarray(self.height))


def pnp(object_points: np.ndarray, image_points: np.ndarray, K: np.ndarray
        ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Pose of one camera from 3D-2D correspondences (OpenCV SQPnP, then LM refinement).

    object_points (N,3) metres, image_points (N,2) pixels, K (3,3). Needs N >= 4 points that
    are not all collinear. Returns ``(R (3,3), t (3,), rms reprojection px)`` or None when the
    solve fails or puts points behind the camera.
    """
    pts = _pnp_points(object_points, image_points, 4)
    if pts is None:
        return None
    obj, img = pts
    try:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, None, flags=cv2.SOLVEPNP_SQPNP)
        if not ok:
            return None
        rvec, tvec = cv2.solvePnPRefineLM(obj, img, K, None, rvec, tvec)
    except cv2.error:
        return None
    return _accepted_pose(rvec, tvec, obj, img, K)


def _pnp_points(object_points: np.ndarray, image_points: np.ndarray, minimum: int
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """OpenCV's (N,1,3) and (N,1,2) float64 arrays, or None for fewer than ``minimum``
    points or a non-finite value."""
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    img = np.ascontiguousarray(image_points, dtype=np.float64).reshape(-1, 1, 2)
    if len(obj) < minimum or not (np.isfinite(obj).all() and np.isfinite(img).all()):
        return None
    return obj, img


def _accepted_pose(rvec: np.ndarray, tvec: np.ndarray, obj: np.ndarray, img: np.ndarray,
                   K: np.ndarray, keep: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, float] | None:
    """``(R, t, rms px over the points keep)`` of a solved pose (every point when ``keep`` is
    None), or None when it is not finite or puts over 10 % of the points behind the camera."""
    R, _ = cv2.Rodrigues(rvec)
    t = tvec.reshape(3)
    depth = (obj.reshape(-1, 3) @ R.T + t)[:, 2]
    if not np.isfinite(R).all() or (depth <= 0).mean() > 0.1:
        return None
    if keep is not None:
        obj, img = obj[keep], img[keep]
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2, -1))))
    return R, t, rms


def rig_prior(K: np.ndarray, width, height, count: int, arc_degrees: float, distance: float,
              target: np.ndarray) -> Rig:
    """A coarse rig guess: ``count`` cameras evenly on a horizontal arc facing the body.

    Cameras sit at ``distance`` from ``target`` (the body's chest, in the body-anchored world
    frame: the signer faces +z), at the target's height. Used for views PnP cannot solve.
    """
    angles = np.radians(np.linspace(-arc_degrees / 2, arc_degrees / 2, count)) if count > 1 \
        else np.zeros(1)
    Rs, ts = [], []
    for a in angles:
        c = np.asarray(target, float) + distance * np.array([np.sin(a), 0.0, np.cos(a)])
        R, t = look_at(c, target)
        Rs.append(R)
        ts.append(t)
    return Rig(K=np.asarray(K, float), R=np.stack(Rs), t=np.stack(ts),
               width=np.asarray(width), height=np.asarray(height))


def rig_up_direction(R: np.ndarray, min_spread: float = 0.1) -> np.ndarray | None:
    """World vertical of a rig of level cameras (no roll), in the rig's world frame.

    A level camera's image x axis (row 0 of ``R``) is horizontal, so the vertical is the
    direction most orthogonal to every camera's x axis (smallest right singular vector); its
    sign makes it point against the cameras' image-down axes. R (V,3,3). Returns a unit (3,)
    vector, or None when the x axes do not span a plane (fewer than 2 distinct directions,
    e.g. one camera or parallel cameras).
    """
    X = np.asarray(R, float)[:, 0, :]
    if len(X) < 2:
        return None
    _, sv, vt = np.linalg.svd(X)
    if sv[1] < min_spread * max(sv[0], 1e-12):
        return None
    up = vt[-1]
    if up @ (-np.asarray(R, float)[:, 1, :].sum(0)) < 0:
        up = -up
    return up / np.linalg.norm(up)


def pnp_ransac(object_points: np.ndarray, image_points: np.ndarray, K: np.ndarray,
               threshold_px: float, iterations: int = 200, seed: int = 0
               ) -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """Pose of one camera robust to outlying correspondences (RANSAC, then LM on inliers).

    object_points (N,3) metres, image_points (N,2) pixels, K (3,3); ``threshold_px``: the
    inlier reprojection distance. Returns ``(R, t, rms px of the inliers, inlier fraction)`` or
    None when fewer than 6 points, no consensus, or points behind the camera.
    """
    pts = _pnp_points(object_points, image_points, 6)
    if pts is None:
        return None
    obj, img = pts
    cv2.setRNGSeed(seed)
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            obj, img, K, None, iterationsCount=iterations, reprojectionError=threshold_px,
            confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
        if not ok or inl is None or len(inl) < 6:
            return None
        inl = inl.reshape(-1)
        rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, None, rvec, tvec)
    except cv2.error:
        return None
    pose = _accepted_pose(rvec, tvec, obj, img, K, inl)
    return None if pose is None else (*pose, len(inl) / len(obj))


def take(uv: torch.Tensor, view: torch.Tensor, batch: torch.Tensor, point: torch.Tensor
         ) -> torch.Tensor:
    """``uv[view, batch, point]`` (M,C) of projections ``uv (V,B,N,C)`` through one flat
    ``index_select``: its backward adds into the gradient directly, where the backward of
    advanced indexing sorts the indices first (slow at the fit's million points)."""
    V, B, N = uv.shape[:3]
    return uv.reshape(V * B * N, -1).index_select(0, (view * B + batch) * N + point)


def projection_matrices(K: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(V,3,4) ``K [R|t]`` of cameras K, R (V,3,3), t (V,3)."""
    return np.einsum("vij,vjk->vik", K, np.concatenate([R, t[:, :, None]], axis=2))


def triangulate(P: np.ndarray, uv: np.ndarray, w: np.ndarray, min_views: int = 2
                ) -> tuple[np.ndarray, np.ndarray]:
    """Linear (DLT) triangulation of many points.

    P (V,3,4) projection matrices ``K [R|t]``; uv (V,N,2) pixels; w (V,N) weights (0 = not
    seen). Returns (X (N,3) world points, ok (N,) bool: seen in >= ``min_views`` views and in
    front of the cameras that saw it). Rows of a point are normalised so each view counts
    by its weight only.
    """
    V, N = w.shape
    A = np.concatenate([uv[..., 0:1] * P[:, None, 2] - P[:, None, 0],
                        uv[..., 1:2] * P[:, None, 2] - P[:, None, 1]], axis=0)  # (2V,N,4)
    A = A / np.maximum(np.linalg.norm(A, axis=-1, keepdims=True), 1e-12)
    A = A * np.concatenate([w, w], 0)[..., None]
    _, _, vt = np.linalg.svd(np.transpose(A, (1, 0, 2)))  # (N,4,4)
    Xh = vt[:, -1]
    ok = ((w > 0).sum(0) >= min_views) & (np.abs(Xh[:, 3]) > 1e-12)
    X = Xh[:, :3] / np.where(ok, Xh[:, 3], 1.0)[:, None]
    z = np.einsum("vij,nj->vni", P[:, :, :3], X) + P[:, None, :, 3]
    front = ((z[..., 2] > 0) | (w <= 0)).all(0)
    return np.where((ok & front)[:, None], X, 0.0), ok & front
