"""PNG images: atomic writes and reads whose errors name the file."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from signsplat.errors import InputError
from signsplat.io.atomic import atomic_path


def write_png(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Write an RGB (H,W,3) or grey (H,W) uint8 image as PNG, atomically."""
    path = Path(path)
    if image.dtype != np.uint8:
        raise TypeError(f"{path}: expected a uint8 image, got {image.dtype}")
    data = image[..., ::-1] if image.ndim == 3 else image  # OpenCV wants BGR
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), np.ascontiguousarray(data)):
            raise OSError(f"{path}: could not write PNG")
    return path


def _read(path: str | os.PathLike, flags: int, what: str) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: {what} file not found")
    image = cv2.imread(str(path), flags)
    if image is None:
        raise InputError(f"{path}: not a readable {what} (corrupt or unsupported format)")
    return image


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as RGB uint8 (H,W,3); a missing or corrupt file names the file."""
    return _read(path, cv2.IMREAD_COLOR, "image")[..., ::-1].copy()


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """Read a single-channel mask PNG as bool (H,W); errors name the file."""
    return _read(path, cv2.IMREAD_GRAYSCALE, "mask") > 127


def write_mask(path: str | os.PathLike, mask: np.ndarray) -> Path:
    """Write a bool or 0/1 (H,W) mask as a 0/255 PNG, atomically."""
    return write_png(path, np.where(mask, 255, 0).astype(np.uint8))
