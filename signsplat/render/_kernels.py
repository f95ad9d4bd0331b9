"""Numba kernels of the CPU backend: projection, SH colours, tile binning, compositing, backward.

Every kernel is compiled with ``cache=True`` (:mod:`signsplat.numba_cache` has the cache location)
and is generic over the float type: the caller passes ``T`` = ``np.float32`` or ``np.float64``
and every literal is written ``T(...)`` so float32 inputs are computed in float32 throughout
(Numba would otherwise promote ``float32 * 0.5`` to float64).

The projection formulas are :mod:`._ewa`'s, the same source the PyTorch reference
(:mod:`.projection`) runs on tensors, so the floating-point operations and their order are the
same and projected means agree bit for bit; this matters because a one-ulp shift of a sharp
Gaussian's centre changes pixels by ~1e-4.

Parallel layout (``prange``):
- projection / SH: over (camera, Gaussian) or over Gaussians (backward, to reduce without races);
- binning: over bands of tile rows, each band scanning the depth-sorted Gaussians;
- compositing forward and backward: over (camera, tile), in the order ``tile_order`` gives
  (``_cpu.tile_schedule``: one equal share of work per thread's block); the backward sums the
  per-pixel terms of each Gaussian inside the tile and writes the tile's total to the row of
  that (tile, Gaussian) intersection, and the rows are then added up per Gaussian in
  intersection order, serially: the sums do not depend on which thread took which tile, so
  gradients are the same bit for bit from run to run and for any thread count. Nothing per
  (pixel, Gaussian) is stored.
"""

from __future__ import annotations

import math
import types as pytypes
from pathlib import Path

import numba
import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic, overload

from signsplat.numba_cache import cache_kernels_of

from . import _ewa
from ._constants import (
    ALPHA_THRESHOLD,
    CPU_TILE,
    DIR_EPS2,
    MAX_ALPHA,
    MAX_EXTENT_SIGMA,
    MAX_RADIUS,
    QUAT_EPS2,
    TRANSMITTANCE_THRESHOLD,
)

# cached by content, recompiled when these kernels, their shared formulas or constants change
CACHE_DIR = cache_kernels_of(__file__, _ewa.__file__, Path(__file__).with_name("_constants.py"))

TILE = CPU_TILE  # compile-time constant: the pixel loop is exactly one 16-lane row


def _renamed(fn, suffix: str):
    """A copy of ``fn`` with another (qual)name, so Numba caches it in files of its own."""
    g = pytypes.FunctionType(fn.__code__, fn.__globals__, fn.__name__ + suffix,
                             fn.__defaults__, fn.__closure__)
    g.__qualname__ = fn.__qualname__ + suffix
    g.__module__ = fn.__module__
    g.__doc__ = fn.__doc__
    return g


class Kernel:
    """A kernel compiled twice: ``parallel=True`` for float32 (the fast path) and serially for
    float64 (gradcheck and tests only; it compiles in about half the time). ``K.name[T](...)``
    picks the variant for the float type ``T``."""

    def __init__(self, fn, fastmath=False):
        self.py_func = fn
        # error_model="numpy": no ZeroDivisionError checks (their branches stop vectorisation)
        self.parallel = njit(cache=True, parallel=True, fastmath=fastmath,
                             error_model="numpy")(fn)
        self.serial = njit(cache=True, fastmath=fastmath, error_model="numpy")(
            _renamed(fn, "__serial"))
        self.__doc__ = fn.__doc__

    def __getitem__(self, T):
        return self.parallel if T is np.float32 else self.serial


def kernel(fn) -> Kernel:
    return Kernel(fn)


def kernel_fastmath(fn) -> Kernel:
    """Like :func:`kernel`, allowing LLVM to reassociate float additions (vectorised sums)."""
    return Kernel(fn, fastmath={"reassoc"})

# ----------------------------------------------------------------------------- exp(-s), float32
# A branch-free exp(-s) that LLVM vectorises (libm's expf is not vectorised without SVML):
# Cephes' expf range reduction and degree-5 minimax polynomial, then 2^-n by building the float's
# exponent bits. Max relative error 1.4 ulp on [0, 80]; s is clamped to [0, 80] (exp(-80) is far
# below any threshold used here). float64 uses math.exp.

_F32_LOG2E = np.float32(1.44269504088896341)
_F32_C1 = np.float32(0.693359375)
_F32_C2 = np.float32(-2.12194440e-4)
_F32_MAXS = np.float32(80.0)
_F32_ZERO = np.float32(0.0)
_F32_HALF = np.float32(0.5)
_F32_ONE = np.float32(1.0)
_F32_P0 = np.float32(1.9875691500e-4)
_F32_P1 = np.float32(1.3981999507e-3)
_F32_P2 = np.float32(8.3334519073e-3)
_F32_P3 = np.float32(4.1665795894e-2)
_F32_P4 = np.float32(1.6666665459e-1)
_F32_P5 = np.float32(5.0000001201e-1)


@intrinsic
def _bits_to_f32(typingctx, x):
    sig = types.float32(x)

    def codegen(context, builder, signature, args):
        v = args[0]
        if v.type.width != 32:
            v = builder.trunc(v, ir.IntType(32))
        return builder.bitcast(v, ir.FloatType())

    return sig, codegen


def exp_neg(s):  # pragma: no cover - replaced by the overload inside jitted code
    return math.exp(-s)


@overload(exp_neg, inline="always")
def _ol_exp_neg(s):
    if s == types.float32:

        def impl32(s):
            s = min(max(s, _F32_ZERO), _F32_MAXS)
            n = np.int32(s * _F32_LOG2E + _F32_HALF)
            nf = np.float32(n)
            x = nf * _F32_C1 - s
            x = x + nf * _F32_C2
            z = x * x
            y = (((((_F32_P0 * x + _F32_P1) * x + _F32_P2) * x + _F32_P3) * x + _F32_P4) * x
                 + _F32_P5) * z + x + _F32_ONE
            return y * _bits_to_f32((np.int32(127) - n) << np.int32(23))

        return impl32

    def impl64(s):
        return math.exp(-s)

    return impl64


@njit(cache=True)
def exp_neg_array(s, out):
    """Test helper: ``out[i] = exp(-s[i])`` with the kernel's exp."""
    for i in range(s.shape[0]):
        out[i] = exp_neg(s[i])


# ----------------------------------------------------------------------------- projection helpers
# The projection formulas live in :mod:`._ewa`, shared with the PyTorch reference. These helpers
# are ordinary compiled functions (LLVM inlines them): inlined at the Numba IR level, their
# nested tuples trip the parfor array analysis of the parallel kernels.
_rotmat = njit(cache=True)(_ewa.rotmat)
_world_cov = njit(cache=True)(_ewa.world_cov)
_cam_point = njit(cache=True)(_ewa.cam_point)
_cam_cov = njit(cache=True)(_ewa.cam_cov)
_fov_limits = njit(cache=True)(_ewa.fov_limits)
_jacobian = njit(cache=True)(_ewa.jacobian)
_cov2d = njit(cache=True)(_ewa.cov2d)


@njit(cache=True, inline="always")
def _quat_rotmat(qw, qx, qy, qz, T):
    """Safe normalisation and rotation matrix (flat tuple r00..r22), plus the normalised
    quaternion, the inverse norm and whether the clamp was active."""
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    clamped = not (n2 > T(QUAT_EPS2))
    inv = T(1.0) / math.sqrt(n2 if not clamped else T(QUAT_EPS2))
    w = qw * inv
    x = qx * inv
    y = qy * inv
    z = qz * inv
    return _rotmat(w, x, y, z, T), w, x, y, z, inv, clamped


