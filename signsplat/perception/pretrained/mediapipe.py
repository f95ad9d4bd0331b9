"""MediaPipe's geometry in numpy: SSD anchors and detection decoding, weighted non-maximum
suppression, rotated regions of interest (ROIs), crops and the projection of landmarks back.

Facts (not code) from MediaPipe 0.10's graphs and calculators (google-ai-edge/mediapipe:
``calculators/tflite/ssd_anchors_calculator.cc``, ``calculators/tensor/
tensors_to_detections_calculator.cc``, ``calculators/util/non_max_suppression_calculator.cc``,
``detections_to_rects_calculator.cc``, ``alignment_points_to_rects_calculator.cc``,
``rect_transformation_calculator.cc``, ``landmark_projection_calculator.cc``,
``calculators/tensor/image_to_tensor_utils.cc`` and ``image_to_tensor_converter_opencv.cc``).

Conventions: every ROI here is in image pixels (MediaPipe keeps them normalised by the image
size; the two agree for the square ROIs all models use). ``rotation`` is in radians; a point
(u, v) of a crop of size (W, H) lies in the image at
``centre + R(rotation) @ ((u / W - 0.5) * width, (v / H - 0.5) * height)`` with
``R(a) = [[cos a, -sin a], [sin a, cos a]]`` (image y down, so a positive angle turns the crop
clockwise on screen). Image coordinates are OpenCV's (pixel centres on integers), as
MediaPipe's CPU crop uses them; crop outputs are read in the same convention, so the two
cancel and results equal MediaPipe's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np


@dataclass(frozen=True)
class Roi:
    """A rotated rectangle in image pixels: centre (cx, cy), size (w, h), rotation (radians)."""

    cx: float
    cy: float
    w: float
    h: float
    rotation: float = 0.0

    def corners(self) -> np.ndarray:
        """(4, 2) corners in crop order (0,0), (W,0), (W,H), (0,H) of its crop."""
        return crop_to_image(np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float64), self, (1, 1))


def normalize_radians(angle: float) -> float:
    """Angle in [-pi, pi) (MediaPipe's NormalizeRadians)."""
    return float(angle - 2 * np.pi * np.floor((angle + np.pi) / (2 * np.pi)))


def rotation_between(p0, p1, target: float) -> float:
    """Crop rotation that turns the direction p0 -> p1 to ``target`` radians (counter-clockwise
    from the image's +x axis with y up): ``normalize(target - atan2(-(y1 - y0), x1 - x0))``."""
    return normalize_radians(target - np.arctan2(-(p1[1] - p0[1]), p1[0] - p0[0]))


# --- crops --------------------------------------------------------------------------------

def crop_matrix(roi: Roi, out_wh: tuple[int, int]) -> np.ndarray:
    """2x3 affine: crop pixel (u, v) of an ``out_wh = (W, H)`` crop -> image pixel."""
    W, H = out_wh
    c, s = np.cos(roi.rotation), np.sin(roi.rotation)
    a = np.array([[c * roi.w / W, -s * roi.h / H], [s * roi.w / W, c * roi.h / H]])
    t = np.array([roi.cx, roi.cy]) - a @ np.array([W / 2, H / 2])
    return np.hstack([a, t[:, None]])


def crop_to_image(points: np.ndarray, roi: Roi, out_wh: tuple[int, int]) -> np.ndarray:
    """Crop pixels (..., 2) -> image pixels (..., 2) (MediaPipe's landmark projection)."""
    m = crop_matrix(roi, out_wh)
    pts = np.asarray(points, np.float64)
    return pts @ m[:, :2].T + m[:, 2]


def image_to_crop(points: np.ndarray, roi: Roi, out_wh: tuple[int, int]) -> np.ndarray:
    """Image pixels (..., 2) -> crop pixels (..., 2) (inverse of :func:`crop_to_image`)."""
    m = crop_matrix(roi, out_wh)
    inv = np.linalg.inv(m[:, :2])
    return (np.asarray(points, np.float64) - m[:, 2]) @ inv.T


def pad_roi(roi: Roi, out_wh: tuple[int, int]) -> tuple[Roi, tuple[float, float]]:
    """Grow ``roi`` to the crop's aspect ratio (MediaPipe's keep_aspect_ratio letterbox).

    Returns the grown ROI and the (horizontal, vertical) padding as fractions of the crop on
    each side."""
    W, H = out_wh
    tensor_aspect, roi_aspect = H / W, roi.h / roi.w
    if tensor_aspect > roi_aspect:
        return replace(roi, h=roi.w * tensor_aspect), (0.0, (1 - roi_aspect / tensor_aspect) / 2)
    return replace(roi, w=roi.h / tensor_aspect), ((1 - tensor_aspect / roi_aspect) / 2, 0.0)


def crop(image: np.ndarray, roi: Roi, out_wh: tuple[int, int], value_range=(0.0, 1.0),
         border: str = "replicate") -> np.ndarray:
    """A (1, 3, H, W) float32 model input: bilinear crop of RGB uint8 ``image`` (H, W, 3) in
    ``roi``, values mapped from 0..255 to ``value_range``; outside the image ``border`` is
    'replicate' (edge pixels) or 'zero' (black)."""
    W, H = out_wh
    mode = cv2.BORDER_REPLICATE if border == "replicate" else cv2.BORDER_CONSTANT
    patch = cv2.warpAffine(image, crop_matrix(roi, out_wh), (W, H),
                           flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=mode,
                           borderValue=0)
    lo, hi = value_range
    x = patch.astype(np.float32) * np.float32((hi - lo) / 255.0) + np.float32(lo)
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None])


