"""Independent triangle-mesh renderer for ground truth (never the splat rasterizer).

A z-buffer rasterizer written with Numba. Each triangle is tested per pixel in homogeneous
camera coordinates (Olano & Greer 1997): for a pixel ray ``d = K^-1 [u, v, 1]`` and camera-space
vertices ``v0, v1, v2`` the weights ``lam = [v0 v1 v2]^-1 d`` are all positive exactly when the
ray hits the triangle in front of the camera; then the barycentrics ``lam / sum(lam)`` are
perspective-correct and the depth is ``z = 1 / sum(lam)``. Triangles crossing the near plane
need no special case beyond bounding their screen box by the near-clipped polygon, and
triangles fully behind the near plane are culled.

Triangles are drawn in index order with a strict depth test, so the result is deterministic
(ties go to the lower face index). The kernels release the GIL (``nogil``): callers render
several views at once from a thread pool.

Functions take NumPy arrays: positions in metres (world frame), cameras in the OpenCV
convention ``x_cam = R @ x_world + t``, pixel centres at integer coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from signsplat.numba_cache import cache_kernels_of

cache_kernels_of(__file__)  # compiled once per content, not once per checkout

__all__ = ["Raster", "rasterize", "interpolate", "interpolate_at", "face_attribute",
           "nearest_corner", "vertex_normals", "face_normals", "downsample", "camera_depth",
           "scale_intrinsics"]

_NEAR_DEFAULT = 1e-3


@dataclass(frozen=True)
class Raster:
    """Per-pixel result of :func:`rasterize` for an image of ``H x W`` pixels.

    Attributes:
        depth: (H, W) float32 camera-space z in metres, ``inf`` where nothing is drawn.
        face_id: (H, W) int32 index of the visible triangle, -1 where nothing is drawn.
        bary: (H, W, 3) float32 perspective-correct barycentric weights of the triangle's
            three vertices (zero where nothing is drawn).
    """

    depth: np.ndarray
    face_id: np.ndarray
    bary: np.ndarray

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool, True where a triangle is drawn."""
        return self.face_id >= 0

    @property
    def shape(self) -> tuple[int, int]:
        return self.face_id.shape