@njit(cache=True, inline="always")
def _view_rows(V):
    """Rows 0-2 of a 4x4 world-to-camera matrix as the flat tuple of :mod:`._ewa`."""
    return (V[0, 0], V[0, 1], V[0, 2], V[0, 3], V[1, 0], V[1, 1], V[1, 2], V[1, 3],
            V[2, 0], V[2, 1], V[2, 2], V[2, 3])


@njit(cache=True, inline="always")
def _gaussian_cov(quats, scales, g, T):
    """Rotation (flat), normalised quaternion and its inverse norm and clamp flag,
    ``M = R diag(s)`` and the world covariance ``S`` of Gaussian ``g``."""
    r, w, x, y, z, qinv, qcl = _quat_rotmat(quats[g, 0], quats[g, 1], quats[g, 2],
                                             quats[g, 3], T)
    M, S = _world_cov(r, scales[g, 0], scales[g, 1], scales[g, 2])
    return r, (w, x, y, z, qinv, qcl), M, S


@njit(cache=True, inline="always")
def _project_cam(V, K, m0, m1, m2, S, Wf, Hf, T):
    """EWA projection of one Gaussian (mean m, world covariance S) into the camera with rows
    ``V`` (flat tuple) and intrinsics ``K``: what :func:`project_fwd` and :func:`project_bwd`
    compute alike. Returns the camera-space point, ``u = x/z``, ``v = y/z``, (fx, fy, cx, cy),
    the clamp limits, the camera covariance, the Jacobian, ``J Sc`` and the 2D covariance."""
    px, py, pz = _cam_point(V, m0, m1, m2)
    Sc = _cam_cov(V, S)
    fx = K[0, 0]
    fy = K[1, 1]
    cx = K[0, 2]
    cy = K[1, 2]
    u = px / pz
    v = py / pz
    lim = _fov_limits(fx, fy, cx, cy, Wf, Hf, T)
    lxp, lxn, lyp, lyn = lim
    uc = min(max(u, -lxn), lxp)
    vc = min(max(v, -lyn), lyp)
    J = _jacobian(fx, fy, pz, uc, vc)
    JS, cov = _cov2d(J, Sc)
    return (px, py, pz), u, v, (fx, fy, cx, cy), lim, Sc, J, JS, cov


@kernel
def project_fwd(means, quats, scales, opacities, viewmats, Ks, width, height, eps2d, near, far,
                antialiased, T, radii, means2d, depths, conics, comps):
    """EWA projection of N Gaussians into C cameras. Outputs are flat over (camera, Gaussian);
    culled entries get radii 0 and zeros elsewhere (comps 1)."""
    C = viewmats.shape[0]
    N = means.shape[0]
    Wf = T(width)
    Hf = T(height)
    e2 = T(eps2d)
    nearf = T(near)
    farf = T(far)
    thr = T(ALPHA_THRESHOLD)
    for idx_ in prange(C * N):
        idx = np.int64(idx_)  # prange indices may be unsigned
        c = idx // N
        g = idx - c * N
        radii[idx, 0] = 0
        radii[idx, 1] = 0
        means2d[idx, 0] = T(0.0)
        means2d[idx, 1] = T(0.0)
        depths[idx] = T(0.0)
        conics[idx, 0] = T(0.0)
        conics[idx, 1] = T(0.0)
        conics[idx, 2] = T(0.0)
        comps[idx] = T(1.0)
        m0 = means[g, 0]
        m1 = means[g, 1]
        m2 = means[g, 2]
        V = _view_rows(viewmats[c])
        pz = _cam_point(V, m0, m1, m2)[2]
        if not (pz >= nearf and pz <= farf):
            continue
        _r, _q, _M, S = _gaussian_cov(quats, scales, g, T)
        ((px, py, pz), u, v, (fx, fy, cx, cy), _lim, _Sc, _J, _JS,
         (cov00, cov01, cov11)) = _project_cam(V, Ks[c], m0, m1, m2, S, Wf, Hf, T)
        mx = fx * u + cx
        my = fy * v + cy
        det_orig = cov00 * cov11 - cov01 * cov01
        a = cov00 + e2
        cc = cov11 + e2
        b = cov01
        det = a * cc - b * b
        if not (det > T(0.0) and det < T(np.inf)):
            continue
        if not (abs(mx) < T(np.inf) and abs(my) < T(np.inf)):
            continue
        comp = T(1.0)
        op = opacities[g]
        if antialiased:
            r = det_orig / det
            comp = math.sqrt(r) if r > T(0.0) else T(0.0)
            op = op * comp
        if not (op >= thr):
            continue
        ext = min(T(MAX_EXTENT_SIGMA), math.sqrt(T(2.0) * math.log(op / thr)))
        rx = min(math.ceil(ext * math.sqrt(a)), T(MAX_RADIUS))
        ry = min(math.ceil(ext * math.sqrt(cc)), T(MAX_RADIUS))
        if not (rx > T(0.0) or ry > T(0.0)):
            continue
        if mx + rx <= T(0.0) or mx - rx >= Wf or my + ry <= T(0.0) or my - ry >= Hf:
            continue
        radii[idx, 0] = np.int32(rx)
        radii[idx, 1] = np.int32(ry)
        means2d[idx, 0] = mx
        means2d[idx, 1] = my
        depths[idx] = pz
        conics[idx, 0] = cc / det
        conics[idx, 1] = -b / det
        conics[idx, 2] = a / det
        comps[idx] = comp


