"""The Gaussians' attributes of each (frame, point), from the canonical parameters (one fused step).

For B frames and P points, with the pose network's residuals ``heads`` (B, P, 11: scale 3,
rotation 4, opacity 1, colour 3; absent = zero), the shading gain (B, P, 3; absent = 1) and
each point's blended LBS rotation ``q_blend`` (B, P, 4, any norm):

- ``scales = smin + (smax - smin) sigmoid(scale_raw + d_s)`` (bounded per part by ``smax``);
- ``quats = n(q_blend) (x) n(quat + d_q)``, ``n(q) = q / max(|q|, 1e-9)``, Hamilton product,
  (w, x, y, z);
- ``opacities = sigmoid(opacity_raw + d_o)``;
- ``colors``: SH coefficients with the colour residual added to the DC term and the decoded
  colour multiplied by the gain: ``dc' = g (dc + d_c) + (g - 1) 0.5 / SH_C0``,
  ``rest' = g rest`` (the rasterizer decodes ``SH_C0 dc + 0.5 + sum rest Y``).

:func:`point_attributes` runs a Numba kernel forward and backward on CPU tensors (about twenty
elementwise PyTorch operations and their backward in one pass over the points);
:func:`point_attributes_torch` is the same in PyTorch operations (other devices, and the tests'
oracle).
"""

from __future__ import annotations

import numpy as np
import torch

SH_C0 = 0.28209479177387814  # Y_0^0; gsplat colour = SH_C0 * f_dc + 0.5 (+ higher bands)
HEADS = (3, 4, 1, 3)  # pose-network residuals: scale, rotation, opacity, colour


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of (..., 4) quaternions in (w, x, y, z) order."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw], -1)


def _normalise(q: torch.Tensor) -> torch.Tensor:
    return q / q.norm(dim=-1, keepdim=True).clamp_min(1e-9)


def point_attributes_torch(scale_raw, quat, opacity_raw, sh_dc, sh_rest, heads, gain, q_blend,
                           smax, smin: float):
    """See the module docstring. scale_raw (P, 3), quat (P, 4), opacity_raw (P,), sh_dc (P, 3),
    sh_rest (P, R, 3), heads (B, P, 11) or None, gain (B, P, 3) or None, q_blend (B, P, 4),
    smax (P,). Returns scales (B, P, 3), quats (B, P, 4), opacities (B, P),
    colors (B, P, R + 1, 3)."""
    b = q_blend.shape[0]
    if heads is not None:
        d_s, d_q, d_o, d_c = heads.split(HEADS, -1)
        scale_raw, quat = scale_raw + d_s, quat + d_q
        opacity_raw, sh_dc = opacity_raw + d_o[..., 0], sh_dc + d_c
    if gain is not None:
        sh_dc = gain * sh_dc + (gain - 1.0) * (0.5 / SH_C0)
        sh_rest = gain[:, :, None] * sh_rest
    sh_dc, sh_rest = sh_dc.expand(b, -1, -1), sh_rest.expand(b, -1, -1, -1)
    colors = torch.cat([sh_dc[:, :, None], sh_rest], 2)
    scales = (smin + (smax[:, None] - smin) * torch.sigmoid(scale_raw)).expand(b, -1, -1)
    quats = quat_mul(_normalise(q_blend), _normalise(quat).expand(b, -1, -1))
    return scales, quats, torch.sigmoid(opacity_raw).expand(b, -1), colors


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


class _PointAttributes(torch.autograd.Function):
    @staticmethod
    def forward(ctx, scale_raw, quat, opacity_raw, sh_dc, sh_rest, heads, gain, q_blend, smax,
                smin):
        from signsplat.avatar import _kernels as K

        T = np.float64 if q_blend.dtype == torch.float64 else np.float32
        b, p = q_blend.shape[:2]
        r = sh_rest.shape[1]
        arrays = [_np(t) for t in (scale_raw, quat, opacity_raw, sh_dc, sh_rest)]
        hd = _np(heads) if heads is not None else np.zeros((1, 1, 11), T)
        gn = _np(gain) if gain is not None else np.zeros((1, 1, 3), T)
        rest = (hd, heads is not None, gn, gain is not None, _np(q_blend), _np(smax), T(smin),
                T(0.5 / SH_C0))
        out = (np.empty((b, p, 3), T), np.empty((b, p, 4), T), np.empty((b, p), T),
               np.empty((b, p, r + 1, 3), T))
        K.attrs_fwd(*arrays, *rest, *out)
        ctx.arrays = (arrays, rest)
        return tuple(torch.from_numpy(o) for o in out)

    @staticmethod
    def backward(ctx, v_scales, v_quats, v_opacities, v_colors):
        from signsplat.avatar import _kernels as K

        arrays, rest = ctx.arrays
        hd, has_heads, gn, has_gain, qb = rest[:5]
        b, p = qb.shape[:2]
        T = qb.dtype.type
        r = arrays[4].shape[1]

        def grad(g, shape):
            return _np(g) if g is not None else np.zeros(shape, T)

        v = (grad(v_scales, (b, p, 3)), grad(v_quats, (b, p, 4)), grad(v_opacities, (b, p)),
             grad(v_colors, (b, p, r + 1, 3)))
        g = [np.empty_like(a) for a in arrays] + [np.empty_like(hd), np.empty_like(gn),
                                                   np.empty_like(qb)]
        K.attrs_bwd(*arrays, *rest, *v, *g)
        g_heads = torch.from_numpy(g[5]) if has_heads else None
        g_gain = torch.from_numpy(g[6]) if has_gain else None
        return (*(torch.from_numpy(x) for x in g[:5]), g_heads, g_gain, torch.from_numpy(g[7]),
                None, None)


def point_attributes(scale_raw, quat, opacity_raw, sh_dc, sh_rest, heads, gain, q_blend, smax,
                     smin: float):
    """The attributes (see the module docstring and :func:`point_attributes_torch` for shapes);
    differentiable in every tensor but ``smax``."""
    if q_blend.device.type == "cpu" and q_blend.dtype in (torch.float32, torch.float64):
        return _PointAttributes.apply(scale_raw, quat, opacity_raw, sh_dc, sh_rest, heads, gain,
                                      q_blend, smax, smin)
    return point_attributes_torch(scale_raw, quat, opacity_raw, sh_dc, sh_rest, heads, gain,
                                  q_blend, smax, smin)
