"""Differentiable 3D Gaussian rasterization with gsplat 1.5.3's ``rasterization()`` API.

Backends
--------
``"cpu"``
    Ours: Numba kernels (projection, SH colours, tile binning with a depth sort, compositing
    and its backward), parallel over tiles on all cores, wrapped in ``torch.autograd.Function``.
    The backward never materialises per-(pixel, Gaussian) tensors. Compiled code is cached on
    disk (see ``signsplat.numba_cache``); the first call in a fresh checkout compiles (~30 s).
``"reference"``
    Plain PyTorch with autograd, dense per (pixel, Gaussian) pair; obvious rather than fast.
    The tests' oracle. Works on any device.
``"gsplat"``
    gsplat's CUDA kernels, when gsplat is installed and the tensors are on a CUDA device
    (imported lazily, never required).
``"auto"`` (default)
    The tensors' device decides: CUDA with gsplat installed -> ``"gsplat"``; otherwise
    ``"cpu"`` (CUDA tensors without gsplat take a round trip through host memory; ``meta``
    tensors then stay on the CPU).

Numerics (identical in every backend, forward and backward)
-----------------------------------------------------------
- **Covariance.** ``Sigma = R S S^T R^T`` with ``R`` from the quaternion (wxyz) normalised as
  ``q / sqrt(max(|q|^2, 1e-24))``: a zero quaternion yields the zero vector, whose rotation
  formula is the identity, with a zero gradient (no NaN). Scales are used as given (no exp).
- **EWA projection.** ``mean2d = (fx x/z + cx, fy y/z + cy)``; the Jacobian
  ``J = [[fx/z, 0, -fx u/z], [0, fy/z, -fy v/z]]`` uses ``u = x/z`` and ``v = y/z`` clamped to
  the image frustum widened by 0.3 of the half field of view on each side (about 1.3x the FOV,
  as 3DGS/gsplat); the clamp passes no gradient where active. ``cov2d = J Sigma_cam J^T``.
- **Dilation.** ``cov2d + eps2d * I`` (eps2d = 0.3 px^2 by default). With
  ``rasterize_mode="antialiased"`` the opacity is multiplied by the compensation
  ``sqrt(max(det(cov2d) / det(cov2d + eps2d I), 0))`` (Mip-Splatting), differentiably.
- **Culling** (radii = 0, no contribution, zero gradient): depth outside
  ``[near_plane, far_plane]``; dilated determinant not positive or not finite; non-finite
  projected mean; effective opacity below 1/255; bounding box outside the image.
- **Radius.** Opacity-aware: ``extent = min(3.33, sqrt(2 log(opacity / (1/255))))`` standard
  deviations, ``radii = ceil(extent * sqrt(diag(cov2d + eps2d I)))`` per axis ([C, N, 2], as
  gsplat 1.5). This box contains every pixel where ``alpha >= 1/255``, so tiling never changes
  the image.
- **Alpha.** Pixel centres at ``(i + 0.5, j + 0.5)``;
  ``sigma = 0.5 (a dx^2 + c dy^2) + b dx dy`` with the conic (a, b, c) and ``d = mean - pixel``;
  ``alpha = min(0.999, opacity * exp(-sigma))``; pairs with ``sigma < 0`` or
  ``alpha < 1/255`` are skipped. The min() passes no gradient where it clamps.
- **Compositing.** Front to back in depth order (ties by Gaussian index); a pixel stops before
  the Gaussian that would bring its transmittance to ``<= 1e-4`` (that one is not composited).
  ``render_alphas = 1 - T_final``; the background is added as ``T_final * background``.
  The backward recovers transmittances as ``T / (1 - alpha)`` (alpha <= 0.999) with the very
  same tests and constants as the forward.
- **Colours.** ``colors`` are post-activation features [N, D] / [C, N, D], or with
  ``sh_degree`` SH coefficients [N, K, 3] / [C, N, K, 3] evaluated (degree 0-3, 3DGS basis) in
  the direction from the camera centre ``inverse(viewmat)[:3, 3]`` to the mean, then
  ``max(sh + 0.5, 0)``. Depth modes composite the camera-space z; "ED" divides by
  ``max(alpha, 1e-10)``.
- **Gradients** flow to means, quats, scales, opacities, colors (or SH coefficients),
  viewmats and backgrounds; not to Ks (as gsplat). ``meta["means2d"]`` [C, N, 2] is the
  projected-mean tensor in the graph: ``retain_grad()`` it before ``backward()`` to read its
  gradient (pixels), and with ``absgrad=True`` ``meta["means2d"].absgrad`` holds the sum over
  pixels of the absolute per-pixel terms (AbsGS).

float32 and float64 inputs are supported (float64 for gradcheck). See docs/rasterizer.md.
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from . import _gsplat
from ._constants import DEFAULT_EPS2D

__all__ = ["rasterization", "BACKENDS", "DEFAULT_EPS2D", "RENDER_MODES", "select_backend"]

BACKENDS = ("auto", "cpu", "reference", "gsplat")
RENDER_MODES = ("RGB", "D", "ED", "RGB+D", "RGB+ED")
RASTERIZE_MODES = ("classic", "antialiased")

_warned_roundtrip = False


def select_backend(backend: str, device_type: str, gsplat_available: bool | None = None) -> str:
    """The backend that ``rasterization`` runs for tensors on ``device_type``."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if gsplat_available is None:
        gsplat_available = _gsplat.available()
    if backend == "auto":
        return "gsplat" if device_type == "cuda" and gsplat_available else "cpu"
    if backend == "gsplat":
        if not gsplat_available:
            raise ImportError("backend='gsplat' needs the gsplat package (pip install gsplat)")
        if device_type != "cuda":
            raise ValueError("backend='gsplat' needs CUDA tensors")
    return backend


