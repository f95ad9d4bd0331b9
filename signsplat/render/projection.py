"""EWA projection of 3D Gaussians, in plain PyTorch (the reference; autograd does the backward).

Written element by element, in the same order of floating-point operations as the CPU kernel
(:func:`signsplat.render._kernels.project_fwd`), so both give bit-identical projected means for
float32 inputs. Culled (camera, Gaussian) entries have ``radii == 0`` and zeros elsewhere; the
intermediate values of culled entries are replaced by harmless ones before any division, so
their (zero) gradients never turn into NaN.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from ._constants import (
    ALPHA_THRESHOLD,
    FOV_CLAMP_MARGIN,
    MAX_EXTENT_SIGMA,
    MAX_RADIUS,
    QUAT_EPS2,
)


def quat_to_rotmat(quats: Tensor) -> tuple[Tensor, ...]:
    """Rotation matrix entries (r00, r01, ..., r22) of ``quats`` [..., 4] (wxyz, any norm).

    Normalised as ``q / sqrt(max(|q|^2, QUAT_EPS2))``: a zero quaternion gives the identity
    matrix (its formula evaluated at q = 0) and a zero gradient, never NaN.
    """
    qw, qx, qy, qz = quats.unbind(-1)
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    inv = 1.0 / torch.sqrt(torch.clamp(n2, min=QUAT_EPS2))
    w, x, y, z = qw * inv, qx * inv, qy * inv, qz * inv
    r00 = 1.0 - 2.0 * (y * y + z * z)
    r01 = 2.0 * (x * y - w * z)
    r02 = 2.0 * (x * z + w * y)
    r10 = 2.0 * (x * y + w * z)
    r11 = 1.0 - 2.0 * (x * x + z * z)
    r12 = 2.0 * (y * z - w * x)
    r20 = 2.0 * (x * z - w * y)
    r21 = 2.0 * (y * z + w * x)
    r22 = 1.0 - 2.0 * (x * x + y * y)
    return r00, r01, r02, r10, r11, r12, r20, r21, r22


def covariance(quats: Tensor, scales: Tensor) -> tuple[Tensor, ...]:
    """World covariance ``R S S R^T`` as its six entries (S00, S01, S02, S11, S12, S22)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22 = quat_to_rotmat(quats)
    s0, s1, s2 = scales.unbind(-1)
    M00, M01, M02 = r00 * s0, r01 * s1, r02 * s2
    M10, M11, M12 = r10 * s0, r11 * s1, r12 * s2
    M20, M21, M22 = r20 * s0, r21 * s1, r22 * s2
    S00 = M00 * M00 + M01 * M01 + M02 * M02
    S01 = M00 * M10 + M01 * M11 + M02 * M12
    S02 = M00 * M20 + M01 * M21 + M02 * M22
    S11 = M10 * M10 + M11 * M11 + M12 * M12
    S12 = M10 * M20 + M11 * M21 + M12 * M22
    S22 = M20 * M20 + M21 * M21 + M22 * M22
    return S00, S01, S02, S11, S12, S22


