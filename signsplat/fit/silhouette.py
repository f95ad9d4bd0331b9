"""Silhouette terms of the multi-view fit: the person masks constrain the body's outline.

Why: keypoints pin the skeleton but not the surface. With detections a few pixels off, the
fitted body and cameras of ``studio6`` sat ~2 px from the truth in the images, and the avatar
trained on them blurs (docs/avatar.md). Six masks constrain the outline from six directions.

Two one-sided chamfer terms per (view, frame), both in squared pixels and clamped at
``clamp_px`` so a wrong mask pulls with a bounded force:

- ``inside``: every vertex projecting into the image must lie inside the mask - the mean of
  the mask's outside distance transform (bilinear, 0 inside) over those vertices. Occlusion
  cannot break it: every point of the body projects inside its own silhouette.
- ``cover``: every contour pixel of the mask must have a silhouette ("rim") vertex of the body
  near it - the mean squared distance from the contour pixels to the nearest rim vertex
  (normal at most ``rim_cos`` off perpendicular to the viewing ray). Rim vertices are chosen
  and matched without gradient (a k-d tree per image); the gradient flows through the matched
  vertices' projections. Contour pixels on the image border (a body cut by the frame) are not
  silhouette and are left out.

Frames whose mask is empty (no person detected) contribute nothing. Both terms are summed over
views and averaged over frames, like the keypoint term (:mod:`signsplat.fit.objective`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree

from signsplat.fit.cameras import project
from signsplat.geometry.mesh import vertex_normals


@dataclass
class SilhouetteTargets:
    """Per-(view, frame) targets built once from masks (see :func:`targets_from_masks`).

    ``outside (V*T,1,H,W)`` float distance (px) to the mask, 0 inside; ``contours`` list over
    ``V*T`` of (N,2) float32 contour pixels (x, y); ``valid (V,T)`` bool: the mask is non-empty.
    """

    outside: torch.Tensor
    contours: list[np.ndarray]
    valid: torch.Tensor
    width: int
    height: int


def mask_contour(mask: np.ndarray, max_points: int) -> np.ndarray:
    """(N,2) float32 x, y of the mask's boundary pixels (inner 4-neighbour boundary), without
    the image border, evenly subsampled to at most ``max_points``."""
    m = mask.astype(np.uint8)
    boundary = mask & ~cv2.erode(m, np.ones((3, 3), np.uint8)).astype(bool)
    boundary[0, :] = boundary[-1, :] = boundary[:, 0] = boundary[:, -1] = False
    ys, xs = np.nonzero(boundary)
    pts = np.stack([xs, ys], 1).astype(np.float32)
    if len(pts) > max_points:
        pts = pts[np.linspace(0, len(pts) - 1, max_points).astype(np.int64)]
    return pts


def targets_from_masks(masks: np.ndarray, max_contour_points: int = 300,
                       dtype=torch.float32, device="cpu") -> SilhouetteTargets:
    """``masks (V,T,H,W)`` bool -> :class:`SilhouetteTargets`."""
    masks = np.asarray(masks, bool)
    if masks.ndim != 4:
        raise ValueError(f"masks must be (views, frames, height, width), got {masks.shape}")
    V, T, H, W = masks.shape
    outside = np.zeros((V * T, 1, H, W), np.float32)
    contours = []
    valid = masks.reshape(V * T, H * W).any(1)
    for i, m in enumerate(masks.reshape(V * T, H, W)):
        if valid[i]:
            outside[i, 0] = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 5)
            contours.append(mask_contour(m, max_contour_points))
        else:
            contours.append(np.zeros((0, 2), np.float32))
    return SilhouetteTargets(torch.as_tensor(outside, dtype=dtype, device=device), contours,
                             torch.as_tensor(valid.reshape(V, T), device=device), W, H)


@dataclass
class ContourMatches:
    """Which body vertex each mask contour pixel is matched to (see :func:`match_contours`):
    ``view``, ``batch``, ``vertex`` (M,) int64 and ``pixel`` (M,2) of the contour pixels, for
    the frames ``frames`` (B,) of the targets."""

    view: torch.Tensor
    batch: torch.Tensor
    vertex: torch.Tensor
    pixel: torch.Tensor
    frames: np.ndarray

    @property
    def count(self) -> int:
        return int(self.vertex.shape[0])


@dataclass
class MatchCache:
    """Contour matches kept over several evaluations (ICP-style): re-matched every ``every``
    calls of :func:`silhouette_terms`, or at once when the frames change. One per stage run."""

    every: int = 1
    matches: ContourMatches | None = None
    age: int = 0

    def current(self, frames: torch.Tensor) -> ContourMatches | None:
        m = self.matches
        if m is None or self.age >= self.every or not np.array_equal(
                m.frames, frames.cpu().numpy()):
            return None
        return m


def match_contours(verts: torch.Tensor, faces: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
                   uv: torch.Tensor, front: torch.Tensor, targets: SilhouetteTargets,
                   frames: torch.Tensor, rim_cos: float = 0.25) -> ContourMatches:
    """Nearest rim vertex of every contour pixel, per (view, frame), without gradient.

    ``uv (V,B,N,2)`` and ``front (V,B,N)`` are the vertices' projections; rim vertices have a
    normal at most ``rim_cos`` off perpendicular to the viewing ray (one k-d tree per image).
    """
    V, B = uv.shape[:2]
    T = targets.valid.shape[1]
    with torch.no_grad():
        n = vertex_normals(verts.detach(), faces.long())
        centres = -torch.einsum("vji,vj->vi", R.detach(), t.detach())  # (V,3)
        ray = torch.nn.functional.normalize(verts.detach()[None] - centres[:, None, None], dim=-1)
        rim = ((n[None] * ray).sum(-1).abs() < rim_cos) & front  # (V,B,N)
        uv_np = uv.detach().cpu().double().numpy()
        rim_np = rim.cpu().numpy()
    sel_v, sel_b, sel_n, pts = [], [], [], []
    frames_np = frames.cpu().numpy()
    for v in range(V):
        for b in range(B):
            c = targets.contours[v * T + int(frames_np[b])]
            ids = np.nonzero(rim_np[v, b])[0]
            if len(c) == 0 or len(ids) == 0:
                continue
            _, j = cKDTree(uv_np[v, b, ids]).query(c)
            sel_v.append(np.full(len(c), v))
            sel_b.append(np.full(len(c), b))
            sel_n.append(ids[j])
            pts.append(c)
    dev = verts.device
    if not pts:
        empty = torch.zeros(0, dtype=torch.int64, device=dev)
        return ContourMatches(empty, empty, empty, verts.new_zeros((0, 2)), frames_np.copy())
    return ContourMatches(
        torch.as_tensor(np.concatenate(sel_v), device=dev),
        torch.as_tensor(np.concatenate(sel_b), device=dev),
        torch.as_tensor(np.concatenate(sel_n), device=dev),
        torch.as_tensor(np.concatenate(pts), dtype=verts.dtype, device=dev), frames_np.copy())


def _outside_rows(targets: SilhouetteTargets, frames: torch.Tensor) -> torch.Tensor:
    """The outside-distance maps of every view at ``frames (B,)``, (V*B,1,H,W): the maps
    themselves, not a copy, when ``frames`` is the whole sequence in order."""
    V, T = targets.valid.shape
    if len(frames) == T and bool((frames.cpu() == torch.arange(T)).all()):
        return targets.outside
    rows = (torch.arange(V, device=frames.device)[:, None] * T + frames[None]).reshape(-1)
    return targets.outside[rows.to(targets.outside.device)]


def silhouette_terms(verts: torch.Tensor, faces: torch.Tensor, K: torch.Tensor, R: torch.Tensor,
                     t: torch.Tensor, targets: SilhouetteTargets, frames: torch.Tensor,
                     clamp_px: float = 10.0, rim_cos: float = 0.25, near: float = 0.05,
                     cache: MatchCache | None = None,
                     projected: tuple[torch.Tensor, torch.Tensor] | None = None
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """(inside, cover) of ``verts (B,N,3)`` world metres, frames ``frames (B,)`` of the targets.

    K, R, t (V,...) cameras. Vertices at or behind the ``near`` plane are ignored by both terms.
    ``cache``: reuse the contour matches of earlier calls (:class:`MatchCache`); None matches
    every call. The cover term's gradient flows through the matched vertices either way.
    ``projected``: ``project(verts, K, R, t)`` when the caller has it already.
    """
    V = K.shape[0]
    B = verts.shape[0]
    H, W = targets.height, targets.width
    uv, z = project(verts, K, R, t) if projected is None else projected  # (V,B,N,2), (V,B,N)
    front = z > near
    valid = targets.valid[:, frames]  # (V,B)
    grid = uv / uv.new_tensor([W - 1, H - 1]) * 2 - 1
    grid = torch.nan_to_num(grid, nan=2.0, posinf=2.0, neginf=-2.0).clamp(-2, 2)
    d = torch.nn.functional.grid_sample(_outside_rows(targets, frames),
                                        grid.reshape(V * B, 1, -1, 2), align_corners=True,
                                        padding_mode="border")
    d = d.reshape(V, B, -1)
    in_image = front & (uv[..., 0] > 1) & (uv[..., 0] < W - 2) & (uv[..., 1] > 1) & \
        (uv[..., 1] < H - 2)
    w = (in_image & valid[..., None]).to(d.dtype)
    inside = ((d.clamp(max=clamp_px) ** 2 * w).sum(-1) / w.sum(-1).clamp(min=1)).sum() / max(B, 1)

    matches = None if cache is None else cache.current(frames)
    if matches is None:
        matches = match_contours(verts, faces, R, t, uv, front, targets, frames, rim_cos)
        if cache is not None:
            cache.matches, cache.age = matches, 0
    if cache is not None:
        cache.age += 1
    if matches.count == 0:
        return inside, verts.new_zeros(())
    iv, ib, idx, p = matches.view, matches.batch, matches.vertex, matches.pixel
    dist2 = ((uv[iv, ib, idx] - p) ** 2).sum(-1).clamp(max=clamp_px ** 2)
    key = iv * B + ib
    per = verts.new_zeros(V * B).index_add_(0, key, dist2)
    cnt = verts.new_zeros(V * B).index_add_(0, key, torch.ones_like(dist2))
    cover = (per / cnt.clamp(min=1)).sum() / max(B, 1)
    return inside, cover
