"""The ``gsplat`` backend: gsplat's CUDA rasterizer, used when gsplat is installed and the
tensors live on a CUDA device. gsplat is imported lazily and is never a requirement.

It is called with ``packed=False`` so ``meta`` has the same [C, N, ...] layout as the other
backends (``meta["means2d"]`` [C, N, 2], ``meta["radii"]`` [C, N, 2]).
"""

from __future__ import annotations

import functools
import importlib
import importlib.util
from typing import Any

from torch import Tensor


@functools.lru_cache(maxsize=1)
def available() -> bool:
    """True when gsplat can be imported (the CUDA check is done on the tensors' device)."""
    return importlib.util.find_spec("gsplat") is not None


def rasterize(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
              viewmats: Tensor, Ks: Tensor, width: int, height: int, near_plane: float,
              far_plane: float, eps2d: float, sh_degree: int | None,
              backgrounds: Tensor | None, render_mode: str, rasterize_mode: str,
              tile_size: int, absgrad: bool) -> tuple[Tensor, Tensor, dict[str, Any]]:
    gsplat = importlib.import_module("gsplat")
    render_colors, render_alphas, meta = gsplat.rasterization(
        means, quats, scales, opacities, colors, viewmats, Ks, width, height,
        near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, sh_degree=sh_degree,
        packed=False, tile_size=tile_size, backgrounds=backgrounds, render_mode=render_mode,
        absgrad=absgrad, rasterize_mode=rasterize_mode)
    meta = dict(meta)
    meta.setdefault("n_cameras", viewmats.shape[0])
    meta["backend"] = "gsplat"
    return render_colors, render_alphas, meta