# --- ROIs from points ------------------------------------------------------------------------

def alignment_roi(center, scale_point, target: float) -> Roi:
    """Square ROI centred on ``center`` with side 2 |scale_point - center|, rotated so that the
    direction center -> scale_point points to ``target`` (AlignmentPointsRectsCalculator)."""
    center, scale_point = np.asarray(center, float), np.asarray(scale_point, float)
    side = 2.0 * float(np.linalg.norm(scale_point - center))
    return Roi(float(center[0]), float(center[1]), side, side,
               rotation_between(center, scale_point, target))


def box_roi(points: np.ndarray, rotation: float = 0.0) -> Roi:
    """Axis-aligned bounding box of (N, 2) points as an ROI with the given rotation
    (DetectionsToRectsCalculator on a box)."""
    lo, hi = np.min(points, axis=0), np.max(points, axis=0)
    c = (lo + hi) / 2
    return Roi(float(c[0]), float(c[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1]), rotation)


def transform_roi(roi: Roi, scale_x: float = 1.0, scale_y: float = 1.0, shift_x: float = 0.0,
                  shift_y: float = 0.0, square_long: bool = True) -> Roi:
    """Shift (in units of the ROI's own size, along its rotated axes), square to the long side
    and scale (RectTransformationCalculator)."""
    c, s = np.cos(roi.rotation), np.sin(roi.rotation)
    dx, dy = roi.w * shift_x, roi.h * shift_y
    cx, cy = roi.cx + c * dx - s * dy, roi.cy + s * dx + c * dy
    w, h = roi.w, roi.h
    if square_long:
        w = h = max(w, h)
    return Roi(cx, cy, w * scale_x, h * scale_y, roi.rotation)


# Hand landmarks the hand's ROI is computed from (wrist, thumb base, knuckles and the joints
# above them), as HandLandmarksToRectCalculator takes them.
HAND_ROI_POINTS = (0, 1, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18)


def hand_landmarks_roi(points: np.ndarray) -> Roi:
    """ROI of 21 hand landmarks (HandLandmarksToRectCalculator): rotation from the wrist to the
    mean of the index/ring knuckles' midpoint and the middle knuckle (MCP joints), then the box
    of :data:`HAND_ROI_POINTS` in that rotated frame."""
    pts = np.asarray(points, np.float64)[list(HAND_ROI_POINTS)]
    wrist = pts[0]
    mid = ((pts[4] + pts[8]) / 2 + pts[6]) / 2
    rot = rotation_between(wrist, mid, np.pi / 2)
    center0 = (pts.min(0) + pts.max(0)) / 2
    c, s = np.cos(-rot), np.sin(-rot)
    local = (pts - center0) @ np.array([[c, -s], [s, c]]).T
    lo, hi = local.min(0), local.max(0)
    pc = (lo + hi) / 2
    cr, sr = np.cos(rot), np.sin(rot)
    centre = center0 + np.array([cr * pc[0] - sr * pc[1], sr * pc[0] + cr * pc[1]])
    return Roi(float(centre[0]), float(centre[1]), float(hi[0] - lo[0]), float(hi[1] - lo[1]),
               rot)


# --- SSD detections --------------------------------------------------------------------------

def ssd_anchors(input_size: int, strides: tuple[int, ...], offset: float = 0.5) -> np.ndarray:
    """(A, 2) anchor centres in [0, 1] for MediaPipe's fixed-size SSD anchors (one aspect ratio
    plus the interpolated one, i.e. 2 anchors per layer; layers of equal stride share a grid)."""
    out, i = [], 0
    while i < len(strides):
        j = i
        while j < len(strides) and strides[j] == strides[i]:
            j += 1
        per_cell = 2 * (j - i)
        n = int(np.ceil(input_size / strides[i]))
        ys, xs = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        centres = np.stack([(xs + offset) / n, (ys + offset) / n], -1).reshape(-1, 1, 2)
        out.append(np.repeat(centres, per_cell, axis=1).reshape(-1, 2))
        i = j
    return np.concatenate(out).astype(np.float64)


@dataclass
class Detections:
    """Decoded detections in crop pixels: boxes (N, 4) x0, y0, x1, y1; keypoints (N, K, 2);
    scores (N,), best first after :func:`weighted_nms`."""

    boxes: np.ndarray
    keypoints: np.ndarray
    scores: np.ndarray

    def __len__(self) -> int:
        return len(self.scores)


