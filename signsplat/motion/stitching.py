"""Motion stitching: gloss clips -> one continuous SMPL-X track (paper section 3.6).

Between two glosses only the last pose of the first and the first pose of the second are
used. Joint rotations (body, jaw, eyes, both hands) become unit quaternions and are
interpolated by SLERP along the shorter arc (``roma.unitquat_slerp``) with the cubic
ease-in/ease-out time warp ``w(s) = 3 s^2 - 2 s^3``; expression coefficients are interpolated
linearly with the same warp; global orientation and translation are averaged over the whole
sequence and held fixed; betas are constant.

The transition length adapts to the motion: ``ceil(max joint angle difference in degrees /
deg_per_frame)`` frames, clamped to ``[min_transition, max_transition]``. Every gloss may be
held for a few frames at its start and end, and consecutive fingerspelled letters are
separated by their own (shorter) holds.

:func:`stitch_frames` is a generator over frames, so a very long sentence needs memory for one
clip and one transition only; :func:`stitch_clips` collects it into arrays and
:func:`write_stitched_table` streams it into an ``smplx_params`` Parquet table.

Hand poses are interpolated in the 'flat' convention (full rotations): clips stored relative
to the MANO mean are converted first (:func:`signsplat.stitch.library.to_flat`), so the mean
is never added twice.
"""

from __future__ import annotations

import math
import os
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import roma
import torch

from signsplat.io.atomic import atomic_path
from signsplat.motion.clips import GlossClip

#: Rotation blocks (axis-angle, 3 values per joint) that are SLERPed.
ROTATION_BLOCKS = ("body_pose", "jaw_pose", "leye_pose", "reye_pose", "left_hand_pose",
                   "right_hand_pose")
#: Sizes of every block in an output frame (SMPL-X, 10 betas / 10 expression by default).
FRAME_BLOCKS = {"global_orient": 3, "body_pose": 63, "jaw_pose": 3, "leye_pose": 3,
                "reye_pose": 3, "left_hand_pose": 45, "right_hand_pose": 45,
                "expression": 10, "transl": 3, "betas": 10}
TRANSITION = "transition"


