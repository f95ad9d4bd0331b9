"""Standard point-cloud PLY (binary little endian: x, y, z float32; red, green, blue uchar).

This is the layout 3DGS loaders read for a splat initialisation (``fetchPly`` style), and what
trimesh / Open3D / MeshLab open as a point cloud.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from signsplat.io.atomic import atomic_path

_VERTEX = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                    ("red", "u1"), ("green", "u1"), ("blue", "u1")])


def write_points_ply(path: str | os.PathLike, points: np.ndarray,
                     colors: np.ndarray | None = None, comment: str = "") -> Path:
    """Write ``points`` (N,3) metres and ``colors`` (N,3) uint8 RGB (grey if None) atomically.

    Non-finite points are dropped. Returns the path. N = 0 writes a valid empty cloud.
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    cols = (np.full((len(pts), 3), 128, np.uint8) if colors is None
            else np.asarray(colors).reshape(-1, 3))
    if len(cols) != len(pts):
        raise ValueError(f"{len(pts)} points but {len(cols)} colours")
    keep = np.isfinite(pts).all(1)
    pts, cols = pts[keep], cols[keep]
    vert = np.empty(len(pts), _VERTEX)
    for i, k in enumerate("xyz"):
        vert[k] = pts[:, i]
    for i, k in enumerate(("red", "green", "blue")):
        vert[k] = np.clip(cols[:, i], 0, 255)
    lines = ["ply", "format binary_little_endian 1.0"]
    lines += [f"comment {c}" for c in comment.splitlines() if c]
    lines += [f"element vertex {len(pts)}", "property float x", "property float y",
              "property float z", "property uchar red", "property uchar green",
              "property uchar blue", "end_header"]
    header = ("\n".join(lines) + "\n").encode("ascii")
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header)
            fh.write(vert.tobytes())
    return path
