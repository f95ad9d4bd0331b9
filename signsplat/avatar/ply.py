"""Standard 3D Gaussian Splatting PLY (Kerbl et al. 2023 layout), readable by common splat viewers.

Binary little-endian, one ``vertex`` element, float32 properties in this order:
``x y z nx ny nz f_dc_0..2 f_rest_0..(3*(K-1)-1) opacity scale_0..2 rot_0..3`` where
K = (sh_degree + 1)^2. ``f_rest`` is channel-major (all R coefficients, then G, then B),
``opacity`` is the logit, ``scale_*`` the natural log of the scales in metres and ``rot_*`` the
quaternion (w, x, y, z). Normals are written as zeros, as 3DGS does.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from signsplat.errors import InputError
from signsplat.io.atomic import atomic_path


def ply_fields(sh_degree: int) -> list[str]:
    k = (sh_degree + 1) ** 2
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(3 * (k - 1))]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def write_gaussian_ply(path: str | os.PathLike, means: torch.Tensor, quats: torch.Tensor,
                       scales: torch.Tensor, opacities: torch.Tensor, sh: torch.Tensor,
                       sh_degree: int) -> Path:
    """Write N Gaussians atomically.

    means (N,3) m; quats (N,4) wxyz; scales (N,3) m (> 0); opacities (N,) in (0,1);
    sh (N,K',3) SH coefficients with K' >= (sh_degree+1)^2 (extra bands are dropped).
    """
    k = (sh_degree + 1) ** 2
    if sh.shape[1] < k:
        raise ValueError(f"sh has {sh.shape[1]} bases, degree {sh_degree} needs {k}")
    n = means.shape[0]
    sh = sh[:, :k].detach().float().cpu()
    op = opacities.detach().float().cpu().clamp(1e-6, 1 - 1e-6)
    cols = [
        means.detach().float().cpu(),
        torch.zeros(n, 3),
        sh[:, 0],
        sh[:, 1:].transpose(1, 2).reshape(n, -1),
        (torch.log(op) - torch.log1p(-op)).reshape(n, 1),
        torch.log(scales.detach().float().cpu().clamp_min(1e-12)),
        quats.detach().float().cpu(),
    ]
    data = torch.cat(cols, 1).numpy().astype("<f4")
    names = ply_fields(sh_degree)
    assert data.shape[1] == len(names)
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name in names]
    header += ["end_header"]
    path = Path(path)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(("\n".join(header) + "\n").encode("ascii"))
            fh.write(np.ascontiguousarray(data).tobytes())
    return path


def read_gaussian_ply(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a PLY written in the layout above: property name -> (N,) float32 array."""
    path = Path(path)
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply") or end < 0:
        raise InputError(f"{path}: not a PLY file")
    lines = raw[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise InputError(f"{path}: only binary little-endian PLY is supported")
    n = next(int(line.split()[2]) for line in lines if line.startswith("element vertex"))
    names = [line.split()[2] for line in lines if line.startswith("property float")]
    data = np.frombuffer(raw[end + len(b"end_header\n"):], dtype="<f4", count=n * len(names))
    data = data.reshape(n, len(names))
    return {name: data[:, i] for i, name in enumerate(names)}
