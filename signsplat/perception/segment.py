"""Person segmentation with a MODNet-style ONNX model: RGB batch in, alpha (N, 1, H, W) out.

Pre-processing: resize each RGB frame to the model's input size (bilinear; area when
shrinking), normalise ``(v - mean) / std`` (v in 0..255). Post-processing: clip alpha to
[0, 1], resize it back to the frame size (bilinear), threshold at ``spec.threshold``.
"""

from __future__ import annotations

import numpy as np
import cv2

from signsplat.perception.contracts import LoadedModel, SegmenterSpec
from signsplat.perception.keypoints import box_from_mask, normalise


def reference_size(h: int, w: int, ref: int) -> tuple[int, int]:
    """(H, W) by MODNet's inference rule: when both sides are larger or both smaller than
    ``ref``, scale so the shorter side is ``ref``; then round each side down to a multiple of
    32 (at least 32)."""
    rh, rw = h, w
    if max(h, w) < ref or min(h, w) > ref:
        if w >= h:
            rh, rw = ref, int(w / h * ref)
        else:
            rh, rw = int(h / w * ref), ref
    return max(32, rh - rh % 32), max(32, rw - rw % 32)


def _model_size(model: LoadedModel, image: np.ndarray, ref: int | None = None) -> tuple[int, int]:
    """(H, W) fed to the model: its configured/static size, else :func:`reference_size` with
    ``ref``, else the frame rounded to 32."""
    if model.input_size is not None:
        return model.input_size
    h, w = image.shape[:2]
    if ref:
        return reference_size(h, w, ref)
    return (max(32, int(round(h / 32)) * 32), max(32, int(round(w / 32)) * 32))


def resize(image: np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """Resize (H, W[, C]) to ``hw`` (bilinear; area interpolation when shrinking)."""
    h, w = hw
    if image.shape[:2] == (h, w):
        return image
    shrink = h < image.shape[0] and w < image.shape[1]
    return cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)


def segment_batch(model: LoadedModel, spec: SegmenterSpec,
                  images: list[np.ndarray]) -> list[np.ndarray]:
    """Alpha float32 (H, W) in [0, 1] at each frame's own size, for RGB uint8 frames."""
    out: list[np.ndarray | None] = [None] * len(images)
    groups: dict[tuple[int, int], list[int]] = {}
    for i, img in enumerate(images):
        groups.setdefault(_model_size(model, img, spec.reference_size), []).append(i)
    for hw, idx in groups.items():
        batch = normalise(np.stack([resize(images[i], hw) for i in idx]), spec.mean, spec.std,
                          spec.color_order)
        alpha = model.run(batch)[0][:, 0]
        for j, i in enumerate(idx):
            a = np.clip(np.nan_to_num(alpha[j].astype(np.float32)), 0.0, 1.0)
            out[i] = resize(a, images[i].shape[:2]) if a.shape != images[i].shape[:2] else a
    return out  # type: ignore[return-value]


def mask_stats(alpha: np.ndarray, threshold: float) -> dict:
    """Mask (bool (H, W)) and its summary: area (pixels), box xyxy (NaN when empty), confidence.

    confidence: mean alpha over the mask's pixels (0 when the mask is empty).
    """
    mask = alpha > threshold
    box = box_from_mask(mask)
    area = int(mask.sum())
    return {
        "mask": mask,
        "area": area,
        "box": box if box is not None else np.full(4, np.nan),
        "confidence": float(alpha[mask].mean()) if area else 0.0,
    }
