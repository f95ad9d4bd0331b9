"""Real spherical harmonics up to degree 3 (the 3DGS / gsplat basis and sign convention).

``colors = max(sum_k B_k(d) coeffs_k + 0.5, 0)`` with ``d`` the unit direction from the camera
centre to the Gaussian, exactly as gsplat's ``rasterization`` does with ``sh_degree`` set. The
basis is evaluated as polynomials in the normalised direction (x, y, z); the CPU kernel uses the
same polynomials and their derivatives.
"""

from __future__ import annotations

import torch
from torch import Tensor

from ._constants import DIR_EPS2

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


def num_sh_bases(degree: int) -> int:
    return (degree + 1) ** 2


def sh_bases(degree: int, dirs: Tensor) -> Tensor:
    """Basis values [..., (degree + 1)^2] at unit directions ``dirs`` [..., 3]."""
    if not 0 <= degree <= 3:
        raise ValueError(f"sh_degree must be in 0..3, got {degree}")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        out += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [SH_C2[0] * (x * y), SH_C2[1] * (y * z), SH_C2[2] * (2.0 * zz - xx - yy),
                SH_C2[3] * (x * z), SH_C2[4] * (xx - yy)]
        if degree >= 3:
            out += [SH_C3[0] * y * (3.0 * xx - yy),
                    SH_C3[1] * (x * y) * z,
                    SH_C3[2] * y * (4.0 * zz - xx - yy),
                    SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
                    SH_C3[4] * x * (4.0 * zz - xx - yy),
                    SH_C3[5] * z * (xx - yy),
                    SH_C3[6] * x * (xx - 3.0 * yy)]
    return torch.stack(out, -1)


def normalize_dirs(dirs: Tensor) -> Tensor:
    """``dirs / |dirs|`` with the norm clamped below (a zero vector stays zero, no NaN)."""
    n2 = (dirs * dirs).sum(-1, keepdim=True)
    return dirs / torch.sqrt(torch.clamp(n2, min=DIR_EPS2))


def spherical_harmonics(degree: int, dirs: Tensor, coeffs: Tensor) -> Tensor:
    """Evaluate SH ``coeffs`` [..., K, 3] (K >= (degree+1)^2; extra bands ignored) in the
    directions ``dirs`` [..., 3] (any length; normalised here). Returns [..., 3], without the
    +0.5 offset and clamp that :func:`sh_to_color` adds."""
    nb = num_sh_bases(degree)
    if coeffs.shape[-2] < nb:
        raise ValueError(f"sh_degree {degree} needs {nb} coefficients, got {coeffs.shape[-2]}")
    bases = sh_bases(degree, normalize_dirs(dirs))
    return (bases[..., None] * coeffs[..., :nb, :]).sum(-2)


def sh_to_color(degree: int, dirs: Tensor, coeffs: Tensor) -> Tensor:
    """gsplat's colour from SH: ``clamp_min(SH(dirs) + 0.5, 0)``."""
    return torch.clamp_min(spherical_harmonics(degree, dirs, coeffs) + 0.5, 0.0)
