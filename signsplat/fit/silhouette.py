"""Silhouette terms of the multi-view fit: the person masks constrain the body's outline.

Why: keypoints pin the skeleton but not the surface. With detections a few pixels off, the
fitted body and cameras of ``studio6`` sat ~2 px from the truth in the images, and the avatar
trained on them blurs (docs/avatar.md). Six masks constrain the outline from six directions.

Two one-sided chamfer terms per (view, frame), both in squared pixels and clamped at
``clamp_px`` so a wrong mask pulls with a bounded force:

- ``inside``: every vertex projecting into the image must lie inside the mask's outline - the
  mean of the squared outside distance over those vertices (bilinear, 0 inside). The body
  hiding itself cannot break it (every point of the body projects inside its own silhouette);
  an object in front of the person can, as it cuts the mask: the hidden part is then pulled
  with the bounded force.
- ``cover``: every point of the mask's outline must have the body's contour near it - the mean
  squared distance from the outline points to the nearest point of the contour: the projected
  mesh edges between a triangle facing the camera and one facing away. Points are matched
  without gradient (a k-d tree per image), as a fraction along their edge; the gradient flows
  through the edge's two projected vertices. Outline points on the image border (a body cut by
  the frame) are not silhouette and are left out. Matched to the nearest vertex instead, an
  outline point between two vertices would pull the body by up to half an edge.

The outline is where a mask pixel meets a pixel outside it, half a pixel from both centres
(pixel centres at integer coordinates; a mask pixel is one whose centre the person covers).
Measured from the mask pixels' centres instead, both terms would pull the body's outline half a
pixel inwards in every view.

Frames whose mask is empty (no person detected) contribute nothing. Both terms are summed over
views and averaged over frames, like the keypoint term (:mod:`signsplat.fit.objective`).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch
from scipy.spatial import cKDTree

from signsplat.fit.cameras import project, take
from signsplat.fit.flow import bilinear
from signsplat.fit.pool import map_threads


@dataclass
class SilhouetteTargets:
    """Per-(view, frame) targets built once from masks (see :func:`targets_from_masks`).

    ``outside (V*T,1,H,W)`` float signed distance (px) to the mask's outline, negative inside;
    ``contours`` list over ``V*T`` of (N,2) float32 outline points (x, y); ``valid (V,T)``
    bool: the mask is non-empty.
    """

    outside: torch.Tensor
    contours: list[np.ndarray]
    valid: torch.Tensor
    width: int
    height: int


def mask_contour(mask: np.ndarray, max_points: int) -> np.ndarray:
    """(N,2) float32 x, y of points on the mask's outline: the mid-point between each mask
    pixel and each of its 4-neighbours outside the mask, neither on the image border, evenly
    subsampled to at most ``max_points``."""
    m = np.asarray(mask, bool)
    inner = np.zeros_like(m)
    inner[1:-1, 1:-1] = m[1:-1, 1:-1]  # the image border is not the outline
    pts = []
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        out = ~np.roll(m, (-dy, -dx), axis=(0, 1))  # the neighbour at (y + dy, x + dx)
        ys, xs = np.nonzero(inner & out)
        pts.append(np.stack([xs + 0.5 * dx, ys + 0.5 * dy], 1))
    pts = np.concatenate(pts).astype(np.float32)
    pts = pts[np.lexsort((pts[:, 0], pts[:, 1]))]  # row by row, like the pixels
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
            # signed distance to the outline, midway between a mask pixel's centre and its
            # outside neighbour's: bilinear sampling crosses 0 there
            out = cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 5)
            inn = cv2.distanceTransform(m.astype(np.uint8), cv2.DIST_L2, 5)
            outside[i, 0] = np.where(m, 0.5 - inn, out - 0.5)
            contours.append(mask_contour(m, max_contour_points))
        else:
            contours.append(np.zeros((0, 2), np.float32))
    return SilhouetteTargets(torch.as_tensor(outside, dtype=dtype, device=device), contours,
                             torch.as_tensor(valid.reshape(V, T), device=device), W, H)


@dataclass
class ContourMatches:
    """Where each mask outline point is matched on the body's contour (see
    :func:`match_contours`): the point at fraction ``along`` (M,) from vertex ``start`` to
    vertex ``end`` (M,) int64 of a contour edge, in view ``view`` and batch row ``batch`` (M,)
    int64; ``pixel`` (M,2) the outline points, for the frames ``frames`` (B,) of the targets."""

    view: torch.Tensor
    batch: torch.Tensor
    start: torch.Tensor
    end: torch.Tensor
    along: torch.Tensor
    pixel: torch.Tensor
    frames: np.ndarray

    @property
    def count(self) -> int:
        return int(self.start.shape[0])


@dataclass
class MatchCache:
    """Contour matches kept over several evaluations (ICP-style): re-matched every ``every``
    calls of :func:`silhouette_terms`, or at once when the frames change. One per stage run;
    ``edges`` keeps the stage's mesh edges (:func:`mesh_edges`, the faces do not change)."""

    every: int = 1
    matches: ContourMatches | None = None
    age: int = 0
    edges: tuple[torch.Tensor, torch.Tensor] | None = None

    def current(self, frames: torch.Tensor) -> ContourMatches | None:
        m = self.matches
        if m is None or self.age >= self.every or not np.array_equal(
                m.frames, frames.cpu().numpy()):
            return None
        return m


