"""A small ray-cast renderer of textured quads: multi-view test rigs independent of the simulator.

The scene is a box room (textured walls, floor and a textured block in the middle); cameras sit
on an arc around it and look at its centre. Images follow the project's OpenCV conventions
(``x_cam = R @ x_world + t``, pixel centres at integer coordinates).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import skimage.data

from signsplat.io.tables import write_table


@dataclass(frozen=True)
class Quad:
    """A textured parallelogram ``origin + a * u + b * v`` for ``a, b`` in [0, 1] (metres)."""

    origin: np.ndarray  # (3,)
    u: np.ndarray  # (3,) edge along the texture's columns
    v: np.ndarray  # (3,) edge along the texture's rows
    texture: np.ndarray  # (H, W, 3) uint8


def _rgb(img: np.ndarray) -> np.ndarray:
    return img if img.ndim == 3 else np.repeat(img[..., None], 3, axis=2)


def textured_room(textureless: bool = False) -> list[Quad]:
    """Quads of a 4 m x 3 m x 2.5 m room with a 0.8 m block; flat grey when ``textureless``."""
    tex = [
        _rgb(skimage.data.astronaut()), _rgb(skimage.data.brick()), _rgb(skimage.data.gravel()),
        _rgb(skimage.data.coffee()), _rgb(skimage.data.chelsea()), _rgb(skimage.data.rocket()),
        _rgb(skimage.data.grass()),
    ]
    if textureless:
        tex = [np.full((8, 8, 3), 128, np.uint8) for _ in tex]
    a = np.array
    return [
        Quad(a([-2.0, 2.5, -1.5]), a([4.0, 0, 0]), a([0, -2.5, 0]), tex[0]),  # back wall
        Quad(a([-2.0, 2.5, 1.5]), a([0, 0, -3.0]), a([0, -2.5, 0]), tex[1]),  # left wall
        Quad(a([2.0, 2.5, -1.5]), a([0, 0, 3.0]), a([0, -2.5, 0]), tex[5]),  # right wall
        Quad(a([-2.0, 0.0, -1.5]), a([4.0, 0, 0]), a([0, 0, 3.0]), tex[2]),  # floor
        Quad(a([-0.4, 0.8, 0.4]), a([0.8, 0, 0]), a([0, -0.8, 0]), tex[3]),  # block front
        Quad(a([0.4, 0.8, 0.4]), a([0, 0, -0.8]), a([0, -0.8, 0]), tex[4]),  # block right side
        Quad(a([-0.4, 0.8, -0.4]), a([0, 0, 0.8]), a([0, -0.8, 0]), tex[6]),  # block left side
        Quad(a([-0.4, 0.8, -0.4]), a([0.8, 0, 0]), a([0, 0, 0.8]), tex[1]),  # block top
    ]


def look_at(centre: np.ndarray, target: np.ndarray,
            up=(0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera ``(R (3,3), t (3,))`` of an OpenCV camera at ``centre`` facing ``target``."""
    z = target - centre
    z = z / np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, float))  # image x to the right, y down
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def arc_cameras(count: int, arc_degrees: float, distance: float = 3.2, height: float = 1.3,
                target=(0.0, 0.9, 0.0), jitter: float = 0.0, seed: int = 0):
    """``count`` look-at cameras evenly on an arc in front of +z; returns lists of R, t."""
    rng = np.random.default_rng(seed)
    angles = np.radians(np.linspace(-arc_degrees / 2, arc_degrees / 2, count))
    Rs, ts = [], []
    for ang in angles:
        c = np.array([distance * np.sin(ang), height, distance * np.cos(ang)])
        c = c + rng.normal(0.0, jitter, 3)
        R, t = look_at(c, np.asarray(target, float))
        Rs.append(R)
        ts.append(t)
    return Rs, ts


def intrinsics(width: int, height: int, fov_degrees: float) -> np.ndarray:
    """(3,3) K with vertical field of view ``fov_degrees``, centre ``((w-1)/2, (h-1)/2)``."""
    f = 0.5 * height / np.tan(np.radians(fov_degrees) / 2)
    return np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])


