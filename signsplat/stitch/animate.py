"""Render a stitched SMPL-X track with a trained avatar, streamed into an MP4 (issue 7).

The track's frames (:class:`signsplat.motion.stitching.Frame`) are posed in small batches by the
body model and the avatar (:class:`signsplat.avatar.model.AvatarModel`), rasterized one by one
from one camera (``signsplat.render.rasterization``) and written straight into a
:class:`signsplat.io.video.VideoWriter`: memory holds one batch of frames, never the video.

The avatar's identity is kept: its own ``betas`` replace the track's (the Gaussians are
anchored on the mesh of that shape), and by default the body is placed where the avatar was
trained (chordal mean of its training ``global_orient``, mean ``transl``) so that the scene's
cameras frame it; ``placement="track"`` keeps the track's own placement.

Cameras (:class:`Camera`) use the tables' OpenCV convention (pixel centres at integer
coordinates); the half-pixel shift the rasterizer needs is applied when rendering.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np
import torch

from signsplat.errors import InputError
from signsplat.motion.stitching import FRAME_BLOCKS, Frame, mean_rotation

#: Blocks passed to the body model (``label``/``gloss_index`` are not parameters).
BODY_BLOCKS = tuple(FRAME_BLOCKS)


@dataclass(frozen=True)
class Camera:
    """A pinhole camera. viewmat (4, 4) world-to-camera (OpenCV: x right, y down, z forward),
    K (3, 3) intrinsics in pixels with pixel centres at integer coordinates, image size."""

    viewmat: np.ndarray
    K: np.ndarray
    width: int
    height: int
    name: str = ""

    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for an image of ``width`` x ``height`` pixels (K scaled)."""
        sx, sy = width / self.width, height / self.height
        K = np.array(self.K, np.float64)
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 1] *= sx
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return replace(self, K=K, width=int(width), height=int(height))

    def raster_K(self) -> torch.Tensor:
        """(3, 3) float32 intrinsics for the rasterizer (pixel centres at i + 0.5)."""
        K = np.array(self.K, np.float32)
        K[0, 2] += 0.5
        K[1, 2] += 0.5
        return torch.from_numpy(K)

    @property
    def centre(self) -> np.ndarray:
        """(3,) camera position in the world."""
        R, t = self.viewmat[:3, :3], self.viewmat[:3, 3]
        return -R.T @ t

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World points (..., 3) -> pixels (..., 2) (OpenCV convention) and depths (...,) m."""
        p = np.asarray(points, np.float64)
        cam = p @ self.viewmat[:3, :3].T + self.viewmat[:3, 3]
        z = cam[..., 2]
        zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
        uv = (cam[..., :2] / zs[..., None]) @ self.K[:2, :2].T + self.K[:2, 2]
        return uv, z


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 1.0, 0.0)) -> np.ndarray:
    """(4, 4) OpenCV world-to-camera matrix of a camera at ``eye`` looking at ``target``
    (world ``up`` appears upwards in the image)."""
    eye, target = np.asarray(eye, np.float64), np.asarray(target, np.float64)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, np.float64))  # x = y cross z with y = -up
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("camera looks along the up direction")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, :3] = np.stack([x, y, z])
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def load_cameras(path: str | os.PathLike) -> list[Camera]:
    """The static cameras of a ``cameras`` table, sorted by view."""
    from signsplat.io.tables import read_table

    df = read_table(path, "cameras")
    static = df[df["frame"] == -1] if (df["frame"] == -1).any() else df
    cams = []
    for view in sorted(static["view"].unique()):
        row = static[static["view"] == view].iloc[0]
        m = np.eye(4)
        m[:3, :3] = np.asarray(row["R"], np.float64).reshape(3, 3)
        m[:3, 3] = np.asarray(row["t"], np.float64)
        K = np.array([[row["fx"], 0, row["cx"]], [0, row["fy"], row["cy"]], [0, 0, 1]],
                     np.float64)
        cams.append(Camera(m, K, int(row["width"]), int(row["height"]), f"view{int(view)}"))
    if not cams:
        raise InputError(f"{path}: no cameras")
    return cams


def axes_target(cameras: Sequence[Camera]) -> np.ndarray:
    """(3,) least-squares point closest to every camera's optical axis (what a rig looks at);
    for a single camera, the point 2 m along its axis."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cameras:
        d = c.viewmat[2, :3] / np.linalg.norm(c.viewmat[2, :3])
        P = np.eye(3) - np.outer(d, d)
        A += P
        b += P @ c.centre
    if len(cameras) < 2 or np.linalg.cond(A) > 1e8:
        c = cameras[0]
        return c.centre + 2.0 * c.viewmat[2, :3]
    return np.linalg.solve(A, b)


