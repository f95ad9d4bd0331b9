"""The shipped default networks: a small segmenter and a small SimCC keypoint model.

Both are built from depthwise-separable convolutions (MobileNet style) with a U-Net decoder,
sized for 2 CPU cores. Their exported ONNX graphs follow the stage contracts exactly:

- :class:`TinySegmenter`: (N, 3, H, W) normalised RGB (H, W multiples of 16) -> alpha
  (N, 1, H, W) = sigmoid(logit). ``forward_logits`` is used for training.
- :class:`TinySimCC`: (N, 3, H, W) normalised RGB crop -> ``simcc_x`` (N, K, W*r) and
  ``simcc_y`` (N, K, H*r) with r = 2. Internally it predicts a 2D heatmap of logits at stride
  4, (N, K, H/4, W/4), trained with per-pixel BCE against Gaussians (peak 1; all zero for
  invisible keypoints). The SimCC vectors are the heatmap's max over the other axis, linearly
  upsampled to r bins per pixel and passed through a sigmoid, so each vector's maximum is the
  heatmap's peak probability and the decoded score is a probability in [0, 1].
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn


def _bn_act(c: int) -> list[nn.Module]:
    return [nn.BatchNorm2d(c), nn.ReLU(inplace=True)]


class SepConv(nn.Sequential):
    """Depthwise 3x3 (stride, dilation) + pointwise 1x1, each with BN + ReLU."""

    def __init__(self, cin: int, cout: int, stride: int = 1, dilation: int = 1):
        super().__init__(
            nn.Conv2d(cin, cin, 3, stride, padding=dilation, dilation=dilation, groups=cin,
                      bias=False), *_bn_act(cin),
            nn.Conv2d(cin, cout, 1, bias=False), *_bn_act(cout),
        )


class Residual(nn.Module):
    """x + SepConv(x) (same channels, stride 1)."""

    def __init__(self, c: int, dilation: int = 1):
        super().__init__()
        self.body = SepConv(c, c, 1, dilation)

    def forward(self, x):
        return x + self.body(x)


class Up(nn.Module):
    """Upsample the coarse map x2 (bilinear), add a 1x1 projection of the skip, refine."""

    def __init__(self, c_coarse: int, c_skip: int, cout: int):
        super().__init__()
        self.reduce = nn.Conv2d(c_coarse, cout, 1, bias=False)
        self.skip = nn.Conv2d(c_skip, cout, 1, bias=False)
        self.refine = SepConv(cout, cout)

    def forward(self, coarse, skip):
        up = F.interpolate(self.reduce(coarse), size=skip.shape[-2:], mode="bilinear",
                           align_corners=False)
        return self.refine(up + self.skip(skip))


class Encoder(nn.Module):
    """Feature maps at strides 2, 4, 8, 16, 32 (channels ``widths``)."""

    def __init__(self, widths=(16, 24, 48, 96, 128)):
        super().__init__()
        w = widths
        self.s2 = nn.Sequential(nn.Conv2d(3, w[0], 3, 2, 1, bias=False), *_bn_act(w[0]))
        self.s4 = nn.Sequential(SepConv(w[0], w[1], 2), Residual(w[1]))
        self.s8 = nn.Sequential(SepConv(w[1], w[2], 2), Residual(w[2]), Residual(w[2]))
        self.s16 = nn.Sequential(SepConv(w[2], w[3], 2), Residual(w[3]), Residual(w[3], 2))
        self.s32 = nn.Sequential(SepConv(w[3], w[4], 2), Residual(w[4]), Residual(w[4], 2))

    def forward(self, x):
        f2 = self.s2(x)
        f4 = self.s4(f2)
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        return f2, f4, f8, f16, self.s32(f16)


class TinySegmenter(nn.Module):
    """Person alpha matte, MODNet-style contract; input normalised to [-1, 1]."""

    def __init__(self, widths=(16, 24, 48, 96, 128)):
        super().__init__()
        w = widths
        self.encoder = Encoder(widths)
        self.full = nn.Sequential(nn.Conv2d(3, 8, 3, 1, 1, bias=False), *_bn_act(8))
        self.up16 = Up(w[4], w[3], 64)
        self.up8 = Up(64, w[2], 48)
        self.up4 = Up(48, w[1], 32)
        self.up2 = Up(32, w[0], 16)
        self.up1 = Up(16, 8, 8)
        self.head = nn.Conv2d(8, 1, 1)

    def forward_logits(self, x):
        f2, f4, f8, f16, f32 = self.encoder(x)
        y = self.up16(f32, f16)
        y = self.up8(y, f8)
        y = self.up4(y, f4)
        y = self.up2(y, f2)
        y = self.up1(y, self.full(x))
        return self.head(y)

    def forward(self, x):
        return torch.sigmoid(self.forward_logits(x))


class TinySimCC(nn.Module):
    """Top-down whole-body keypoints in the RTMPose SimCC output contract."""

    stride = 4

    def __init__(self, num_keypoints: int = 133, split_ratio: int = 2,
                 widths=(16, 24, 48, 96, 128), head_width: int = 64):
        super().__init__()
        w = widths
        self.split_ratio = split_ratio
        self.encoder = Encoder(widths)
        self.up16 = Up(w[4], w[3], 96)
        self.up8 = Up(96, w[2], head_width)
        self.up4 = Up(head_width, w[1], head_width)
        self.head = nn.Conv2d(head_width, num_keypoints, 1)

    def heatmap_logits(self, x):
        """(N, 3, H, W) -> heatmap logits (N, K, H/4, W/4); cell j centre at crop 4j + 1.5."""
        _, f4, f8, f16, f32 = self.encoder(x)
        y = self.up16(f32, f16)
        y = self.up8(y, f8)
        y = self.up4(y, f4)
        return self.head(y)

    def simcc(self, logits):
        """Heatmap logits -> (simcc_x (N, K, W*r), simcc_y (N, K, H*r)) probabilities."""
        scale = self.stride * self.split_ratio
        lx = logits.amax(dim=2)
        ly = logits.amax(dim=3)
        lx = F.interpolate(lx, scale_factor=scale, mode="linear", align_corners=False)
        ly = F.interpolate(ly, scale_factor=scale, mode="linear", align_corners=False)
        return torch.sigmoid(lx), torch.sigmoid(ly)

    def forward(self, x):
        return self.simcc(self.heatmap_logits(x))


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


def export_onnx(model: nn.Module, path, input_hw: tuple[int, int], output_names: list[str],
                opset: int = 18, atol: float = 1e-4) -> None:
    """Export ``model`` (eval mode) to ONNX with a dynamic batch axis ``N`` (torch.export).

    The file is checked before it replaces ``path``: onnxruntime's outputs for a random batch
    of 3 must match PyTorch's within ``atol``.
    """
    import onnxruntime as ort

    from signsplat.io.atomic import atomic_path

    model = model.eval()
    batch = torch.export.Dim("N", min=1, max=1024)
    x = torch.randn(3, 3, *input_hw, generator=torch.Generator().manual_seed(0))
    with atomic_path(path) as tmp, torch.no_grad():
        torch.onnx.export(model, (torch.zeros(2, 3, *input_hw),), str(tmp),
                          input_names=["input"], output_names=output_names,
                          dynamic_shapes=({0: batch},), opset_version=opset, dynamo=True,
                          optimize=True, verbose=False, external_data=False)
        ref = model(x)
        ref = ref if isinstance(ref, tuple) else (ref,)
        sess = ort.InferenceSession(str(tmp), providers=["CPUExecutionProvider"])
        got = sess.run(output_names, {"input": x.numpy()})
        for name, a, b in zip(output_names, got, ref):
            err = float(np.abs(a - b.numpy()).max())
            if a.shape != tuple(b.shape) or err > atol:
                raise RuntimeError(f"{path}: ONNX output {name} differs from PyTorch "
                                   f"(shape {a.shape} vs {tuple(b.shape)}, max error {err:.2e})")
