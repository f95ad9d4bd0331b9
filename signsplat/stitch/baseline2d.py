"""The 2D baseline the paper compares against: glosses stitched in image space (issue 7).

The same glosses, holds and transition lengths as the 3D stitching: every gloss frame is
posed by the body model (same betas and placement as the avatar video), its 133
COCO-WholeBody keypoints (:class:`~signsplat.body.keypoints.WholeBodyRegressor`) are projected
with the same camera, and every transition frame is a **linear interpolation of the 2D
keypoints** between the last frame of one gloss and the first of the next (by default with the
same cubic ease-in/ease-out timing as the 3D stitching, so the two differ only in where they
interpolate). The result is drawn as a skeleton video.

Interpolating joint positions linearly in 2D does not keep bone lengths: a forearm that turns
between two glosses shortens half way (the paper's point); the 3D stitching turns joints and
keeps them (see :mod:`signsplat.stitch.evaluate`).

Streaming: a transition is held back only until the next gloss's first pose is known, so
memory holds one batch plus one transition.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator

import cv2
import numpy as np
import torch

from signsplat.body import joints as JN
from signsplat.motion.stitching import TRANSITION, Frame, ease_in_out
from signsplat.stitch.animate import (
    Camera,
    Identity,
    RenderStats,
    batch_params,
    batched,
)


def _hand_bones(offset: int) -> list[tuple[int, int]]:
    bones = []
    for finger in range(5):
        chain = [0] + [1 + 4 * finger + k for k in range(4)]
        bones += [(offset + a, offset + b) for a, b in zip(chain[:-1], chain[1:])]
    return bones


#: COCO-WholeBody bones drawn and measured: torso and arms, legs and feet, both hands.
TORSO_ARM_BONES = [(5, 6), (5, 11), (6, 12), (11, 12), (5, 7), (7, 9), (6, 8), (8, 10)]
HEAD_BONES = [(0, 1), (0, 2), (1, 3), (2, 4)]
LEG_BONES = [(11, 13), (13, 15), (12, 14), (14, 16), (15, 17), (15, 18), (15, 19), (16, 20),
             (16, 21), (16, 22)]
LEFT_HAND_BONES = _hand_bones(JN.KP_LEFT_HAND[0])
RIGHT_HAND_BONES = _hand_bones(JN.KP_RIGHT_HAND[0])
SKELETON_BONES = TORSO_ARM_BONES + HEAD_BONES + LEG_BONES + LEFT_HAND_BONES + RIGHT_HAND_BONES
#: Bones whose length variation is reported (the signing articulators: torso, arms, hands).
METRIC_BONES = TORSO_ARM_BONES + LEFT_HAND_BONES + RIGHT_HAND_BONES

_COLORS = {"body": (60, 60, 60), "left": (30, 110, 220), "right": (220, 70, 40),
           "face": (120, 120, 120)}  # RGB


def project_keypoints(body, regressor, frames: list[Frame], identity: Identity | None,
                      camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Pose ``frames`` and project their keypoints: (B, 133, 2) pixels and (B, 133, 3) world
    positions (metres)."""
    params = batch_params(frames, identity, regressor.joint_idx.device)
    with torch.no_grad():
        kp3 = regressor(body(**params)).detach().cpu().numpy().astype(np.float64)
    uv, _ = camera.project(kp3)
    return uv, kp3


def interpolate_transition(a: np.ndarray, b: np.ndarray, n: int, ease: bool = True
                           ) -> np.ndarray:
    """(n, K, 2) in-between keypoints from ``a`` to ``b`` (K, 2), both excluded; linear in
    space, timed like the 3D stitching (``s = k / (n + 1)``, cubic ease when ``ease``)."""
    s = np.arange(1, n + 1, dtype=np.float64) / (n + 1)
    w = ease_in_out(s) if ease else s
    return a[None] + (b - a)[None] * w[:, None, None]


def baseline_keypoints(frames: Iterable[Frame], body, regressor, camera: Camera,
                       identity: Identity | None = None, batch: int = 32, ease: bool = True
                       ) -> Iterator[tuple[Frame, np.ndarray]]:
    """Yield ``(frame, keypoints (133, 2) pixels)`` of the 2D-stitched sequence, in order.

    Gloss frames are posed and projected; transition frames are interpolated linearly in 2D
    between the neighbouring gloss frames (a transition at the very end holds the last pose).
    """
    pending: list[Frame] = []
    last = None
    for chunk in batched(frames, max(1, int(batch))):
        idx = [i for i, f in enumerate(chunk) if f.label != TRANSITION]
        uv = project_keypoints(body, regressor, [chunk[i] for i in idx], identity, camera)[0] \
            if idx else None
        kps = dict(zip(idx, uv)) if idx else {}
        for i, f in enumerate(chunk):
            if f.label == TRANSITION:
                pending.append(f)
                continue
            kp = kps[i]
            if pending:
                start = last if last is not None else kp
                inter = interpolate_transition(start, kp, len(pending), ease)
                yield from zip(pending, inter)
                pending = []
            last = kp
            yield f, kp
    for f in pending:
        yield f, last


def draw_skeleton(kp: np.ndarray, width: int, height: int, valid: np.ndarray | None = None,
                  background=(255, 255, 255), thickness: int = 2) -> np.ndarray:
    """(H, W, 3) uint8 RGB image of a COCO-WholeBody skeleton from keypoints (133, 2) pixels
    (OpenCV convention); keypoints with ``valid`` False are not drawn."""
    img = np.empty((height, width, 3), np.uint8)
    img[:] = np.asarray(background, np.uint8)
    ok = np.isfinite(kp).all(-1)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    shift = 4
    fixed = np.round(np.nan_to_num(kp) * (1 << shift)).clip(-2**28, 2**28).astype(np.int64)
    hand_t = max(1, thickness // 2)
    for bones, color, t in ((TORSO_ARM_BONES + HEAD_BONES + LEG_BONES, _COLORS["body"],
                             thickness), (LEFT_HAND_BONES, _COLORS["left"], hand_t),
                            (RIGHT_HAND_BONES, _COLORS["right"], hand_t)):
        for a, b in bones:
            if ok[a] and ok[b]:
                cv2.line(img, tuple(map(int, fixed[a])), tuple(map(int, fixed[b])), color, t,
                         cv2.LINE_AA, shift)
    for k in JN.KP_FACE:
        if ok[k]:
            cv2.circle(img, tuple(map(int, fixed[k])), 1 << shift, _COLORS["face"], -1,
                       cv2.LINE_AA, shift)
    return img


def render_baseline(frames: Iterable[Frame], body, regressor, camera: Camera, writer,
                    identity: Identity | None = None, ease: bool = True, batch: int = 32,
                    on_frame: Callable[[Frame, np.ndarray], None] | None = None
                    ) -> RenderStats:
    """Draw the 2D-stitched skeleton of ``frames`` into ``writer`` (streamed); ``on_frame``
    sees every frame's keypoints (133, 2). Returns :class:`RenderStats`."""
    valid = regressor.valid.cpu().numpy()
    stats = RenderStats()
    t0 = time.perf_counter()
    for frame, kp in baseline_keypoints(frames, body, regressor, camera, identity, batch, ease):
        t1 = time.perf_counter()
        img = draw_skeleton(kp, camera.width, camera.height, valid)
        stats.render_seconds += time.perf_counter() - t1
        writer.write(img)
        stats.frames += 1
        if on_frame is not None:
            on_frame(frame, kp)
    stats.total_seconds = time.perf_counter() - t0
    return stats
