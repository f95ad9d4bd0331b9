"""Video in and out: frame extraction from camera files, streaming MP4 writing.

Reading uses PyAV (FFmpeg). Every error names the file: a missing or unreadable video, a
video with no video stream, a frame range past the end, or views whose frame counts differ.
Writing streams frames to an MP4 in a temporary file renamed on close, so memory stays flat
for long videos and a killed run leaves no half-written file.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from signsplat.errors import InputError
from signsplat.io.atomic import atomic_path

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def _resize(frame: np.ndarray, size: tuple[int, int] | None) -> np.ndarray:
    if size is None or (frame.shape[1], frame.shape[0]) == tuple(size):
        return frame
    return cv2.resize(frame, tuple(size), interpolation=cv2.INTER_AREA)


def _crop(frame: np.ndarray, crop: tuple[int, int, int, int] | None, where: str) -> np.ndarray:
    """``frame[y:y+h, x:x+w]``; a box reaching outside the frame is an error naming it."""
    if crop is None:
        return frame
    x, y, w, h = (int(v) for v in crop)
    H, W = frame.shape[:2]
    if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > W or y + h > H:
        raise InputError(f"{where}: crop box x,y,w,h = {x},{y},{w},{h} does not fit the "
                         f"{W}x{H} frame")
    return np.ascontiguousarray(frame[y:y + h, x:x + w])


def video_fps(path: str | os.PathLike) -> float | None:
    """Average frame rate of a video file, or None for an image folder."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: camera input not found")
    if path.is_dir():
        return None
    try:
        with av.open(str(path)) as container:
            rate = container.streams.video[0].average_rate
            return float(rate) if rate else None
    except (av.FFmpegError, IndexError) as exc:
        raise InputError(f"{path}: unreadable video ({exc})") from None


def iter_frames(path: str | os.PathLike, start: int = 0, end: int | None = None,
                size: tuple[int, int] | None = None,
                crop: tuple[int, int, int, int] | None = None
                ) -> Iterator[tuple[int, np.ndarray]]:
    """Yield ``(index, rgb uint8 (H,W,3))`` for frames ``start <= index < end``.

    ``path`` is a video file or a folder of images (sorted by name). ``crop`` = (x, y, w, h)
    cuts every frame to that box first, ``size`` = (W, H) then resizes it. A frame that
    cannot be decoded is an error naming the file and the frame.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: camera input not found")
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not files:
            raise InputError(f"{path}: folder holds no images ({', '.join(IMAGE_SUFFIXES)})")
        for index, file in enumerate(files[start:end], start=start):
            image = cv2.imread(str(file), cv2.IMREAD_COLOR)
            if image is None:
                raise InputError(f"{file}: not a readable image")
            yield index, _resize(_crop(image[..., ::-1], crop, str(file)), size)
        return
    try:
        container = av.open(str(path))
    except av.FFmpegError as exc:
        raise InputError(f"{path}: unreadable video, frame 0 cannot be read ({exc})") from None
    with container:
        if not container.streams.video:
            raise InputError(f"{path}: file has no video stream")
        index = -1
        try:
            for index, frame in enumerate(container.decode(video=0)):
                if index < start:
                    continue
                if end is not None and index >= end:
                    break
                rgb = _crop(frame.to_ndarray(format="rgb24"), crop, f"{path}: frame {index}")
                yield index, _resize(rgb, size)
        except av.FFmpegError as exc:
            raise InputError(f"{path}: corrupt video, decoding failed at frame {index + 1} "
                             f"({exc})") from None


class VideoWriter:
    """Stream RGB frames into an H.264 MP4, written atomically on :meth:`close`.

    >>> with VideoWriter("out.mp4", fps=25) as writer:
    ...     writer.write(frame)          # (H,W,3) uint8, every frame the same size
    """

    def __init__(self, path: str | os.PathLike, fps: float, crf: int = 18):
        self.path = Path(path)
        self.fps = fps
        self.crf = crf
        self.frames = 0
        self._ctx = atomic_path(self.path)
        self._tmp = self._ctx.__enter__()
        self._container = av.open(str(self._tmp), "w", format="mp4")
        self._stream = None

    def write(self, frame: np.ndarray) -> None:
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3:
            raise ValueError(f"{self.path}: frames must be (H,W,3) uint8, got "
                             f"{frame.shape} {frame.dtype}")
        h, w = frame.shape[:2]
        if self._stream is None:
            self._stream = self._container.add_stream(
                "libx264", rate=Fraction(self.fps).limit_denominator(1001))
            # H.264 with yuv420p needs even sizes; pad by one pixel when odd
            self._stream.width, self._stream.height = w + w % 2, h + h % 2
            self._stream.pix_fmt = "yuv420p"
            self._stream.options = {"crf": str(self.crf)}
        if (w + w % 2, h + h % 2) != (self._stream.width, self._stream.height):
            raise ValueError(f"{self.path}: frame size {w}x{h} differs from the first frame's")
        if w % 2 or h % 2:
            frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        for packet in self._stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        if self._stream is not None:
            for packet in self._stream.encode():
                self._container.mux(packet)
        self._container.close()
        self._ctx.__exit__(None, None, None)

    def abort(self) -> None:
        self._container.close()
        self._ctx.__exit__(RuntimeError, RuntimeError("aborted"), None)

    def __enter__(self) -> "VideoWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()
