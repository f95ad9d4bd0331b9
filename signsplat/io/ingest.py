"""Real footage in: extract the frames of one video (or image folder) per camera.

Writes the same files the simulator writes for its images, so every later stage treats real
and synthetic sequences alike: ``images/{view:02d}/{frame:04d}.png``, ``frames.parquet`` and,
when a calibration file is given, ``cameras.parquet``.

A calibration file is YAML: ``views: [{fx, fy, cx, cy, R: [9 row-major], t: [3]}, ...]``, one
entry per camera in the order of the camera inputs (``R``/``t`` optional: identity/zero).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from tqdm import tqdm

from signsplat.errors import InputError
from signsplat.io.images import write_png
from signsplat.io.tables import write_table
from signsplat.io.video import iter_frames, video_fps


def _calibration_table(path: Path, scene: str, sizes: list[tuple[int, int]]) -> pd.DataFrame:
    try:
        views = (yaml.safe_load(path.read_text()) or {}).get("views")
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"{path}: unreadable calibration file ({exc})") from None
    if not isinstance(views, list) or len(views) != len(sizes):
        raise InputError(f"{path}: key 'views' must list {len(sizes)} cameras (one per camera "
                         f"input), found {len(views) if isinstance(views, list) else views!r}")
    rows = []
    for view, (cam, (w, h)) in enumerate(zip(views, sizes)):
        missing = [k for k in ("fx", "fy", "cx", "cy") if k not in cam]
        if missing:
            raise InputError(f"{path}: views[{view}] lacks key(s) {missing}")
        R = np.asarray(cam.get("R", np.eye(3).ravel()), float).ravel()
        t = np.asarray(cam.get("t", np.zeros(3)), float).ravel()
        if R.size != 9 or t.size != 3:
            raise InputError(f"{path}: views[{view}]: R needs 9 values and t 3, "
                             f"found {R.size} and {t.size}")
        rows.append(dict(scene=scene, view=view, frame=-1, width=w, height=h,
                         fx=float(cam["fx"]), fy=float(cam["fy"]), cx=float(cam["cx"]),
                         cy=float(cam["cy"]), R=R.tolist(), t=t.tolist()))
    return pd.DataFrame(rows)


def extract_sequence(scene: str, cameras: list[str | os.PathLike], out_dir: str | os.PathLike,
                     fps: float | None = None, start: int = 0, end: int | None = None,
                     size: tuple[int, int] | None = None,
                     calibration: str | os.PathLike | None = None,
                     crop: tuple[int, int, int, int] | None = None) -> pd.DataFrame:
    """Extract frames ``start..end`` of every camera; returns the ``frames`` table.

    ``crop`` = (x, y, w, h) cuts every frame to that box (camera pixels) before ``size``
    resizes it. All cameras must yield the same number of frames; otherwise an
    :class:`InputError` names each file with its count. Nothing is written to
    ``frames.parquet`` unless every camera decoded completely; its metadata records the
    camera files (``cameras``, JSON list) so later stages can name them.
    """
    out_dir = Path(out_dir)
    cameras = [Path(c) for c in cameras]
    if not cameras:
        raise InputError(f"sequence {scene!r}: no camera inputs given")
    fps = fps or video_fps(cameras[0]) or 25.0
    rows, counts, sizes = [], {}, []
    for view, cam in enumerate(cameras):
        n = 0
        shape = None
        for index, rgb in tqdm(iter_frames(cam, start, end, size, crop),
                               desc=f"{scene} view {view}", unit="frame", leave=False):
            rel = f"images/{view:02d}/{index - start:04d}.png"
            write_png(out_dir / rel, rgb)
            shape = rgb.shape
            rows.append(dict(scene=scene, view=view, frame=index - start,
                             time=(index - start) / fps, image=rel, mask=""))
            n += 1
        if n == 0:
            raise InputError(f"{cam}: no frames in range start={start}, end={end}")
        counts[str(cam)] = n
        sizes.append((shape[1], shape[0]))
    if len(set(counts.values())) > 1:
        listing = ", ".join(f"{k}: {v}" for k, v in counts.items())
        raise InputError(f"sequence {scene!r}: cameras have different frame counts ({listing})")
    frames = pd.DataFrame(rows)
    if calibration:
        write_table(_calibration_table(Path(calibration), scene, sizes),
                    out_dir / "cameras.parquet", "cameras")
    write_table(frames, out_dir / "frames.parquet", "frames",
                metadata={"fps": str(fps), "cameras": json.dumps([str(c) for c in cameras])})
    return frames