def mesh_edges(faces: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(edges (E,2), sides (E,2))`` int64 of the edges two triangles share: the edge's two
    vertices and its two faces (trimesh's face adjacency)."""
    import trimesh  # only when the silhouette terms run: not part of every fit's start-up

    f = faces.detach().cpu().numpy()
    mesh = trimesh.Trimesh(vertices=np.zeros((int(f.max()) + 1, 3)), faces=f, process=False)
    # torch.tensor copies: trimesh's cached arrays are read-only
    return tuple(torch.tensor(a, dtype=torch.int64, device=faces.device)
                 for a in (mesh.face_adjacency_edges, mesh.face_adjacency))


def match_contours(verts: torch.Tensor, faces: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
                   uv: torch.Tensor, front: torch.Tensor, targets: SilhouetteTargets,
                   frames: torch.Tensor, candidates: int = 8,
                   edges: tuple[torch.Tensor, torch.Tensor] | None = None) -> ContourMatches:
    """Nearest point of the body's contour to every mask outline point, per (view, frame),
    without gradient.

    The contour is the mesh's edges between a triangle facing the camera and one facing away
    (both ends in front of the camera), projected: the outline of the body's image and the
    folds inside it. Each outline point takes the nearest of its ``candidates`` nearest edges
    by mid-point (one k-d tree per image). ``uv (V,B,N,2)`` and ``front (V,B,N)`` are the
    vertices' projections; ``edges``: :func:`mesh_edges` of ``faces`` when the caller keeps
    them.
    """
    V, B = uv.shape[:2]
    T = targets.valid.shape[1]
    edges, sides = mesh_edges(faces) if edges is None else edges
    with torch.no_grad():
        tri = verts.detach()[:, faces.long()]  # (B,F,3,3)
        normal = torch.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0], dim=-1)
        centres = -torch.einsum("vji,vj->vi", R.detach(), t.detach())  # (V,3)
        # n . (c - v0) > 0: the triangle faces camera centre c
        facing = torch.einsum("bfk,vk->vbf", normal, centres) > \
            (normal * tri[:, :, 0]).sum(-1)[None]
        contour = (facing[..., sides[:, 0]] != facing[..., sides[:, 1]]) & \
            front[..., edges[:, 0]] & front[..., edges[:, 1]]  # (V,B,E)
        contour_np = contour.cpu().numpy()
        uv_np = uv.detach().cpu().double().numpy()
    edges_np = edges.cpu().numpy()
    frames_np = frames.cpu().numpy()

    def match_image(vb: tuple[int, int]) -> tuple | None:
        v, b = vb
        c = targets.contours[v * T + int(frames_np[b])]
        ids = np.nonzero(contour_np[v, b])[0]
        if len(c) == 0 or len(ids) == 0:
            return None
        p0, p1 = uv_np[v, b, edges_np[ids, 0]], uv_np[v, b, edges_np[ids, 1]]
        k = min(candidates, len(ids))
        _, near = cKDTree(0.5 * (p0 + p1)).query(c, k=k)
        near = near.reshape(len(c), k)
        a, d = p0[near], p1[near] - p0[near]  # (M,k,2)
        frac = np.clip(((c[:, None] - a) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-12),
                       0.0, 1.0)
        gap = ((a + frac[..., None] * d - c[:, None]) ** 2).sum(-1)
        best = gap.argmin(1)
        r = np.arange(len(c))
        chosen = edges_np[ids[near[r, best]]]
        return (np.full(len(c), v), np.full(len(c), b), chosen[:, 0], chosen[:, 1],
                frac[r, best], c)

    # the images are independent: side by side on the fit's threads, rows in image order
    rows = [r for r in map_threads(match_image, [(v, b) for v in range(V) for b in range(B)])
            if r is not None]
    dev = verts.device
    if not rows:
        empty = torch.zeros(0, dtype=torch.int64, device=dev)
        return ContourMatches(empty, empty, empty, empty, verts.new_zeros(0),
                              verts.new_zeros((0, 2)), frames_np.copy())
    cols = [np.concatenate(x) for x in zip(*rows)]
    ints = [torch.as_tensor(x, dtype=torch.int64, device=dev) for x in cols[:4]]
    return ContourMatches(*ints, torch.as_tensor(cols[4], dtype=verts.dtype, device=dev),
                          torch.as_tensor(cols[5], dtype=verts.dtype, device=dev),
                          frames_np.copy())


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
                     clamp_px: float = 10.0, near: float = 0.05,
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
    with torch.no_grad():
        front = z > near
        in_image = front & (uv[..., 0] > 1) & (uv[..., 0] < W - 2) & (uv[..., 1] > 1) & \
            (uv[..., 1] < H - 2)
        w = in_image & targets.valid[:, frames][..., None]
        counted = w.sum(-1).clamp(min=1)  # (V,B)
        grid = torch.addcmul(uv.new_tensor(-1.0), uv.detach(),
                             uv.new_tensor([2 / (W - 1), 2 / (H - 1)]))
        grid = grid.nan_to_num_(nan=2.0, posinf=2.0, neginf=-2.0).clamp_(-2, 2)
        maps = _outside_rows(targets, frames)  # (V*B,1,H,W), row v * B + b
        d = torch.nn.functional.grid_sample(maps, grid.reshape(V * B, 1, -1, 2),
                                            align_corners=True,
                                            padding_mode="border").reshape(V, B, -1)
        # the inside term's value and gradient come from the vertices outside the outline
        # only (clamped at 0 inside): they alone are sampled again, with gradient
        out_v, out_b, out_n = torch.nonzero(w & (d >= 0), as_tuple=True)

    matches = None if cache is None else cache.current(frames)
    if matches is None:
        if cache is not None and cache.edges is None:
            cache.edges = mesh_edges(faces)
        matches = match_contours(verts, faces, R, t, uv, front, targets, frames,
                                 edges=None if cache is None else cache.edges)
        if cache is not None:
            cache.matches, cache.age = matches, 0
    if cache is not None:
        cache.age += 1
    iv, ib = matches.view, matches.batch
    # one gather for every point with gradient (each gather's backward fills a zero tensor of
    # uv's size): the outside vertices, then the matched edges' starts and ends
    M, P = len(out_n), matches.count
    at = take(uv, torch.cat([out_v, iv, iv]), torch.cat([out_b, ib, ib]),
              torch.cat([out_n, matches.start, matches.end]))
    image = out_v * B + out_b
    d_out = bilinear(maps, image, at[:M])[:, 0]
    per_image = uv.new_zeros(V * B).index_add_(0, image, d_out.clamp(min=0, max=clamp_px) ** 2)
    inside = (per_image / counted.reshape(-1)).sum() / max(B, 1)
    if P == 0:
        return inside, verts.new_zeros(())
    frac = matches.along[:, None]
    on_body = (1 - frac) * at[M:M + P] + frac * at[M + P:]
    dist2 = ((on_body - matches.pixel) ** 2).sum(-1).clamp(max=clamp_px ** 2)
    key = iv * B + ib
    per = verts.new_zeros(V * B).index_add_(0, key, dist2)
    cnt = verts.new_zeros(V * B).index_add_(0, key, torch.ones_like(dist2))
    cover = (per / cnt.clamp(min=1)).sum() / max(B, 1)
    return inside, cover
