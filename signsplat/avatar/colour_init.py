"""Colour initialisation from the training images (switch ``train.color_init``).

A mesh-anchored avatar knows where every point is in every training image before training
starts, so its colours need not start grey: each point takes the median of the pixel colours it
lands on in a few training images where it is visible. This is the mesh-anchored counterpart of
initialising 3DGS from a coloured point cloud; training then refines everything as before.

A point is *visible* in an image when it is inside the image and the person mask, faces the
camera (posed normal against the viewing ray, cosine above ``min_cosine``) and is not hidden: its
camera depth is within ``depth_tolerance`` of the expected depth the initial Gaussians render at
that pixel (the rasterizer's ``ED`` mode, so self-occlusion by an arm is handled).
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from signsplat.avatar.data import SceneData, target
from signsplat.avatar.model import SH_C0, AvatarModel, vertex_normals


def sample_pairs(train_frames: np.ndarray, train_views: np.ndarray, count: int,
                 seed: int) -> list[tuple[int, int]]:
    """``count`` (frame index, view index) pairs spread over the training frames and views."""
    rng = np.random.default_rng(seed)
    pairs = [(int(f), int(v)) for f in train_frames for v in train_views]
    if len(pairs) <= count:
        return pairs
    pick = rng.choice(len(pairs), size=count, replace=False)
    return [pairs[i] for i in sorted(pick)]


@torch.no_grad()
def observed_colours(model: AvatarModel, body, smplx_get, data: SceneData,
                     pairs: list[tuple[int, int]], rasterize, backend: str,
                     min_cosine: float = 0.3, depth_tolerance: float = 0.015
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """Median observed RGB (P, 3) of every point and the number of images it was seen in (P,).

    ``smplx_get(frame_idx_tensor)`` returns the SMPL-X blocks of those frames (the trainer's
    parameters); points never seen get count 0 (their colour row is meaningless).
    """
    samples: list[torch.Tensor] = []
    seen: list[torch.Tensor] = []
    bg = torch.zeros(3)
    for frame_i, view_i in pairs:
        params = smplx_get(torch.tensor([frame_i]))
        out = body(**params)
        g = model(out.v_shaped, out.vertices, out.transforms, params.get("transl"), 0)
        vm, K = data.viewmats[view_i], data.Ks[view_i]
        depth, _, _ = rasterize(
            means=g.means[0], quats=g.quats[0], scales=g.scales[0], opacities=g.opacities[0],
            colors=g.colors[0], viewmats=vm[None], Ks=K[None], width=data.width,
            height=data.height, sh_degree=0, render_mode="ED", backend=backend)
        x = g.means[0]
        cam = x @ vm[:3, :3].T + vm[:3, 3]
        z = cam[:, 2]
        uv = cam[:, :2] / z.clamp_min(1e-6)[:, None] * K.diagonal()[:2] + K[:2, 2]
        grid = torch.stack([uv[:, 0] / data.width, uv[:, 1] / data.height], -1) * 2 - 1
        img, mask = target(data, view_i, frame_i, bg)
        stack = torch.cat([img, mask, depth[0].permute(2, 0, 1)], 0)[None]  # (1, 5, H, W)
        val = F.grid_sample(stack, grid[None, :, None], mode="nearest", align_corners=False,
                            padding_mode="zeros")[0, :, :, 0].T  # (P, 5)
        centre = -vm[:3, :3].T @ vm[:3, 3]
        n_v = vertex_normals(out.vertices, model.faces)[0][model.anchors]  # (P, 3, 3)
        n = (n_v * model.barycentric()[..., None]).sum(1)
        ray = centre - x
        cos = (n * ray).sum(-1) / (n.norm(dim=-1) * ray.norm(dim=-1)).clamp_min(1e-9)
        inside = (grid.abs() < 1).all(-1) & (z > 1e-3)
        ok = inside & (val[:, 3] > 0.5) & (cos > min_cosine) & (
            (z - val[:, 4]).abs() < depth_tolerance)
        samples.append(torch.where(ok[:, None], val[:, :3], torch.full_like(val[:, :3],
                                                                            float("nan"))))
        seen.append(ok)
    stacked = torch.stack(samples)  # (S, P, 3)
    count = torch.stack(seen).sum(0)
    return torch.nanmedian(stacked, dim=0).values, count


@torch.no_grad()
def initialise_colours(model: AvatarModel, colours: torch.Tensor, count: torch.Tensor,
                       min_count: int = 1) -> int:
    """Set the degree-0 SH of points seen at least ``min_count`` times to ``colours``; returns
    how many points were set (the others keep their initial colour)."""
    ok = count >= min_count
    rgb = colours.clamp(0.02, 0.98)
    model.sh_dc[ok] = ((rgb[ok] - 0.5) / SH_C0)[:, None, :]
    return int(ok.sum())
