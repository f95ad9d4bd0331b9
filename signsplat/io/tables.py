"""Every Parquet table that passes between stages, with its columns documented once.

A stage writes a table with :func:`write_table` (columns checked, file written atomically,
metadata such as conventions stored in the Parquet schema) and reads one with
:func:`read_table` (a missing file or column is an error naming the file and the column).

Conventions used by all tables
------------------------------
- Units: metres, seconds, pixels; angles in radians unless a column says degrees.
- Cameras follow OpenCV: ``x_cam = R @ x_world + t``, camera looks down +z, image x right,
  y down; pixel centres at integer coordinates (``u = fx * x / z + cx``).
- World frame: y up, the signer faces +z, metres.
- List columns (``betas``, ``R`` ...) hold fixed-length float lists, row-major.
- ``frame`` is the 0-based frame index of a sequence; ``view`` the 0-based camera index.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from signsplat.errors import SignSplatError
from signsplat.io.atomic import atomic_path


@dataclass(frozen=True)
class Table:
    name: str
    doc: str
    columns: dict[str, str]  # column name -> description (with dtype and unit)
    extra_columns: bool = False  # whether columns beyond these are allowed
    metadata: dict[str, str] = field(default_factory=dict)  # metadata keys -> description


_SMPLX_COLUMNS = {
    "betas": "list<float32>[S] shape coefficients (constant over a sequence)",
    "expression": "list<float32>[E] expression coefficients",
    "global_orient": "list<float32>[3] axis-angle of the pelvis in the world frame",
    "body_pose": "list<float32>[63] axis-angle of joints 1..21",
    "jaw_pose": "list<float32>[3] axis-angle of the jaw",
    "leye_pose": "list<float32>[3] axis-angle of the left eye",
    "reye_pose": "list<float32>[3] axis-angle of the right eye",
    "left_hand_pose": "list<float32>[45] axis-angle of left-hand joints (see hand_mean metadata)",
    "right_hand_pose": "list<float32>[45] axis-angle of right-hand joints (see hand_mean metadata)",
    "transl": "list<float32>[3] translation of the model in metres",
}

_CAMERA_COLUMNS = {
    "scene": "str sequence name",
    "view": "int32 camera index",
    "frame": "int32 frame index, or -1 when the camera is static over the sequence",
    "width": "int32 image width in pixels",
    "height": "int32 image height in pixels",
    "fx": "float64 focal length x in pixels",
    "fy": "float64 focal length y in pixels",
    "cx": "float64 principal point x in pixels",
    "cy": "float64 principal point y in pixels",
    "R": "list<float64>[9] world-to-camera rotation, row-major",
    "t": "list<float64>[3] world-to-camera translation in metres",
}

TABLES: dict[str, Table] = {
    t.name: t
    for t in [
        Table(
            "frames",
            "Input frames of a sequence: one row per view and frame (simulated or extracted).",
            {
                "scene": "str sequence name",
                "view": "int32 camera index",
                "frame": "int32 frame index",
                "time": "float64 seconds from the first frame",
                "image": "str path of the RGB PNG, relative to the table's folder",
                "mask": "str path of the ground-truth mask PNG (empty when there is none)",
            },
        ),
        Table("cameras", "Camera intrinsics and extrinsics (OpenCV convention).", _CAMERA_COLUMNS,
              extra_columns=True),
        Table(
            "smplx_params",
            "SMPL-X parameters per frame (ground truth, fitted or stitched).",
            {"scene": "str sequence name", "frame": "int32 frame index", **_SMPLX_COLUMNS},
            extra_columns=True,
            metadata={
                "hand_mean": "'flat' (hand pose is the full rotation) or 'mano' (hand pose is "
                "added to the MANO mean pose)",
                "body_model": "name or path of the body model the parameters belong to",
            },
        ),
        Table(
            "keypoints",
            "2D whole-body keypoints (COCO-WholeBody 133), one row per keypoint.",
            {
                "scene": "str sequence name",
                "view": "int32 camera index",
                "frame": "int32 frame index",
                "kp": "int16 keypoint id 0..132 (signsplat.body.joints.COCO_WHOLEBODY_NAMES)",
                "x": "float32 pixel x (NaN when unknown)",
                "y": "float32 pixel y (NaN when unknown)",
                "score": "float32 confidence in [0, 1]; ground truth uses visibility",
            },
            extra_columns=True,  # ground truth adds 'visible' (bool) and 'depth' (float32 m)
            metadata={
                "model": "the detected keypoints' model file(s)",
                "source": "their keypointer: 'onnx' (a SimCC model), 'mediapipe' (the "
                "pretrained keypointer) or 'onnx+mediapipe' (a SimCC model with MediaPipe's "
                "fingers)",
                "note": "what the keypointer reports of its run (how many frames took "
                "MediaPipe's fingers, frames left without keypoints), or empty",
            },
        ),
        Table(
            "gloss_library",
            "Gloss clips: one row per gloss with its SMPL-X track stored as list columns.",
            {
                "gloss": "str gloss name (upper case, e.g. HELLO)",
                "words": "list<str> English words/lemmas the gloss translates",
                "kind": "str 'sign' or 'letter' (fingerspelling alphabet)",
                "fps": "float64 frames per second of the track",
                "num_frames": "int32 frames in the track",
                "source": "str where the clip comes from",
                "licence": "str licence of the clip",
                "hand_mean": "str 'flat' or 'mano' convention of the hand poses",
                "body_pose": "list<float32>[N*63]",
                "left_hand_pose": "list<float32>[N*45]",
                "right_hand_pose": "list<float32>[N*45]",
                "jaw_pose": "list<float32>[N*3]",
                "expression": "list<float32>[N*10]",
            },
            extra_columns=True,
        ),
        Table(
            "timings",
            "Wall-clock time of a stage's parts, reported beside its accuracy figures.",
            {
                "scene": "str sequence name",
                "stage": "str stage name",
                "step": "str part of the stage",
                "seconds": "float64 wall-clock seconds",
                "count": "int64 items processed (frames, images, iterations)",
            },
        ),
    ]
}


def register_table(table: Table) -> Table:
    """Add a stage's table to :data:`TABLES` (each table is documented exactly once)."""
    if table.name in TABLES and TABLES[table.name] != table:
        raise ValueError(f"table {table.name!r} is already defined differently")
    TABLES[table.name] = table
    return table