@kernel
def project_bwd(means, quats, scales, viewmats, Ks, width, height, eps2d, antialiased, T,
                radii, conics, comps, v_means2d, v_depths, v_conics, v_comps, want_viewmats,
                n_threads, v_means, v_quats, v_scales, v_view_buf):
    """Backward of :func:`project_fwd`. Parallel over Gaussians (each loops over cameras), so
    the per-Gaussian outputs need no reduction; viewmat gradients go to per-thread buffers
    ``v_view_buf[thread, camera, 12]`` (rows 0-2 of the 4x4 matrix)."""
    C = viewmats.shape[0]
    N = means.shape[0]
    Wf = T(width)
    Hf = T(height)
    e2 = T(eps2d)
    for g_ in prange(N):
        g = np.int64(g_)  # prange indices may be unsigned
        th = numba.get_thread_id()
        m0 = means[g, 0]
        m1 = means[g, 1]
        m2 = means[g, 2]
        s0 = scales[g, 0]
        s1 = scales[g, 1]
        s2 = scales[g, 2]
        r, (qw, qx, qy, qz, qinv, qcl), M, S = _gaussian_cov(quats, scales, g, T)
        r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
        M00, M01, M02, M10, M11, M12, M20, M21, M22 = M
        S00, S01, S02, S11, S12, S22 = S
        # accumulated gradient of the world covariance (symmetric, full-matrix convention)
        gS00 = T(0.0)
        gS01 = T(0.0)
        gS02 = T(0.0)
        gS11 = T(0.0)
        gS12 = T(0.0)
        gS22 = T(0.0)
        vm0 = T(0.0)
        vm1 = T(0.0)
        vm2 = T(0.0)
        any_vis = False
        for c in range(C):
            idx = c * N + g
            if radii[idx, 0] <= 0 and radii[idx, 1] <= 0:
                continue
            any_vis = True
            V = viewmats[c]
            ((px, py, pz), u, v, (fx, fy, cx, cy), (lxp, lxn, lyp, lyn), _Sc,
             (J00, J02, J11, J12), (T00, T01, T02, T10, T11, T12),
             _cov) = _project_cam(_view_rows(V), Ks[c], m0, m1, m2, S, Wf, Hf, T)
            ca = conics[idx, 0]
            cb = conics[idx, 1]
            cc = conics[idx, 2]
            vca = v_conics[idx, 0]
            vcb = v_conics[idx, 1]
            vcc = v_conics[idx, 2]
            # d conic / d (a, b, c) of the dilated 2D covariance [[a, b], [b, c]]
            va = -(ca * ca * vca + ca * cb * vcb + cb * cb * vcc)
            vb = -(T(2.0) * ca * cb * vca + (ca * cc + cb * cb) * vcb + T(2.0) * cc * cb * vcc)
            vc2 = -(cb * cb * vca + cb * cc * vcb + cc * cc * vcc)
            if antialiased:
                comp = comps[idx]
                if comp > T(0.0):
                    vr = v_comps[idx] * T(0.5) / comp
                    r = comp * comp
                    inv_det = ca * cc - cb * cb  # det of the conic = 1 / det(cov')
                    va += vr * ((T(1.0) - r) * ca - e2 * inv_det)
                    vb += vr * (T(2.0) * (T(1.0) - r) * cb)
                    vc2 += vr * ((T(1.0) - r) * cc - e2 * inv_det)
            # symmetric-matrix gradient G of cov2d: [[va, vb/2], [vb/2, vc2]]
            h = T(0.5) * vb
            # v_J = 2 G J Sc  (rows of J Sc are T0*, T1*)
            vJ00 = T(2.0) * va * T00 + vb * T10
            vJ02 = T(2.0) * va * T02 + vb * T12
            vJ11 = vb * T01 + T(2.0) * vc2 * T11
            vJ12 = vb * T02 + T(2.0) * vc2 * T12
            # v_Sc = J^T G J
            g00 = va * J00
            g01 = h * J11
            g02 = va * J02 + h * J12
            g10 = h * J00
            g11 = vc2 * J11
            g12 = h * J02 + vc2 * J12
            G00 = J00 * g00
            G01 = J00 * g01
            G02 = J00 * g02
            G11 = J11 * g11
            G12 = J11 * g12
            G22 = J02 * g02 + J12 * g12
            # camera-space mean
            vmx = v_means2d[idx, 0]
            vmy = v_means2d[idx, 1]
            vu = fx * vmx
            vv = fy * vmy
            vz = -(vJ00 * J00 + vJ02 * J02 + vJ11 * J11 + vJ12 * J12) / pz
            vuc = -fx / pz * vJ02
            vvc = -fy / pz * vJ12
            if u >= -lxn and u <= lxp:
                vu += vuc
            if v >= -lyn and v <= lyp:
                vv += vvc
            vx = vu / pz
            vy = vv / pz
            vz += -(u * vu + v * vv) / pz + v_depths[idx]
            # world mean: p = R m + t
            vm0 += V[0, 0] * vx + V[1, 0] * vy + V[2, 0] * vz
            vm1 += V[0, 1] * vx + V[1, 1] * vy + V[2, 1] * vz
            vm2 += V[0, 2] * vx + V[1, 2] * vy + V[2, 2] * vz
            # world covariance: v_S = R^T G R
            B00 = G00 * V[0, 0] + G01 * V[1, 0] + G02 * V[2, 0]
            B01 = G00 * V[0, 1] + G01 * V[1, 1] + G02 * V[2, 1]
            B02 = G00 * V[0, 2] + G01 * V[1, 2] + G02 * V[2, 2]
            B10 = G01 * V[0, 0] + G11 * V[1, 0] + G12 * V[2, 0]
            B11 = G01 * V[0, 1] + G11 * V[1, 1] + G12 * V[2, 1]
            B12 = G01 * V[0, 2] + G11 * V[1, 2] + G12 * V[2, 2]
            B20 = G02 * V[0, 0] + G12 * V[1, 0] + G22 * V[2, 0]
            B21 = G02 * V[0, 1] + G12 * V[1, 1] + G22 * V[2, 1]
            B22 = G02 * V[0, 2] + G12 * V[1, 2] + G22 * V[2, 2]
            gS00 += V[0, 0] * B00 + V[1, 0] * B10 + V[2, 0] * B20
            gS01 += V[0, 0] * B01 + V[1, 0] * B11 + V[2, 0] * B21
            gS02 += V[0, 0] * B02 + V[1, 0] * B12 + V[2, 0] * B22
            gS11 += V[0, 1] * B01 + V[1, 1] * B11 + V[2, 1] * B21
            gS12 += V[0, 1] * B02 + V[1, 1] * B12 + V[2, 1] * B22
            gS22 += V[0, 2] * B02 + V[1, 2] * B12 + V[2, 2] * B22
            if want_viewmats:
                # v_R = 2 G R S + v_p m^T ; v_t = v_p   (B = G R, so G R S = B S)
                vb_ = v_view_buf[th, c]
                vb_[0] += T(2.0) * (B00 * S00 + B01 * S01 + B02 * S02) + vx * m0
                vb_[1] += T(2.0) * (B00 * S01 + B01 * S11 + B02 * S12) + vx * m1
                vb_[2] += T(2.0) * (B00 * S02 + B01 * S12 + B02 * S22) + vx * m2
                vb_[3] += vx
                vb_[4] += T(2.0) * (B10 * S00 + B11 * S01 + B12 * S02) + vy * m0
                vb_[5] += T(2.0) * (B10 * S01 + B11 * S11 + B12 * S12) + vy * m1
                vb_[6] += T(2.0) * (B10 * S02 + B11 * S12 + B12 * S22) + vy * m2
                vb_[7] += vy
                vb_[8] += T(2.0) * (B20 * S00 + B21 * S01 + B22 * S02) + vz * m0
                vb_[9] += T(2.0) * (B20 * S01 + B21 * S11 + B22 * S12) + vz * m1
                vb_[10] += T(2.0) * (B20 * S02 + B21 * S12 + B22 * S22) + vz * m2
                vb_[11] += vz
        v_means[g, 0] = vm0
        v_means[g, 1] = vm1
        v_means[g, 2] = vm2
        if not any_vis:
            v_quats[g, 0] = T(0.0)
            v_quats[g, 1] = T(0.0)
            v_quats[g, 2] = T(0.0)
            v_quats[g, 3] = T(0.0)
            v_scales[g, 0] = T(0.0)
            v_scales[g, 1] = T(0.0)
            v_scales[g, 2] = T(0.0)
            continue
        # S = M M^T  ->  v_M = 2 v_S M
        vM00 = T(2.0) * (gS00 * M00 + gS01 * M10 + gS02 * M20)
        vM01 = T(2.0) * (gS00 * M01 + gS01 * M11 + gS02 * M21)
        vM02 = T(2.0) * (gS00 * M02 + gS01 * M12 + gS02 * M22)
        vM10 = T(2.0) * (gS01 * M00 + gS11 * M10 + gS12 * M20)
        vM11 = T(2.0) * (gS01 * M01 + gS11 * M11 + gS12 * M21)
        vM12 = T(2.0) * (gS01 * M02 + gS11 * M12 + gS12 * M22)
        vM20 = T(2.0) * (gS02 * M00 + gS12 * M10 + gS22 * M20)
        vM21 = T(2.0) * (gS02 * M01 + gS12 * M11 + gS22 * M21)
        vM22 = T(2.0) * (gS02 * M02 + gS12 * M12 + gS22 * M22)
        v_scales[g, 0] = vM00 * r00 + vM10 * r10 + vM20 * r20
        v_scales[g, 1] = vM01 * r01 + vM11 * r11 + vM21 * r21
        v_scales[g, 2] = vM02 * r02 + vM12 * r12 + vM22 * r22
        v00 = vM00 * s0
        v01 = vM01 * s1
        v02 = vM02 * s2
        v10 = vM10 * s0
        v11 = vM11 * s1
        v12 = vM12 * s2
        v20 = vM20 * s0
        v21 = vM21 * s1
        v22 = vM22 * s2
        w = qw
        x = qx
        y = qy
        z = qz
        gw = T(2.0) * (-z * v01 + y * v02 + z * v10 - x * v12 - y * v20 + x * v21)
        gx = T(2.0) * (y * v01 + z * v02 + y * v10 - T(2.0) * x * v11 - w * v12 + z * v20
                       + w * v21 - T(2.0) * x * v22)
        gy = T(2.0) * (-T(2.0) * y * v00 + x * v01 + w * v02 + x * v10 + z * v12 - w * v20
                       + z * v21 - T(2.0) * y * v22)
        gz = T(2.0) * (-T(2.0) * z * v00 - w * v01 + x * v02 + w * v10 - T(2.0) * z * v11
                       + y * v12 + x * v20 + y * v21)
        if qcl:
            v_quats[g, 0] = gw * qinv
            v_quats[g, 1] = gx * qinv
            v_quats[g, 2] = gy * qinv
            v_quats[g, 3] = gz * qinv
        else:
            dot = w * gw + x * gx + y * gy + z * gz
            v_quats[g, 0] = (gw - w * dot) * qinv
            v_quats[g, 1] = (gx - x * dot) * qinv
            v_quats[g, 2] = (gy - y * dot) * qinv
            v_quats[g, 3] = (gz - z * dot) * qinv