def camera_depth(points: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Camera-space coordinates of world points: (N, 3) -> (N, 3) float64 (z = depth)."""
    return np.asarray(points, np.float64) @ np.asarray(R, np.float64).T + np.asarray(t, np.float64)


@numba.njit(cache=True, nogil=True)
def _screen_box(c0, c1, c2, fx, fy, cx, cy, near, W, H):
    """Integer pixel bounding box (x0, x1, y0, y1) of a camera-space triangle clipped at z=near.

    Returns x0 > x1 when the triangle is entirely behind the near plane or off screen.
    """
    umin, umax, vmin, vmax = np.inf, -np.inf, np.inf, -np.inf
    verts = (c0, c1, c2)
    count = 0
    for i in range(3):
        a = verts[i]
        b = verts[(i + 1) % 3]
        if a[2] >= near:
            u = fx * a[0] / a[2] + cx
            v = fy * a[1] / a[2] + cy
            umin = min(umin, u)
            umax = max(umax, u)
            vmin = min(vmin, v)
            vmax = max(vmax, v)
            count += 1
        if (a[2] >= near) != (b[2] >= near):
            s = (near - a[2]) / (b[2] - a[2])
            px = a[0] + s * (b[0] - a[0])
            py = a[1] + s * (b[1] - a[1])
            u = fx * px / near + cx
            v = fy * py / near + cy
            umin = min(umin, u)
            umax = max(umax, u)
            vmin = min(vmin, v)
            vmax = max(vmax, v)
            count += 1
    if count == 0:
        return 1, 0, 1, 0
    # clamp in float first: clipped vertices can project arbitrarily far away
    umin = max(umin, -1.0)
    vmin = max(vmin, -1.0)
    umax = min(umax, W + 1.0)
    vmax = min(vmax, H + 1.0)
    x0 = max(int(np.ceil(umin)), 0)
    x1 = min(int(np.floor(umax)), W - 1)
    y0 = max(int(np.ceil(vmin)), 0)
    y1 = min(int(np.floor(vmax)), H - 1)
    return x0, x1, y0, y1


@numba.njit(cache=True, nogil=True)
def _setup(cam, faces, fx, fy, cx, cy, near, W, H, boxes, inv):
    """Per-triangle screen boxes and inverse vertex matrices (degenerate -> empty box)."""
    for f in range(faces.shape[0]):
        c0 = cam[faces[f, 0]]
        c1 = cam[faces[f, 1]]
        c2 = cam[faces[f, 2]]
        x0, x1, y0, y1 = _screen_box(c0, c1, c2, fx, fy, cx, cy, near, W, H)
        # M has the camera-space vertices as columns; lam = M^-1 d
        m00, m01, m02 = c0[0], c1[0], c2[0]
        m10, m11, m12 = c0[1], c1[1], c2[1]
        m20, m21, m22 = c0[2], c1[2], c2[2]
        a00 = m11 * m22 - m12 * m21
        a01 = m02 * m21 - m01 * m22
        a02 = m01 * m12 - m02 * m11
        a10 = m12 * m20 - m10 * m22
        a11 = m00 * m22 - m02 * m20
        a12 = m02 * m10 - m00 * m12
        a20 = m10 * m21 - m11 * m20
        a21 = m01 * m20 - m00 * m21
        a22 = m00 * m11 - m01 * m10
        det = m00 * a00 + m01 * a10 + m02 * a20
        scale = abs(c0[0]) + abs(c0[1]) + abs(c0[2]) + abs(c1[0]) + abs(c1[1]) + abs(c1[2]) \
            + abs(c2[0]) + abs(c2[1]) + abs(c2[2])
        if abs(det) <= 1e-12 * scale * scale * scale or x0 > x1 or y0 > y1:
            boxes[f, 0], boxes[f, 1], boxes[f, 2], boxes[f, 3] = 1, 0, 1, 0
            continue
        boxes[f, 0], boxes[f, 1], boxes[f, 2], boxes[f, 3] = x0, x1, y0, y1
        r = 1.0 / det
        inv[f, 0, 0], inv[f, 0, 1], inv[f, 0, 2] = a00 * r, a01 * r, a02 * r
        inv[f, 1, 0], inv[f, 1, 1], inv[f, 1, 2] = a10 * r, a11 * r, a12 * r
        inv[f, 2, 0], inv[f, 2, 1], inv[f, 2, 2] = a20 * r, a21 * r, a22 * r


@numba.njit(cache=True, nogil=True)
def _raster_kernel(boxes, inv, fx, fy, cx, cy, near, depth, face_id, bary):
    for f in range(boxes.shape[0]):
        x0, x1, y0, y1 = boxes[f, 0], boxes[f, 1], boxes[f, 2], boxes[f, 3]
        if x0 > x1 or y0 > y1:
            continue
        i00, i01, i02 = inv[f, 0, 0], inv[f, 0, 1], inv[f, 0, 2]
        i10, i11, i12 = inv[f, 1, 0], inv[f, 1, 1], inv[f, 1, 2]
        i20, i21, i22 = inv[f, 2, 0], inv[f, 2, 1], inv[f, 2, 2]
        for y in range(y0, y1 + 1):
            dy = (y - cy) / fy
            for x in range(x0, x1 + 1):
                dx = (x - cx) / fx
                l0 = i00 * dx + i01 * dy + i02
                l1 = i10 * dx + i11 * dy + i12
                l2 = i20 * dx + i21 * dy + i22
                if l0 < 0.0 or l1 < 0.0 or l2 < 0.0:
                    continue
                s = l0 + l1 + l2
                if s <= 0.0:
                    continue
                z = 1.0 / s
                if z < near or z >= depth[y, x]:
                    continue
                depth[y, x] = z
                face_id[y, x] = f
                bary[y, x, 0] = l0 * z
                bary[y, x, 1] = l1 * z
                bary[y, x, 2] = l2 * z


def rasterize(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, R: np.ndarray,
              t: np.ndarray, width: int, height: int, near: float = _NEAR_DEFAULT) -> Raster:
    """Rasterize a triangle mesh seen by one pinhole camera.

    Args:
        vertices: (V, 3) float world positions in metres.
        faces: (F, 3) int vertex indices (either winding; no back-face culling).
        K: (3, 3) intrinsics ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels.
        R, t: (3, 3), (3,) world-to-camera rotation and translation (OpenCV).
        width, height: image size in pixels.
        near: near-plane depth in metres; surface closer than this is not drawn.

    Returns:
        :class:`Raster` with depth (camera z, metres), face ids and barycentrics. Empty
        views (nothing in front of the camera, no faces) give an all-empty raster.
    """
    W, H = int(width), int(height)
    depth = np.full((H, W), np.inf, np.float32)
    face_id = np.full((H, W), -1, np.int32)
    bary = np.zeros((H, W, 3), np.float32)
    faces = np.ascontiguousarray(faces, dtype=np.int64).reshape(-1, 3)
    if faces.shape[0] == 0 or W == 0 or H == 0:
        return Raster(depth, face_id, bary)
    K = np.asarray(K, np.float64)
    if K[0, 1] != 0.0:
        raise ValueError("rasterize: skewed intrinsics (K[0,1] != 0) are not supported")
    cam = np.ascontiguousarray(camera_depth(vertices, R, t))
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    boxes = np.empty((faces.shape[0], 4), np.int64)
    inv = np.zeros((faces.shape[0], 3, 3), np.float64)
    _setup(cam, faces, fx, fy, cx, cy, float(near), W, H, boxes, inv)
    # the kernel writes float64 depth for a stable test, stored as float32 afterwards
    depth64 = np.full((H, W), np.inf, np.float64)
    _raster_kernel(boxes, inv, fx, fy, cx, cy, float(near), depth64, face_id, bary)
    depth[...] = depth64
    return Raster(depth, face_id, bary)


def interpolate(raster: Raster, faces: np.ndarray, attributes: np.ndarray) -> np.ndarray:
    """Interpolate per-vertex attributes at the drawn pixels.

    Args:
        raster: result of :func:`rasterize`.
        faces: (F, 3) the faces that were rasterized.
        attributes: (V, C) per-vertex values.

    Returns:
        (P, C) float32 values at the P pixels where ``raster.mask`` is True, in row-major
        pixel order (``np.nonzero(raster.mask)``).
    """
    mask = raster.mask
    return interpolate_at(faces, attributes, raster.face_id[mask], raster.bary[mask])


def interpolate_at(faces: np.ndarray, attributes: np.ndarray, face_ids: np.ndarray,
                   bary: np.ndarray) -> np.ndarray:
    """Barycentric interpolation: (V, C) attributes at P (face id, (3,) weights) -> (P, C)."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    attributes = np.ascontiguousarray(attributes, dtype=np.float32)
    if attributes.ndim == 1:
        return _interp_kernel(faces, attributes[:, None], np.ascontiguousarray(face_ids),
                              np.ascontiguousarray(bary, dtype=np.float32))[:, 0]
    return _interp_kernel(faces, attributes, np.ascontiguousarray(face_ids),
                          np.ascontiguousarray(bary, dtype=np.float32))


@numba.njit(cache=True, nogil=True)
def _interp_kernel(faces, attributes, face_ids, bary):
    P, C = face_ids.shape[0], attributes.shape[1]
    out = np.empty((P, C), np.float32)
    for p in range(P):
        f = face_ids[p]
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        wa, wb, wc = bary[p, 0], bary[p, 1], bary[p, 2]
        for k in range(C):
            out[p, k] = wa * attributes[a, k] + wb * attributes[b, k] + wc * attributes[c, k]
    return out


def face_attribute(raster: Raster, faces: np.ndarray, vertex_values: np.ndarray) -> np.ndarray:
    """Per drawn pixel, the value of the triangle vertex with the largest barycentric weight.

    Use for discrete per-vertex data (part labels). Returns (P,) in the order of
    ``np.nonzero(raster.mask)``.
    """
    mask = raster.mask
    return nearest_corner(faces, vertex_values, raster.face_id[mask], raster.bary[mask])


def nearest_corner(faces: np.ndarray, vertex_values: np.ndarray, face_ids: np.ndarray,
                   bary: np.ndarray) -> np.ndarray:
    """(V,) discrete values at P (face id, weights): the value of the heaviest corner -> (P,)."""
    corner = np.argmax(bary, axis=1)
    return np.asarray(vertex_values)[np.asarray(faces)[face_ids, corner]]


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3) float32 of a triangle mesh.

    The direction follows the face winding (counter-clockwise seen from outside = outward).
    """
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    idx = f.reshape(-1)
    n = np.stack([np.bincount(idx, weights=np.repeat(fn[:, c], 3), minlength=len(v))
                  for c in range(3)], axis=1)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.maximum(norm, 1e-12)).astype(np.float32)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit face normals (F, 3) float32 following the winding."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return (fn / np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-12)).astype(np.float32)


def scale_intrinsics(K: np.ndarray, factor: int) -> np.ndarray:
    """Intrinsics of the same camera sampled ``factor`` times denser per axis.

    Pixel centres stay at integer coordinates: ``u_hi = factor * (u + 0.5) - 0.5``.
    """
    K = np.asarray(K, np.float64).copy()
    K[0, 0] *= factor
    K[1, 1] *= factor
    K[0, 2] = factor * (K[0, 2] + 0.5) - 0.5
    K[1, 2] = factor * (K[1, 2] + 0.5) - 0.5
    return K


def downsample(image: np.ndarray, factor: int) -> np.ndarray:
    """Box-filter an (H*f, W*f) or (H*f, W*f, C) array down to (H, W[, C]) float32."""
    if factor == 1:
        return image
    image = np.asarray(image, np.float32)
    flat = image if image.ndim == 3 else image[..., None]
    out = _downsample_kernel(np.ascontiguousarray(flat), int(factor))
    return out if image.ndim == 3 else out[..., 0]


@numba.njit(cache=True, nogil=True)
def _downsample_kernel(image, f):
    H, W, C = image.shape[0] // f, image.shape[1] // f, image.shape[2]
    out = np.zeros((H, W, C), np.float32)
    scale = 1.0 / (f * f)
    for y in range(H):
        for x in range(W):
            for dy in range(f):
                for dx in range(f):
                    for k in range(C):
                        out[y, x, k] += image[y * f + dy, x * f + dx, k]
            for k in range(C):
                out[y, x, k] *= scale
    return out