class TableError(SignSplatError, ValueError):
    """A table file is missing, unreadable or lacks a column."""


def _check_columns(df: pd.DataFrame, table: Table, where: str) -> None:
    missing = [c for c in table.columns if c not in df.columns]
    if missing:
        raise TableError(f"{where}: table '{table.name}' lacks column(s) {missing}; "
                         f"expected {list(table.columns)}")
    if not table.extra_columns:
        extra = [c for c in df.columns if c not in table.columns]
        if extra:
            raise TableError(f"{where}: table '{table.name}' has unknown column(s) {extra}; "
                             f"allowed {list(table.columns)}")


def write_table(df: pd.DataFrame, path: str | os.PathLike, table: str,
                metadata: dict[str, str] | None = None) -> Path:
    """Check ``df`` against the named table and write it to ``path`` atomically."""
    spec = TABLES[table]
    path = Path(path)
    _check_columns(df, spec, str(path))
    arrow = pa.Table.from_pandas(df.reset_index(drop=True), preserve_index=False)
    meta = dict(arrow.schema.metadata or {})
    meta[b"signsplat.table"] = table.encode()
    if metadata:
        meta[b"signsplat.meta"] = json.dumps(metadata).encode()
    arrow = arrow.replace_schema_metadata(meta)
    with atomic_path(path) as tmp:
        pq.write_table(arrow, tmp)
    return path


def read_table(path: str | os.PathLike, table: str) -> pd.DataFrame:
    """Read a table written by :func:`write_table`; metadata ends up in ``df.attrs``."""
    path = Path(path)
    if not path.exists():
        raise TableError(f"{path}: file not found (expected table '{table}')")
    try:
        arrow = pq.read_table(path)
    except Exception as exc:  # pyarrow raises several types for corrupt files
        raise TableError(f"{path}: not a readable Parquet file ({exc})") from exc
    df = arrow.to_pandas()
    _check_columns(df, TABLES[table], str(path))
    df.attrs = table_metadata(arrow)
    return df


def table_metadata(arrow: pa.Table | pa.Schema) -> dict:
    """The metadata :func:`write_table` stored in an Arrow table read from its file, or in
    its schema alone (``pyarrow.parquet.read_schema``); {} when none."""
    schema = arrow if isinstance(arrow, pa.Schema) else arrow.schema
    return json.loads((schema.metadata or {}).get(b"signsplat.meta", b"{}"))


def read_columns(path: str | os.PathLike, columns: list[str]) -> pd.DataFrame:
    """The named columns of any Parquet table (for readers that accept several table kinds
    sharing these columns); a missing file or column raises :class:`TableError` naming it."""
    path = Path(path)
    if not path.exists():
        raise TableError(f"{path}: file not found (expected columns {columns})")
    try:
        return pq.read_table(path, columns=list(columns)).to_pandas()
    except Exception as exc:  # pyarrow raises several types for corrupt files/missing columns
        raise TableError(f"{path}: no readable Parquet table with columns {columns} "
                         f"({exc})") from exc
