"""Gloss clips that users bring: SignAvatars-layout arrays and the workflow's own fitted
sequences, plus hand-mean convention handling.

Hand-mean conventions
---------------------
SMPL-X adds the MANO mean hand pose to the hand pose parameters unless the model is built with
``flat_hand_mean=True``. A clip records which convention its hand poses follow:

- 'flat': the hand pose is the full rotation of each hand joint (our tables' default).
- 'mano': the hand pose is relative to the mean, the full rotation is ``pose + hands_mean``.

Stitching works in 'flat' (:func:`to_flat`), so a clip is offset by the mean exactly once.
The MANO mean comes from the body model's ``hands_meanl`` / ``hands_meanr`` (:func:`hands_mean`).

SignAvatars layout
------------------
Per frame 182 values: global orient 3, body 63, left hand 45, right hand 45, jaw 3, betas 10,
expression 10, translation 3 (:data:`SIGNAVATARS_LAYOUT`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.errors import InputError
from signsplat.io.tables import read_table
from signsplat.motion.clips import GlossClip

SIGNAVATARS_LAYOUT: tuple[tuple[str, int], ...] = (
    ("global_orient", 3), ("body_pose", 63), ("left_hand_pose", 45), ("right_hand_pose", 45),
    ("jaw_pose", 3), ("betas", 10), ("expression", 10), ("transl", 3),
)
SIGNAVATARS_WIDTH = sum(k for _, k in SIGNAVATARS_LAYOUT)  # 182
HAND_MEANS = ("flat", "mano")


def hands_mean(model) -> dict[str, np.ndarray]:
    """MANO mean hand poses {'left': (45,), 'right': (45,)} float64 of a body model.

    ``model``: a :class:`signsplat.body.model.BodyModel` (buffers ``hands_mean_l/_r``), a dict
    of model arrays (keys ``hands_meanl``/``hands_meanr``) or the path of a model ``.npz``.
    """
    if isinstance(model, (str, os.PathLike)):
        from signsplat.body.model_file import load_model_arrays
        model = load_model_arrays(model)
    if isinstance(model, Mapping):
        return {"left": np.asarray(model["hands_meanl"], np.float64).reshape(45),
                "right": np.asarray(model["hands_meanr"], np.float64).reshape(45)}
    return {"left": model.hands_mean_l.detach().cpu().double().numpy().reshape(45),
            "right": model.hands_mean_r.detach().cpu().double().numpy().reshape(45)}


def convert_hand_pose(pose: np.ndarray, src: str, dst: str, mean: np.ndarray | None) -> np.ndarray:
    """Convert hand poses (..., 45) between the 'flat' and 'mano' conventions."""
    for c in (src, dst):
        if c not in HAND_MEANS:
            raise ValueError(f"hand_mean must be one of {HAND_MEANS}, got {c!r}")
    if src == dst:
        return np.asarray(pose).copy()
    if mean is None:
        raise ValueError(f"converting hand poses from {src!r} to {dst!r} needs the MANO mean "
                         "(hands_meanl/r of the body model)")
    mean = np.asarray(mean, np.float64).reshape(45)
    out = np.asarray(pose, np.float64) + (mean if src == "mano" else -mean)
    return out.astype(np.asarray(pose).dtype)


def convert_clip(clip: GlossClip, dst: str, means: dict[str, np.ndarray] | None) -> GlossClip:
    """A copy of ``clip`` with its hand poses in convention ``dst``."""
    if clip.hand_mean == dst:
        return clip
    poses = dict(clip.poses)
    for side in ("left", "right"):
        key = f"{side}_hand_pose"
        if key in poses:
            poses[key] = convert_hand_pose(poses[key], clip.hand_mean, dst,
                                           None if means is None else means[side])
    return replace(clip, poses=poses, hand_mean=dst)


def to_flat(clip: GlossClip, means: dict[str, np.ndarray] | None = None) -> GlossClip:
    """``clip`` with 'flat' hand poses (a no-op for flat clips; 'mano' clips need ``means``)."""
    return convert_clip(clip, "flat", means)


# --- gloss boundaries ---------------------------------------------------------------------

def read_boundaries(spec) -> pd.DataFrame:
    """Gloss boundaries as a DataFrame with columns ``gloss``, ``start``, ``end`` (frames,
    end exclusive) and optional ``words`` (list or ';'-separated string) and ``sequence``.

    ``spec``: a DataFrame, a list of (gloss, start, end[, words]) tuples, or a CSV/TSV path.
    """
    if isinstance(spec, pd.DataFrame):
        df = spec.copy()
    elif isinstance(spec, (str, os.PathLike)):
        path = Path(spec)
        if not path.exists():
            raise InputError(f"{path}: gloss boundary file not found")
        df = pd.read_csv(path, sep="\t" if path.suffix in (".tsv", ".tab") else ",")
    else:
        rows = [tuple(r) for r in spec]
        cols = ["gloss", "start", "end", "words"][:max((len(r) for r in rows), default=3)]
        df = pd.DataFrame(rows, columns=cols)
    missing = [c for c in ("gloss", "start", "end") if c not in df.columns]
    if missing:
        raise InputError(f"gloss boundaries lack column(s) {missing}; need gloss, start, end")
    bad = df[(df.start < 0) | (df.end <= df.start)]
    if len(bad):
        raise InputError(f"gloss boundaries: bad frame range(s) for {list(bad.gloss)} "
                         "(need 0 <= start < end)")
    return df.reset_index(drop=True)


def _words(row, gloss: str) -> tuple[str, ...]:
    w = getattr(row, "words", None)
    if w is None or (isinstance(w, float) and np.isnan(w)):
        return (gloss.lower().replace("-", " "),)
    if isinstance(w, str):
        return tuple(x.strip().lower() for x in w.split(";") if x.strip())
    return tuple(str(x).lower() for x in w)


def _cut(poses: dict[str, np.ndarray], bounds: pd.DataFrame, n: int, fps: float, hand_mean: str,
         source: str, licence: str, where: str) -> dict[str, GlossClip]:
    clips = {}
    for row in bounds.itertuples(index=False):
        s, e = int(row.start), int(row.end)
        if e > n:
            raise InputError(f"{where}: gloss {row.gloss!r} ends at frame {e} but the "
                             f"sequence has {n} frames")
        gloss = str(row.gloss).upper()
        clips[gloss] = GlossClip(
            gloss=gloss, words=_words(row, gloss), kind=str(getattr(row, "kind", "sign")),
            fps=float(fps), hand_mean=hand_mean,
            poses={k: np.ascontiguousarray(v[s:e], dtype=np.float32) for k, v in poses.items()},
            source=source, licence=licence)
    return clips


def import_signavatars(arrays, boundaries, fps: float, hand_mean: str, source: str,
                       licence: str) -> dict[str, GlossClip]:
    """Cut an (N, 182) SignAvatars-layout SMPL-X array into gloss clips.

    Args:
        arrays: (N, 182) array, or a path to ``.npy`` / ``.npz`` (first array) holding it.
        boundaries: see :func:`read_boundaries`.
        fps: frame rate of the array.
        hand_mean: 'flat' or 'mano', the convention the array's hand poses follow.
        source, licence: provenance recorded with every clip (required: say where data is from).
    """
    where = "SignAvatars array"
    if isinstance(arrays, (str, os.PathLike)):
        where = str(arrays)
        try:
            data = np.load(arrays, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise InputError(f"{arrays}: cannot read SMPL-X array ({exc})") from exc
        arrays = data[data.files[0]] if hasattr(data, "files") else data
    arr = np.asarray(arrays, np.float64)
    if arr.ndim != 2 or arr.shape[1] != SIGNAVATARS_WIDTH:
        raise InputError(f"{where}: expected shape (N, {SIGNAVATARS_WIDTH}) in the SignAvatars "
                         f"layout, got {arr.shape}")
    if hand_mean not in HAND_MEANS:
        raise InputError(f"{where}: hand_mean must be one of {HAND_MEANS}, got {hand_mean!r}")
    poses, o = {}, 0
    for name, k in SIGNAVATARS_LAYOUT:
        poses[name] = arr[:, o:o + k]
        o += k
    return _cut(poses, read_boundaries(boundaries), len(arr), fps, hand_mean, source, licence,
                where)


def import_fitted(table, boundaries, fps: float, source: str, licence: str,
                  scene: str | None = None) -> dict[str, GlossClip]:
    """Cut the workflow's own fitted sequence (``smplx_params`` table) into gloss clips.

    The hand-mean convention comes from the table's ``hand_mean`` metadata ('flat' if absent).
    ``scene`` selects one sequence when the table holds several.
    """
    where = "smplx_params table"
    if isinstance(table, (str, os.PathLike)):
        where = str(table)
        table = read_table(table, "smplx_params")
    df = table if scene is None else table[table.scene == scene]
    if scene is None and df.scene.nunique() > 1:
        raise InputError(f"{where}: holds scenes {sorted(df.scene.unique())}; pass scene=")
    df = df.sort_values("frame").reset_index(drop=True)
    hand_mean = table.attrs.get("hand_mean", "flat") if hasattr(table, "attrs") else "flat"
    blocks = [b for b in ("global_orient", "body_pose", "jaw_pose", "leye_pose", "reye_pose",
                          "left_hand_pose", "right_hand_pose", "expression", "transl", "betas")
              if b in df.columns]
    poses = {b: np.stack([np.asarray(v, np.float64) for v in df[b]]) if len(df)
             else np.zeros((0, 3)) for b in blocks}
    return _cut(poses, read_boundaries(boundaries), len(df), fps, hand_mean, source, licence,
                where)


def merge_libraries(*libraries: Mapping[str, GlossClip],
                    means: dict[str, np.ndarray] | None = None) -> dict[str, GlossClip]:
    """Union of libraries (later ones win on equal gloss names), all converted to 'flat'."""
    out: dict[str, GlossClip] = {}
    for lib in libraries:
        for name, clip in lib.items():
            out[name] = to_flat(clip, means)
    return out