# ----------------------------------------------------------------------------- spherical harmonics
_SH_C0 = 0.28209479177387814
_SH_C1 = 0.4886025119029199
_SH_C2_0 = 1.0925484305920792
_SH_C2_1 = -1.0925484305920792
_SH_C2_2 = 0.31539156525252005
_SH_C2_3 = -1.0925484305920792
_SH_C2_4 = 0.5462742152960396
_SH_C3_0 = -0.5900435899266435
_SH_C3_1 = 2.890611442640554
_SH_C3_2 = -0.4570457994644658
_SH_C3_3 = 0.3731763325901154
_SH_C3_4 = -0.4570457994644658
_SH_C3_5 = 1.445305721320277
_SH_C3_6 = -0.5900435899266435


@njit(cache=True, inline="always")
def _sh_basis(degree, x, y, z, T, B):
    B[0] = T(_SH_C0)
    if degree >= 1:
        B[1] = -T(_SH_C1) * y
        B[2] = T(_SH_C1) * z
        B[3] = -T(_SH_C1) * x
    if degree >= 2:
        xx = x * x
        yy = y * y
        zz = z * z
        B[4] = T(_SH_C2_0) * (x * y)
        B[5] = T(_SH_C2_1) * (y * z)
        B[6] = T(_SH_C2_2) * (T(2.0) * zz - xx - yy)
        B[7] = T(_SH_C2_3) * (x * z)
        B[8] = T(_SH_C2_4) * (xx - yy)
        if degree >= 3:
            B[9] = T(_SH_C3_0) * y * (T(3.0) * xx - yy)
            B[10] = T(_SH_C3_1) * (x * y) * z
            B[11] = T(_SH_C3_2) * y * (T(4.0) * zz - xx - yy)
            B[12] = T(_SH_C3_3) * z * (T(2.0) * zz - T(3.0) * xx - T(3.0) * yy)
            B[13] = T(_SH_C3_4) * x * (T(4.0) * zz - xx - yy)
            B[14] = T(_SH_C3_5) * z * (xx - yy)
            B[15] = T(_SH_C3_6) * x * (xx - T(3.0) * yy)


@kernel
def sh_fwd(degree, coeffs, per_camera, means, campos, radii, T, out):
    """colors[c, g] = max(sum_k B_k(dir) coeffs[g, k] + 0.5, 0), dir = normalise(mean - campos).
    ``coeffs`` is [N, K, 3] or, with ``per_camera``, [C*N, K, 3]. Culled entries get 0."""
    C = campos.shape[0]
    N = means.shape[0]
    nb = (degree + 1) * (degree + 1)
    for idx_ in prange(C * N):
        idx = np.int64(idx_)  # prange indices may be unsigned
        c = idx // N
        g = idx - c * N
        if radii[idx, 0] <= 0 and radii[idx, 1] <= 0:
            out[idx, 0] = T(0.0)
            out[idx, 1] = T(0.0)
            out[idx, 2] = T(0.0)
            continue
        B = np.empty(16, dtype=T)
        dx = means[g, 0] - campos[c, 0]
        dy = means[g, 1] - campos[c, 1]
        dz = means[g, 2] - campos[c, 2]
        n2 = dx * dx + dy * dy + dz * dz
        inv = T(1.0) / math.sqrt(max(n2, T(DIR_EPS2)))
        _sh_basis(degree, dx * inv, dy * inv, dz * inv, T, B)
        ci = idx if per_camera else g
        for ch in range(3):
            acc = T(0.0)
            for k in range(nb):
                acc += B[k] * coeffs[ci, k, ch]
            acc += T(0.5)
            out[idx, ch] = acc if acc > T(0.0) else T(0.0)


@njit(cache=True, inline="always")
def _sh_basis_grad(degree, x, y, z, T, w, gx, gy, gz):
    """Gradient of sum_k w[k] B_k(x, y, z) with respect to (x, y, z) (unnormalised polynomial)."""
    rx = T(0.0)
    ry = T(0.0)
    rz = T(0.0)
    if degree >= 1:
        ry += -T(_SH_C1) * w[1]
        rz += T(_SH_C1) * w[2]
        rx += -T(_SH_C1) * w[3]
    if degree >= 2:
        xx = x * x
        yy = y * y
        zz = z * z
        rx += T(_SH_C2_0) * y * w[4]
        ry += T(_SH_C2_0) * x * w[4]
        ry += T(_SH_C2_1) * z * w[5]
        rz += T(_SH_C2_1) * y * w[5]
        rx += -T(2.0) * T(_SH_C2_2) * x * w[6]
        ry += -T(2.0) * T(_SH_C2_2) * y * w[6]
        rz += T(4.0) * T(_SH_C2_2) * z * w[6]
        rx += T(_SH_C2_3) * z * w[7]
        rz += T(_SH_C2_3) * x * w[7]
        rx += T(2.0) * T(_SH_C2_4) * x * w[8]
        ry += -T(2.0) * T(_SH_C2_4) * y * w[8]
        if degree >= 3:
            rx += T(_SH_C3_0) * T(6.0) * x * y * w[9]
            ry += T(_SH_C3_0) * (T(3.0) * xx - T(3.0) * yy) * w[9]
            rx += T(_SH_C3_1) * y * z * w[10]
            ry += T(_SH_C3_1) * x * z * w[10]
            rz += T(_SH_C3_1) * x * y * w[10]
            rx += T(_SH_C3_2) * (-T(2.0) * x * y) * w[11]
            ry += T(_SH_C3_2) * (T(4.0) * zz - xx - T(3.0) * yy) * w[11]
            rz += T(_SH_C3_2) * (T(8.0) * y * z) * w[11]
            rx += T(_SH_C3_3) * (-T(6.0) * x * z) * w[12]
            ry += T(_SH_C3_3) * (-T(6.0) * y * z) * w[12]
            rz += T(_SH_C3_3) * (T(6.0) * zz - T(3.0) * xx - T(3.0) * yy) * w[12]
            rx += T(_SH_C3_4) * (T(4.0) * zz - T(3.0) * xx - yy) * w[13]
            ry += T(_SH_C3_4) * (-T(2.0) * x * y) * w[13]
            rz += T(_SH_C3_4) * (T(8.0) * x * z) * w[13]
            rx += T(_SH_C3_5) * (T(2.0) * x * z) * w[14]
            ry += T(_SH_C3_5) * (-T(2.0) * y * z) * w[14]
            rz += T(_SH_C3_5) * (xx - yy) * w[14]
            rx += T(_SH_C3_6) * (T(3.0) * xx - T(3.0) * yy) * w[15]
            ry += T(_SH_C3_6) * (-T(6.0) * x * y) * w[15]
    return rx, ry, rz