def project(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, viewmats: Tensor,
            Ks: Tensor, width: int, height: int, eps2d: float = 0.3, near_plane: float = 0.01,
            far_plane: float = 1e10, antialiased: bool = False) -> dict[str, Tensor]:
    """Project N Gaussians into C pinhole cameras.

    Returns ``radii`` [C, N, 2] int32, ``means2d`` [C, N, 2], ``depths`` [C, N], ``conics``
    [C, N, 3] (inverse of the dilated 2D covariance: a, b, c with sigma = 0.5 (a dx^2 + c dy^2)
    + b dx dy) and ``compensations`` [C, N] (1 unless ``antialiased``).
    """
    C = viewmats.shape[0]
    m0, m1, m2 = means.unbind(-1)  # [N]

    def V(i: int, j: int) -> Tensor:
        return viewmats[:, i, j, None]  # [C, 1]

    px = V(0, 0) * m0 + V(0, 1) * m1 + V(0, 2) * m2 + V(0, 3)
    py = V(1, 0) * m0 + V(1, 1) * m1 + V(1, 2) * m2 + V(1, 3)
    pz = V(2, 0) * m0 + V(2, 1) * m1 + V(2, 2) * m2 + V(2, 3)
    depth_ok = (pz >= near_plane) & (pz <= far_plane)
    pz_s = torch.where(depth_ok, pz, torch.ones_like(pz))

    S00, S01, S02, S11, S12, S22 = covariance(quats, scales)  # [N]
    A00 = V(0, 0) * S00 + V(0, 1) * S01 + V(0, 2) * S02
    A01 = V(0, 0) * S01 + V(0, 1) * S11 + V(0, 2) * S12
    A02 = V(0, 0) * S02 + V(0, 1) * S12 + V(0, 2) * S22
    A10 = V(1, 0) * S00 + V(1, 1) * S01 + V(1, 2) * S02
    A11 = V(1, 0) * S01 + V(1, 1) * S11 + V(1, 2) * S12
    A12 = V(1, 0) * S02 + V(1, 1) * S12 + V(1, 2) * S22
    A20 = V(2, 0) * S00 + V(2, 1) * S01 + V(2, 2) * S02
    A21 = V(2, 0) * S01 + V(2, 1) * S11 + V(2, 2) * S12
    A22 = V(2, 0) * S02 + V(2, 1) * S12 + V(2, 2) * S22
    C00 = A00 * V(0, 0) + A01 * V(0, 1) + A02 * V(0, 2)
    C01 = A00 * V(1, 0) + A01 * V(1, 1) + A02 * V(1, 2)
    C02 = A00 * V(2, 0) + A01 * V(2, 1) + A02 * V(2, 2)
    C11 = A10 * V(1, 0) + A11 * V(1, 1) + A12 * V(1, 2)
    C12 = A10 * V(2, 0) + A11 * V(2, 1) + A12 * V(2, 2)
    C22 = A20 * V(2, 0) + A21 * V(2, 1) + A22 * V(2, 2)

    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    u = px / pz_s
    v = py / pz_s
    mx = fx * u + cx
    my = fy * v + cy
    tanx = 0.5 * width / fx
    tany = 0.5 * height / fy
    lxp = (width - cx) / fx + FOV_CLAMP_MARGIN * tanx
    lxn = cx / fx + FOV_CLAMP_MARGIN * tanx
    lyp = (height - cy) / fy + FOV_CLAMP_MARGIN * tany
    lyn = cy / fy + FOV_CLAMP_MARGIN * tany
    uc = torch.clamp(u, min=-lxn, max=lxp)
    vc = torch.clamp(v, min=-lyn, max=lyp)
    J00 = fx / pz_s
    J02 = -fx * uc / pz_s
    J11 = fy / pz_s
    J12 = -fy * vc / pz_s
    T00 = J00 * C00 + J02 * C02
    T01 = J00 * C01 + J02 * C12
    T02 = J00 * C02 + J02 * C22
    T11 = J11 * C11 + J12 * C12
    T12 = J11 * C12 + J12 * C22
    cov00 = T00 * J00 + T02 * J02
    cov01 = T01 * J11 + T02 * J12
    cov11 = T11 * J11 + T12 * J12
    det_orig = cov00 * cov11 - cov01 * cov01
    a = cov00 + eps2d
    c = cov11 + eps2d
    b = cov01
    det = a * c - b * b
    det_ok = (det > 0) & (det < math.inf)
    det_s = torch.where(det_ok, det, torch.ones_like(det))
    if antialiased:
        r = det_orig / det_s
        pos = r > 0
        comp = torch.where(pos, torch.sqrt(torch.where(pos, r, torch.ones_like(r))),
                           torch.zeros_like(r))
    else:
        comp = torch.ones_like(det)

    with torch.no_grad():  # visibility and radii are not differentiable
        op = opacities[None, :] * comp if antialiased else opacities[None, :].expand_as(det)
        op_ok = op >= ALPHA_THRESHOLD
        op_s = torch.where(op_ok, op, torch.ones_like(op))
        ext = torch.clamp(torch.sqrt(2.0 * torch.log(op_s / ALPHA_THRESHOLD)),
                          max=MAX_EXTENT_SIGMA)
        a_s = torch.where(det_ok, a, torch.ones_like(a))
        c_s = torch.where(det_ok, c, torch.ones_like(c))
        rx = torch.clamp(torch.ceil(ext * torch.sqrt(a_s)), max=MAX_RADIUS)
        ry = torch.clamp(torch.ceil(ext * torch.sqrt(c_s)), max=MAX_RADIUS)
        finite = torch.isfinite(mx) & torch.isfinite(my)
        inside = ~((mx + rx <= 0) | (mx - rx >= width) | (my + ry <= 0) | (my - ry >= height))
        valid = depth_ok & det_ok & finite & op_ok & ((rx > 0) | (ry > 0)) & inside
        radii = torch.stack([torch.where(valid, rx, 0.0), torch.where(valid, ry, 0.0)], -1)
        radii = radii.to(torch.int32)

    zero = torch.zeros_like(det)
    means2d = torch.stack([torch.where(valid, mx, zero), torch.where(valid, my, zero)], -1)
    conics = torch.stack([torch.where(valid, c / det_s, zero),
                          torch.where(valid, -b / det_s, zero),
                          torch.where(valid, a / det_s, zero)], -1)
    depths = torch.where(valid, pz, zero)
    comps = torch.where(valid, comp, torch.ones_like(comp))
    assert means2d.shape == (C, means.shape[0], 2)
    return {"radii": radii, "means2d": means2d, "depths": depths, "conics": conics,
            "compensations": comps}


def camera_centers(viewmats: Tensor) -> Tensor:
    """World positions of the cameras [C, 3] (``inverse(viewmats)[:, :3, 3]``, as gsplat)."""
    return torch.linalg.inv(viewmats)[:, :3, 3]
