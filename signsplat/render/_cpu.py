"""The ``cpu`` backend: the Numba kernels of :mod:`._kernels` behind ``torch.autograd.Function``s.

The graph mirrors gsplat's (packed=False): projection -> (SH colours) -> tile binning ->
compositing, so ``meta["means2d"]`` is a real intermediate tensor [C, N, 2] whose ``.grad`` is
available after ``retain_grad()``, and whose ``.absgrad`` is set by the compositing backward when
``absgrad=True``.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import torch
from torch import Tensor

from . import _kernels as K
from ._constants import CPU_TILE
from ._outputs import finish, mode_backgrounds
from .projection import camera_centers


def _np(t: Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


def _dtype_class(dtype: torch.dtype):
    return np.float64 if dtype == torch.float64 else np.float32


def _n_threads(T) -> int:
    """Threads a kernel variant may use (float64 variants are serial)."""
    return numba.get_num_threads() if T is np.float32 else 1


def tile_schedule(costs: np.ndarray, n_threads: int) -> np.ndarray:
    """The order in which the compositing kernels visit the tiles (int64 indices).

    Numba's OpenMP layer splits a ``prange`` into ``n_threads`` contiguous blocks of equal
    length, whatever ``parallel_chunksize`` says, so the order decides each thread's share.
    Tiles are taken heaviest first (``costs``: the length of each tile's list) and dealt to
    the blocks in snake order (0, 1, ..., n-1, n-1, ..., 0, 0, ...); the lightest ``m % n``
    go one each to the first blocks, which are one longer when ``n`` does not divide ``m``
    (as OpenMP's static split). Each block keeps its tiles heaviest first. Every tile is
    composited on its own, so the order changes no output.
    """
    order = np.argsort(-costs, kind="stable")
    m = len(order)
    n = max(1, min(int(n_threads), m))
    if n == 1:
        return order.astype(np.int64)
    turn, seat = np.divmod(np.arange(m), n)
    block = np.where(turn % 2 == 0, seat, n - 1 - seat)
    block[m - m % n:] = np.arange(m % n)
    return order[np.argsort(block, kind="stable")].astype(np.int64)


# ----------------------------------------------------------------------------- projection
class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, opacities, viewmats, Ks, width, height, eps2d,
                near_plane, far_plane, antialiased):
        T = _dtype_class(means.dtype)
        C, N = viewmats.shape[0], means.shape[0]
        radii = np.empty((C * N, 2), np.int32)
        means2d = np.empty((C * N, 2), T)
        depths = np.empty(C * N, T)
        conics = np.empty((C * N, 3), T)
        comps = np.empty(C * N, T)
        K.project_fwd[T](_np(means), _np(quats), _np(scales), _np(opacities), _np(viewmats),
                      _np(Ks), int(width), int(height), float(eps2d), float(near_plane),
                      float(far_plane), bool(antialiased), T, radii, means2d, depths, conics,
                      comps)
        radii_t = torch.from_numpy(radii).view(C, N, 2)
        conics_t = torch.from_numpy(conics).view(C, N, 3)
        comps_t = torch.from_numpy(comps).view(C, N)
        ctx.save_for_backward(means, quats, scales, viewmats, Ks, radii_t, conics_t, comps_t)
        ctx.cfg = (int(width), int(height), float(eps2d), bool(antialiased))
        ctx.mark_non_differentiable(radii_t)
        return (radii_t, torch.from_numpy(means2d).view(C, N, 2),
                torch.from_numpy(depths).view(C, N), conics_t, comps_t)

    @staticmethod
    def backward(ctx, _v_radii, v_means2d, v_depths, v_conics, v_comps):
        means, quats, scales, viewmats, Ks, radii, conics, comps = ctx.saved_tensors
        width, height, eps2d, antialiased = ctx.cfg
        T = _dtype_class(means.dtype)
        C, N = viewmats.shape[0], means.shape[0]

        def grad_or_zeros(g, shape):
            return _np(g).reshape(shape) if g is not None else np.zeros(shape, T)

        nt = _n_threads(T)
        want_view = ctx.needs_input_grad[4]
        v_means = np.empty((N, 3), T)
        v_quats = np.empty((N, 4), T)
        v_scales = np.empty((N, 3), T)
        v_view_buf = np.zeros((nt if want_view else 1, C, 12), T)
        K.project_bwd[T](_np(means), _np(quats), _np(scales), _np(viewmats), _np(Ks), width,
                      height, eps2d, antialiased, T, _np(radii).reshape(C * N, 2),
                      _np(conics).reshape(C * N, 3), _np(comps).reshape(C * N),
                      grad_or_zeros(v_means2d, (C * N, 2)), grad_or_zeros(v_depths, (C * N,)),
                      grad_or_zeros(v_conics, (C * N, 3)), grad_or_zeros(v_comps, (C * N,)),
                      want_view, nt, v_means, v_quats, v_scales, v_view_buf)
        v_view = None
        if want_view:
            v_view = torch.zeros(C, 4, 4, dtype=means.dtype)
            v_view[:, :3, :] = torch.from_numpy(v_view_buf.sum(0)).view(C, 3, 4)
        return (torch.from_numpy(v_means), torch.from_numpy(v_quats),
                torch.from_numpy(v_scales), None, v_view, None, None, None, None, None, None,
                None)


# ----------------------------------------------------------------------------- SH colours
class _SHColors(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, campos, coeffs, degree, radii):
        T = _dtype_class(means.dtype)
        C, N = campos.shape[0], means.shape[0]
        per_camera = coeffs.dim() == 4
        co = _np(coeffs).reshape((C * N) if per_camera else N, coeffs.shape[-2], 3)
        out = np.empty((C * N, 3), T)
        rad = _np(radii).reshape(C * N, 2)
        K.sh_fwd[T](int(degree), co, per_camera, _np(means), _np(campos), rad, T, out)
        colors = torch.from_numpy(out).view(C, N, 3)
        ctx.save_for_backward(means, campos, coeffs, radii, colors)
        ctx.degree = int(degree)
        return colors

    @staticmethod
    def backward(ctx, v_colors):
        means, campos, coeffs, radii, colors = ctx.saved_tensors
        T = _dtype_class(means.dtype)
        C, N = campos.shape[0], means.shape[0]
        per_camera = coeffs.dim() == 4
        Kc = coeffs.shape[-2]
        co = _np(coeffs).reshape((C * N) if per_camera else N, Kc, 3)
        v_co = np.empty_like(co)
        v_dirs = np.empty((C * N, 3), T)
        K.sh_bwd[T](ctx.degree, co, per_camera, _np(means), _np(campos),
                 _np(radii).reshape(C * N, 2), T, _np(colors).reshape(C * N, 3),
                 _np(v_colors).reshape(C * N, 3), v_co, v_dirs)
        vd = torch.from_numpy(v_dirs).view(C, N, 3)
        return vd.sum(0), -vd.sum(1), torch.from_numpy(v_co).view(coeffs.shape), None, None


# ----------------------------------------------------------------------------- binning
def bin_gaussians(means2d: np.ndarray, radii: np.ndarray, depths: np.ndarray, C: int, N: int,
                  tiles_x: int, tiles_y: int, tile_size: int = CPU_TILE
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Per-tile lists of flat (camera * N + gaussian) ids, each sorted front to back (ties by
    Gaussian index). Returns ``offsets`` [C * tiles + 1] (int64) and ``flat_ids`` (int32)."""
    CN = C * N
    rects = np.empty((CN, 4), np.int32)
    if CN:
        T = np.float64 if means2d.dtype == np.float64 else np.float32
        K.tile_rects[T](means2d.reshape(CN, 2), radii.reshape(CN, 2), tile_size, tiles_x,
                        tiles_y, rects)
    vis = np.flatnonzero((rects[:, 1] > rects[:, 0]) & (rects[:, 3] > rects[:, 2]))
    cam = vis // max(N, 1)
    cam_start = np.searchsorted(vis, np.arange(C + 1, dtype=np.int64) * N).astype(np.int64)
    d = depths.reshape(CN)[vis]
    if (d.dtype == np.float32 and N < (1 << 26) and C < 64
            and (len(d) == 0 or d.min() > 0)):
        # one integer sort: camera | positive-float depth bits (order-preserving) | gaussian id
        key = ((cam.astype(np.uint64) << np.uint64(57))
               | (d.view(np.uint32).astype(np.uint64) << np.uint64(26))
               | (vis - cam * N).astype(np.uint64))
        key.sort()
        order = (key >> np.uint64(57)).astype(np.int64) * N + \
            (key & np.uint64((1 << 26) - 1)).astype(np.int64)
    else:
        order = vis[np.lexsort((vis, d, cam))]
    nt = tiles_x * tiles_y
    counts = np.empty(C * nt, np.int64)
    # bands of tile rows scanned in parallel (each band scans its camera's Gaussians once)
    bands = max(1, min(tiles_y, math.ceil(numba.get_num_threads() / max(C, 1))))
    K.bin_count[np.float32](order, cam_start, rects, tiles_x, tiles_y, bands, counts)
    offsets = np.zeros(C * nt + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    flat_ids = np.empty(int(offsets[-1]), np.int32)
    K.bin_fill[np.float32](order, cam_start, rects, tiles_x, tiles_y, bands, offsets, flat_ids)
    return offsets, flat_ids


# ----------------------------------------------------------------------------- compositing
class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, backgrounds, radii, depths, width,
                height, absgrad, info):
        T = _dtype_class(means2d.dtype)
        C, N = means2d.shape[:2]
        D = colors.shape[-1]
        tiles_x = math.ceil(width / CPU_TILE)
        tiles_y = math.ceil(height / CPU_TILE)
        m2 = _np(means2d).reshape(C * N, 2)
        rad = _np(radii).reshape(C * N, 2)
        offsets, flat_ids = bin_gaussians(m2, rad, _np(depths), C, N, tiles_x, tiles_y)
        shared = colors.stride(0) == 0 and C > 1 or C == 1
        col = _np(colors[0]) if shared else _np(colors).reshape(C * N, D)
        per_cam = not shared
        con = _np(conics).reshape(C * N, 3)
        op = _np(opacities).reshape(C * N)
        has_bg = backgrounds is not None
        bg = _np(backgrounds) if has_bg else np.zeros((C, D), T)
        out_color = np.empty((C, height, width, D), T)
        out_T = np.empty((C, height, width), T)
        out_last = np.empty((C, height, width), np.int32)
        pairs = np.zeros(C * tiles_x * tiles_y, np.int64)
        isect_rows = np.zeros((len(flat_ids), 2), np.uint8)
        row_par = np.empty((C * N, 2), np.float64)
        K.raster_params[T](con, op, rad, T, row_par)
        tile_order = tile_schedule(np.diff(offsets), _n_threads(T))
        K.raster_fwd[T](m2, con, col, per_cam, op, rad, bg, has_bg, offsets, flat_ids, N,
                        width, height, tiles_x, tiles_y, T, out_color, out_T, out_last,
                        pairs, isect_rows, tile_order, row_par)
        if info is not None:
            info["n_isects"] = int(len(flat_ids))
            info["pairs_forward"] = int(pairs.sum())
        ctx.arrays = (m2, con, col, per_cam, op, rad, bg, has_bg, offsets, flat_ids, out_T,
                      out_last, tiles_x, tiles_y, isect_rows, tile_order)
        ctx.cfg = (C, N, D, width, height, absgrad)
        ctx.save_for_backward(means2d)
        render = torch.from_numpy(out_color)
        alphas = 1.0 - torch.from_numpy(out_T)[..., None]
        return render, alphas

    @staticmethod
    def backward(ctx, v_render, v_alphas):
        (means2d,) = ctx.saved_tensors
        (m2, con, col, per_cam, op, rad, bg, has_bg, offsets, flat_ids, out_T, out_last,
         tiles_x, tiles_y, isect_rows, tile_order) = ctx.arrays
        C, N, D, width, height, absgrad = ctx.cfg
        T = _dtype_class(means2d.dtype)
        vr = _np(v_render) if v_render is not None else np.zeros((C, height, width, D), T)
        va = _np(v_alphas)[..., 0] if v_alphas is not None else np.zeros((C, height, width), T)
        KK = 8 + D
        gbuf = np.zeros((len(flat_ids), KK), T)  # one row per (tile, Gaussian) intersection
        K.raster_bwd[T](m2, con, col, per_cam, op, rad, bg, has_bg, offsets, flat_ids, N,
                        width, height, tiles_x, tiles_y, T, out_T, out_last, isect_rows, vr,
                        va, gbuf, tile_order)
        red = np.zeros((C * N, KK), T)
        K.reduce_isects(gbuf, flat_ids, red)
        red_t = torch.from_numpy(red)
        v_means2d = red_t[:, 0:2].reshape(C, N, 2)
        v_conics = red_t[:, 2:5].reshape(C, N, 3)
        v_op = red_t[:, 5].reshape(C, N)
        v_colors = red_t[:, 6:6 + D].reshape(C, N, D)
        if absgrad:
            means2d.absgrad = red_t[:, 6 + D:8 + D].reshape(C, N, 2).clone()
        v_bg = None
        if ctx.needs_input_grad[4]:
            tfin = torch.from_numpy(out_T)
            v_bg = (torch.from_numpy(vr) * tfin[..., None]).sum((1, 2))
        return (v_means2d, v_conics, v_colors, v_op, v_bg, None, None, None, None, None, None)


# ----------------------------------------------------------------------------- pipeline
def rasterize(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
              viewmats: Tensor, Ks: Tensor, width: int, height: int, near_plane: float,
              far_plane: float, eps2d: float, sh_degree: int | None,
              backgrounds: Tensor | None, render_mode: str, rasterize_mode: str,
              tile_size: int, absgrad: bool) -> tuple[Tensor, Tensor, dict[str, Any]]:
    C, N = viewmats.shape[0], means.shape[0]
    antialiased = rasterize_mode == "antialiased"
    radii, means2d, depths, conics, comps = _Project.apply(
        means, quats, scales, opacities, viewmats, Ks, width, height, eps2d, near_plane,
        far_plane, antialiased)
    opac = opacities[None, :] * comps if antialiased else opacities[None, :].expand(C, N)
    if render_mode in ("D", "ED"):
        feats = depths[..., None]
    else:
        if sh_degree is None:
            feats = colors if colors.dim() == 3 else colors[None].expand(C, N, colors.shape[-1])
        else:
            feats = _SHColors.apply(means, camera_centers(viewmats), colors, sh_degree, radii)
        if render_mode in ("RGB+D", "RGB+ED"):
            if feats.dim() == 3 and feats.stride(0) == 0:
                feats = feats.contiguous()
            feats = torch.cat([feats, depths[..., None]], dim=-1)
    bg = mode_backgrounds(backgrounds, render_mode, C, means)
    info: dict[str, Any] = {}
    render_colors, render_alphas = _Rasterize.apply(means2d, conics, feats, opac, bg, radii,
                                                    depths, width, height, absgrad, info)
    return finish(render_colors, render_alphas, render_mode, radii=radii, means2d=means2d,
                  depths=depths, conics=conics, opacities=opac,
                  compensations=comps if antialiased else None, width=width, height=height,
                  tile_size=tile_size, n_isects=info.get("n_isects", 0),
                  n_pairs=info.get("pairs_forward", 0), backend="cpu")
