"""Image losses and metrics: L1, D-SSIM (kornia), PSNR, and LPIPS when weights exist locally.

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

import kornia
import torch
from torch import nn
from torch.nn import functional as F

from signsplat.errors import InputError


def l1(render: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    return (render - gt).abs().mean()


def dssim(render: torch.Tensor, gt: torch.Tensor, window: int = 11) -> torch.Tensor:
    """1 - mean SSIM (Gaussian window of ``window`` pixels)."""
    return 1.0 - kornia.metrics.ssim(render, gt, window).mean()


def ssim(render: torch.Tensor, gt: torch.Tensor, window: int = 11,
         mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean SSIM per image (B,); over ``mask`` (B,1,H,W) pixels when given."""
    s = kornia.metrics.ssim(render, gt, window).mean(1, keepdim=True)
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