@kernel
def sh_bwd(degree, coeffs, per_camera, means, campos, radii, T, colors, v_colors,
           v_coeffs, v_dirs):
    """Backward of :func:`sh_fwd`: ``v_coeffs`` (same shape as coeffs, fully written) and
    ``v_dirs[c*N+g]`` = gradient w.r.t. (mean - campos). Parallel over Gaussians."""
    C = campos.shape[0]
    N = means.shape[0]
    K = coeffs.shape[1]
    nb = (degree + 1) * (degree + 1)
    for g_ in prange(N):
        g = np.int64(g_)  # prange indices may be unsigned
        B = np.empty(16, dtype=T)
        wk = np.zeros(16, dtype=T)
        if not per_camera:
            for k in range(K):
                for ch in range(3):
                    v_coeffs[g, k, ch] = T(0.0)
        for c in range(C):
            idx = c * N + g
            v_dirs[idx, 0] = T(0.0)
            v_dirs[idx, 1] = T(0.0)
            v_dirs[idx, 2] = T(0.0)
            ci = idx if per_camera else g
            if per_camera:
                for k in range(K):
                    for ch in range(3):
                        v_coeffs[ci, k, ch] = T(0.0)
            if radii[idx, 0] <= 0 and radii[idx, 1] <= 0:
                continue
            dx = means[g, 0] - campos[c, 0]
            dy = means[g, 1] - campos[c, 1]
            dz = means[g, 2] - campos[c, 2]
            n2 = dx * dx + dy * dy + dz * dz
            inv = T(1.0) / math.sqrt(max(n2, T(DIR_EPS2)))
            x = dx * inv
            y = dy * inv
            z = dz * inv
            _sh_basis(degree, x, y, z, T, B)
            for k in range(16):
                wk[k] = T(0.0)
            for ch in range(3):
                # colors = max(raw + 0.5, 0): no gradient where clamped
                vc = v_colors[idx, ch]
                if colors[idx, ch] <= T(0.0):
                    # recompute the unclamped value to decide (clamp_min passes at exactly 0)
                    acc = T(0.0)
                    for k in range(nb):
                        acc += B[k] * coeffs[ci, k, ch]
                    acc += T(0.5)
                    if acc < T(0.0):
                        vc = T(0.0)
                for k in range(nb):
                    v_coeffs[ci, k, ch] += B[k] * vc
                    wk[k] += coeffs[ci, k, ch] * vc
            if degree >= 1:
                gx, gy, gz = _sh_basis_grad(degree, x, y, z, T, wk, T(0.0), T(0.0), T(0.0))
                dot = x * gx + y * gy + z * gz
                v_dirs[idx, 0] = (gx - x * dot) * inv
                v_dirs[idx, 1] = (gy - y * dot) * inv
                v_dirs[idx, 2] = (gz - z * dot) * inv


# ----------------------------------------------------------------------------- binning
@kernel
def tile_rects(means2d, radii, tile_size, tiles_x, tiles_y, rects):
    """rects[i] = (tx0, tx1, ty0, ty1) tile range (exclusive ends) of each projected Gaussian,
    empty for culled ones. Same bounds as gsplat: floor((m - r) / ts) .. ceil((m + r) / ts)."""
    n = means2d.shape[0]
    ts = float(tile_size)
    for i_ in prange(n):
        i = np.int64(i_)  # prange indices may be unsigned
        rx = radii[i, 0]
        ry = radii[i, 1]
        if rx <= 0 and ry <= 0:
            rects[i, 0] = 0
            rects[i, 1] = 0
            rects[i, 2] = 0
            rects[i, 3] = 0
            continue
        mx = float(means2d[i, 0])
        my = float(means2d[i, 1])
        x0 = math.floor((mx - rx) / ts)
        x1 = math.ceil((mx + rx) / ts)
        y0 = math.floor((my - ry) / ts)
        y1 = math.ceil((my + ry) / ts)
        rects[i, 0] = min(max(x0, 0), tiles_x)
        rects[i, 1] = min(max(x1, 0), tiles_x)
        rects[i, 2] = min(max(y0, 0), tiles_y)
        rects[i, 3] = min(max(y1, 0), tiles_y)


@njit(cache=True, inline="always")
def _band(bid, bands_per_cam, tiles_y):
    """Camera and tile rows [r0, r1) of the binning band ``bid`` (bands of tile rows, per
    camera)."""
    c = bid // bands_per_cam
    b = bid - c * bands_per_cam
    return c, (tiles_y * b) // bands_per_cam, (tiles_y * (b + 1)) // bands_per_cam


@njit(cache=True, inline="always")
def _rect_in_band(rects, i, r0, r1):
    """Tile columns [xa, xb) and rows [ya, yb) of Gaussian ``i`` inside the band's rows
    [r0, r1) (ya >= yb: none)."""
    return rects[i, 0], rects[i, 1], max(rects[i, 2], r0), min(rects[i, 3], r1)


@kernel
def bin_count(order, cam_start, rects, tiles_x, tiles_y, bands_per_cam, counts):
    """counts[c * tiles_y * tiles_x + tile] = number of Gaussians overlapping each tile.
    Parallel over bands of tile rows; each band scans its camera's visible Gaussians."""
    C = cam_start.shape[0] - 1
    nt = tiles_x * tiles_y
    for bid_ in prange(C * bands_per_cam):
        c, r0, r1 = _band(np.int64(bid_), bands_per_cam, tiles_y)
        base = c * nt
        for t in range(r0 * tiles_x, r1 * tiles_x):
            counts[base + t] = 0
        for j in range(cam_start[c], cam_start[c + 1]):
            i = order[j]
            xa, xb, ya, yb = _rect_in_band(rects, i, r0, r1)
            if ya >= yb:
                continue
            for ty in range(ya, yb):
                row = base + ty * tiles_x
                for tx in range(xa, xb):
                    counts[row + tx] += 1


@kernel
def bin_fill(order, cam_start, rects, tiles_x, tiles_y, bands_per_cam, offsets, flat_ids):
    """Write each tile's Gaussians in depth order (``order`` is depth-sorted per camera)."""
    C = cam_start.shape[0] - 1
    nt = tiles_x * tiles_y
    for bid_ in prange(C * bands_per_cam):
        c, r0, r1 = _band(np.int64(bid_), bands_per_cam, tiles_y)
        base = c * nt
        cursor = np.empty((r1 - r0) * tiles_x, dtype=np.int64)
        for t in range((r1 - r0) * tiles_x):
            cursor[t] = offsets[base + r0 * tiles_x + t]
        for j in range(cam_start[c], cam_start[c + 1]):
            i = order[j]
            xa, xb, ya, yb = _rect_in_band(rects, i, r0, r1)
            if ya >= yb:
                continue
            for ty in range(ya, yb):
                row = (ty - r0) * tiles_x
                for tx in range(xa, xb):
                    k = row + tx
                    flat_ids[cursor[k]] = i
                    cursor[k] += 1


