"""Barycentric interpolation of per-vertex values to the avatar's points, with its own backward.

Every point of the avatar is a convex combination of three mesh vertices, so its position,
rotation and the per-vertex network outputs are ``out[b, p] = sum_k w[p, k] v[b, a[p, k]]``.
Written as ``(v[:, a] * w[..., None]).sum(2)``, autograd keeps a (B, P, 3, D) gather, reduces
over a short middle axis and back-propagates the gather with a sorting scatter (the
deterministic kernel), which made it a large part of a training step. Here:

- CPU tensors: Numba kernels (:mod:`._kernels`), parallel over points forward and over
  vertices backward (each vertex's gradient summed in one fixed order, through a
  vertex -> (point, corner) list cached per ``anchors`` tensor): the same bits for any thread
  count.
- other devices: the three anchors gathered as rows of a vertex-major copy, summed with fused
  multiply-adds; the backward adds rows with ``index_add_``.

``align`` takes each anchor's quaternion (the first four channels; the others as they are) on
the hemisphere of the point's first anchor's (no gradient through that choice of sign). Values are the plain formula's
up to rounding (tests/avatar/test_interp.py).
"""

from __future__ import annotations

import weakref

import numpy as np
import torch

from signsplat.avatar import _kernels as K

# id(anchors) -> (weak reference to it, its version, number of vertices, offsets, entries)
_LISTS: dict[int, tuple] = {}