def _check(means, quats, scales, opacities, colors, viewmats, Ks, width, height, sh_degree,
           backgrounds, render_mode, rasterize_mode, tile_size):
    if render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
    if rasterize_mode not in RASTERIZE_MODES:
        raise ValueError(f"rasterize_mode must be one of {RASTERIZE_MODES}, "
                         f"got {rasterize_mode!r}")
    if int(width) < 1 or int(height) < 1:
        raise ValueError(f"image size must be positive, got {width}x{height}")
    if int(tile_size) < 1:
        raise ValueError(f"tile_size must be positive, got {tile_size}")
    if means.dim() != 2 or means.shape[-1] != 3:
        raise ValueError(f"means must be [N, 3], got {tuple(means.shape)}")
    N = means.shape[0]
    if viewmats.dim() != 3 or viewmats.shape[1:] != (4, 4) or viewmats.shape[0] < 1:
        raise ValueError(f"viewmats must be [C, 4, 4], got {tuple(viewmats.shape)}")
    C = viewmats.shape[0]
    for name, t, shape in (("quats", quats, (N, 4)), ("scales", scales, (N, 3)),
                           ("opacities", opacities, (N,)), ("Ks", Ks, (C, 3, 3))):
        if tuple(t.shape) != shape:
            raise ValueError(f"{name} must be {list(shape)}, got {tuple(t.shape)}")
    if sh_degree is None:
        if not ((colors.dim() == 2 and colors.shape[0] == N)
                or (colors.dim() == 3 and colors.shape[:2] == (C, N))):
            raise ValueError(f"colors must be [N, D] or [C, N, D] without sh_degree, "
                             f"got {tuple(colors.shape)}")
        D = colors.shape[-1]
    else:
        if not 0 <= int(sh_degree) <= 3:
            raise ValueError(f"sh_degree must be in 0..3, got {sh_degree}")
        ok = ((colors.dim() == 3 and colors.shape[0] == N)
              or (colors.dim() == 4 and colors.shape[:2] == (C, N)))
        if not ok or colors.shape[-1] != 3 or colors.shape[-2] < (int(sh_degree) + 1) ** 2:
            raise ValueError(f"colors must be SH coefficients [N, K, 3] or [C, N, K, 3] with "
                             f"K >= {(int(sh_degree) + 1) ** 2}, got {tuple(colors.shape)}")
        D = 3
    if backgrounds is not None and render_mode not in ("D", "ED"):
        if tuple(backgrounds.shape) != (C, D):
            raise ValueError(f"backgrounds must be [C, D] = [{C}, {D}], "
                             f"got {tuple(backgrounds.shape)}")
    return C, N


