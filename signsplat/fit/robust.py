"""Robust kernels applied to residual norms (torch, differentiable, finite everywhere).

All functions take the squared residual norm ``r2`` (any shape, >= 0, units px^2 or m^2) and a
scale ``sigma`` in the same unit as the residual; they return a per-element cost with the same
shape, behaving like ``r2`` (up to a constant) for small residuals.
"""

from __future__ import annotations

import torch


def geman_mcclure(r2: torch.Tensor, sigma: float) -> torch.Tensor:
    """Geman-McClure: ``sigma^2 r^2 / (sigma^2 + r^2)``; saturates at ``sigma^2`` for outliers."""
    s2 = float(sigma) ** 2
    return s2 * r2 / (s2 + r2)


def huber(r2: torch.Tensor, sigma: float) -> torch.Tensor:
    """Huber on the norm: ``r^2`` below ``sigma``, ``2 sigma r - sigma^2`` above (linear).

    The square root is only taken where ``r > sigma`` (and clamped), so the gradient stays finite
    at ``r = 0``.
    """
    s = float(sigma)
    big = r2 > s * s
    r = torch.sqrt(torch.where(big, r2, torch.full_like(r2, s * s)).clamp_min(1e-12))
    return torch.where(big, 2 * s * r - s * s, r2)


def l2(r2: torch.Tensor, sigma: float = 1.0) -> torch.Tensor:
    """Plain squared error (no robustness), for comparison."""
    return r2


KERNELS = {"geman_mcclure": geman_mcclure, "huber": huber, "l2": l2}


def kernel(name: str):
    """Look a kernel up by its config name; unknown names raise ValueError listing the known."""
    try:
        return KERNELS[name]
    except KeyError:
        raise ValueError(f"unknown robust kernel {name!r}; known: {sorted(KERNELS)}") from None
