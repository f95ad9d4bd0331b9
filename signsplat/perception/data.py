"""Training samples for the default detectors, drawn from simulated scenes.

A simulated scene folder holds ``frames.parquet`` (table ``frames``: image and ground-truth
mask paths relative to the folder) and ``keypoints_gt.parquet`` (table ``keypoints`` with a
``visible`` column). :func:`load_scenes` reads every ``stride``-th frame of every view into
memory (uint8); the samplers draw augmented batches from it with a ``numpy`` Generator, so a
fixed seed gives the same batches.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from signsplat.body.joints import NUM_KEYPOINTS
from signsplat.errors import InputError
from signsplat.io.tables import read_table
from signsplat.io.images import read_mask, read_rgb
from signsplat.perception.keypoints import (box_from_mask, box_to_center_scale, crop_matrix,
                                            fix_aspect_ratio, warp_crop)


@dataclass
class FrameSet:
    """Frames in memory: images (F, H, W, 3) uint8 RGB, masks (F, H, W) uint8 0/1,
    keypoints (F, K, 2) float32 pixels, visible (F, K) bool, and which scene each came from."""

    images: np.ndarray
    masks: np.ndarray
    keypoints: np.ndarray
    visible: np.ndarray
    scene: np.ndarray

    def __len__(self) -> int:
        return len(self.images)


def load_scene(sim_dir: str | os.PathLike, stride: int = 1, max_views: int | None = None,
               k: int = NUM_KEYPOINTS) -> FrameSet:
    """Every ``stride``-th frame of a simulated scene folder (frames with a GT mask only)."""
    sim_dir = Path(sim_dir)
    frames = read_table(sim_dir / "frames.parquet", "frames")
    kps = read_table(sim_dir / "keypoints_gt.parquet", "keypoints")
    if "visible" not in kps.columns:
        kps = kps.assign(visible=kps["score"] > 0.5)
    frames = frames[frames["frame"] % stride == 0]
    if max_views is not None:
        frames = frames[frames["view"] < max_views]
    kps = kps.sort_values(["view", "frame", "kp"])
    table = {key: g for key, g in kps.groupby(["view", "frame"], sort=False)}
    images, masks, points, vis = [], [], [], []
    for _, r in frames.sort_values(["view", "frame"]).iterrows():
        g = table.get((r["view"], r["frame"]))
        if g is None or len(g) != k or not r["mask"]:
            continue
        images.append(read_rgb(sim_dir / r["image"]))
        masks.append(read_mask(sim_dir / r["mask"]).astype(np.uint8))
        xy = g[["x", "y"]].to_numpy(np.float32)
        v = g["visible"].to_numpy(bool) & np.isfinite(xy).all(1)
        points.append(np.nan_to_num(xy, nan=-1e4))
        vis.append(v)
    if not images:
        raise InputError(f"{sim_dir}: no frames with ground-truth masks and keypoints")
    name = str(frames["scene"].iloc[0])
    return FrameSet(np.stack(images), np.stack(masks), np.stack(points), np.stack(vis),
                    np.array([name] * len(images)))


def _pad_to(a: np.ndarray, h: int, w: int) -> np.ndarray:
    """``a`` (F, H, W, ...) with zeros added below and to the right up to (h, w)."""
    pad = [(0, 0), (0, h - a.shape[1]), (0, w - a.shape[2])] + [(0, 0)] * (a.ndim - 3)
    return np.pad(a, pad) if h > a.shape[1] or w > a.shape[2] else a


def concat(sets: list[FrameSet]) -> FrameSet:
    """One frame set of several. Scenes of other image sizes are padded with black below and
    to the right to the largest: a keypoint crop sees black outside the image either way."""
    h = max(s.images.shape[1] for s in sets)
    w = max(s.images.shape[2] for s in sets)
    return FrameSet(np.concatenate([_pad_to(s.images, h, w) for s in sets]),
                    np.concatenate([_pad_to(s.masks, h, w) for s in sets]),
                    *(np.concatenate([getattr(s, f) for s in sets])
                      for f in ("keypoints", "visible", "scene")))


# --- photometric augmentation --------------------------------------------------------------

def photometric(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random gain/bias per channel, contrast, blur and noise on an RGB uint8 image."""
    x = img.astype(np.float32)
    x = x * rng.uniform(0.75, 1.25, 3) + rng.uniform(-20, 20, 3)
    mean = x.mean()
    x = (x - mean) * rng.uniform(0.7, 1.3) + mean
    if rng.random() < 0.25:
        x = cv2.GaussianBlur(x, (0, 0), rng.uniform(0.5, 1.5))
    if rng.random() < 0.5:
        x = x + rng.normal(0, rng.uniform(1, 8), x.shape).astype(np.float32)
    return np.clip(x, 0, 255).astype(np.uint8)


