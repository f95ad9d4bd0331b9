"""Numba kernels of the avatar (CPU tensors; generic over float32/64): barycentric interpolation
(:mod:`signsplat.avatar.interp`) and the per-point attributes (:mod:`signsplat.avatar.attributes`).

- ``bary_fwd``: parallel over points, ``out[b, p] = sum_k s w[p, k] values[b, a[p, k]]`` where
  ``s`` is 1, or with ``align``, on the first four channels, the sign of the dot product of
  the anchor's and the point's first anchor's first four channels (quaternions on one
  hemisphere).
- ``bary_bwd_values``: parallel over vertices through a vertex -> (point, corner) list sorted
  by point (``csr``), so each vertex's gradient is summed in one fixed order by one thread:
  the same bits for any thread count.
- ``bary_bwd_weights``: parallel over points.
- ``attrs_fwd`` / ``attrs_bwd``: the Gaussians' attributes of each (frame, point) from the
  canonical parameters, the pose network's residuals, the shading gain and the blended LBS
  rotation (formulas in :mod:`signsplat.avatar.attributes`), parallel over points; the
  gradients of the shared canonical parameters are summed over the frames in one order.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from signsplat.numba_cache import cache_kernels_of

cache_kernels_of(__file__)  # compiled once per content, not once per checkout


@njit(cache=True, parallel=True, error_model="numpy")
def bary_fwd(values, anchors, weights, align, out, signs):  # pragma: no cover - compiled
    nb, _, nd = values.shape
    n = anchors.shape[0]
    na = 4 if align else 0  # channels that take the anchor's sign
    for p_ in prange(n):
        p = np.int64(p_)
        for b in range(nb):
            a0 = anchors[p, 0]
            for d in range(nd):
                out[b, p, d] = 0.0
            for k in range(3):
                a = anchors[p, k]
                s = values.dtype.type(1.0)
                if align:
                    dot = values.dtype.type(0.0)
                    for d in range(4):
                        dot += values[b, a, d] * values[b, a0, d]
                    if dot < 0:
                        s = values.dtype.type(-1.0)
                signs[b, p, k] = s
                w = weights[p, k]
                for d in range(na):
                    out[b, p, d] += s * w * values[b, a, d]
                for d in range(na, nd):
                    out[b, p, d] += w * values[b, a, d]


@njit(cache=True, parallel=True, error_model="numpy")
def bary_bwd_values(grad, weights, signs, na, offsets, entries, out):  # pragma: no cover
    nb, _, nd = grad.shape
    nv = offsets.shape[0] - 1
    for v_ in prange(nv):
        v = np.int64(v_)
        for b in range(nb):
            for d in range(nd):
                out[b, v, d] = 0.0
            for e in range(offsets[v], offsets[v + 1]):
                idx = entries[e]
                p = idx // 3
                k = idx - 3 * p
                w = weights[p, k]
                ws = signs[b, p, k] * w
                for d in range(na):
                    out[b, v, d] += ws * grad[b, p, d]
                for d in range(na, nd):
                    out[b, v, d] += w * grad[b, p, d]


@njit(cache=True, parallel=True, error_model="numpy")
def bary_bwd_weights(grad, values, anchors, signs, na, out):  # pragma: no cover - compiled
    nb, _, nd = grad.shape
    n = anchors.shape[0]
    for p_ in prange(n):
        p = np.int64(p_)
        for k in range(3):
            a = anchors[p, k]
            acc = values.dtype.type(0.0)
            for b in range(nb):
                part = values.dtype.type(0.0)
                for d in range(na):
                    part += grad[b, p, d] * values[b, a, d]
                rest = values.dtype.type(0.0)
                for d in range(na, nd):
                    rest += grad[b, p, d] * values[b, a, d]
                acc += signs[b, p, k] * part + rest
            out[p, k] = acc


@njit(cache=True, parallel=True, error_model="numpy")
def attrs_fwd(scale_raw, quat, opacity_raw, sh_dc, sh_rest, heads, has_heads, gain, has_gain,
              q_blend, smax, smin, c0, scales, quats, opacities, colors):  # pragma: no cover
    nb, n = q_blend.shape[0], q_blend.shape[1]
    nr = sh_rest.shape[1]
    T = q_blend.dtype.type
    eps = T(1e-9)
    for p_ in prange(n):
        p = np.int64(p_)
        span = smax[p] - smin
        for b in range(nb):
            for k in range(3):
                x = scale_raw[p, k]
                if has_heads:
                    x += heads[b, p, k]
                scales[b, p, k] = smin + span * (T(1.0) / (T(1.0) + np.exp(-x)))
            qw, qx, qy, qz = quat[p, 0], quat[p, 1], quat[p, 2], quat[p, 3]
            if has_heads:
                qw += heads[b, p, 3]
                qx += heads[b, p, 4]
                qy += heads[b, p, 5]
                qz += heads[b, p, 6]
            nq = max(np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz), eps)
            qw, qx, qy, qz = qw / nq, qx / nq, qy / nq, qz / nq
            aw, ax, ay, az = q_blend[b, p, 0], q_blend[b, p, 1], q_blend[b, p, 2], q_blend[b, p, 3]
            na = max(np.sqrt(aw * aw + ax * ax + ay * ay + az * az), eps)
            aw, ax, ay, az = aw / na, ax / na, ay / na, az / na
            quats[b, p, 0] = aw * qw - ax * qx - ay * qy - az * qz
            quats[b, p, 1] = aw * qx + ax * qw + ay * qz - az * qy
            quats[b, p, 2] = aw * qy - ax * qz + ay * qw + az * qx
            quats[b, p, 3] = aw * qz + ax * qy - ay * qx + az * qw
            o = opacity_raw[p]
            if has_heads:
                o += heads[b, p, 7]
            opacities[b, p] = T(1.0) / (T(1.0) + np.exp(-o))
            for j in range(3):
                dc = sh_dc[p, j]
                if has_heads:
                    dc += heads[b, p, 8 + j]
                if has_gain:
                    g = gain[b, p, j]
                    colors[b, p, 0, j] = g * dc + (g - T(1.0)) * c0
                    for r in range(nr):
                        colors[b, p, 1 + r, j] = g * sh_rest[p, r, j]
                else:
                    colors[b, p, 0, j] = dc
                    for r in range(nr):
                        colors[b, p, 1 + r, j] = sh_rest[p, r, j]


@njit(cache=True, parallel=True, error_model="numpy")
def attrs_bwd(scale_raw, quat, opacity_raw, sh_dc, sh_rest, heads, has_heads, gain, has_gain,
              q_blend, smax, smin, c0, v_scales, v_quats, v_opacities, v_colors,
              g_scale_raw, g_quat, g_opacity_raw, g_sh_dc, g_sh_rest, g_heads, g_gain,
              g_q_blend):  # pragma: no cover - compiled
    nb, n = q_blend.shape[0], q_blend.shape[1]
    nr = sh_rest.shape[1]
    T = q_blend.dtype.type
    eps = T(1e-9)
    for p_ in prange(n):
        p = np.int64(p_)
        span = smax[p] - smin
        for k in range(3):
            g_scale_raw[p, k] = T(0.0)
            g_sh_dc[p, k] = T(0.0)
        for k in range(4):
            g_quat[p, k] = T(0.0)
        g_opacity_raw[p] = T(0.0)
        for r in range(nr):
            for j in range(3):
                g_sh_rest[p, r, j] = T(0.0)
        for b in range(nb):
            # scales
            for k in range(3):
                x = scale_raw[p, k]
                if has_heads:
                    x += heads[b, p, k]
                sg = T(1.0) / (T(1.0) + np.exp(-x))
                gx = v_scales[b, p, k] * span * sg * (T(1.0) - sg)
                g_scale_raw[p, k] += gx
                if has_heads:
                    g_heads[b, p, k] = gx
            # rotation: out = normalise(a) (x) normalise(q)
            qw, qx, qy, qz = quat[p, 0], quat[p, 1], quat[p, 2], quat[p, 3]
            if has_heads:
                qw += heads[b, p, 3]
                qx += heads[b, p, 4]
                qy += heads[b, p, 5]
                qz += heads[b, p, 6]
            nq_raw = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
            nq = max(nq_raw, eps)
            bw, bx, by, bz = qw / nq, qx / nq, qy / nq, qz / nq
            aw, ax, ay, az = q_blend[b, p, 0], q_blend[b, p, 1], q_blend[b, p, 2], q_blend[b, p, 3]
            na_raw = np.sqrt(aw * aw + ax * ax + ay * ay + az * az)
            na = max(na_raw, eps)
            aw, ax, ay, az = aw / na, ax / na, ay / na, az / na
            gw, gx_, gy, gz = (v_quats[b, p, 0], v_quats[b, p, 1], v_quats[b, p, 2],
                               v_quats[b, p, 3])
            gaw = gw * bw + gx_ * bx + gy * by + gz * bz
            gax = -gw * bx + gx_ * bw - gy * bz + gz * by
            gay = -gw * by + gx_ * bz + gy * bw - gz * bx
            gaz = -gw * bz - gx_ * by + gy * bx + gz * bw
            gbw = gw * aw + gx_ * ax + gy * ay + gz * az
            gbx = -gw * ax + gx_ * aw + gy * az - gz * ay
            gby = -gw * ay - gx_ * az + gy * aw + gz * ax
            gbz = -gw * az + gx_ * ay - gy * ax + gz * aw
            # through the normalisations (a constant denominator where the clamp holds)
            if na_raw > eps:
                dot = gaw * aw + gax * ax + gay * ay + gaz * az
                gaw, gax, gay, gaz = ((gaw - aw * dot) / na, (gax - ax * dot) / na,
                                      (gay - ay * dot) / na, (gaz - az * dot) / na)
            else:
                gaw, gax, gay, gaz = gaw / na, gax / na, gay / na, gaz / na
            g_q_blend[b, p, 0] = gaw
            g_q_blend[b, p, 1] = gax
            g_q_blend[b, p, 2] = gay
            g_q_blend[b, p, 3] = gaz
            if nq_raw > eps:
                dot = gbw * bw + gbx * bx + gby * by + gbz * bz
                gbw, gbx, gby, gbz = ((gbw - bw * dot) / nq, (gbx - bx * dot) / nq,
                                      (gby - by * dot) / nq, (gbz - bz * dot) / nq)
            else:
                gbw, gbx, gby, gbz = gbw / nq, gbx / nq, gby / nq, gbz / nq
            g_quat[p, 0] += gbw
            g_quat[p, 1] += gbx
            g_quat[p, 2] += gby
            g_quat[p, 3] += gbz
            if has_heads:
                g_heads[b, p, 3] = gbw
                g_heads[b, p, 4] = gbx
                g_heads[b, p, 5] = gby
                g_heads[b, p, 6] = gbz
            # opacity
            o = opacity_raw[p]
            if has_heads:
                o += heads[b, p, 7]
            so = T(1.0) / (T(1.0) + np.exp(-o))
            go = v_opacities[b, p] * so * (T(1.0) - so)
            g_opacity_raw[p] += go
            if has_heads:
                g_heads[b, p, 7] = go
            # colours
            for j in range(3):
                gc = v_colors[b, p, 0, j]
                if has_gain:
                    g = gain[b, p, j]
                    dc = sh_dc[p, j]
                    if has_heads:
                        dc += heads[b, p, 8 + j]
                    acc = gc * (dc + c0)
                    for r in range(nr):
                        gr = v_colors[b, p, 1 + r, j]
                        acc += gr * sh_rest[p, r, j]
                        g_sh_rest[p, r, j] += g * gr
                    g_gain[b, p, j] = acc
                    gc = gc * g
                else:
                    for r in range(nr):
                        g_sh_rest[p, r, j] += v_colors[b, p, 1 + r, j]
                g_sh_dc[p, j] += gc
                if has_heads:
                    g_heads[b, p, 8 + j] = gc


def vertex_lists(anchors: np.ndarray, num_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """(offsets (V+1,), entries (3P,)): for vertex v, ``entries[offsets[v]:offsets[v+1]]`` are
    the flat indices ``3 p + k`` with ``anchors[p, k] == v``, in increasing order."""
    flat = anchors.reshape(-1)
    entries = np.argsort(flat, kind="stable").astype(np.int64)
    counts = np.bincount(flat, minlength=num_vertices)
    offsets = np.zeros(num_vertices + 1, np.int64)
    np.cumsum(counts, out=offsets[1:])
    return offsets, entries
