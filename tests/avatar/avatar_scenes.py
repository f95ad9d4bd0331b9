"""Helpers of the avatar tests: cameras, random SMPL-X parameters and scenes around the
stand-in body (``tiny_body`` of tests/conftest.py)."""

from __future__ import annotations

import math

import numpy as np
import torch

from signsplat.avatar.data import SMPLX_BLOCKS, SceneData

SIZES = {"betas": 10, "expression": 10, "global_orient": 3, "body_pose": 63, "jaw_pose": 3,
         "leye_pose": 3, "reye_pose": 3, "left_hand_pose": 45, "right_hand_pose": 45,
         "transl": 3}


def look_at(eye, target=(0.0, 1.0, 0.0)) -> torch.Tensor:
    """OpenCV world-to-camera 4x4 (x right, y down, z forward), world y up."""
    eye = np.asarray(eye, float)
    z = np.asarray(target) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, -1.0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    m = np.eye(4)
    m[:3, :3] = R
    m[:3, 3] = -R @ eye
    return torch.tensor(m, dtype=torch.float32)


def rig(n_views: int = 3, size: int = 32, distance: float = 1.6):
    angles = np.linspace(-0.6, 0.6, n_views)
    vm = torch.stack([look_at((distance * math.sin(a), 1.0, distance * math.cos(a)))
                      for a in angles])
    f = size * 1.2
    K = torch.tensor([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1]],
                     dtype=torch.float32).expand(n_views, -1, -1).clone()
    return vm, K


def random_smplx(n_frames: int, seed: int = 0, scale: float = 0.15) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    out = {k: torch.randn(n_frames, n, generator=g) * scale for k, n in SIZES.items()}
    out["betas"] = out["betas"][:1].expand(n_frames, -1).clone() * 0
    out["expression"] *= 0
    out["transl"] *= 0.1
    return out


def make_scene(images: torch.Tensor, vm, K, smplx) -> SceneData:
    """images (C, F, H, W, 3) float in [0, 1] -> SceneData with full masks."""
    c, f, h, w, _ = images.shape
    return SceneData(
        scene="tiny", frames=np.arange(f), views=np.arange(c),
        images=(images.clamp(0, 1) * 255).round().to(torch.uint8),
        masks=torch.full((c, f, h, w), 255, dtype=torch.uint8),
        viewmats=vm, Ks=K, smplx={k: smplx[k] for k in SMPLX_BLOCKS},
    )