def rasterization(
    means: Tensor,
    quats: Tensor,
    scales: Tensor,
    opacities: Tensor,
    colors: Tensor,
    viewmats: Tensor,
    Ks: Tensor,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = DEFAULT_EPS2D,
    sh_degree: int | None = None,
    backgrounds: Tensor | None = None,
    render_mode: str = "RGB",
    rasterize_mode: str = "classic",
    tile_size: int = 16,
    absgrad: bool = False,
    backend: str = "auto",
) -> tuple[Tensor, Tensor, dict[str, Any]]:
    """Rasterize N 3D Gaussians into C images (gsplat 1.5.3 ``rasterization``, packed=False).

    Args:
        means: centres [N, 3] (world). quats: rotations [N, 4], wxyz, any norm.
        scales: standard deviations [N, 3] (not log). opacities: [N] in [0, 1].
        colors: [N, D] or [C, N, D] features; with ``sh_degree``, SH coefficients [N, K, 3] or
            [C, N, K, 3] with K >= (sh_degree + 1)^2.
        viewmats: world-to-camera [C, 4, 4]. Ks: pinhole intrinsics [C, 3, 3].
        width, height: image size in pixels.
        near_plane, far_plane: depth culling range. eps2d: 2D dilation (px^2).
        backgrounds: [C, D] colours behind the Gaussians (ignored for "D"/"ED").
        render_mode: "RGB", "D" (accumulated z), "ED" (expected z), "RGB+D", "RGB+ED".
        rasterize_mode: "classic" or "antialiased" (Mip-Splatting opacity compensation).
        tile_size: gsplat's tile size (the CPU backend always bins into 16x16 tiles; results
            do not depend on it).
        absgrad: also compute ``meta["means2d"].absgrad`` in the backward.
        backend: "auto", "cpu", "reference" or "gsplat" (see the module docstring).

    Returns:
        ``render_colors`` [C, H, W, X] (X = D, 1 or D + 1), ``render_alphas`` [C, H, W, 1] and
        ``meta`` with at least ``radii`` [C, N, 2] (int32, 0 = culled), ``means2d`` [C, N, 2],
        ``depths`` [C, N], ``conics`` [C, N, 3], ``opacities`` [C, N], ``width``, ``height``,
        ``n_cameras``, ``tile_size``, ``gaussian_ids`` (None: unpacked layout) and ``backend``.
    """
    C, N = _check(means, quats, scales, opacities, colors, viewmats, Ks, width, height,
                  sh_degree, backgrounds, render_mode, rasterize_mode, tile_size)
    dtype = means.dtype
    if dtype not in (torch.float32, torch.float64):
        raise TypeError(f"means must be float32 or float64, got {dtype}")
    device = means.device
    choice = select_backend(backend, device.type)
    args = [t.to(dtype) if t.dtype != dtype else t
            for t in (means, quats, scales, opacities, colors, viewmats, Ks)]
    bg = backgrounds.to(dtype) if backgrounds is not None and backgrounds.dtype != dtype \
        else backgrounds
    kwargs = dict(width=int(width), height=int(height), near_plane=float(near_plane),
                  far_plane=float(far_plane), eps2d=float(eps2d),
                  sh_degree=None if sh_degree is None else int(sh_degree), backgrounds=bg,
                  render_mode=render_mode, rasterize_mode=rasterize_mode,
                  tile_size=int(tile_size), absgrad=bool(absgrad))
    if choice == "gsplat":
        return _gsplat.rasterize(*args, **kwargs)
    if choice == "reference":
        from . import _reference

        return _reference.rasterize(*args, **kwargs)
    from . import _cpu

    if device.type != "cpu":
        global _warned_roundtrip
        if not _warned_roundtrip:
            import warnings

            warnings.warn(f"rasterization: {device.type} tensors without gsplat run on the CPU "
                          "kernel (host round trip); install gsplat for the GPU path",
                          stacklevel=2)
            _warned_roundtrip = True
        args = [t.cpu() for t in args]
        if bg is not None:
            kwargs["backgrounds"] = bg.cpu()
        colors_out, alphas_out, meta = _cpu.rasterize(*args, **kwargs)
        return colors_out.to(device), alphas_out.to(device), meta
    return _cpu.rasterize(*args, **kwargs)