def _bilinear(tex: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample (H, W, 3) ``tex`` at float pixel positions ``x, y`` (N,) -> (N, 3) float."""
    h, w = tex.shape[:2]
    x0 = np.clip(np.floor(x).astype(int), 0, w - 2) if w > 1 else np.zeros(len(x), int)
    y0 = np.clip(np.floor(y).astype(int), 0, h - 2) if h > 1 else np.zeros(len(y), int)
    fx = np.clip(x - x0, 0, 1)[:, None]
    fy = np.clip(y - y0, 0, 1)[:, None]
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    t = tex.astype(np.float64)
    top = t[y0, x0] * (1 - fx) + t[y0, x1] * fx
    bot = t[y1, x0] * (1 - fx) + t[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def render(quads: list[Quad], K: np.ndarray, R: np.ndarray, t: np.ndarray, width: int,
           height: int, supersample: int = 2) -> np.ndarray:
    """Ray-cast the quads into a (height, width, 3) uint8 RGB image (box-filtered supersampling)."""
    s = supersample
    us, vs = np.meshgrid((np.arange(width * s) + 0.5) / s - 0.5,
                         (np.arange(height * s) + 0.5) / s - 0.5)
    pix = np.stack([us, vs, np.ones_like(us)], -1).reshape(-1, 3)
    d = pix @ np.linalg.inv(K).T @ R  # rows: R^T K^-1 p
    c = -R.T @ t
    best = np.full(len(d), np.inf)
    out = np.zeros((len(d), 3))
    for q in quads:
        n = np.cross(q.u, q.v)
        denom = d @ n
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = ((q.origin - c) @ n) / denom
        p = c + depth[:, None] * d - q.origin
        a = p @ q.u / (q.u @ q.u)
        b = p @ q.v / (q.v @ q.v)
        hit = (depth > 1e-6) & (depth < best) & (a >= 0) & (a <= 1) & (b >= 0) & (b <= 1)
        if not hit.any():
            continue
        th, tw = q.texture.shape[:2]
        out[hit] = _bilinear(q.texture, a[hit] * (tw - 1), b[hit] * (th - 1))
        best[hit] = depth[hit]
    img = out.reshape(height * s, width * s, 3).astype(np.float32)
    img = cv2.resize(img, (width, height), interpolation=cv2.INTER_AREA)
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


def write_rig(out_dir: Path, scene: str, Rs, ts, K: np.ndarray, width: int, height: int,
              quads: list[Quad], frames: int = 1) -> tuple[Path, Path]:
    """Write a simulator-shaped folder: ``frames.parquet``, ``cameras.parquet``, ``images/``.

    The rig is static, so every frame of a view shows the same image; returns the two table paths.
    """
    out_dir = Path(out_dir)
    frame_rows, cam_rows = [], []
    for view, (R, t) in enumerate(zip(Rs, ts)):
        img = render(quads, K, R, t, width, height)
        for frame in range(frames):
            rel = f"images/{view:02d}/{frame:04d}.png"
            (out_dir / rel).parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(out_dir / rel), img[..., ::-1])
            frame_rows.append(dict(scene=scene, view=view, frame=frame, time=frame / 25.0,
                                   image=rel, mask=""))
        cam_rows.append(dict(scene=scene, view=view, frame=-1, width=width, height=height,
                             fx=K[0, 0], fy=K[1, 1], cx=K[0, 2], cy=K[1, 2],
                             R=np.asarray(R, float).ravel().tolist(),
                             t=np.asarray(t, float).ravel().tolist()))
    fdf = pd.DataFrame(frame_rows).astype({"view": "int32", "frame": "int32"})
    cdf = pd.DataFrame(cam_rows).astype({"view": "int32", "frame": "int32", "width": "int32",
                                          "height": "int32"})
    return (write_table(fdf, out_dir / "frames.parquet", "frames"),
            write_table(cdf, out_dir / "cameras.parquet", "cameras"))
