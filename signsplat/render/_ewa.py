"""The EWA projection formulas, written once for the PyTorch reference and the Numba kernels.

Every function here is plain arithmetic (``+ - * /`` and nothing else), so the same source runs
on Python floats, on broadcasting tensors (:mod:`.projection`, autograd does the backward) and,
compiled with ``njit(inline="always")``, inside the CPU kernels (:mod:`._kernels`). The order
of the floating-point operations is therefore the same in both backends and float32 projected
means agree bit for bit (a one-ulp shift of a sharp Gaussian's centre changes pixels by ~1e-4).

``T`` turns a literal into the working float type: ``np.float32`` / ``np.float64`` in the
kernels (a bare Python literal would promote Numba's float32 arithmetic to float64), ``float``
for tensors (torch keeps the tensor's dtype). Clamps, square roots and the culling tests are
backend-specific and stay with the callers.

Matrices are passed as flat tuples, row-major: the rotation ``r = (r00, r01, ..., r22)``, the
world-to-camera rows ``V = (v00, v01, v02, v03, v10, ..., v23)`` (rows 0-2 of the 4x4 matrix),
symmetric 3x3 matrices as ``(S00, S01, S02, S11, S12, S22)``.
"""

from __future__ import annotations

from ._constants import FOV_CLAMP_MARGIN


def rotmat(w, x, y, z, T):
    """Rotation matrix of the unit quaternion (w, x, y, z) as a flat tuple (r00, ..., r22)."""
    return (T(1.0) - T(2.0) * (y * y + z * z), T(2.0) * (x * y - w * z),
            T(2.0) * (x * z + w * y),
            T(2.0) * (x * y + w * z), T(1.0) - T(2.0) * (x * x + z * z),
            T(2.0) * (y * z - w * x),
            T(2.0) * (x * z - w * y), T(2.0) * (y * z + w * x),
            T(1.0) - T(2.0) * (x * x + y * y))


def world_cov(r, s0, s1, s2):
    """``M = R diag(s)`` (flat, 9) and the world covariance ``S = M M^T`` (6 entries)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = r
    M00, M01, M02 = r00 * s0, r01 * s1, r02 * s2
    M10, M11, M12 = r10 * s0, r11 * s1, r12 * s2
    M20, M21, M22 = r20 * s0, r21 * s1, r22 * s2
    S = (M00 * M00 + M01 * M01 + M02 * M02,
         M00 * M10 + M01 * M11 + M02 * M12,
         M00 * M20 + M01 * M21 + M02 * M22,
         M10 * M10 + M11 * M11 + M12 * M12,
         M10 * M20 + M11 * M21 + M12 * M22,
         M20 * M20 + M21 * M21 + M22 * M22)
    return (M00, M01, M02, M10, M11, M12, M20, M21, M22), S


def cam_point(V, m0, m1, m2):
    """Camera-space position ``R m + t`` of the world point (m0, m1, m2)."""
    v00, v01, v02, v03, v10, v11, v12, v13, v20, v21, v22, v23 = V
    return (v00 * m0 + v01 * m1 + v02 * m2 + v03,
            v10 * m0 + v11 * m1 + v12 * m2 + v13,
            v20 * m0 + v21 * m1 + v22 * m2 + v23)


def cam_cov(V, S):
    """Camera-space covariance ``R S R^T`` (6 entries), as ``A = R S`` then ``A R^T``."""
    v00, v01, v02, _v03, v10, v11, v12, _v13, v20, v21, v22, _v23 = V
    S00, S01, S02, S11, S12, S22 = S
    A00 = v00 * S00 + v01 * S01 + v02 * S02
    A01 = v00 * S01 + v01 * S11 + v02 * S12
    A02 = v00 * S02 + v01 * S12 + v02 * S22
    A10 = v10 * S00 + v11 * S01 + v12 * S02
    A11 = v10 * S01 + v11 * S11 + v12 * S12
    A12 = v10 * S02 + v11 * S12 + v12 * S22
    A20 = v20 * S00 + v21 * S01 + v22 * S02
    A21 = v20 * S01 + v21 * S11 + v22 * S12
    A22 = v20 * S02 + v21 * S12 + v22 * S22
    return (A00 * v00 + A01 * v01 + A02 * v02,
            A00 * v10 + A01 * v11 + A02 * v12,
            A00 * v20 + A01 * v21 + A02 * v22,
            A10 * v10 + A11 * v11 + A12 * v12,
            A10 * v20 + A11 * v21 + A12 * v22,
            A20 * v20 + A21 * v21 + A22 * v22)


def fov_limits(fx, fy, cx, cy, width, height, T):
    """Clamp range of x/z and y/z for the Jacobian: the image frustum widened by
    ``FOV_CLAMP_MARGIN`` of the half field of view on each side. Returns (lxp, lxn, lyp, lyn):
    ``-lxn <= x/z <= lxp``, ``-lyn <= y/z <= lyp``."""
    tanx = T(0.5) * width / fx
    tany = T(0.5) * height / fy
    return ((width - cx) / fx + T(FOV_CLAMP_MARGIN) * tanx,
            cx / fx + T(FOV_CLAMP_MARGIN) * tanx,
            (height - cy) / fy + T(FOV_CLAMP_MARGIN) * tany,
            cy / fy + T(FOV_CLAMP_MARGIN) * tany)


def jacobian(fx, fy, z, uc, vc):
    """Non-zero entries (J00, J02, J11, J12) of the projection's Jacobian
    ``[[fx/z, 0, -fx u/z], [0, fy/z, -fy v/z]]`` at the clamped ``u = x/z``, ``v = y/z``."""
    return fx / z, -fx * uc / z, fy / z, -fy * vc / z


def cov2d(J, Sc):
    """``J Sc`` (its rows, 6 entries: T00, T01, T02, T10, T11, T12) and the 2D covariance
    ``J Sc J^T`` as (cov00, cov01, cov11)."""
    J00, J02, J11, J12 = J
    C00, C01, C02, C11, C12, C22 = Sc
    T00 = J00 * C00 + J02 * C02
    T01 = J00 * C01 + J02 * C12
    T02 = J00 * C02 + J02 * C22
    T10 = J11 * C01 + J12 * C02
    T11 = J11 * C11 + J12 * C12
    T12 = J11 * C12 + J12 * C22
    return ((T00, T01, T02, T10, T11, T12),
            (T00 * J00 + T02 * J02, T01 * J11 + T02 * J12, T11 * J11 + T12 * J12))
