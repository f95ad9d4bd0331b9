"""Image losses and metrics: L1, D-SSIM, PSNR, and LPIPS when weights exist locally.

SSIM is kornia's definition (Gaussian window of sigma 1.5, ``window`` taps, reflect padding,
C1 = 0.01^2, C2 = 0.03^2, 1e-12 added to the denominator), computed here with the blur as two
matrix products: ``A_h X A_w^T`` with banded matrices that hold the window and the reflect
padding. On the avatar's small crops this was 3x faster than the depthwise convolutions
forward and backward (docs/avatar.md, "Cost of a step"); kornia stays the tests' oracle.

Images are (B, 3, H, W) float in [0, 1]. LPIPS (Zhang et al. 2018, AlexNet variant) needs
weights that this project does not ship and never downloads: :func:`load_lpips` reads one local
state-dict file holding the AlexNet feature layers under torchvision's names
(``features.{0,3,6,8,10}.{weight,bias}``) and the LPIPS linear heads under the ``lpips``
package's names (``lin{0..4}.model.1.weight``), i.e. the two official files merged. With no
file, LPIPS is reported as unavailable and its loss weight is ignored.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

import torch
from torch import nn
from torch.nn import functional as F

from signsplat.errors import InputError


def l1(render: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    return (render - gt).abs().mean()


_BLUR: dict[tuple, torch.Tensor] = {}


def blur_matrix(n: int, window: int, dtype: torch.dtype = torch.float32,
                device: torch.device | str = "cpu") -> torch.Tensor:
    """(n, n) matrix of a ``window``-tap Gaussian blur (sigma 1.5, kornia's SSIM window) with
    reflect padding (``-1 -> 1``, ``n -> n - 2``): ``A @ x`` blurs x along its first axis."""
    key = (n, window, dtype, str(device))
    if key not in _BLUR:
        r = window // 2
        x = np.arange(window) - r
        g = np.exp(-x ** 2 / (2 * 1.5 ** 2))
        g = g / g.sum()
        j = np.arange(n)[:, None] + x[None, :]  # (n, window) source rows
        if n > 1:  # reflect about 0 and n - 1 (repeatedly, for images shorter than r)
            period = 2 * (n - 1)
            j = np.mod(j, period)
            j = np.where(j >= n, period - j, j)
        else:
            j = np.zeros_like(j)
        a = np.zeros((n, n))
        np.add.at(a, (np.repeat(np.arange(n), window), j.reshape(-1)), np.tile(g, n))
        if len(_BLUR) > 256:
            _BLUR.clear()
        _BLUR[key] = torch.as_tensor(a).to(dtype=dtype, device=device)
    return _BLUR[key]


def ssim_map(x: torch.Tensor, y: torch.Tensor, window: int = 11) -> torch.Tensor:
    """SSIM per pixel and channel (B, C, H, W) of (B, C, H, W) images (kornia's definition)."""
    h, w = x.shape[-2:]
    a_h = blur_matrix(h, window, x.dtype, x.device)
    a_w = blur_matrix(w, window, x.dtype, x.device)

    def blur(t: torch.Tensor) -> torch.Tensor:
        return a_h @ t @ a_w.T

    c1, c2 = 0.01 ** 2, 0.03 ** 2
    with torch.no_grad() if not y.requires_grad else torch.enable_grad():
        mu2, e22 = blur(torch.cat([y, y * y], 1)).split(y.shape[1], 1)
    mu1, e11, e12 = blur(torch.cat([x, x * x, x * y], 1)).split(x.shape[1], 1)
    mu12, mu1_sq, mu2_sq = mu1 * mu2, mu1 * mu1, mu2 * mu2
    num = (2 * mu12 + c1) * (2 * (e12 - mu12) + c2)
    den = (mu1_sq + mu2_sq + c1) * ((e11 - mu1_sq) + (e22 - mu2_sq) + c2)
    return num / (den + 1e-12)


def dssim(render: torch.Tensor, gt: torch.Tensor, window: int = 11) -> torch.Tensor:
    """1 - mean SSIM (Gaussian window of ``window`` pixels)."""
    return 1.0 - ssim_map(render, gt, window).mean()


def ssim(render: torch.Tensor, gt: torch.Tensor, window: int = 11,
         mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean SSIM per image (B,); over ``mask`` (B,1,H,W) pixels when given."""
    s = ssim_map(render, gt, window).mean(1, keepdim=True)
    if mask is None:
        return s.flatten(1).mean(1)
    m = mask.to(s.dtype)
    return (s * m).flatten(1).sum(1) / m.flatten(1).sum(1).clamp_min(1)


def psnr(render: torch.Tensor, gt: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
    """PSNR in dB per image (B,) for values in [0, 1]; over ``mask`` (B,1,H,W) pixels if given."""
    se = ((render - gt) ** 2).mean(1, keepdim=True)
    if mask is None:
        mse = se.flatten(1).mean(1)
    else:
        m = mask.to(se.dtype)
        mse = (se * m).flatten(1).sum(1) / m.flatten(1).sum(1).clamp_min(1)
    return -10.0 * torch.log10(mse.clamp_min(1e-10))


_ALEX = ((3, 64, 11, 4, 2), (64, 192, 5, 1, 2), (192, 384, 3, 1, 1), (384, 256, 3, 1, 1),
         (256, 256, 3, 1, 1))
_ALEX_IDX = (0, 3, 6, 8, 10)


class LPIPS(nn.Module):
    """LPIPS distance with an AlexNet backbone; ``forward(a, b) -> (B,)`` for [0, 1] images."""

    def __init__(self):
        super().__init__()
        self.features = nn.ModuleDict(
            {str(i): nn.Conv2d(ci, co, k, s, p) for i, (ci, co, k, s, p) in zip(_ALEX_IDX, _ALEX)})
        self.lins = nn.ModuleList(nn.Conv2d(co, 1, 1, bias=False) for _, co, *_ in _ALEX)
        self.register_buffer("shift", torch.tensor([-0.030, -0.088, -0.188]).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor([0.458, 0.448, 0.450]).view(1, 3, 1, 1))
        self.requires_grad_(False)

    def _taps(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = ((x * 2 - 1) - self.shift) / self.scale
        out = []
        for n, i in enumerate(_ALEX_IDX):
            if n in (1, 2):
                x = F.max_pool2d(x, 3, 2)
            x = F.relu(self.features[str(i)](x))
            out.append(x)
        return out

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        total = 0.0
        for lin, fa, fb in zip(self.lins, self._taps(a), self._taps(b)):
            na = fa / (fa.norm(dim=1, keepdim=True) + 1e-10)
            nb = fb / (fb.norm(dim=1, keepdim=True) + 1e-10)
            total = total + lin((na - nb) ** 2).mean((2, 3))[:, 0]
        return total


def load_lpips(path: str | os.PathLike | None) -> LPIPS | None:
    """The LPIPS network from a local weight file (format in the module docstring), or None.

    A path that is given but missing or incomplete is an :class:`InputError` naming the file
    and the missing keys.
    """
    if not path:
        return None
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: LPIPS weight file not found")
    state = torch.load(path, map_location="cpu", weights_only=True)
    net = LPIPS()
    mapped = {}
    for i in _ALEX_IDX:
        for p in ("weight", "bias"):
            mapped[f"features.{i}.{p}"] = f"features.{i}.{p}"
    for n in range(5):
        mapped[f"lins.{n}.weight"] = f"lin{n}.model.1.weight"
    missing = [src for src in mapped.values() if src not in state]
    if missing:
        raise InputError(f"{path}: LPIPS weights lack key(s) {missing}")
    net.load_state_dict({dst: state[src] for dst, src in mapped.items()}, strict=False)
    return net


def image_loss(render: torch.Tensor, gt: torch.Tensor, w_l1: float, w_dssim: float,
               window: int = 11, lpips: LPIPS | None = None,
               w_lpips: float = 0.0) -> dict[str, torch.Tensor]:
    """Named weighted terms: ``l1``, ``dssim`` and (with a network and weight) ``lpips``."""
    terms = {"l1": w_l1 * l1(render, gt)}
    if w_dssim > 0:
        terms["dssim"] = w_dssim * dssim(render, gt, window)
    if lpips is not None and w_lpips > 0:
        terms["lpips"] = w_lpips * lpips(render, gt).mean()
    return terms