def decode_detections(raw_boxes: np.ndarray, raw_scores: np.ndarray, anchors: np.ndarray,
                      input_size: int, num_keypoints: int, min_score: float,
                      clip: float = 100.0) -> Detections:
    """SSD outputs -> detections above ``min_score`` (TensorsToDetectionsCalculator with
    reverse_output_order, sigmoid scores, fixed anchors of size 1).

    raw_boxes (A, 4 + 2K): centre offsets and size (x, y, w, h) then keypoints (x, y), in input
    pixels relative to the anchor centre; raw_scores (A,) logits."""
    s = float(input_size)
    a = anchors * s
    score = 1.0 / (1.0 + np.exp(-np.clip(raw_scores.reshape(-1).astype(np.float64), -clip, clip)))
    keep = np.flatnonzero(score >= min_score)
    r = raw_boxes[keep].astype(np.float64)
    cx, cy = r[:, 0] + a[keep, 0], r[:, 1] + a[keep, 1]
    w, h = r[:, 2], r[:, 3]
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], -1)
    kps = r[:, 4:4 + 2 * num_keypoints].reshape(-1, num_keypoints, 2) + a[keep, None, :]
    return Detections(boxes, kps, score[keep])


def iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """IoU of one (4,) xyxy box with (N, 4) boxes."""
    x0 = np.maximum(box[0], boxes[:, 0])
    y0 = np.maximum(box[1], boxes[:, 1])
    x1 = np.minimum(box[2], boxes[:, 2])
    y1 = np.minimum(box[3], boxes[:, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area = (box[2] - box[0]) * (box[3] - box[1])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    union = area + areas - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1), 0.0)


def weighted_nms(det: Detections, threshold: float = 0.3) -> Detections:
    """MediaPipe's weighted non-maximum suppression: each kept detection is the score-weighted
    mean (box and keypoints) of the detections overlapping the best remaining one by IoU above
    ``threshold``, with the best one's score."""
    order = np.argsort(-det.scores, kind="stable")
    boxes, kps, scores = [], [], []
    while order.size:
        best = order[0]
        over = iou(det.boxes[best], det.boxes[order]) > threshold
        group = order[over]
        wts = det.scores[group][:, None]
        boxes.append((det.boxes[group] * wts).sum(0) / wts.sum())
        kps.append((det.keypoints[group] * wts[:, :, None]).sum(0) / wts.sum())
        scores.append(det.scores[best])
        order = order[~over]
    k = det.keypoints.shape[1]
    return Detections(np.array(boxes).reshape(-1, 4), np.array(kps).reshape(-1, k, 2),
                      np.array(scores, np.float64))


def project_detections(det: Detections, roi: Roi, out_wh: tuple[int, int]) -> Detections:
    """Detections from crop pixels to image pixels (boxes become the axis-aligned boxes of
    their projected corners)."""
    if not len(det):
        return det
    kps = crop_to_image(det.keypoints, roi, out_wh)
    b = det.boxes
    corners = np.stack([b[:, [0, 1]], b[:, [2, 1]], b[:, [2, 3]], b[:, [0, 3]]], 1)
    c = crop_to_image(corners, roi, out_wh)
    boxes = np.concatenate([c.min(1), c.max(1)], -1)
    return Detections(boxes, kps, det.scores)


# --- landmarks -------------------------------------------------------------------------------

def sigmoid(x):
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


def refine_from_heatmap(points: np.ndarray, heatmap: np.ndarray, input_wh: tuple[int, int],
                        kernel: int = 7, min_confidence: float = 0.5) -> np.ndarray:
    """Refine crop-pixel landmarks (K, 2) with heatmap logits (K, h, w): where the window's
    peak probability is at least ``min_confidence``, the point becomes the probability-weighted
    mean cell of the ``kernel`` x ``kernel`` window around it (RefineLandmarksFromHeatmap;
    cells are read at their index, as MediaPipe does)."""
    k, hh, hw = heatmap.shape
    W, H = input_wh
    out = points.copy()
    prob = sigmoid(heatmap)
    half = (kernel - 1) // 2
    for i in range(k):
        col = int(points[i, 0] / W * hw)  # truncation toward zero, as in C++
        row = int(points[i, 1] / H * hh)
        if not (0 <= col < hw and 0 <= row < hh):
            continue
        r0, r1 = max(0, row - half), min(hh, row + half + 1)
        c0, c1 = max(0, col - half), min(hw, col + half + 1)
        win = prob[i, r0:r1, c0:c1]
        total = win.sum()
        if win.max() >= min_confidence and total > 0:
            rows, cols = np.mgrid[r0:r1, c0:c1]
            out[i, 0] = (win * cols).sum() / total / hw * W
            out[i, 1] = (win * rows).sum() / total / hh * H
    return out
