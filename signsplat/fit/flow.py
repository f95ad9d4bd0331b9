"""Optical-flow term of the multi-view fit: the images' own motion pins how the body moves.

Why: after the keypoint and mask stages, most of what changes from frame to frame in the fit's
error comes from the detector (on ``studio6`` the right hand's projection wanders 1.4 px
between frames, the torso 0.6 px), and an avatar trained on such bodies blurs. Dense optical
flow between two frames of one camera is measured on the image texture itself: on ``studio6``
OpenCV's DIS flow agrees with the true motion of the visible surface to about 0.1-0.2 px.

For each view and each pair of frames ``(a, b = a + gap)`` (``gaps`` in frame numbers; only
pairs whose frame numbers differ by exactly ``gap``) the forward flow F and the backward flow
are computed once. F is trusted where the two agree within ``consistency_px`` and where both
frames' person masks hold the point; elsewhere it is NaN.

The term: a body vertex seen in both frames (a point z-buffer per image, see
:func:`visible_vertices`) that projects to ``p`` in frame a should move by ``F(p)``:
``| (uv_b - uv_a) - F(p) |^2`` in squared pixels, clamped at ``clamp_px^2``, averaged over the
pair's vertices, summed over pairs and divided by the frames of the batch (like the keypoint
and silhouette terms). Which vertices and their target motions are chosen without gradient,
every ``flow_rematch_every`` steps of the stage (a :class:`~signsplat.fit.silhouette.MatchCache`);
the gradient flows through both frames' projections, so the term constrains the motion between
frames and never the absolute position (the keypoints and masks keep that).

Memory: the flow fields, ``pairs x H x W x 8`` bytes (``studio6``: 6 views, 60 frames, gaps
1, 2, 4 -> 1,038 pairs, 544 MB at 256 x 256).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import torch

from signsplat.fit.cameras import take
from signsplat.fit.pool import map_threads

#: OpenCV's DIS presets by name (config ``fit.multiview.flow.preset``)
PRESETS = {"ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
           "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
           "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM}


@dataclass
class FlowTargets:
    """Flow fields of every frame pair (see :func:`flow_targets`).

    ``flow (P,2,H,W)`` px from frame ``a`` to frame ``b`` of ``view`` (NaN where untrusted);
    ``view``, ``a``, ``b`` (P,) int64 indices into the fit's views and frames.
    """

    flow: torch.Tensor
    view: torch.Tensor
    a: torch.Tensor
    b: torch.Tensor
    width: int
    height: int

    @property
    def num_pairs(self) -> int:
        return int(self.view.shape[0])


@dataclass
class FlowMatches:
    """Vertices followed by the flow term: pair ``pair``, vertex ``vertex`` (M,) int64, its
    target motion ``motion (M,2)`` px; ``frames`` (B,) of the batch they were chosen for."""

    pair: torch.Tensor
    vertex: torch.Tensor
    motion: torch.Tensor
    frames: np.ndarray

    @property
    def count(self) -> int:
        return int(self.vertex.shape[0])


def frame_pairs(frames: np.ndarray, gaps) -> list[tuple[int, int]]:
    """Index pairs (i, j), i < j, of the frames whose numbers differ by one of ``gaps``."""
    frames = np.asarray(frames)
    pos = {int(f): i for i, f in enumerate(frames)}
    out = []
    for g in sorted({int(g) for g in gaps}):
        if g < 1:
            raise ValueError(f"flow gaps must be >= 1 frame, got {g}")
        out += [(i, pos[int(f) + g]) for i, f in enumerate(frames) if int(f) + g in pos]
    return out


def trusted_flow(first: np.ndarray, second: np.ndarray, mask_a: np.ndarray, mask_b: np.ndarray,
                 dis, consistency_px: float) -> np.ndarray:
    """(H,W,2) float32 flow from grey image ``first`` to ``second``, NaN where the backward
    flow does not bring the point back within ``consistency_px`` or where it leaves the masks."""
    fwd = dis.calc(first, second, None)
    bwd = dis.calc(second, first, None)
    h, w = first.shape
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    tx, ty = gx + fwd[..., 0], gy + fwd[..., 1]
    back = cv2.remap(bwd, tx, ty, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                     borderValue=(np.nan, np.nan))
    landed = cv2.remap(mask_b.astype(np.uint8), tx, ty, cv2.INTER_NEAREST,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    ok = (np.linalg.norm(fwd + back, axis=-1) < consistency_px) & mask_a & landed
    fwd[~ok] = np.nan
    return fwd


def flow_targets(images: np.ndarray, masks: np.ndarray, frames: np.ndarray, gaps,
                 consistency_px: float, preset: str, dtype=torch.float32,
                 device="cpu", progress=None) -> FlowTargets:
    """Trusted flow of every view's frame pairs. ``images (V,T,H,W)`` uint8 grey,
    ``masks (V,T,H,W)`` bool, ``frames (T,)`` frame numbers. Pairs with an empty mask are
    left out. ``progress``: an optional callable wrapped around the pair iterator."""
    images = np.asarray(images)
    masks = np.asarray(masks, bool)
    if images.ndim != 4 or images.shape != masks.shape:
        raise ValueError(f"images {images.shape} and masks {masks.shape} must both be "
                         "(views, frames, height, width)")
    if preset not in PRESETS:
        raise ValueError(f"unknown flow preset {preset!r}; known {sorted(PRESETS)}")
    V, _T, H, W = images.shape
    dis = cv2.DISOpticalFlow_create(PRESETS[preset])
    jobs = [(v, i, j) for v in range(V) for i, j in frame_pairs(frames, gaps)
            if masks[v, i].any() and masks[v, j].any()]
    flows = np.empty((len(jobs), 2, H, W), np.float32)
    for k, (v, i, j) in enumerate(progress(jobs) if progress else jobs):
        flows[k] = trusted_flow(images[v, i], images[v, j], masks[v, i], masks[v, j], dis,
                                consistency_px).transpose(2, 0, 1)
    idx = np.asarray(jobs, np.int64).reshape(-1, 3)
    as_t = lambda x: torch.as_tensor(x, device=device)
    return FlowTargets(torch.as_tensor(flows, dtype=dtype, device=device), as_t(idx[:, 0]),
                       as_t(idx[:, 1]), as_t(idx[:, 2]), W, H)


def visible_vertices(uv: torch.Tensor, z: torch.Tensor, width: int, height: int,
                     near: float = 0.05, cell_px: float = 2.0, tolerance_m: float = 0.02
                     ) -> torch.Tensor:
    """(V,B,N) bool: the vertex is in the image, in front of ``near`` and within
    ``tolerance_m`` of the nearest vertex projecting into its ``cell_px`` cell (a point
    z-buffer; the mesh is dense enough at fitting resolutions that a cell of 2 px holds
    the front surface). ``uv (V,B,N,2)`` px, ``z (V,B,N)`` m."""
    V, B, N = z.shape
    gw, gh = int(np.ceil(width / cell_px)), int(np.ceil(height / cell_px))
    ok = (z > near) & (uv[..., 0] >= 0) & (uv[..., 1] >= 0) & (uv[..., 0] < width) & \
        (uv[..., 1] < height)
    cx = (uv[..., 0] / cell_px).floor().clamp(0, gw - 1).long()
    cy = (uv[..., 1] / cell_px).floor().clamp(0, gh - 1).long()
    image = torch.arange(V * B, device=z.device).reshape(V, B, 1)
    cells = V * B * gw * gh
    # points not in the image go to one extra cell nobody reads (no boolean indexing: faster)
    key = torch.where(ok, image * (gw * gh) + cy * gw + cx, cells).reshape(-1)
    zbuf = torch.full((cells + 1,), float("inf"), dtype=z.dtype, device=z.device)
    zbuf.scatter_reduce_(0, key, z.reshape(-1), reduce="amin")
    return ok & (z <= zbuf[key].reshape(V, B, N) + tolerance_m)


def bilinear(fields: torch.Tensor, index: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Bilinear samples (M,C) of ``fields (P,C,H,W)`` at ``points (M,2)`` (x, y px) of the
    fields ``index (M,)``; NaN where a corner is NaN, points clamped to the image."""
    _, C, H, W = fields.shape
    x = points[:, 0].clamp(0, W - 1)
    y = points[:, 1].clamp(0, H - 1)
    x0 = x.floor().clamp(max=W - 2).long()
    y0 = y.floor().clamp(max=H - 2).long()
    wx, wy = (x - x0)[:, None], (y - y0)[:, None]
    # gathers from the flat fields (a view when they are contiguous): indexing
    # fields[index, :, y, x] directly takes PyTorch's slow path for a slice between indices
    flat = fields.reshape(-1)
    channel = torch.arange(C, device=index.device)
    first = ((index[:, None] * C + channel) * H + y0[:, None]) * W + x0[:, None]  # (M,C)
    corner = lambda dy, dx: flat[first + (dy * W + dx)]
    return ((corner(0, 0) * (1 - wx) + corner(0, 1) * wx) * (1 - wy)
            + (corner(1, 0) * (1 - wx) + corner(1, 1) * wx) * wy)


