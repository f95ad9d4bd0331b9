"""Gloss clips: short SMPL-X tracks of single signs, and their ``gloss_library`` table.

The simulator (:mod:`signsplat.synth`) builds clips and composes them into a scene's motion;
the sign-video stage (:mod:`signsplat.stitch`) reads clips that users bring and stitches a
sentence. Both use this package, which sits below them.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.errors import InputError
from signsplat.io.tables import read_table, write_table

#: Block name -> values per frame, as stored in the table.
BLOCK_SIZES = {"body_pose": 63, "left_hand_pose": 45, "right_hand_pose": 45, "jaw_pose": 3,
               "expression": 10}


@dataclass
class GlossClip:
    """One gloss clip.

    Attributes:
        gloss: gloss name (upper case).
        words: English words/lemmas it translates.
        kind: 'sign' or 'letter'.
        fps: frames per second.
        hand_mean: 'flat' or 'mano' convention of the hand poses.
        poses: block name -> (N, k) float32 array (``body_pose`` 63, ``left_hand_pose`` 45,
            ``right_hand_pose`` 45, ``jaw_pose`` 3, ``expression`` 10; imported clips may add
            ``global_orient`` 3, ``transl`` 3, ``betas``).
        source, licence: provenance.
    """

    gloss: str
    words: tuple[str, ...]
    kind: str
    fps: float
    hand_mean: str
    poses: dict[str, np.ndarray]
    source: str = ""
    licence: str = ""
    meta: dict = field(default_factory=dict)

    @property
    def num_frames(self) -> int:
        return int(next(iter(self.poses.values())).shape[0])




def clips_from_table(df: pd.DataFrame, where: str = "<table>") -> dict[str, GlossClip]:
    """Turn ``gloss_library`` rows into clips; list columns are reshaped to (N, k)."""
    extra = ("global_orient", "transl", "betas", "leye_pose", "reye_pose")
    clips: dict[str, GlossClip] = {}
    for row in df.itertuples(index=False):
        n = int(row.num_frames)
        poses = {}
        for name in list(BLOCK_SIZES) + [c for c in extra if c in df.columns]:
            val = getattr(row, name)
            if val is None or (not isinstance(val, (list, np.ndarray))):
                continue
            arr = np.asarray(val, dtype=np.float32)
            if n == 0 or arr.size % n:
                raise InputError(f"{where}: gloss {row.gloss!r} column {name!r} has {arr.size} "
                                 f"values, not a multiple of num_frames={n}")
            poses[name] = arr.reshape(n, -1)
        for name, k in BLOCK_SIZES.items():
            if name in poses and name != "expression" and poses[name].shape[1] != k:
                raise InputError(f"{where}: gloss {row.gloss!r} column {name!r} has "
                                 f"{poses[name].shape[1]} values per frame, expected {k}")
        clips[row.gloss] = GlossClip(
            gloss=row.gloss, words=tuple(row.words), kind=row.kind, fps=float(row.fps),
            hand_mean=row.hand_mean, poses=poses, source=row.source, licence=row.licence)
    return clips


def load_gloss_library(path: str | os.PathLike) -> dict[str, GlossClip]:
    """Read a ``gloss_library`` Parquet file -> gloss name -> :class:`GlossClip`."""
    return clips_from_table(read_table(path, "gloss_library"), str(path))


def clips_to_table(clips: Iterable[GlossClip]) -> pd.DataFrame:
    """Clips -> ``gloss_library`` rows (extra list columns for ``global_orient``, ``transl``,
    ``betas``, ``leye_pose``, ``reye_pose`` when a clip has them)."""
    rows = []
    for c in clips:
        row = {"gloss": c.gloss, "words": list(c.words), "kind": c.kind, "fps": float(c.fps),
               "num_frames": np.int32(c.num_frames), "source": c.source, "licence": c.licence,
               "hand_mean": c.hand_mean}
        for b, v in c.poses.items():
            row[b] = np.asarray(v, np.float32).reshape(-1)
        for b in ("body_pose", "left_hand_pose", "right_hand_pose", "jaw_pose", "expression"):
            row.setdefault(b, np.zeros(0, np.float32))
        rows.append(row)
    return pd.DataFrame(rows)


def write_library(clips: Iterable[GlossClip], path: str | os.PathLike) -> Path:
    """Write imported clips as a ``gloss_library`` Parquet table (atomically)."""
    return write_table(clips_to_table(clips), path, "gloss_library")
