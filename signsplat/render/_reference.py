"""The ``reference`` backend: plain PyTorch, obvious rather than fast; the tests' oracle.

Per camera it sorts the visible Gaussians by depth, evaluates every (pixel, Gaussian) pair of a
chunk of pixels as dense [P, M] tensors, and composites with a cumulative product. Autograd
does every gradient. ``absgrad`` is gathered by hooks on the per-pair offsets ``dx, dy`` (their
gradients are exactly the per-pixel terms of d loss / d means2d).

``cull_blocks=True`` (used by the benchmark) restricts each 16x16 block of pixels to the
Gaussians whose bounding box reaches it; the tests check it changes nothing.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ._constants import ALPHA_THRESHOLD, MAX_ALPHA, TRANSMITTANCE_THRESHOLD
from ._outputs import finish, mode_backgrounds
from .projection import camera_centers, project
from .sh import sh_to_color


def composite_pixels(px: Tensor, py: Tensor, means2d: Tensor, conics: Tensor, opacities: Tensor,
                     colors: Tensor, hook=None) -> tuple[Tensor, Tensor]:
    """Colour [P, D] and final transmittance [P] of pixel centres (px, py) [P] over Gaussians
    given front to back (means2d [M, 2], conics [M, 3], opacities [M], colors [M, D])."""
    dx = means2d[None, :, 0] - px[:, None]  # gsplat: delta = mean - pixel
    dy = means2d[None, :, 1] - py[:, None]
    if hook is not None and dx.requires_grad:
        hook(dx, dy)
    a, b, c = conics[None, :, 0], conics[None, :, 1], conics[None, :, 2]
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    alpha = torch.clamp(opacities[None, :] * torch.exp(-sigma), max=MAX_ALPHA)
    valid = (sigma >= 0) & (alpha >= ALPHA_THRESHOLD)
    alpha = torch.where(valid, alpha, torch.zeros_like(alpha))
    one_minus = 1.0 - alpha
    trans = torch.cumprod(one_minus, dim=1)
    trans_before = torch.cat([torch.ones_like(trans[:, :1]), trans[:, :-1]], dim=1)
    # a pixel stops before the Gaussian that would bring it to T <= 1e-4 (and after it nothing
    # can be composited, since T only decreases)
    include = valid & (trans_before * one_minus > TRANSMITTANCE_THRESHOLD)
    weights = torch.where(include, alpha * trans_before, torch.zeros_like(alpha))
    color = weights @ colors
    t_final = torch.prod(torch.where(include, one_minus, torch.ones_like(one_minus)), dim=1)
    return color, t_final


def colors_per_camera(colors: Tensor, sh_degree: int | None, means: Tensor, viewmats: Tensor,
                      C: int, N: int) -> Tensor:
    """[C, N, D] post-activation colours from ``colors`` ([N, D], [C, N, D] or SH
    [N, K, 3] / [C, N, K, 3] when ``sh_degree`` is set)."""
    if sh_degree is None:
        return colors.expand(C, N, colors.shape[-1]) if colors.dim() == 2 else colors
    dirs = means[None, :, :] - camera_centers(viewmats)[:, None, :]  # [C, N, 3]
    coeffs = colors if colors.dim() == 4 else colors[None].expand(C, *colors.shape)
    return sh_to_color(sh_degree, dirs, coeffs)


def rasterize(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, colors: Tensor,
              viewmats: Tensor, Ks: Tensor, width: int, height: int, near_plane: float,
              far_plane: float, eps2d: float, sh_degree: int | None, backgrounds: Tensor | None,
              render_mode: str, rasterize_mode: str, tile_size: int, absgrad: bool,
              pixel_chunk: int = 4096, cull_blocks: bool = False
              ) -> tuple[Tensor, Tensor, dict]:
    C, N = viewmats.shape[0], means.shape[0]
    Ks = Ks.detach()  # like gsplat: not differentiable w.r.t. the intrinsics
    antialiased = rasterize_mode == "antialiased"
    proj = project(means, quats, scales, opacities, viewmats, Ks, width, height, eps2d=eps2d,
                   near_plane=near_plane, far_plane=far_plane, antialiased=antialiased)
    radii, means2d, depths, conics = (proj["radii"], proj["means2d"], proj["depths"],
                                      proj["conics"])
    opac = opacities[None, :] * proj["compensations"] if antialiased else \
        opacities[None, :].expand(C, N)
    if render_mode in ("D", "ED"):
        feats = depths[..., None]
    else:
        feats = colors_per_camera(colors, sh_degree, means, viewmats, C, N)
        if render_mode in ("RGB+D", "RGB+ED"):
            feats = torch.cat([feats, depths[..., None]], dim=-1)
    D = feats.shape[-1]
    bg = mode_backgrounds(backgrounds, render_mode, C, means)

    absbuf = torch.zeros(C, N, 2, dtype=means.dtype, device=means.device) if absgrad else None
    if absgrad and means2d.requires_grad:
        def _publish(grad, m2d=means2d):
            m2d.absgrad = absbuf.clone()
            absbuf.zero_()
        means2d.register_hook(_publish)

    ys, xs = torch.meshgrid(torch.arange(height, device=means.device),
                            torch.arange(width, device=means.device), indexing="ij")
    px_all = xs.reshape(-1).to(means.dtype) + 0.5
    py_all = ys.reshape(-1).to(means.dtype) + 0.5
    renders, t_finals = [], []
    for c in range(C):
        vis = torch.nonzero((radii[c] > 0).any(-1))[:, 0]
        order = torch.sort(depths[c, vis].detach(), stable=True).indices
        idx = vis[order]
        m2, con, op, col = means2d[c, idx], conics[c, idx], opac[c, idx], feats[c, idx]

        def make_hook(gidx, c=c):
            """Hook adding sum_p |d loss / d dx[p, m]| into absbuf[c, gidx[m], 0] (and y)."""
            if absbuf is None:
                return None

            def add(axis):
                def fn(g):  # returns None: the gradient itself is left unchanged
                    absbuf[c, :, axis].index_add_(0, gidx, g.abs().sum(0))
                return fn

            def hook(dx, dy):
                dx.register_hook(add(0))
                dy.register_hook(add(1))
            return hook

        if cull_blocks:
            color_img, t_img = _composite_blocks(width, height, m2, con, op, col,
                                                 radii[c, idx], idx, make_hook, means.dtype)
        else:
            parts_c, parts_t = [], []
            for s in range(0, height * width, pixel_chunk):
                cc, tt = composite_pixels(px_all[s:s + pixel_chunk], py_all[s:s + pixel_chunk],
                                          m2, con, op, col, make_hook(idx))
                parts_c.append(cc)
                parts_t.append(tt)
            color_img = torch.cat(parts_c).reshape(height, width, D)
            t_img = torch.cat(parts_t).reshape(height, width)
        if bg is not None:
            color_img = color_img + t_img[..., None] * bg[c]
        renders.append(color_img)
        t_finals.append(t_img)
    render_colors = torch.stack(renders)
    render_alphas = 1.0 - torch.stack(t_finals)[..., None]
    return finish(render_colors, render_alphas, render_mode, radii=radii, means2d=means2d,
                  depths=depths, conics=conics, opacities=opac,
                  compensations=proj["compensations"] if antialiased else None, width=width,
                  height=height, tile_size=tile_size, backend="reference")


def _composite_blocks(width, height, m2, con, op, col, radii, idx, make_hook, dtype, block=16):
    """Like the dense path, block by block, each block over the Gaussians whose bounding box
    (widened by a pixel) reaches its pixel centres."""
    D = col.shape[-1]
    dev = m2.device
    mxd, myd = m2[:, 0].detach(), m2[:, 1].detach()
    rx, ry = radii[:, 0].to(dtype) + 1.0, radii[:, 1].to(dtype) + 1.0
    rows_c, rows_t = [], []
    for y0 in range(0, height, block):
        y1 = min(height, y0 + block)
        row_c, row_t = [], []
        for x0 in range(0, width, block):
            x1 = min(width, x0 + block)
            sel = torch.nonzero((mxd + rx >= x0 + 0.5) & (mxd - rx <= x1 - 0.5)
                                & (myd + ry >= y0 + 0.5) & (myd - ry <= y1 - 0.5))[:, 0]
            if len(sel) == 0:
                row_c.append(torch.zeros(y1 - y0, x1 - x0, D, dtype=dtype, device=dev))
                row_t.append(torch.ones(y1 - y0, x1 - x0, dtype=dtype, device=dev))
                continue
            ys, xs = torch.meshgrid(torch.arange(y0, y1, device=dev),
                                    torch.arange(x0, x1, device=dev), indexing="ij")
            cc, tt = composite_pixels(xs.reshape(-1).to(dtype) + 0.5,
                                      ys.reshape(-1).to(dtype) + 0.5,
                                      m2[sel], con[sel], op[sel], col[sel], make_hook(idx[sel]))
            row_c.append(cc.reshape(y1 - y0, x1 - x0, D))
            row_t.append(tt.reshape(y1 - y0, x1 - x0))
        rows_c.append(torch.cat(row_c, 1))
        rows_t.append(torch.cat(row_t, 1))
    return torch.cat(rows_c, 0), torch.cat(rows_t, 0)