def batch_positions(frames: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Position in the batch ``frames (B,)`` of each sequence frame ``index``, -1 if absent."""
    dev = index.device
    size = int(frames.max()) + 2 if len(frames) else 1
    local = torch.full((size,), -1, dtype=torch.int64, device=dev)
    local[frames.to(dev)] = torch.arange(len(frames), device=dev)
    return torch.where(index < size, local[index.clamp(max=size - 1)], -1)


def match_flow(uv: torch.Tensor, z: torch.Tensor, targets: FlowTargets, frames: torch.Tensor,
               near: float = 0.05, max_vertices: int = 0) -> FlowMatches:
    """Vertices seen in both frames of every pair inside the batch ``frames (B,)`` and the
    flow at their projection in the first frame (no gradient). ``max_vertices`` > 0 keeps at
    most about that many per pair, evenly spaced in vertex order (every k-th of those found)."""
    dev = uv.device
    frames_np = frames.cpu().numpy()
    la, lb = batch_positions(frames, targets.a), batch_positions(frames, targets.b)
    sel = torch.nonzero((la >= 0) & (lb >= 0)).flatten()
    empty = torch.zeros(0, dtype=torch.int64, device=dev)
    if len(sel) == 0:
        return FlowMatches(empty, empty, uv.new_zeros((0, 2)), frames_np.copy())
    uv, z = uv.detach(), z.detach()
    view_of = targets.view[sel]

    def one_view(v: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The pairs of view ``v`` (their rows of ``sel`` ascending): pair, vertex, flow."""
        with torch.no_grad():
            pairs = sel[view_of == v]
            vis = visible_vertices(uv[v:v + 1], z[v:v + 1], targets.width, targets.height,
                                   near)[0]  # (B,N)
            a = la[pairs]
            keep = vis[a] & vis[lb[pairs]]  # (S,N): seen in both frames
            if max_vertices > 0:
                found = keep.sum(1, keepdim=True)
                step = torch.div(found + max_vertices - 1, max_vertices, rounding_mode="floor")
                keep = keep & ((keep.cumsum(1) - 1) % step.clamp(min=1) == 0)
            s_idx, n_idx = torch.nonzero(keep, as_tuple=True)
            f = bilinear(targets.flow, pairs[s_idx], uv[v, a[s_idx], n_idx])
            ok = torch.isfinite(f).all(-1)
            return pairs[s_idx[ok]], n_idx[ok], f[ok]

    # the views are independent: side by side on the fit's threads, in view order (the
    # targets list their pairs view by view, so the matches come in the same order)
    parts = map_threads(one_view, [int(v) for v in torch.unique(view_of)])
    pair, vertex, f = (torch.cat(x) for x in zip(*parts))
    return FlowMatches(pair, vertex, f.to(uv.dtype), frames_np.copy())


def flow_term(uv: torch.Tensor, z: torch.Tensor, targets: FlowTargets, frames: torch.Tensor,
              clamp_px: float, cache=None, max_vertices: int = 0) -> torch.Tensor:
    """The flow term of the batch: ``uv (V,B,N,2)``, ``z (V,B,N)`` the projections of the
    batch's vertices, ``frames (B,)`` their indices in the targets. ``cache``: a
    :class:`~signsplat.fit.silhouette.MatchCache` keeping the matches between re-matchings
    (None: match every call); ``max_vertices``: see :func:`match_flow`. Zero when no pair of
    frames lies inside the batch."""
    matches = None if cache is None else cache.current(frames)
    if matches is None:
        matches = match_flow(uv, z, targets, frames, max_vertices=max_vertices)
        if cache is not None:
            cache.matches, cache.age = matches, 0
    if cache is not None:
        cache.age += 1
    if matches.count == 0:
        return uv.new_zeros(())
    pair, vert = matches.pair, matches.vertex
    view = targets.view[pair]
    a, b = batch_positions(frames, targets.a[pair]), batch_positions(frames, targets.b[pair])
    # one gather for both ends (each gather's backward fills a zero tensor of uv's size)
    ends = take(uv, view.repeat(2), torch.cat([b, a]), vert.repeat(2))
    moved = ends[:len(vert)] - ends[len(vert):]
    r2 = ((moved - matches.motion) ** 2).sum(-1).clamp(max=clamp_px ** 2)
    P = targets.num_pairs
    per = uv.new_zeros(P).index_add_(0, pair, r2)
    cnt = uv.new_zeros(P).index_add_(0, pair, torch.ones_like(r2))
    used = cnt > 0
    return (per[used] / cnt[used]).sum() / max(len(frames), 1)