def front_camera(cameras: Sequence[Camera]) -> Camera:
    """A virtual camera straight in front of the signer (world +z, the signer faces +z) at the
    rig's mean distance and height, looking at the point the rig looks at, with the
    intrinsics of the first camera."""
    target = axes_target(cameras)
    offs = np.stack([c.centre - target for c in cameras])
    dist = float(np.linalg.norm(offs[:, [0, 2]], axis=1).mean())
    height = float(offs[:, 1].mean())
    eye = target + np.array([0.0, height, dist])
    c0 = cameras[0]
    return Camera(look_at(eye, target), np.array(c0.K, np.float64), c0.width, c0.height, "front")


def framing_camera(points: np.ndarray, size: int, fov_degrees: float = 30.0,
                   margin: float = 1.15) -> Camera:
    """A front camera (from +z) whose square image of ``size`` pixels frames ``points``
    (N, 3) (e.g. the upper-body joints of the rest pose) with a ``margin``."""
    p = np.asarray(points, np.float64)
    lo, hi = p.min(0), p.max(0)
    target = (lo + hi) / 2
    half = max(hi[0] - lo[0], hi[1] - lo[1]) / 2 * margin
    f = size / 2 / math.tan(math.radians(fov_degrees) / 2)
    dist = half / math.tan(math.radians(fov_degrees) / 2) + (hi[2] - target[2])
    eye = target + np.array([0.0, 0.0, dist])
    K = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1]])
    return Camera(look_at(eye, target), K, size, size, "framing")


def choose_camera(choice: str | int, size: int | None, cameras_path: str | os.PathLike | None,
                  rest_points: np.ndarray | None = None) -> Camera:
    """The camera to render from.

    ``choice``: a view index of the cameras table, or ``"front"`` (virtual camera in front of
    the rig, see :func:`front_camera`; without a table, :func:`framing_camera` on
    ``rest_points``). ``size``: square output side in pixels (None = the camera's own size).
    """
    if cameras_path is None:
        if str(choice) != "front":
            raise InputError(f"camera {choice!r} needs a cameras table (--cameras)")
        if rest_points is None:
            raise InputError("camera 'front' without a cameras table needs body points")
        return framing_camera(rest_points, size or 256)
    cams = load_cameras(cameras_path)
    if str(choice) == "front":
        cam = front_camera(cams)
    else:
        try:
            view = int(choice)
        except ValueError:
            raise InputError(f"camera must be 'front' or a view index, got {choice!r}") from None
        if not 0 <= view < len(cams):
            raise InputError(f"{cameras_path}: no camera {view} (have 0..{len(cams) - 1})")
        cam = cams[view]
    return cam.resized(size, size) if size else cam


# ---------------------------------------------------------------------------- parameters
@dataclass(frozen=True)
class Identity:
    """What the avatar fixes for every frame: ``betas`` (S,) and optionally the placement
    ``global_orient`` (3,) / ``transl`` (3,) (None: keep the track's)."""

    betas: np.ndarray
    global_orient: np.ndarray | None = None
    transl: np.ndarray | None = None


def batch_params(frames: Sequence[Frame], identity: Identity | None = None,
                 device: torch.device | str = "cpu") -> dict[str, torch.Tensor]:
    """Stack frames into body-model inputs: block -> (B, k) float32 tensors, with the
    identity's betas and placement substituted."""
    out = {}
    for b in BODY_BLOCKS:
        arr = np.stack([np.asarray(f.params[b], np.float32) for f in frames])
        if identity is not None:
            fixed = {"betas": identity.betas, "global_orient": identity.global_orient,
                     "transl": identity.transl}.get(b)
            if fixed is not None:
                arr = np.tile(np.asarray(fixed, np.float32), (len(frames), 1))
        out[b] = torch.from_numpy(np.ascontiguousarray(arr)).to(device)
    return out