def _occluder(img: np.ndarray, rng: np.random.Generator, center=None,
              size: float | None = None) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Paint a random rectangle (flat colour or noise); returns image and box x0, y0, x1, y1."""
    h, w = img.shape[:2]
    s = size if size is not None else rng.uniform(0.1, 0.3) * min(h, w)
    bw, bh = s * rng.uniform(0.6, 1.6), s * rng.uniform(0.6, 1.6)
    cx, cy = center if center is not None else (rng.uniform(0, w), rng.uniform(0, h))
    x0, y0 = int(max(0, cx - bw / 2)), int(max(0, cy - bh / 2))
    x1, y1 = int(min(w, cx + bw / 2)), int(min(h, cy + bh / 2))
    out = img.copy()
    if x1 > x0 and y1 > y0:
        if rng.random() < 0.5:
            out[y0:y1, x0:x1] = rng.integers(0, 256, 3, dtype=np.uint8)
        else:
            out[y0:y1, x0:x1] = rng.integers(0, 256, (y1 - y0, x1 - x0, 3), dtype=np.uint8)
    return out, (x0, y0, x1, y1)


# --- keypoint samples ----------------------------------------------------------------------

def keypoint_sample(fs: FrameSet, i: int, out_hw: tuple[int, int], rng: np.random.Generator,
                    padding: float = 1.25, augment: bool = True):
    """One augmented top-down crop: image (H, W, 3) uint8, keypoints (K, 2) crop px, visible (K,).

    The crop box is the ground-truth mask box (jittered), as inference uses the predicted
    mask's box. Occluders hide keypoints (marked invisible, so the model learns low scores).
    """
    box = box_from_mask(fs.masks[i] > 0)
    if box is None:
        box = np.array([0, 0, fs.images.shape[2], fs.images.shape[1]], np.float64)
    c, s = box_to_center_scale(box, padding)
    angle = 0.0
    if augment:
        size = s / padding
        c = c + rng.uniform(-0.06, 0.06, 2) * size
        s = s * rng.uniform(0.9, 1.12, 2)
        angle = np.deg2rad(rng.uniform(-12, 12)) if rng.random() < 0.5 else 0.0
    s = fix_aspect_ratio(s, out_hw[1] / out_hw[0])
    m = crop_matrix(c, s, out_hw, angle)
    crop = warp_crop(fs.images[i], m, out_hw)
    pts = fs.keypoints[i].astype(np.float64) @ m[:, :2].T + m[:, 2]
    vis = fs.visible[i].copy()
    h, w = out_hw
    if augment:
        if rng.random() < 0.35:
            if rng.random() < 0.5:  # hide a hand (the hard case in sign language)
                hand = slice(91, 112) if rng.random() < 0.5 else slice(112, 133)
                seen = vis[hand]
                centre = pts[hand][seen].mean(0) if seen.any() else None
                if centre is not None:
                    crop, ob = _occluder(crop, rng, centre + rng.normal(0, 3, 2),
                                         rng.uniform(0.12, 0.22) * h)
                else:
                    crop, ob = _occluder(crop, rng)
            else:
                crop, ob = _occluder(crop, rng)
            x0, y0, x1, y1 = ob
            inside = (pts[:, 0] >= x0) & (pts[:, 0] < x1) & (pts[:, 1] >= y0) & (pts[:, 1] < y1)
            vis &= ~inside
        crop = photometric(crop, rng)
    vis &= (pts[:, 0] >= 0) & (pts[:, 0] <= w - 1) & (pts[:, 1] >= 0) & (pts[:, 1] <= h - 1)
    return crop, pts.astype(np.float32), vis


def heatmap_targets(pts: np.ndarray, vis: np.ndarray, out_hw: tuple[int, int], stride: int,
                    sigma: float) -> np.ndarray:
    """Gaussian targets (K, H/stride, W/stride) float32, peak 1; zeros for invisible points.

    Cell j's centre is at crop pixel ``stride * j + (stride - 1) / 2``; sigma in cells.
    """
    hh, ww = out_hw[0] // stride, out_hw[1] // stride
    gx = (pts[:, 0:1] - (stride - 1) / 2) / stride
    gy = (pts[:, 1:2] - (stride - 1) / 2) / stride
    ex = np.exp(-0.5 * ((np.arange(ww)[None] - gx) / sigma) ** 2)  # (K, W)
    ey = np.exp(-0.5 * ((np.arange(hh)[None] - gy) / sigma) ** 2)  # (K, H)
    t = ey[:, :, None] * ex[:, None, :]
    t[~vis] = 0.0
    return t.astype(np.float32)


# --- segmentation samples ------------------------------------------------------------------

def random_background(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """A random backdrop (H, W, 3) uint8: a flat colour (half of them near-neutral greys), a
    linear gradient between two colours, or smooth blotches (a coarse random grid upsampled)."""
    def colour():
        if rng.random() < 0.5:
            return np.full(3, rng.uniform(20, 245)) + rng.normal(0, 6, 3)
        return rng.uniform(0, 255, 3)

    kind = rng.random()
    if kind < 0.5:
        bg = np.broadcast_to(colour(), (h, w, 3)).astype(np.float32)
    elif kind < 0.75:
        t = np.linspace(0, 1, h if rng.random() < 0.5 else w, dtype=np.float32)
        t = t[:, None, None] if t.size == h else t[None, :, None]
        bg = np.broadcast_to(colour() * (1 - t) + colour() * t, (h, w, 3)).astype(np.float32)
    else:
        n = int(rng.integers(3, 9))
        grid = (np.full((n, n, 3), colour()) + rng.normal(0, 25, (n, n, 3))).astype(np.float32)
        bg = cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
    return np.clip(bg, 0, 255).astype(np.uint8)


def segmentation_sample(fs: FrameSet, i: int, out_hw: tuple[int, int],
                        rng: np.random.Generator, augment: bool = True,
                        negative_rate: float = 0.05, background_rate: float = 0.0):
    """One augmented frame: image (H, W, 3) uint8 and mask (H, W) float32 0/1.

    Random scale/shift/rotation/flip; a few samples show only background (a person-free
    region of the frame blown up to full size) with an empty mask. With probability
    ``background_rate`` the pixels outside the ground-truth mask are replaced by
    :func:`random_background` first (no draws are made when the rate is 0).
    """
    img, mask = fs.images[i], fs.masks[i]
    h0, w0 = img.shape[:2]
    h, w = out_hw
    if augment and background_rate > 0 and rng.random() < background_rate:
        img = np.where(mask[..., None] > 0, img, random_background(h0, w0, rng))
    if augment and rng.random() < negative_rate:
        cols = np.flatnonzero(mask.any(0))
        if cols.size and (cols[0] > w0 // 6 or w0 - cols[-1] > w0 // 6):
            x0, x1 = (0, cols[0]) if cols[0] >= w0 - cols[-1] else (cols[-1] + 1, w0)
            patch = img[:, x0:x1]
            bg = cv2.resize(patch, (w, h), interpolation=cv2.INTER_LINEAR)
            return photometric(bg, rng), np.zeros((h, w), np.float32)
    scale, angle, shift = 1.0, 0.0, np.zeros(2)
    if augment:
        scale = rng.uniform(0.8, 1.25)
        angle = rng.uniform(-10, 10) if rng.random() < 0.5 else 0.0
        shift = rng.uniform(-0.12, 0.12, 2) * (w0, h0)
    m = cv2.getRotationMatrix2D((w0 / 2, h0 / 2), angle, scale * w / w0)
    m[:, 2] += shift * (w / w0) + (np.array([w, h]) - np.array([w0, h0]) * (w / w0)) / 2
    im = cv2.warpAffine(img, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    mk = cv2.warpAffine(mask.astype(np.float32), m, (w, h), flags=cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REFLECT)
    if augment and rng.random() < 0.5:
        im, mk = im[:, ::-1], mk[:, ::-1]
    if augment:
        im = photometric(np.ascontiguousarray(im), rng)
    return np.ascontiguousarray(im), np.ascontiguousarray((mk > 0.5).astype(np.float32))