def _vertex_lists(anchors: torch.Tensor, num_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    hit = _LISTS.get(id(anchors))
    if hit is not None and hit[0]() is anchors and hit[1] == anchors._version \
            and hit[2] == num_vertices:
        return hit[3], hit[4]
    offsets, entries = K.vertex_lists(anchors.contiguous().numpy(), num_vertices)
    for key in [k for k, v in _LISTS.items() if v[0]() is None]:  # tensors gone since
        del _LISTS[key]
    _LISTS[id(anchors)] = (weakref.ref(anchors), anchors._version, num_vertices, offsets,
                           entries)
    return offsets, entries


def _np(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy()


class _BarycentricCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, values, anchors, weights, align):
        b, v, d = values.shape
        vals = _np(values)
        out = np.empty((b, anchors.shape[0], d), vals.dtype)
        signs = np.empty((b, anchors.shape[0], 3), vals.dtype)
        K.bary_fwd(vals, _np(anchors), _np(weights), bool(align), out, signs)
        ctx.arrays = (vals, signs, 4 if align else 0)
        ctx.save_for_backward(anchors, weights)
        return torch.from_numpy(out)

    @staticmethod
    def backward(ctx, grad):
        anchors, weights = ctx.saved_tensors
        vals, signs, na = ctx.arrays
        g = _np(grad)
        g_values = g_weights = None
        if ctx.needs_input_grad[0]:
            offsets, entries = _vertex_lists(anchors, vals.shape[1])
            out = np.empty_like(vals)
            K.bary_bwd_values(g, _np(weights), signs, na, offsets, entries, out)
            g_values = torch.from_numpy(out)
        if ctx.needs_input_grad[2]:
            out = np.empty((anchors.shape[0], 3), vals.dtype)
            K.bary_bwd_weights(g, vals, _np(anchors), signs, na, out)
            g_weights = torch.from_numpy(out)
        return g_values, None, g_weights, None


class _Barycentric(torch.autograd.Function):
    @staticmethod
    def forward(ctx, values: torch.Tensor, anchors: torch.Tensor, weights: torch.Tensor):
        b, v, d = values.shape
        p = anchors.shape[0]
        rows = values.transpose(0, 1).reshape(v, b * d)  # vertex-major (V, B*D)
        gathered = [rows.index_select(0, anchors[:, k]) for k in range(3)]  # (P, B*D) each
        w = _point_major(weights, b)  # (P, B|1, 3)
        out = gathered[0].view(p, b, d) * w[..., 0:1]
        for k in (1, 2):
            out.addcmul_(gathered[k].view(p, b, d), w[..., k:k + 1])
        ctx.save_for_backward(anchors, weights)
        ctx.gathered = gathered if ctx.needs_input_grad[2] else None
        ctx.shape = (b, v, d)
        return out.transpose(0, 1)  # (B, P, D), a view of the point-major result

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        anchors, weights = ctx.saved_tensors
        b, v, d = ctx.shape
        p = anchors.shape[0]
        g = grad.transpose(0, 1).reshape(p, b, d)  # point-major
        w = _point_major(weights, b)
        g_values = g_weights = None
        if ctx.needs_input_grad[0]:
            acc = grad.new_zeros(v, b * d)
            for k in range(3):
                acc.index_add_(0, anchors[:, k], (g * w[..., k:k + 1]).reshape(p, b * d))
            g_values = acc.view(v, b, d).transpose(0, 1)
        if ctx.needs_input_grad[2]:
            per = [(g * ctx.gathered[k].view(p, b, d)).sum(-1) for k in range(3)]  # (P, B)
            gw = torch.stack(per, -1)  # (P, B, 3)
            g_weights = gw.sum(1) if weights.dim() == 2 else gw.transpose(0, 1)
            if weights.dim() == 3 and weights.shape[0] == 1:
                g_weights = g_weights.sum(0, keepdim=True)
        return g_values, None, g_weights


def _point_major(weights: torch.Tensor, b: int) -> torch.Tensor:
    """(P, 3) or (B|1, P, 3) weights as (P, B|1, 3)."""
    if weights.dim() == 2:
        return weights[:, None]
    return weights.transpose(0, 1)


def barycentric(values: torch.Tensor, anchors: torch.Tensor, weights: torch.Tensor,
                align: bool = False) -> torch.Tensor:
    """(B, P, D) = sum_k s weights[p, k] * values[b, anchors[p, k]].

    values (B, V, D) float; anchors (P, 3) int64 vertex indices (repeats allowed); weights
    (P, 3), same dtype as values. ``s`` is 1, or with ``align`` (D >= 4), on the first four
    channels, the sign that puts the anchor's first four channels on the hemisphere of the
    first anchor's. Differentiable in values and weights.
    """
    if values.dim() != 3 or anchors.dim() != 2 or anchors.shape[1] != 3 or \
            weights.shape != anchors.shape:
        raise ValueError(f"values must be (B, V, D), anchors and weights (P, 3), got "
                         f"{tuple(values.shape)}, {tuple(anchors.shape)}, {tuple(weights.shape)}")
    if align and values.shape[-1] < 4:
        raise ValueError("align needs four channels (a quaternion) first")
    weights = weights.to(values.dtype)
    if values.device.type == "cpu" and values.dtype in (torch.float32, torch.float64):
        return _BarycentricCPU.apply(values, anchors, weights, align)
    return barycentric_torch(values, anchors, weights, align)


def barycentric_torch(values: torch.Tensor, anchors: torch.Tensor, weights: torch.Tensor,
                      align: bool = False) -> torch.Tensor:
    """:func:`barycentric` in PyTorch operations (any device; the path off the CPU)."""
    if not align:
        return _Barycentric.apply(values, anchors, weights)
    q = values[..., :4]
    with torch.no_grad():
        q0 = q.index_select(1, anchors[:, 0])
        sign = torch.stack([torch.where((q.index_select(1, anchors[:, k]) * q0).sum(-1) < 0,
                                        -1.0, 1.0) for k in range(3)], -1).to(values.dtype)
    out = _Barycentric.apply(q, anchors, weights * sign)  # weights (P, 3) * (B, P, 3)
    if values.shape[-1] == 4:
        return out
    return torch.cat([out, _Barycentric.apply(values[..., 4:], anchors, weights)], -1)