def batched(items: Iterable, size: int) -> Iterator[list]:
    """Consecutive lists of ``size`` items (the last may be shorter)."""
    chunk = []
    for it in items:
        chunk.append(it)
        if len(chunk) >= size:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


# ---------------------------------------------------------------------------- renderer
class AvatarRenderer:
    """Poses and renders frames of a track with a trained avatar from one camera.

    Args:
        model: the trained :class:`~signsplat.avatar.model.AvatarModel`.
        body: the body model it was trained on (``BodyModel`` interface).
        identity: betas / placement substituted into every frame.
        camera: the :class:`Camera` (or None: call :meth:`set_camera` before rendering).
        sh_degree: SH degree to evaluate; background: (3,) RGB in [0, 1];
        backend: rasterizer backend ('cpu' is the fast Numba kernel; 'auto' picks it on CPU).
        raster: options of :func:`signsplat.render.rasterization` the avatar was trained with
            (``eps2d``, ``rasterize_mode``; none: the rasterizer's own defaults).
    """

    def __init__(self, model, body, identity: Identity, camera: Camera | None, sh_degree: int = 0,
                 background=(1.0, 1.0, 1.0), backend: str = "auto",
                 device: torch.device | str = "cpu", raster: dict | None = None):
        from signsplat.render import rasterization

        self.model = model.eval().requires_grad_(False)
        self.body = body
        self.identity = identity
        self.sh_degree = int(sh_degree)
        self.device = torch.device(device)
        self.background = torch.tensor(background, dtype=torch.float32, device=self.device)
        self.backend = backend
        self.raster = dict(raster or {})
        self._rasterize = rasterization
        self.scene = ""
        self.camera = None
        if camera is not None:
            self.set_camera(camera)

    def set_camera(self, camera: Camera) -> None:
        """Render from ``camera`` from now on."""
        self.camera = camera
        self._viewmat = torch.as_tensor(camera.viewmat, dtype=torch.float32,
                                        device=self.device)[None]
        self._K = camera.raster_K().to(self.device)[None]

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, body, camera: Camera | None,
                        placement: str = "avatar", background=None, backend: str | None = None,
                        device: torch.device | str = "cpu") -> "AvatarRenderer":
        """Load ``checkpoint.pt`` of ``signsplat train-avatar``. ``placement``: 'avatar'
        (training placement) or 'track'."""
        from signsplat.avatar import load_avatar

        if placement not in ("avatar", "track"):
            raise ValueError(f"placement must be 'avatar' or 'track', got {placement!r}")
        if not os.path.exists(path):
            raise InputError(f"{path}: avatar checkpoint not found")
        model, smplx, state, cfg = load_avatar(path, body, device)
        identity = avatar_identity(smplx, placement == "avatar")
        renderer = cls(model, body, identity, camera, cfg.model.sh_degree,
                       cfg.train.background if background is None else background,
                       cfg.train.render_backend if backend is None else backend, device,
                       raster=cfg.model.raster_options())
        renderer.scene = str(state.get("scene", ""))
        return renderer

    def pose(self, frames: Sequence[Frame]):
        """(body output, posed Gaussians) of a batch of frames."""
        params = batch_params(frames, self.identity, self.device)
        out = self.body(**params)
        g = self.model(out.v_shaped, out.vertices, out.transforms, params["transl"],
                       self.sh_degree)
        return out, g

    @torch.no_grad()
    def render(self, frames: Sequence[Frame]):
        """Render a batch: returns ((B, H, W, 3) uint8 images, body output)."""
        out, g = self.pose(frames)
        cam = self.camera
        images = np.empty((len(frames), cam.height, cam.width, 3), np.uint8)
        for b in range(len(frames)):
            colors, _, _ = self._rasterize(
                means=g.means[b], quats=g.quats[b], scales=g.scales[b],
                opacities=g.opacities[b], colors=g.colors[b], viewmats=self._viewmat,
                Ks=self._K, width=cam.width, height=cam.height, sh_degree=g.sh_degree,
                backgrounds=self.background[None], backend=self.backend, **self.raster)
            images[b] = (colors[0].clamp(0, 1) * 255 + 0.5).to(torch.uint8).cpu().numpy()
        return images, out


