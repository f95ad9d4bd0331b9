"""Whole-body keypoints with a top-down SimCC model (RTMPose/RTMW contract).

Geometry and decoding follow rtmlib/MMPose:

1. person box (x0, y0, x1, y1) from the mask -> centre ``c = ((x0+x1)/2, (y0+y1)/2)`` and
   scale ``s = (x1-x0, y1-y0) * padding`` (padding 1.25);
2. the scale is widened to the model's aspect ratio ``W/H`` (the larger side wins);
3. an affine warp without rotation maps ``c`` to the crop centre ``(W/2, H/2)`` with
   ``W / s_w`` pixels per image pixel (bilinear, black outside the image);
4. the crop is normalised per channel ``(v - mean) / std`` (v in 0..255) and run;
5. decoding: ``x_bin = argmax(simcc_x)``, ``y_bin = argmax(simcc_y)``, crop coordinates
   ``(x_bin, y_bin) / r``, raw score ``min(max(simcc_x), max(simcc_y))`` (rtmlib and MMPose
   take the smaller of the two maxima); a raw score <= 0 means no location;
6. back to the image: ``p = crop / (W, H) * s + c - s / 2``.

Scores: raw SimCC maxima are not probabilities (RTMW's are mostly in [0, 1], used with
thresholds ~0.3); the table stores ``clip(raw, 0, 1)``. The shipped model ends in a sigmoid,
so its maxima are already probabilities of the keypoint being visible near that location and
the clip leaves them unchanged. Keypoints with score 0 have x = y = NaN.
"""

from __future__ import annotations

import numpy as np
import cv2

from signsplat.perception.contracts import KeypointSpec, LoadedModel


def box_from_mask(mask: np.ndarray) -> np.ndarray | None:
    """Pixel-edge box (x0, y0, x1, y1) float64 of a (H, W) bool mask, None when empty.

    x0, y0 are the first foreground column/row, x1, y1 one past the last (so x1 - x0 is the
    width in pixels).
    """
    cols = np.flatnonzero(mask.any(axis=0))
    if cols.size == 0:
        return None
    rows = np.flatnonzero(mask.any(axis=1))
    return np.array([cols[0], rows[0], cols[-1] + 1, rows[-1] + 1], dtype=np.float64)


def box_to_center_scale(box: np.ndarray, padding: float = 1.25) -> tuple[np.ndarray, np.ndarray]:
    """Box (..., 4) xyxy -> centre (..., 2) and padded scale (w, h) (..., 2), in pixels."""
    box = np.asarray(box, dtype=np.float64)
    center = np.stack([box[..., 0] + box[..., 2], box[..., 1] + box[..., 3]], -1) * 0.5
    scale = np.stack([box[..., 2] - box[..., 0], box[..., 3] - box[..., 1]], -1) * padding
    return center, scale


def fix_aspect_ratio(scale: np.ndarray, aspect: float) -> np.ndarray:
    """Widen a (..., 2) scale (w, h) to ``w / h == aspect`` keeping the larger extent."""
    scale = np.asarray(scale, dtype=np.float64)
    w, h = scale[..., 0], scale[..., 1]
    wide = w > h * aspect
    return np.stack([np.where(wide, w, h * aspect), np.where(wide, w / aspect, h)], -1)


def crop_matrix(center: np.ndarray, scale: np.ndarray, out_hw: tuple[int, int],
                angle: float = 0.0) -> np.ndarray:
    """2x3 affine image -> crop: centre to (W/2, H/2), ``W / scale_w`` crop px per image px.

    ``angle`` (radians, counter-clockwise in the image) rotates the crop about the centre
    (training augmentation only; inference uses 0 as rtmlib does).
    """
    h, w = out_hw
    k = w / float(scale[0])
    cs, sn = np.cos(angle) * k, np.sin(angle) * k
    cx, cy = float(center[0]), float(center[1])
    return np.array([[cs, sn, w / 2 - cs * cx - sn * cy],
                     [-sn, cs, h / 2 + sn * cx - cs * cy]], dtype=np.float64)


