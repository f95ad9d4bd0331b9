"""Render-mode plumbing shared by the backends (:mod:`._cpu`, :mod:`._reference`): the
backgrounds of the composited features, the expected-depth division and gsplat's ``meta``."""

from __future__ import annotations

import math
from typing import Any

import torch
from torch import Tensor


def mode_backgrounds(backgrounds: Tensor | None, render_mode: str, C: int,
                     like: Tensor) -> Tensor | None:
    """Backgrounds [C, D] of the features composited for ``render_mode`` (depth channels get
    0), or None; ``like`` gives dtype and device."""
    if backgrounds is None:
        return None
    if render_mode in ("D", "ED"):
        return torch.zeros(C, 1, dtype=like.dtype, device=like.device)
    if render_mode in ("RGB+D", "RGB+ED"):
        return torch.cat([backgrounds, torch.zeros_like(backgrounds[:, :1])], dim=-1)
    return backgrounds


def finish(render_colors: Tensor, render_alphas: Tensor, render_mode: str, *, radii: Tensor,
           means2d: Tensor, depths: Tensor, conics: Tensor, opacities: Tensor,
           compensations: Tensor | None, width: int, height: int, tile_size: int, backend: str,
           **extra: Any) -> tuple[Tensor, Tensor, dict[str, Any]]:
    """The outputs of ``rasterization()``: "ED" modes divide the depth channel by
    ``max(alpha, 1e-10)``; ``meta`` in gsplat's unpacked layout plus ``extra`` and ``backend``."""
    if render_mode in ("ED", "RGB+ED"):
        render_colors = torch.cat([render_colors[..., :-1],
                                   render_colors[..., -1:] / render_alphas.clamp(min=1e-10)], -1)
    meta: dict[str, Any] = {
        "camera_ids": None, "gaussian_ids": None, "radii": radii, "means2d": means2d,
        "depths": depths, "conics": conics, "opacities": opacities,
        "compensations": compensations, "width": width, "height": height,
        "tile_size": tile_size, "n_cameras": radii.shape[0],
        "tile_width": math.ceil(width / tile_size), "tile_height": math.ceil(height / tile_size),
        **extra, "backend": backend,
    }
    return render_colors, render_alphas, meta