def upper_body_points(body, identity: Identity) -> np.ndarray:
    """(N, 3) rest-pose joints of the torso, head and shoulders of ``body`` placed like
    ``identity`` (what :func:`framing_camera` frames for a signing video)."""
    from signsplat.body.joints import JOINT_INDEX

    names = ("pelvis", "spine1", "spine2", "spine3", "neck", "head", "left_collar",
             "right_collar", "left_shoulder", "right_shoulder")
    frame = Frame("rest", 0, {b: np.zeros(k, np.float32) for b, k in FRAME_BLOCKS.items()})
    frame.params["betas"] = np.asarray(identity.betas, np.float32)
    with torch.no_grad():
        joints = body(**batch_params([frame], identity)).joints[0].cpu().numpy()
    pts = joints[[JOINT_INDEX[n] for n in names]]
    # hands sign in front of the chest, up to about a forearm beyond the shoulders
    centre = pts.mean(0)
    return np.concatenate([pts, centre + (pts - centre) * 1.5])


def avatar_identity(smplx, use_placement: bool = True) -> Identity:
    """Identity of a loaded avatar's SMPL-X module (``SmplxParams``): its betas and, with
    ``use_placement``, the chordal mean of its training global orientations and mean
    translation."""
    betas = smplx.betas.detach().cpu().numpy().reshape(-1)
    if not use_placement:
        return Identity(betas)
    go = getattr(smplx, "global_orient", None)
    tr = getattr(smplx, "transl", None)
    go = mean_rotation(go.detach().cpu().numpy().astype(np.float64)) if go is not None \
        else np.zeros(3)
    tr = tr.detach().cpu().numpy().mean(0) if tr is not None else np.zeros(3)
    return Identity(betas, np.asarray(go, np.float32), np.asarray(tr, np.float32))


@dataclass
class RenderStats:
    """Counts and wall-clock seconds of one rendered video."""

    frames: int = 0
    render_seconds: float = 0.0  # posing + rasterizing (wall clock)
    total_seconds: float = 0.0  # including encoding (wall clock)
    cpu_seconds: float = 0.0  # process CPU time (all threads) of posing + rasterizing

    @property
    def render_fps(self) -> float:
        return self.frames / self.render_seconds if self.render_seconds > 0 else 0.0

    @property
    def total_fps(self) -> float:
        return self.frames / self.total_seconds if self.total_seconds > 0 else 0.0

    @property
    def cpu_ms_per_frame(self) -> float:
        return 1000 * self.cpu_seconds / self.frames if self.frames else 0.0


def render_track(frames: Iterable[Frame], renderer: AvatarRenderer, writer,
                 batch: int = 4, on_batch: Callable | None = None) -> RenderStats:
    """Render ``frames`` (any iterable, e.g. :func:`~signsplat.motion.stitching.stitch_frames`)
    into ``writer`` (``write((H, W, 3) uint8)``), ``batch`` frames at a time.

    ``on_batch(frames, body_output)`` is called after each batch (e.g. to accumulate bone
    lengths). Memory holds one batch. Returns :class:`RenderStats`.
    """
    stats = RenderStats()
    t_start = time.perf_counter()
    for chunk in batched(frames, max(1, int(batch))):
        t0, c0 = time.perf_counter(), time.process_time()
        images, out = renderer.render(chunk)
        stats.render_seconds += time.perf_counter() - t0
        stats.cpu_seconds += time.process_time() - c0
        for img in images:
            writer.write(img)
        stats.frames += len(chunk)
        if on_batch is not None:
            on_batch(chunk, out)
    stats.total_seconds = time.perf_counter() - t_start
    return stats