def warp_crop(image: np.ndarray, matrix: np.ndarray, out_hw: tuple[int, int]) -> np.ndarray:
    """Bilinear affine crop (H, W, C) of ``image`` with the given 2x3 matrix, black outside."""
    h, w = out_hw
    return cv2.warpAffine(image, matrix, (w, h), flags=cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def normalise(crops: np.ndarray, mean, std, color_order: str = "rgb") -> np.ndarray:
    """RGB uint8 (N, H, W, 3) -> float32 (N, 3, H, W) ``(v - mean) / std`` in model order."""
    x = crops.astype(np.float32)
    if color_order == "bgr":
        x = x[..., ::-1]
    x = (x - np.asarray(mean, np.float32)) / np.asarray(std, np.float32)
    return np.ascontiguousarray(x.transpose(0, 3, 1, 2))


def decode_simcc(simcc_x: np.ndarray, simcc_y: np.ndarray,
                 split_ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """SimCC (N, K, Wx), (N, K, Hy) -> crop pixel locations (N, K, 2) and raw scores (N, K).

    Raw score = min of the two maxima; where it is <= 0 the location is NaN.
    """
    xs = np.argmax(simcc_x, axis=-1)
    ys = np.argmax(simcc_y, axis=-1)
    vals = np.minimum(simcc_x.max(axis=-1), simcc_y.max(axis=-1)).astype(np.float32)
    locs = np.stack([xs, ys], -1).astype(np.float64) / split_ratio
    locs[vals <= 0] = np.nan
    return locs, vals


def crop_to_image(locs: np.ndarray, center: np.ndarray, scale: np.ndarray,
                  out_hw: tuple[int, int]) -> np.ndarray:
    """Crop pixel locations (N, K, 2) -> image pixels, given per-item centre/scale (N, 2)."""
    h, w = out_hw
    size = np.array([w, h], dtype=np.float64)
    return locs / size * scale[:, None, :] + center[:, None, :] - scale[:, None, :] / 2


def scores_to_unit(raw: np.ndarray, mode: str = "clip") -> np.ndarray:
    """Map raw SimCC maxima to [0, 1] (see the module docstring)."""
    if mode != "clip":
        raise ValueError(f"unknown score_mode {mode!r}; known: 'clip'")
    return np.clip(np.nan_to_num(raw, nan=0.0), 0.0, 1.0).astype(np.float32)


def detect_batch(model: LoadedModel, spec: KeypointSpec, images: list[np.ndarray],
                 boxes: list[np.ndarray | None]) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints of one person per image.

    images: RGB uint8 (H, W, 3) each; boxes: xyxy person box per image or None (no person).
    Returns xy float32 (N, K, 2) image pixels (NaN where unknown) and scores float32 (N, K)
    in [0, 1] (0 where there is no person).
    """
    k = spec.num_keypoints
    n = len(images)
    xy = np.full((n, k, 2), np.nan, np.float32)
    scores = np.zeros((n, k), np.float32)
    todo = [i for i in range(n) if boxes[i] is not None]
    if not todo:
        return xy, scores
    hw = model.input_size
    aspect = hw[1] / hw[0]
    centers, scales, crops = [], [], []
    for i in todo:
        c, s = box_to_center_scale(boxes[i], spec.padding)
        s = fix_aspect_ratio(s, aspect)
        crops.append(warp_crop(images[i], crop_matrix(c, s, hw), hw))
        centers.append(c)
        scales.append(s)
    batch = normalise(np.stack(crops), spec.mean, spec.std, spec.color_order)
    sx, sy = model.run(batch)
    locs, raw = decode_simcc(sx, sy, spec.split_ratio)
    pts = crop_to_image(locs, np.stack(centers), np.stack(scales), hw)
    sc = scores_to_unit(raw, spec.score_mode)
    pts[sc <= 0] = np.nan
    xy[todo] = pts.astype(np.float32)
    scores[todo] = sc
    return xy, scores
