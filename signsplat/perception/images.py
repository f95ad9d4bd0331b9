"""Image reading and writing for the perception stages (8-bit PNG, RGB frames, 0/255 masks)."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from signsplat.errors import InputError
from signsplat.io.atomic import atomic_path


def read_rgb(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3); a missing or corrupt file names the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: image file not found")
    data = np.fromfile(path, dtype=np.uint8)
    img = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if img is None:
        raise InputError(f"{path}: not a readable image (corrupt or unknown format)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """Read a single-channel mask PNG as bool (H, W) (pixel > 127 is foreground)."""
    path = Path(path)
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) if path.is_file() else None
    if img is None:
        raise InputError(f"{path}: mask file missing or unreadable")
    return img > 127


def write_mask(path: str | os.PathLike, mask: np.ndarray) -> None:
    """Write a bool/0-1 (H, W) mask as a 0/255 PNG, atomically."""
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), np.where(mask, 255, 0).astype(np.uint8)):
            raise OSError(f"{path}: could not write PNG")