# ----------------------------------------------------------------------------- compositing
# A tile lives in ONE flat buffer of per-pixel fields (field f of pixel p at f * 256 + p), so
# LLVM sees constant distances between the fields and vectorises the 16-pixel row loops without
# runtime alias checks. Each Gaussian of the tile's depth-sorted list is evaluated row by row
# over the rows its alpha >= 1/255 ellipse can reach (:func:`_tile_rows`, from parameters
# computed once per Gaussian), skipping rows whose pixels are all finished (both are conservative: they only skip
# pairs that would be skipped anyway). No other test per row: a scalar test per row (a square
# root and data-dependent branches) cost more than the row's vector work it saved. A row is
# always evaluated whole: one 16-lane vector (AVX-512) with no scalar remainder. The first four channels are composited inside the row loop;
# channels beyond four (rare) in extra passes.
#
# The row loops keep no integer counters: a sum of 64-bit integers inside the loop halves the
# vector width (8 lanes of int64). What the forward needs per row (did a pixel finish, did the
# Gaussian contribute) are boolean ORs; the row's finished pixels are recounted only when one
# finished (at most 16 times per row and tile).
#
# The per-pair maths (sigma, alpha, the tests that skip a pair) is written once, in
# :func:`_sigma` and :func:`_alpha`, and used by both the forward and the backward.

NP = TILE * TILE
# forward fields
_F_T = 0      # transmittance; -T once the pixel is finished
_F_LAST = 1   # index (relative to the tile's list) of the last Gaussian composited, -1: none
_F_PX = 2     # pixel centre x
_F_W = 3      # weight alpha * T of the current Gaussian (for channels >= 4)
_F_ACC = 4    # accumulated channels
# backward fields
_B_T = 0      # transmittance in front of the current Gaussian (recovered back to front)
_B_Q = 1      # sum of w_j <v_C, c_j> behind, plus background and alpha terms
_B_LAST = 2
_B_PX = 3
_B_PY = 4
_B_W = 5
_B_GD = 6     # <v_C, c> over channels >= 4
_B_VC = 7     # dL/d render_colors per channel


def _off(field: int) -> np.uint64:
    # unsigned offsets: with a signed index Numba emits negative-index wraparound code, which
    # stops LLVM from vectorising the loop
    return np.uint64(field * NP)


_O_T, _O_LAST, _O_PX, _O_W = (_off(f) for f in range(4))
_O_ACC0, _O_ACC1, _O_ACC2, _O_ACC3 = (_off(_F_ACC + k) for k in range(4))
_OB_T, _OB_Q, _OB_LAST, _OB_PX, _OB_PY, _OB_W, _OB_GD = (_off(f) for f in range(7))
_OB_VC0, _OB_VC1, _OB_VC2, _OB_VC3 = (_off(_B_VC + k) for k in range(4))


@njit(cache=True, inline="always")
def _sigma(dx, dy, ca, cb, cc, T):
    """sigma = 1/2 (a dx^2 + c dy^2) + b dx dy, in this order of operations everywhere (the
    reference's), with d = mean - pixel centre."""
    return T(0.5) * (ca * dx * dx + cc * dy * dy) + cb * dx * dy


@njit(cache=True, inline="always")
def _alpha(sig, op, T):
    """G = exp(-sigma), opacity * G, alpha = min(MAX_ALPHA, opacity * G), and whether the pair
    counts at all (sigma >= 0 and alpha >= ALPHA_THRESHOLD): the same constants and tests in
    the forward and the backward."""
    G = exp_neg(sig)
    alr = op * G
    al = min(T(MAX_ALPHA), alr)
    ok = (sig >= T(0.0)) & (al >= T(ALPHA_THRESHOLD))
    return G, alr, al, ok


@njit(cache=True, inline="always")
def _tile_of(tid, n_tiles, tiles_x):
    """Camera and pixel origin (x0, y0) of the flat tile id ``tid``."""
    c = tid // n_tiles
    tt = tid - c * n_tiles
    ty = tt // tiles_x
    tx = tt - ty * tiles_x
    return c, tx * TILE, ty * TILE


@njit(cache=True, inline="always")
def _gaussian(fi, means2d, conics, opacities, colors, colors_per_camera, cN, DI, T):
    """What the compositing loops read of the flat (camera, Gaussian) entry ``fi`` of the
    camera whose entries start at ``cN = camera * N``: mean, conic, opacity, the colour row
    index and its first four channels (0 beyond D). (``fi - cN``, not ``fi % N``: no integer
    division per entry.)"""
    ci = fi if colors_per_camera else fi - cN
    return (means2d[fi, 0], means2d[fi, 1], conics[fi, 0], conics[fi, 1], conics[fi, 2],
            opacities[fi], ci, colors[ci, 0], colors[ci, 1] if DI > 1 else T(0.0),
            colors[ci, 2] if DI > 2 else T(0.0), colors[ci, 3] if DI > 3 else T(0.0))


@njit(cache=True, inline="always")
def _row_range(my, ry, y0, height):
    """Rows (relative to the tile) whose pixel centres lie within the Gaussian's bounding box,
    widened by one pixel against rounding."""
    lo = math.floor(my - float(ry) - 1.5) - y0
    hi = math.floor(my + float(ry) + 0.5) - y0 + 1
    if lo < 0:
        lo = 0
    if hi > TILE:
        hi = TILE
    if hi > height - y0:
        hi = height - y0
    return lo, hi


@njit(cache=True, inline="always")
def _row_params(op, ca, cb, cc):
    """Per-Gaussian parameters of :func:`_tile_rows` (float64): the sigma level of
    alpha = 1/255, slightly enlarged (``ln(opacity * 255)``: alpha >= 1/255 only inside the
    ellipse ``sigma <= level``; the enlargement covers float32 rounding), and the ellipse's
    vertical half-extent: along a row at vertical offset dy the smallest sigma is
    ``dy^2 (c - b^2 / a) / 2``, so it spans ``|dy| <= sqrt(2 level / (c - b^2 / a))``."""
    level = math.log(max(float(op), ALPHA_THRESHOLD) / ALPHA_THRESHOLD) * 1.001 + 1e-3
    s_c = float(cc) - float(cb) * float(cb) / float(ca)
    return level, math.sqrt(2.0 * level / s_c) if s_c > 0.0 else math.inf


_ROW_MARGIN = 0.01  # pixels, on top of the enlarged level


@njit(cache=True, inline="always")
def _tile_rows(mx, my, ry, ca, cb, cc, level, hy, x0, xw, y0, height):
    """Rows [lo, hi) of the tile at (x0, y0) (row length ``xw``) to evaluate for a Gaussian:
    the rows of its bounding box (:func:`_row_range`) that reach the part of the ellipse
    ``sigma <= level`` over the tile's columns. Conservative: the other rows hold only pairs
    with alpha < 1/255.

    With dx = mx - px and dy = my - py, the ellipse's top point is at (-b hy / a, hy). Its
    upper boundary dy = -b dx / c + sqrt((2 level - dx^2 (a - b^2 / c)) / c) is concave, so
    over the tile's columns (an interval of dx) it is highest at the top point's dx clamped to
    that interval; likewise the bottom. Computed in float64."""
    lo, hi = _row_range(my, ry, y0, height)
    a = float(ca)
    b = float(cb)
    c = float(cc)
    s_a = a - b * b / c
    if lo >= hi or not (a > 0.0 and c > 0.0 and s_a > 0.0 and hy < 1e7):
        return lo, hi
    u1 = mx - (float(x0 + xw) - 0.5) - _ROW_MARGIN  # dx over the tile's pixel centres
    u2 = mx - (float(x0) + 0.5) + _ROW_MARGIN
    t = -b * hy / a  # dx of the top point (the bottom one is at -t)
    dxt = min(max(t, u1), u2)
    dxb = min(max(-t, u1), u2)
    rt = 2.0 * level - dxt * dxt * s_a
    rb = 2.0 * level - dxb * dxb * s_a
    if rt < 0.0 or rb < 0.0:  # the columns miss the ellipse
        return 0, 0
    dymax = -b * dxt / c + math.sqrt(rt / c) + _ROW_MARGIN
    dymin = -b * dxb / c - math.sqrt(rb / c) - _ROW_MARGIN
    # rows whose centre py = y0 + y + 0.5 lies in [my - dymax, my - dymin]
    return (max(lo, math.ceil(my - dymax - 0.5) - y0),
            min(hi, math.floor(my - dymin - 0.5) - y0 + 1))


