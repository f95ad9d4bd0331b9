"""The shipped default networks: a small segmenter and a small SimCC keypoint model.

Both are built from depthwise-separable convolutions (MobileNet style) with a U-Net decoder,
sized for 2 CPU cores. Their exported ONNX graphs follow the stage contracts exactly:

- :class:`TinySegmenter`: (N, 3, H, W) normalised RGB (H, W multiples of 16) -> alpha
  (N, 1, H, W) = sigmoid(logit). ``forward_logits`` is used for training.
- :class:`CascadeSimCC` (the shipped keypoint model): a :class:`TinySimCC` coarse stage on
  the crop pooled 2x, then both hands refined by :class:`HandNet` on crops resampled from the
  full-resolution input inside the graph; outputs are SimCC vectors peaked at each keypoint's
  sub-cell location, scaled by its probability (same contract, same decoding).
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
    """Top-down whole-body keypoints in the RTMPose SimCC output contract.

    ``out_stride`` 4 (default) decodes to the encoder's stride-4 features; 2 adds one more
    decoder level on the stride-2 features (four times the heatmap cells, for sub-4-pixel
    localisation at little cost: the level is narrow and the encoder is unchanged).
    """

    def __init__(self, num_keypoints: int = 133, split_ratio: int = 2,
                 widths=(16, 24, 48, 96, 128), head_width: int = 64, out_stride: int = 4):
        super().__init__()
        if out_stride not in (2, 4):
            raise ValueError(f"TinySimCC out_stride must be 2 or 4, got {out_stride}")
        w = widths
        self.split_ratio = split_ratio
        self.stride = out_stride
        self.encoder = Encoder(widths)
        self.up16 = Up(w[4], w[3], 96)
        self.up8 = Up(96, w[2], head_width)
        self.up4 = Up(head_width, w[1], head_width)
        self.up2 = Up(head_width, w[0], head_width) if out_stride == 2 else None
        self.head = nn.Conv2d(head_width, num_keypoints, 1)

    def heatmap_logits(self, x):
        """(N, 3, H, W) -> heatmap logits (N, K, H/s, W/s), s = ``stride``; cell j's centre
        is at input pixel s*j + (s-1)/2."""
        f2, f4, f8, f16, f32 = self.encoder(x)
        y = self.up16(f32, f16)
        y = self.up8(y, f8)
        y = self.up4(y, f4)
        if self.up2 is not None:
            y = self.up2(y, f2)
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
            if a.shape != tuple(b.shape) or not err <= atol:  # NaN fails too
                raise RuntimeError(f"{path}: ONNX output {name} differs from PyTorch "
                                   f"(shape {a.shape} vs {tuple(b.shape)}, max error {err:.2e})")


# --- cascade: coarse whole-body stage + hand refinement, one graph, SimCC outputs ----------

HAND_SLICES = ((91, 112), (112, 133))  # COCO-WholeBody left hand, right hand


def peak_subcell(logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Heatmap logits (N, K, H, W) -> peak cell coordinates x, y (N, K) with sub-cell offsets
    and the peak probability (N, K).

    The offset fits a parabola to log-sigmoid(logits) through the arg-max cell and its two
    neighbours along each axis (exact for a Gaussian peak), clamped to half a cell; on a
    border cell the offset across that border is 0.
    """
    n, k, h, w = logits.shape
    flat = logits.flatten(2)
    idx = flat.argmax(-1, keepdim=True)  # (N, K, 1)
    iy = torch.div(idx, w, rounding_mode="floor")
    ix = idx - iy * w
    # log-sigmoid written out: exported, F.logsigmoid becomes Log(Sigmoid(x)), which is -inf
    # where the sigmoid underflows (a part far from any peak) and then NaN in the parabola
    logp = flat.clamp(max=0) - torch.log1p(torch.exp(-flat.abs()))

    def at(dx: int, dy: int) -> torch.Tensor:
        jx = (ix + dx).clamp(0, w - 1)
        jy = (iy + dy).clamp(0, h - 1)
        return torch.gather(logp, 2, jy * w + jx)[..., 0]

    c = at(0, 0)

    def offset(lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
        den = (lo - 2 * c + hi).clamp(max=-1e-4)
        return (-0.5 * (hi - lo) / den).clamp(-0.5, 0.5)

    def pair(lo: torch.Tensor, hi: torch.Tensor, i: torch.Tensor, n_cells: int):
        # a missing neighbour at the border mirrors the other one (offset 0 there)
        i = i[..., 0]
        return torch.where(i <= 0, hi, lo), torch.where(i >= n_cells - 1, lo, hi)

    x = ix[..., 0].to(logits.dtype) + offset(*pair(at(-1, 0), at(1, 0), ix, w))
    y = iy[..., 0].to(logits.dtype) + offset(*pair(at(0, -1), at(0, 1), iy, h))
    return x, y, c.exp()


def simcc_profile(coord: torch.Tensor, score: torch.Tensor, bins: int, ratio: int,
                  sigma: float = 0.75) -> torch.Tensor:
    """(N, K) pixel coordinates and scores -> (N, K, bins) SimCC vectors.

    Bin b stands for pixel b / ratio (the rtmlib/MMPose decoding); the vector is a Gaussian
    of ``sigma`` pixels around ``coord``, scaled so its maximum equals ``score``: arg-max
    decoding returns the coordinate to within half a bin and max decoding the score.
    """
    grid = torch.arange(bins, dtype=coord.dtype) / ratio
    g = torch.exp(-0.5 * ((grid - coord[..., None]) / sigma) ** 2)
    return g / g.amax(-1, keepdim=True).clamp(min=1e-12) * score[..., None]


def hand_grid(centers: torch.Tensor, side: float, size: int, in_hw: tuple[int, int],
              mirror: torch.Tensor) -> torch.Tensor:
    """Sampling grid (N, size, size, 2) for grid_sample (align_corners=False).

    centers: (N, 2) input pixels (pixel-centre convention); side: crop side in input pixels;
    mirror: (N,) 1 to flip the crop left-right (right hands look like left hands), else 0.
    Hand-crop pixel u maps to input x = cx + sgn * (u + 0.5 - size/2) * side/size.
    """
    h, w = in_hw
    t = (torch.arange(size, dtype=centers.dtype) + 0.5 - size / 2) * (side / size)
    sgn = (1 - 2 * mirror).to(centers.dtype)[:, None]
    xs = centers[:, 0:1] + sgn * t[None]  # (N, size)
    ys = centers[:, 1:2] + t[None]
    gx = (xs + 0.5) / w * 2 - 1
    gy = (ys + 0.5) / h * 2 - 1
    n = centers.shape[0]
    return torch.stack([gx[:, None, :].expand(n, size, size),
                        gy[:, :, None].expand(n, size, size)], -1)


class HandNet(nn.Module):
    """21 hand keypoints as stride-4 heatmap logits from a (N, 3, S, S) hand crop."""

    stride = 4

    def __init__(self, num_keypoints: int = 21, widths=(16, 32, 48, 96, 128),
                 head_width: int = 48):
        super().__init__()
        w = widths
        self.encoder = Encoder(widths)
        self.up16 = Up(w[4], w[3], 64)
        self.up8 = Up(64, w[2], head_width)
        self.up4 = Up(head_width, w[1], head_width)
        self.head = nn.Conv2d(head_width, num_keypoints, 1)

    def forward(self, x):
        _, f4, f8, f16, f32 = self.encoder(x)
        y = self.up16(f32, f16)
        y = self.up8(y, f8)
        y = self.up4(y, f4)
        return self.head(y)


class CascadeSimCC(nn.Module):
    """Whole-body keypoints in the RTMPose SimCC contract, hands refined at full resolution.

    Input (N, 3, H, W) normalised crop (default 256 x 192).

    1. Coarse stage (:class:`TinySimCC`, ``coarse_widths``) on the crop average-pooled 2x:
       133 heatmaps at stride ``2 * coarse_out_stride`` of the input.
    2. Each hand's centre is the score-weighted mean of its 21 coarse keypoints; a
       ``hand_side``-pixel square around it is resampled from the full-resolution input
       (grid_sample, right hands mirrored) to ``hand_size`` pixels and :class:`HandNet`
       predicts the hand's 21 keypoints.
    3. ``hand_passes`` > 1: the crop is re-centred on the score-weighted mean of the previous
       pass's points (moved in proportion to their mean probability, so an empty crop stays
       put) and the hand network runs again; a hand the coarse stage found only at the edge
       of its crop is seen whole the second time.
    4. The hand points replace the coarse ones; the body wrists (COCO 9, 10) are the same
       points as the hand roots (91, 112) and take the hand network's location where its
       probability exceeds ``wrist_min_prob``.

    Every keypoint's sub-cell peak and probability are emitted as SimCC vectors
    (:func:`simcc_profile`), so arg-max/max decoding gives them back.
    """

    WRISTS = ((9, 0), (10, 21))  # (body index, index within the 42 hand points)

    def __init__(self, in_hw: tuple[int, int] = (256, 192), split_ratio: int = 2,
                 hand_size: int = 64, hand_side: float = 80.0, num_keypoints: int = 133,
                 coarse_widths=(16, 24, 48, 96, 128), coarse_head: int = 64,
                 coarse_out_stride: int = 4, hand_passes: int = 1,
                 wrist_min_prob: float | None = None):
        super().__init__()
        self.in_hw = tuple(in_hw)
        self.split_ratio = split_ratio
        self.hand_size = hand_size
        self.hand_side = float(hand_side)
        self.hand_passes = int(hand_passes)
        self.wrist_min_prob = wrist_min_prob
        self.coarse = TinySimCC(num_keypoints, split_ratio, tuple(coarse_widths), coarse_head,
                                coarse_out_stride)
        self.hand = HandNet()
        self.coarse_stride = 2 * self.coarse.stride  # input pixels per coarse cell

    def coarse_logits(self, x):
        return self.coarse.heatmap_logits(F.avg_pool2d(x, 2))

    def hand_crops(self, x, centers: torch.Tensor) -> torch.Tensor:
        """x (N, 3, H, W), centers (N, 2, 2) [left, right] -> crops (2N, 3, S, S), left first
        then right per item (right mirrored)."""
        n = x.shape[0]
        c = centers.reshape(n * 2, 2)
        mirror = torch.arange(2).repeat(n)
        grid = hand_grid(c, self.hand_side, self.hand_size, self.in_hw, mirror)
        xx = x[:, None].expand(n, 2, *x.shape[1:]).reshape(n * 2, *x.shape[1:])
        return F.grid_sample(xx, grid, mode="bilinear", padding_mode="zeros",
                             align_corners=False)

    def hand_points(self, logits: torch.Tensor, centers: torch.Tensor):
        """Hand heatmap logits (2N, 21, h, w) and crop centres (N, 2, 2) -> input-pixel
        x, y (N, 42) and scores (N, 42), left hand then right (inverse of :func:`hand_grid`)."""
        n = centers.shape[0]
        hx, hy, hs = peak_subcell(logits)  # (2N, 21)
        st = self.hand.stride
        u = hx * st + (st - 1) / 2 + 0.5 - self.hand_size / 2
        v = hy * st + (st - 1) / 2 + 0.5 - self.hand_size / 2
        k = self.hand_side / self.hand_size
        sgn = torch.tensor([1.0, -1.0]).repeat(n)[:, None]
        c2 = centers.reshape(n * 2, 2)
        return ((c2[:, 0:1] + sgn * u * k).reshape(n, 42), (c2[:, 1:2] + v * k).reshape(n, 42),
                hs.reshape(n, 42))

    @staticmethod
    def _centers(px, py, score, slices=HAND_SLICES):
        out = []
        for a, b in slices:
            wgt = score[:, a:b] + 1e-4
            out.append(torch.stack([(wgt * px[:, a:b]).sum(1), (wgt * py[:, a:b]).sum(1)], -1)
                       / wgt.sum(1, keepdim=True))
        return torch.stack(out, 1)  # (N, 2, 2)

    def hand_centers(self, coarse_logits: torch.Tensor) -> torch.Tensor:
        """Coarse heatmap logits (N, 133, h, w) -> hand-crop centres (N, 2, 2) [left, right]
        in input pixels: the score-weighted mean of each hand's 21 coarse keypoints."""
        s = self.coarse_stride
        cx, cy, score = peak_subcell(coarse_logits)
        return self._centers(cx * s + (s - 1) / 2, cy * s + (s - 1) / 2, score)

    def recenter(self, centers: torch.Tensor, hx: torch.Tensor, hy: torch.Tensor,
                 hs: torch.Tensor) -> torch.Tensor:
        """Next pass's crop centres (N, 2, 2) from this pass's hand points (N, 42): the
        score-weighted mean, reached in proportion to the hand's mean probability (x2,
        capped at 1), so a crop where nothing was found stays where it was."""
        mean = self._centers(hx, hy, hs, ((0, 21), (21, 42)))
        conf = torch.stack([hs[:, :21].mean(1), hs[:, 21:].mean(1)], 1)  # (N, 2)
        step = (2.0 * conf).clamp(max=1.0)[..., None]
        return centers + step * (mean - centers)

    def forward(self, x):
        s = self.coarse_stride
        cx, cy, score = peak_subcell(self.coarse_logits(x))
        px, py = cx * s + (s - 1) / 2, cy * s + (s - 1) / 2
        centers = self._centers(px, py, score)
        hxp, hyp, hs = self.hand_points(self.hand(self.hand_crops(x, centers)), centers)
        for _ in range(self.hand_passes - 1):
            centers = self.recenter(centers, hxp, hyp, hs)
            hxp, hyp, hs = self.hand_points(self.hand(self.hand_crops(x, centers)), centers)
        if self.wrist_min_prob is not None:
            for body, j in self.WRISTS:
                take = hs[:, j] > self.wrist_min_prob
                px = torch.cat([px[:, :body], torch.where(take, hxp[:, j], px[:, body])[:, None],
                                px[:, body + 1:]], 1)
                py = torch.cat([py[:, :body], torch.where(take, hyp[:, j], py[:, body])[:, None],
                                py[:, body + 1:]], 1)
        a0 = HAND_SLICES[0][0]
        px = torch.cat([px[:, :a0], hxp], 1)
        py = torch.cat([py[:, :a0], hyp], 1)
        # a hand point's score: the hand network's peak probability times the
        # coarse stage's mean probability for that hand (is there a hand near here at all?)
        presence = torch.cat([score[:, a:b].mean(1, keepdim=True).expand(-1, b - a)
                              for a, b in HAND_SLICES], 1)
        score = torch.cat([score[:, :a0], hs * presence], 1)
        h, w = self.in_hw
        r = self.split_ratio
        return simcc_profile(px, score, w * r, r), simcc_profile(py, score, h * r, r)
