"""EWA projection of 3D Gaussians, in plain PyTorch (the reference; autograd does the backward).

The arithmetic is :mod:`._ewa`'s, the very functions the CPU kernel compiles
(:func:`signsplat.render._kernels.project_fwd`), so both give bit-identical projected means for
float32 inputs. Culled (camera, Gaussian) entries have ``radii == 0`` and zeros elsewhere; the
intermediate values of culled entries are replaced by harmless ones before any division, so
their (zero) gradients never turn into NaN.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from . import _ewa
from ._constants import ALPHA_THRESHOLD, DEFAULT_EPS2D, MAX_EXTENT_SIGMA, MAX_RADIUS, QUAT_EPS2


def quat_to_rotmat(quats: Tensor) -> tuple[Tensor, ...]:
    """Rotation matrix entries (r00, r01, ..., r22) of ``quats`` [..., 4] (wxyz, any norm).

    Normalised as ``q / sqrt(max(|q|^2, QUAT_EPS2))``: a zero quaternion gives the identity
    matrix (its formula evaluated at q = 0) and a zero gradient, never NaN.
    """
    qw, qx, qy, qz = quats.unbind(-1)
    n2 = qw * qw + qx * qx + qy * qy + qz * qz
    inv = 1.0 / torch.sqrt(torch.clamp(n2, min=QUAT_EPS2))
    return _ewa.rotmat(qw * inv, qx * inv, qy * inv, qz * inv, float)


def covariance(quats: Tensor, scales: Tensor) -> tuple[Tensor, ...]:
    """World covariance ``R S S^T R^T`` as its six entries (S00, S01, S02, S11, S12, S22)."""
    s0, s1, s2 = scales.unbind(-1)
    return _ewa.world_cov(quat_to_rotmat(quats), s0, s1, s2)[1]


def project(means: Tensor, quats: Tensor, scales: Tensor, opacities: Tensor, viewmats: Tensor,
            Ks: Tensor, width: int, height: int, eps2d: float = DEFAULT_EPS2D, near_plane: float = 0.01,
            far_plane: float = 1e10, antialiased: bool = False) -> dict[str, Tensor]:
    """Project N Gaussians into C pinhole cameras.

    Returns ``radii`` [C, N, 2] int32, ``means2d`` [C, N, 2], ``depths`` [C, N], ``conics``
    [C, N, 3] (inverse of the dilated 2D covariance: a, b, c with sigma = 0.5 (a dx^2 + c dy^2)
    + b dx dy) and ``compensations`` [C, N] (1 unless ``antialiased``).
    """
    C = viewmats.shape[0]
    m0, m1, m2 = means.unbind(-1)  # [N]
    V = tuple(viewmats[:, i, j, None] for i in range(3) for j in range(4))  # [C, 1] each
    px, py, pz = _ewa.cam_point(V, m0, m1, m2)
    depth_ok = (pz >= near_plane) & (pz <= far_plane)
    pz_s = torch.where(depth_ok, pz, torch.ones_like(pz))
    Sc = _ewa.cam_cov(V, covariance(quats, scales))  # [C, N]

    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    u = px / pz_s
    v = py / pz_s
    mx = fx * u + cx
    my = fy * v + cy
    lxp, lxn, lyp, lyn = _ewa.fov_limits(fx, fy, cx, cy, width, height, float)
    uc = torch.clamp(u, min=-lxn, max=lxp)
    vc = torch.clamp(v, min=-lyn, max=lyp)
    J = _ewa.jacobian(fx, fy, pz_s, uc, vc)
    _JS, (cov00, cov01, cov11) = _ewa.cov2d(J, Sc)
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