@dataclass(frozen=True)
class StitchConfig:
    """Knobs of the stitching (all in frames or degrees per frame).

    Attributes:
        deg_per_frame: transition frames = max joint angle difference (degrees) / this.
        min_transition, max_transition: clamp of the transition length (frames, >= 0).
        hold_start, hold_end: frames the first / last pose of every gloss is held.
        letter_hold: frames held between two consecutive fingerspelled letters (replaces
            hold_end + hold_start there).
    """

    deg_per_frame: float = 8.0
    min_transition: int = 3
    max_transition: int = 20
    hold_start: int = 2
    hold_end: int = 2
    letter_hold: int = 1

    def __post_init__(self):
        if not self.deg_per_frame > 0:
            raise ValueError(f"deg_per_frame must be > 0, got {self.deg_per_frame}")
        if not 0 <= self.min_transition <= self.max_transition:
            raise ValueError("need 0 <= min_transition <= max_transition, got "
                             f"{self.min_transition}, {self.max_transition}")
        for name in ("hold_start", "hold_end", "letter_hold"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0")

    @classmethod
    def from_dict(cls, d: dict | None) -> "StitchConfig":
        d = dict(d or {})
        known = {k: d[k] for k in cls.__dataclass_fields__ if k in d}
        return cls(**known)


@dataclass
class Frame:
    """One output frame: ``params[block] -> (k,) float32`` (all of :data:`FRAME_BLOCKS`),
    ``label`` (gloss name or 'transition'), ``gloss_index`` (position in the sequence; for a
    transition the index of the gloss it leaves)."""

    label: str
    gloss_index: int
    params: dict[str, np.ndarray]


def ease_in_out(s: np.ndarray | torch.Tensor):
    """Cubic ease-in/ease-out ``3 s^2 - 2 s^3`` (s in [0, 1])."""
    return s * s * (3.0 - 2.0 * s)


def _quats(aa: np.ndarray) -> torch.Tensor:
    """(k,) flat axis-angle -> (k/3, 4) unit quaternions (xyzw), float64."""
    return roma.rotvec_to_unitquat(_t64(aa).reshape(-1, 3))


def _t64(x) -> torch.Tensor:
    """float64 tensor copy of an array (library arrays may be read-only)."""
    return torch.from_numpy(np.array(x, dtype=np.float64))


def max_angle_deg(pose_a: dict[str, np.ndarray], pose_b: dict[str, np.ndarray]) -> float:
    """Largest geodesic angle (degrees) between corresponding joints of two poses."""
    worst = 0.0
    for block in ROTATION_BLOCKS:
        if block in pose_a and block in pose_b:
            a = _t64(pose_a[block]).reshape(-1, 3)
            b = _t64(pose_b[block]).reshape(-1, 3)
            d = roma.rotvec_geodesic_distance(a, b)
            worst = max(worst, float(d.max()) if d.numel() else 0.0)
    return math.degrees(worst)


def transition_length(pose_a: dict, pose_b: dict, config: StitchConfig) -> int:
    """Adaptive number of in-between frames, clamped to the configured range."""
    # tolerance: float32 poses carry ~1e-5 degree noise, which must not add a frame
    n = math.ceil(max_angle_deg(pose_a, pose_b) / config.deg_per_frame - 1e-4)
    return int(min(max(n, config.min_transition), config.max_transition))


def slerp_blocks(pose_a: dict[str, np.ndarray], pose_b: dict[str, np.ndarray],
                 steps: np.ndarray) -> dict[str, np.ndarray]:
    """Interpolate two poses at warped times ``steps`` (n,) in [0, 1].

    Rotation blocks: SLERP of unit quaternions on the shorter arc; other blocks (expression):
    linear. Returns block -> (n, k) float64.
    """
    t = torch.as_tensor(steps, dtype=torch.float64)
    out = {}
    for block in pose_a:
        if block not in pose_b:
            continue
        if block in ROTATION_BLOCKS:
            q = roma.unitquat_slerp(_quats(pose_a[block]), _quats(pose_b[block]), t,
                                    shortest_arc=True)
            q = q / q.norm(dim=-1, keepdim=True)
            k = np.asarray(pose_a[block]).size
            out[block] = roma.unitquat_to_rotvec(q).reshape(len(steps), k).numpy()
        else:
            a = np.asarray(pose_a[block], np.float64)
            b = np.asarray(pose_b[block], np.float64)
            out[block] = a[None] + (b - a)[None] * np.asarray(steps)[:, None]
    return out


def transition(pose_a: dict, pose_b: dict, config: StitchConfig) -> dict[str, np.ndarray]:
    """In-between frames (n, k) from ``pose_a`` to ``pose_b`` (both excluded), eased."""
    n = transition_length(pose_a, pose_b, config)
    s = np.arange(1, n + 1, dtype=np.float64) / (n + 1)
    return slerp_blocks(pose_a, pose_b, ease_in_out(s))


def mean_rotation(aa: np.ndarray) -> np.ndarray:
    """Chordal L2 mean (3,) of axis-angle rotations (N, 3) (projected mean of matrices)."""
    if len(aa) == 0:
        return np.zeros(3)
    m = roma.rotvec_to_rotmat(_t64(aa)).mean(0)
    return roma.rotmat_to_rotvec(roma.special_procrustes(m)).numpy()


def _held(clips: Sequence[GlossClip]) -> tuple[np.ndarray, np.ndarray]:
    """Global orientation and translation averaged over every frame of every clip."""
    orients, transls = [], []
    for c in clips:
        if "global_orient" in c.poses:
            orients.append(c.poses["global_orient"])
        if "transl" in c.poses:
            transls.append(c.poses["transl"])
    go = mean_rotation(np.concatenate(orients)) if orients else np.zeros(3)
    tr = np.concatenate(transls).mean(0) if transls else np.zeros(3)
    return go, tr


def _betas(clips: Sequence[GlossClip]) -> np.ndarray:
    """Mean betas of the clips that carry them (imported clips), else zeros(10)."""
    have = [c.poses["betas"] for c in clips if "betas" in c.poses]
    if not have:
        return np.zeros(10, np.float32)
    return np.concatenate(have).mean(0).astype(np.float32)


def _pose_at(clip: GlossClip, i: int, blocks: Iterable[str]) -> dict[str, np.ndarray]:
    return {b: clip.poses[b][i] for b in blocks if b in clip.poses}


def _check_clip(clip: GlossClip) -> None:
    if clip.hand_mean != "flat":
        raise ValueError(f"gloss {clip.gloss!r} has hand_mean={clip.hand_mean!r}; convert it "
                         "to 'flat' first (signsplat.stitch.library.to_flat)")
    if clip.num_frames < 1:
        raise ValueError(f"gloss {clip.gloss!r} has no frames")


def stitch_frames(clips: Sequence[GlossClip], config: StitchConfig = StitchConfig(),
                  betas: np.ndarray | None = None, num_expression: int = 10,
                  fps: float | None = None) -> Iterator[Frame]:
    """Stream the stitched sequence frame by frame.

    Args:
        clips: the gloss clips in signing order (hand poses 'flat'); references are enough,
            frames are generated lazily.
        config: transition lengths and holds.
        betas: (S,) shape, constant over the sequence (default: the mean betas of the clips
            that carry betas, else zeros(10)).
        num_expression: size of the expression block (missing blocks are zeros).
        fps: if given, every clip must have this frame rate.
    Yields:
        :class:`Frame` objects with every block of :data:`FRAME_BLOCKS`.
    """
    for c in clips:
        _check_clip(c)
        if fps is not None and abs(c.fps - fps) > 1e-6:
            raise ValueError(f"gloss {c.gloss!r} is at {c.fps} fps, the sequence at {fps}; "
                             "resample it first")
    if not clips:
        return
    go, tr = _held(clips)
    betas = _betas(clips) if betas is None else np.asarray(betas, np.float32)
    sizes = dict(FRAME_BLOCKS, expression=num_expression, betas=len(betas))
    moving = [b for b in sizes if b not in ("global_orient", "transl", "betas")]
    fixed = {"global_orient": go.astype(np.float32), "transl": tr.astype(np.float32),
             "betas": betas}

    def frame(label, idx, pose):
        params = dict(fixed)
        for b in moving:
            v = pose.get(b)
            if v is None:
                v = np.zeros(sizes[b], np.float32)
            else:
                v = np.asarray(v, np.float32).reshape(-1)
                if b == "expression":  # pad / cut to the requested size
                    v = np.pad(v, (0, max(0, sizes[b] - v.size)))[:sizes[b]]
            params[b] = v
        return Frame(label, idx, params)

    for i, clip in enumerate(clips):
        nxt = clips[i + 1] if i + 1 < len(clips) else None
        prev = clips[i - 1] if i > 0 else None
        letters_before = prev is not None and prev.kind == clip.kind == "letter"
        letters_after = nxt is not None and nxt.kind == clip.kind == "letter"
        first = _pose_at(clip, 0, moving)
        last = _pose_at(clip, clip.num_frames - 1, moving)
        for _ in range(0 if letters_before else config.hold_start):
            yield frame(clip.gloss, i, first)
        for k in range(clip.num_frames):
            yield frame(clip.gloss, i, _pose_at(clip, k, moving))
        hold = config.letter_hold if letters_after else config.hold_end
        for _ in range(hold):
            yield frame(clip.gloss, i, last)
        if nxt is not None:
            inter = transition(last, _pose_at(nxt, 0, moving), config)
            n = len(next(iter(inter.values()))) if inter else 0
            for k in range(n):
                yield frame(TRANSITION, i, {b: v[k] for b, v in inter.items()})


def stitch_clips(clips: Sequence[GlossClip], config: StitchConfig = StitchConfig(),
                 betas: np.ndarray | None = None, num_expression: int = 10,
                 fps: float | None = None) -> dict[str, np.ndarray]:
    """The whole stitched sequence as arrays: block -> (T, k) float32, plus ``label`` (T,)
    str and ``gloss_index`` (T,) int32. Use :func:`stitch_frames` for long sentences."""
    frames = list(stitch_frames(clips, config, betas, num_expression, fps))
    n_betas = len(betas) if betas is not None else len(_betas(clips)) if clips else 10
    sizes = dict(FRAME_BLOCKS, expression=num_expression, betas=n_betas)
    out = {b: (np.stack([f.params[b] for f in frames]) if frames
               else np.zeros((0, k), np.float32)) for b, k in sizes.items()}
    out["label"] = np.array([f.label for f in frames], dtype=object)
    out["gloss_index"] = np.array([f.gloss_index for f in frames], dtype=np.int32)
    return out


def write_stitched_table(frames: Iterable[Frame], path: str | os.PathLike, scene: str,
                         chunk: int = 256, metadata: dict[str, str] | None = None) -> int:
    """Stream frames into an ``smplx_params`` Parquet table (extra columns ``label``,
    ``gloss_index``), ``chunk`` rows at a time, atomically. Returns the frame count."""
    import json

    path = Path(path)
    meta = {"hand_mean": "flat", "body_model": "", **(metadata or {})}
    count = 0
    writer = None
    rows: list[Frame] = []

    def flush(tmp):
        nonlocal writer
        cols = {"scene": pa.array([scene] * len(rows)),
                "frame": pa.array(np.arange(count - len(rows), count, dtype=np.int32))}
        for b in rows[0].params:
            cols[b] = pa.array([f.params[b].tolist() for f in rows], pa.list_(pa.float32()))
        cols["label"] = pa.array([f.label for f in rows])
        cols["gloss_index"] = pa.array([f.gloss_index for f in rows], pa.int32())
        table = pa.table(cols)
        if writer is None:
            schema = table.schema.with_metadata({b"signsplat.table": b"smplx_params",
                                                 b"signsplat.meta": json.dumps(meta).encode()})
            writer = pq.ParquetWriter(tmp, schema)
        writer.write_table(table.replace_schema_metadata(writer.schema.metadata))
        rows.clear()

    with atomic_path(path) as tmp:
        try:
            for f in frames:
                rows.append(f)
                count += 1
                if len(rows) >= chunk:
                    flush(tmp)
            if rows:
                flush(tmp)
            if writer is None:  # empty sequence: write an empty table with the columns
                schema = pa.schema([("scene", pa.string()), ("frame", pa.int32())]
                                   + [(b, pa.list_(pa.float32())) for b in FRAME_BLOCKS]
                                   + [("label", pa.string()), ("gloss_index", pa.int32())],
                                   metadata={b"signsplat.table": b"smplx_params",
                                             b"signsplat.meta": json.dumps(meta).encode()})
                pq.write_table(schema.empty_table(), tmp)
        finally:
            if writer is not None:
                writer.close()
    return count
