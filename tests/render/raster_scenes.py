"""Small deterministic scenes for the rasterizer tests (imported by the test modules)."""

from __future__ import annotations

import math

import torch


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, -1.0, 0.0)) -> torch.Tensor:
    """World-to-camera matrix (OpenCV convention: x right, y down, z forward)."""
    eye_t = torch.tensor(eye, dtype=torch.float64)
    f = torch.tensor(target, dtype=torch.float64) - eye_t
    f = f / f.norm()
    r = torch.linalg.cross(torch.tensor(up, dtype=torch.float64), f)
    r = r / r.norm()
    d = torch.linalg.cross(f, r)
    R = torch.stack([r, d, f])
    V = torch.eye(4, dtype=torch.float64)
    V[:3, :3] = R
    V[:3, 3] = -R @ eye_t
    return V


def cameras(C: int, W: int, H: int, dist: float = 2.2, focal: float | None = None):
    """C cameras on an arc around the origin, slightly different intrinsics each."""
    f = 1.2 * W if focal is None else focal
    vms, Ks = [], []
    for c in range(C):
        ang = 0.4 * (c - (C - 1) / 2)
        eye = (dist * math.sin(ang), 0.1 * c, -dist * math.cos(ang))
        vms.append(look_at(eye))
        Ks.append(torch.tensor([[f, 0, W / 2 + 0.3 * c], [0, f * 1.01, H / 2 - 0.2 * c],
                                [0, 0, 1]], dtype=torch.float64))
    return torch.stack(vms), torch.stack(Ks)


def scene(N: int = 300, W: int = 48, H: int = 40, C: int = 1, seed: int = 0,
          dtype=torch.float32, sh_degree: int | None = None, D: int = 3,
          scale=(0.02, 0.08), box: float = 0.5, opacity=(0.05, 0.95), per_camera=False):
    """Random Gaussians in a box around the origin, seen by ``cameras(C, W, H)``."""
    g = torch.Generator().manual_seed(seed)
    f64 = torch.float64
    means = (torch.rand(N, 3, generator=g, dtype=f64) * 2 - 1) * box
    means[:, 2] *= 0.5
    quats = torch.randn(N, 4, generator=g, dtype=f64)
    lo, hi = math.log(scale[0]), math.log(scale[1])
    scales = torch.exp(torch.rand(N, 3, generator=g, dtype=f64) * (hi - lo) + lo)
    opac = torch.rand(N, generator=g, dtype=f64) * (opacity[1] - opacity[0]) + opacity[0]
    lead = (C,) if per_camera else ()
    if sh_degree is None:
        colors = torch.rand(*lead, N, D, generator=g, dtype=f64)
    else:
        colors = torch.randn(*lead, N, (sh_degree + 1) ** 2, 3, generator=g, dtype=f64) * 0.3
    vm, Ks = cameras(C, W, H)
    out = dict(means=means, quats=quats, scales=scales, opacities=opac, colors=colors,
               viewmats=vm, Ks=Ks)
    out = {k: v.to(dtype) for k, v in out.items()}
    out.update(width=W, height=H, sh_degree=sh_degree)
    return out


DIFF_KEYS = ("means", "quats", "scales", "opacities", "colors", "viewmats")


def leafs(s: dict, keys=DIFF_KEYS) -> dict:
    """Copy of a scene whose tensors in ``keys`` are fresh leaves requiring grad."""
    return {k: (v.detach().clone().requires_grad_(k in keys) if torch.is_tensor(v) else v)
            for k, v in s.items()}