@kernel
def raster_params(conics, opacities, radii, T, row_par):
    """Per (camera, Gaussian): ``row_par[i]`` = (level, hy) of :func:`_row_params` (computed
    once, not once per tile)."""
    n = conics.shape[0]
    for i_ in prange(n):
        i = np.int64(i_)  # prange indices may be unsigned
        if radii[i, 0] <= 0 and radii[i, 1] <= 0:
            row_par[i, 0] = 0.0
            row_par[i, 1] = 0.0
            continue
        level, hy = _row_params(opacities[i], conics[i, 0], conics[i, 1], conics[i, 2])
        row_par[i, 0] = level
        row_par[i, 1] = hy


@kernel
def raster_fwd(means2d, conics, colors, colors_per_camera, opacities, radii, backgrounds,
               has_bg, tile_offsets, flat_ids, N, width, height, tiles_x, tiles_y, T,
               out_color, out_T, out_last, pair_counts, isect_rows, tile_order, row_par):
    """Front-to-back compositing, tile by tile.

    Inputs are flat over (camera, Gaussian): means2d [C*N, 2], conics [C*N, 3], opacities
    [C*N], colors [C*N or N, D]. Outputs: out_color [C, H, W, D] (background included),
    out_T [C, H, W] final transmittance, out_last [C, H, W] index (into flat_ids) of the last
    Gaussian composited (-1: none), pair_counts[tile] = (pixel, Gaussian) pairs evaluated,
    isect_rows[j] = (first, last + 1) tile row where the j-th entry of flat_ids was composited
    (the backward visits only those rows). Finished pixels carry -T, so they drop out of the
    ``valid`` mask without a branch.
    """
    D = out_color.shape[3]
    DI = min(D, 4)
    n_tiles = tiles_x * tiles_y
    C = out_color.shape[0]
    tthr = T(TRANSMITTANCE_THRESHOLD)
    nf = _F_ACC + max(D, 4)
    for k_ in prange(C * n_tiles):
        tid = np.int64(tile_order[k_])  # balanced blocks, one per thread (_cpu.tile_schedule)
        c, x0, y0 = _tile_of(tid, n_tiles, tiles_x)
        xw = min(TILE, width - x0)  # row length (a runtime trip count: vectorised, not unrolled)
        buf = np.zeros(nf * NP, dtype=T)
        rowdone = np.zeros(TILE, dtype=np.int64)
        ndone = 0
        for y in range(TILE):
            for x in range(TILE):
                p = y * TILE + x
                buf[_F_PX * NP + p] = T(x0 + x) + T(0.5)
                buf[_F_LAST * NP + p] = T(-1.0)
                if y0 + y >= height or x0 + x >= width:  # outside the image: finished
                    rowdone[y] += 1
                    ndone += 1
                    buf[_F_T * NP + p] = T(-1.0)
                else:
                    buf[_F_T * NP + p] = T(1.0)
        npairs = 0
        start = tile_offsets[tid]
        end = tile_offsets[tid + 1]
        for j in range(start, end):
            if ndone >= NP:
                break
            fi = flat_ids[j]
            lo, hi = _tile_rows(float(means2d[fi, 0]), float(means2d[fi, 1]), radii[fi, 1],
                                conics[fi, 0], conics[fi, 1], conics[fi, 2], row_par[fi, 0],
                                row_par[fi, 1], x0, xw, y0, height)
            if lo >= hi:
                continue
            (mx, my, ca, cb, cc, op, ci,
             c0, c1, c2, c3) = _gaussian(fi, means2d, conics, opacities, colors,
                                         colors_per_camera, c * N, DI, T)
            jr = T(j - start)
            rlo = TILE
            rhi = 0
            for y in range(lo, hi):
                if rowdone[y] >= TILE:
                    continue
                dy = my - (T(y0 + y) + T(0.5))  # one value per row: the same float as per pixel
                npairs += xw
                anyterm = False
                anycontrib = False
                pb = np.uint64(y * TILE)
                pe = np.uint64(y * TILE + xw)
                for p in range(pb, pe):
                    dx = mx - buf[_O_PX + p]
                    sig = _sigma(dx, dy, ca, cb, cc, T)
                    _G, _alr, al, ok = _alpha(sig, op, T)
                    t = buf[_O_T + p]
                    valid = ok & (t > T(0.0))
                    nt = t * (T(1.0) - al)
                    term = valid & (nt <= tthr)
                    contrib = valid & (nt > tthr)
                    w = al * t if contrib else T(0.0)
                    # finished pixels keep -T (so t > 0 fails): no extra field, no branch.
                    # Blends are written as exact arithmetic, not as selects: LLVM turns
                    # "store (c ? x : old)" into a masked store, which the next Gaussian's
                    # loads of the same pixels cannot forward from.
                    cf = T(1.0) if contrib else T(0.0)
                    tf = T(1.0) if term else T(0.0)
                    buf[_O_T + p] = t * (T(1.0) - cf * al) * (T(1.0) - T(2.0) * tf)
                    lst = buf[_O_LAST + p]
                    buf[_O_LAST + p] = lst + cf * (jr - lst)
                    buf[_O_W + p] = w
                    buf[_O_ACC0 + p] += w * c0
                    buf[_O_ACC1 + p] += w * c1
                    buf[_O_ACC2 + p] += w * c2
                    buf[_O_ACC3 + p] += w * c3  # c3 = 0 below four channels: no mask
                    anyterm |= term
                    anycontrib |= contrib
                for k in range(4, D):
                    ck = colors[ci, k]
                    ok_ = np.uint64((_F_ACC + k) * NP)
                    for p in range(pb, pe):
                        buf[ok_ + p] += buf[_O_W + p] * ck
                if anyterm:  # recount the row's finished pixels
                    nd = 0
                    for x in range(TILE):
                        nd += buf[_F_T * NP + y * TILE + x] <= T(0.0)
                    ndone += nd - rowdone[y]
                    rowdone[y] = nd
                if anycontrib:
                    rlo = min(rlo, y)
                    rhi = y + 1
            isect_rows[j, 0] = np.uint8(rlo)
            isect_rows[j, 1] = np.uint8(rhi)
        pair_counts[tid] = npairs
        ymax = min(TILE, height - y0)
        xmax = min(TILE, width - x0)
        for y in range(ymax):
            for x in range(xmax):
                p = y * TILE + x
                tf = abs(buf[_F_T * NP + p])
                out_T[c, y0 + y, x0 + x] = tf
                lr = buf[_F_LAST * NP + p]
                out_last[c, y0 + y, x0 + x] = np.int32(start + np.int64(lr)) if lr >= T(0.0) \
                    else np.int32(-1)
                for k in range(D):
                    val = buf[(_F_ACC + k) * NP + p]
                    if has_bg:
                        val += tf * backgrounds[c, k]
                    out_color[c, y0 + y, x0 + x, k] = val


@kernel_fastmath
def raster_bwd(means2d, conics, colors, colors_per_camera, opacities, radii, backgrounds,
               has_bg, tile_offsets, flat_ids, N, width, height, tiles_x, tiles_y, T,
               final_T, last_ids, isect_rows, v_color, v_alpha, gbuf, tile_order):
    """Back-to-front backward of :func:`raster_fwd`, tile by tile, over the rows where the
    forward composited each Gaussian (``isect_rows``; elsewhere its terms are zero).

    Per pixel it keeps the transmittance (recovered as T / (1 - alpha), as gsplat does) and
    Q = sum over the Gaussians behind of w_j <v_C, c_j> plus the background and alpha terms, so
    dL/dalpha_i = T_i <v_C, c_i> - Q / (1 - alpha_i). The per-pixel terms of each Gaussian are
    summed inside the tile and written to ``gbuf[j, :]``, j the intersection's index in
    ``flat_ids`` (one tile owns each j, so no two threads write a row) =
    (v_mx, v_my, v_conic_a, v_conic_b, v_conic_c, v_opacity, v_color[0..D), |v_mx|, |v_my|);
    :func:`reduce_isects` adds the rows up per Gaussian.
    Compiled with ``reassoc`` so these sums vectorise (this only reorders additions).
    """
    D = v_color.shape[3]
    DI = min(D, 4)
    n_tiles = tiles_x * tiles_y
    C = v_color.shape[0]
    amax = T(MAX_ALPHA)
    nf = _B_VC + max(D, 4)
    for k_ in prange(C * n_tiles):
        tid = np.int64(tile_order[k_])  # balanced blocks, one per thread (_cpu.tile_schedule)
        start = tile_offsets[tid]
        end = tile_offsets[tid + 1]
        if end <= start:
            continue
        c, x0, y0 = _tile_of(tid, n_tiles, tiles_x)
        ymax = min(TILE, height - y0)
        xmax = min(TILE, width - x0)
        xw = xmax  # row length (a runtime trip count: vectorised, not unrolled)
        buf = np.zeros(nf * NP, dtype=T)
        rowmax = np.full(TILE, -1, dtype=np.int64)
        for y in range(TILE):
            for x in range(TILE):
                p = y * TILE + x
                buf[_B_PX * NP + p] = T(x0 + x) + T(0.5)
                buf[_B_PY * NP + p] = T(y0 + y) + T(0.5)
                buf[_B_LAST * NP + p] = T(-1.0)
        jmax = -1
        for y in range(ymax):
            for x in range(xmax):
                p = y * TILE + x
                tf = final_T[c, y0 + y, x0 + x]
                buf[_B_T * NP + p] = tf
                li = np.int64(last_ids[c, y0 + y, x0 + x])
                if li >= 0:
                    buf[_B_LAST * NP + p] = T(li - start)
                if li > rowmax[y]:
                    rowmax[y] = li
                # Q_init = T_N (<v_C, bg> - v_A): alphas = 1 - T_N
                q = -v_alpha[c, y0 + y, x0 + x]
                for k in range(D):
                    vk = v_color[c, y0 + y, x0 + x, k]
                    buf[(_B_VC + k) * NP + p] = vk
                    if has_bg:
                        q += vk * backgrounds[c, k]
                buf[_B_Q * NP + p] = tf * q
            if rowmax[y] > jmax:
                jmax = rowmax[y]
        if jmax < start:
            continue
        vcol = np.zeros(D, dtype=T)
        for j in range(jmax, start - 1, -1):
            lo = np.int64(isect_rows[j, 0])
            hi = np.int64(isect_rows[j, 1])
            if lo >= hi:
                continue
            fi = flat_ids[j]
            (mx, my, ca, cb, cc, op, ci,
             c0, c1, c2, c3) = _gaussian(fi, means2d, conics, opacities, colors,
                                         colors_per_camera, c * N, DI, T)
            jr = T(j - start)
            g_mx = T(0.0)
            g_my = T(0.0)
            g_ca = T(0.0)
            g_cb = T(0.0)
            g_cc = T(0.0)
            g_op = T(0.0)
            a_mx = T(0.0)
            a_my = T(0.0)
            v0 = T(0.0)
            v1 = T(0.0)
            v2 = T(0.0)
            v3 = T(0.0)
            for k in range(4, D):
                vcol[k] = T(0.0)
            touched = False
            for y in range(lo, hi):
                if rowmax[y] < j:
                    continue
                touched = True
                # whole rows: LLVM vectorises this loop 16 lanes wide, so a half row would run
                # its scalar remainder
                pb = np.uint64(y * TILE)
                pe = np.uint64(y * TILE + xw)
                if D > 4:
                    for p in range(pb, pe):
                        buf[_OB_GD + p] = T(0.0)
                    for k in range(4, D):
                        ck = colors[ci, k]
                        ok = np.uint64((_B_VC + k) * NP)
                        for p in range(pb, pe):
                            buf[_OB_GD + p] += buf[ok + p] * ck
                for p in range(pb, pe):
                    dx = mx - buf[_OB_PX + p]
                    dy = my - buf[_OB_PY + p]
                    sig = _sigma(dx, dy, ca, cb, cc, T)
                    G, alr, al, ok = _alpha(sig, op, T)
                    valid = (buf[_OB_LAST + p] >= jr) & ok
                    ra = T(1.0) / (T(1.0) - al)
                    t = buf[_OB_T + p]
                    ti = t * ra
                    w = al * ti if valid else T(0.0)
                    vc0 = buf[_OB_VC0 + p]
                    vc1 = buf[_OB_VC1 + p]
                    vc2 = buf[_OB_VC2 + p]
                    vc3 = buf[_OB_VC3 + p]
                    gd = vc0 * c0 + vc1 * c1 + vc2 * c2 + vc3 * c3 + buf[_OB_GD + p]
                    q = buf[_OB_Q + p]
                    v_al = ti * gd - q * ra
                    vf = T(1.0) if valid else T(0.0)
                    buf[_OB_T + p] = vf * ti + (T(1.0) - vf) * t  # exact blend, see raster_fwd
                    buf[_OB_Q + p] = q + w * gd
                    buf[_OB_W + p] = w
                    v0 += w * vc0
                    v1 += w * vc1
                    v2 += w * vc2
                    v3 += w * vc3
                    live = valid & (alr <= amax)
                    v_sig = -al * v_al if live else T(0.0)
                    g_op += G * v_al if live else T(0.0)
                    g_ca += T(0.5) * dx * dx * v_sig
                    g_cb += dx * dy * v_sig
                    g_cc += T(0.5) * dy * dy * v_sig
                    gx = (ca * dx + cb * dy) * v_sig
                    gy = (cb * dx + cc * dy) * v_sig
                    g_mx += gx
                    g_my += gy
                    a_mx += abs(gx)
                    a_my += abs(gy)
                for k in range(4, D):
                    s = T(0.0)
                    ok = np.uint64((_B_VC + k) * NP)
                    for p in range(pb, pe):
                        s += buf[_OB_W + p] * buf[ok + p]
                    vcol[k] += s
            if touched:
                gb = gbuf[j]
                gb[0] = g_mx
                gb[1] = g_my
                gb[2] = g_ca
                gb[3] = g_cb
                gb[4] = g_cc
                gb[5] = g_op
                gb[6] = v0
                if D > 1:
                    gb[7] = v1
                if D > 2:
                    gb[8] = v2
                if D > 3:
                    gb[9] = v3
                for k in range(4, D):
                    gb[6 + k] = vcol[k]
                gb[6 + D] = a_mx
                gb[7 + D] = a_my


@njit(cache=True)
def reduce_isects(gbuf, flat_ids, out):
    """out[i, :] = sum of gbuf[j, :] over the intersections j of flat id i, in the order of j
    (serial, so the sum is the same for any thread count; ``out`` starts at zero)."""
    K = gbuf.shape[1]
    for j in range(gbuf.shape[0]):
        i = flat_ids[j]
        for k in range(K):
            out[i, k] += gbuf[j, k]
