"""Reading the fit's inputs and writing its outputs (tables of ``signsplat.io.tables``).

Every malformed input raises :class:`signsplat.errors.InputError` naming the file.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.body import joints as body_joints
from signsplat.errors import InputError
from signsplat.fit.cameras import Rig
from signsplat.geometry.align import camera_centres
from signsplat.io.images import read_mask, read_rgb
from signsplat.io.tables import TableError, read_columns, read_table, write_table

SMPLX_BLOCKS = ("betas", "expression", "global_orient", "body_pose", "jaw_pose", "leye_pose",
                "reye_pose", "left_hand_pose", "right_hand_pose", "transl")


def _read(path, table) -> pd.DataFrame:
    try:
        return read_table(path, table)
    except TableError as exc:
        raise InputError(str(exc)) from None


def _read_columns(path, columns) -> pd.DataFrame:
    try:
        return read_columns(path, columns)
    except TableError as exc:
        raise InputError(str(exc)) from None


def mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean (3,3) of rotations ``Rs (F,3,3)``: the rotation nearest to their
    element-wise mean (SVD projection)."""
    U, _, Vt = np.linalg.svd(np.mean(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def read_rig(path: str | os.PathLike, with_extrinsics: bool = True) -> tuple[Rig, str]:
    """Static cameras from a ``cameras`` table -> (Rig sorted by view, scene name).

    A view's static row (``frame == -1``) is used when it has one; a view with per-frame rows
    only (the simulator's ``camera_jitter``) gets its *mean camera*: the chordal mean of the
    rotations and the mean of the centres (the fit models static cameras, so that is what it
    is measured against). Intrinsics and sizes come from the view's first row. With
    ``with_extrinsics=False`` R, t are set to identity/zero (only intrinsics and sizes read).
    """
    df = _read(path, "cameras")
    if df.empty:
        raise InputError(f"{path}: cameras table has no rows")
    df = df.sort_values(["view", "frame"])
    first = df.groupby("view", as_index=False).first()
    views = first["view"].to_numpy()
    if not np.array_equal(views, np.arange(len(views))):
        raise InputError(f"{path}: views must be 0..{len(views) - 1}, got {views.tolist()}")
    K = np.zeros((len(first), 3, 3))
    K[:, 0, 0], K[:, 1, 1] = first["fx"], first["fy"]
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = first["cx"], first["cy"], 1.0
    R, t = np.tile(np.eye(3), (len(first), 1, 1)), np.zeros((len(first), 3))
    if with_extrinsics:
        for v, rows in df.groupby("view"):
            static = rows[rows["frame"] == -1]
            rows = static if len(static) else rows
            Rs = np.stack([np.asarray(r, float).reshape(3, 3) for r in rows["R"]])
            ts = np.stack([np.asarray(x, float).reshape(3) for x in rows["t"]])
            if len(Rs) == 1:
                R[v], t[v] = Rs[0], ts[0]
            else:
                R[v] = mean_rotation(Rs)
                centre = -np.einsum("fji,fj->fi", Rs, ts).mean(0)
                t[v] = -R[v] @ centre
    vals = np.concatenate([K.reshape(-1), R.reshape(-1), t.reshape(-1)])
    if not np.isfinite(vals).all() or (K[:, 0, 0] <= 0).any():
        raise InputError(f"{path}: non-finite or non-positive camera values")
    return Rig(K=K, R=R, t=t, width=first["width"].to_numpy(int),
               height=first["height"].to_numpy(int)), str(first["scene"].iloc[0])


def read_keypoints(path: str | os.PathLike, num_views: int,
                   frames: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A ``keypoints`` table -> (obs (V,T,133,3) float64 x, y, score; frames (T,) int).

    Missing rows are unknown (score 0); frames default to min..max of the table (and of
    ``frames`` when given). NaN coordinates are kept here and removed by the cleaning step.
    """
    df = _read(path, "keypoints")
    if df.empty and frames is None:
        raise InputError(f"{path}: keypoints table has no rows")
    kp = df["kp"].to_numpy(np.int64)
    view = df["view"].to_numpy(np.int64)
    if len(df) and (kp.min() < 0 or kp.max() >= body_joints.NUM_KEYPOINTS):
        raise InputError(f"{path}: keypoint ids must lie in 0..{body_joints.NUM_KEYPOINTS - 1}")
    if len(df) and (view.min() < 0 or view.max() >= num_views):
        raise InputError(f"{path}: view {int(view.max())} but the rig has {num_views} cameras")
    fr = df["frame"].to_numpy(np.int64)
    all_frames = np.unique(np.concatenate([fr, np.asarray(frames if frames is not None else [],
                                                          np.int64)]))
    if len(all_frames) == 0:
        raise InputError(f"{path}: no frames")
    seq = np.arange(all_frames.min(), all_frames.max() + 1)
    if df.duplicated(["view", "frame", "kp"]).any():
        raise InputError(f"{path}: duplicate (view, frame, kp) rows")
    obs = np.zeros((num_views, len(seq), body_joints.NUM_KEYPOINTS, 3))
    ti = fr - seq[0]
    obs[view, ti, kp, 0] = df["x"].to_numpy(np.float64)
    obs[view, ti, kp, 1] = df["y"].to_numpy(np.float64)
    obs[view, ti, kp, 2] = df["score"].to_numpy(np.float64)
    return obs, seq


def read_smplx(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """An ``smplx_params`` table -> (block -> (T,k) float64 sorted by frame, frames (T,))."""
    df = _read(path, "smplx_params").sort_values("frame")
    out = {}
    for name in SMPLX_BLOCKS:
        try:
            out[name] = np.stack([np.asarray(v, np.float64) for v in df[name]])
        except ValueError as exc:
            raise InputError(f"{path}: column {name!r} has ragged lists ({exc})") from None
    if df.attrs.get("hand_mean", "flat") != "flat":
        raise InputError(f"{path}: hand_mean {df.attrs.get('hand_mean')!r}; only 'flat' is "
                         "supported by the fit evaluation")
    return out, df["frame"].to_numpy(np.int64)


def read_frames(path: str | os.PathLike) -> pd.DataFrame:
    """The ``frames`` table (image paths resolved against the table's folder)."""
    df = _read(path, "frames").copy()
    base = Path(path).parent
    df["image_path"] = [str(base / p) for p in df["image"]]
    return df


def mask_files(path: str | os.PathLike) -> dict[tuple[int, int], Path]:
    """``{(view, frame): PNG}`` of a perception ``masks`` table or a simulator ``frames``
    table (both have ``view``, ``frame`` and ``mask``, a path relative to the table's folder);
    rows with an empty path are left out."""
    path = Path(path)
    df = _read_columns(path, ["view", "frame", "mask"])
    return {(int(v), int(f)): path.parent / rel for v, f, rel in df.itertuples(index=False)
            if rel}


def read_masks(path: str | os.PathLike, frames: np.ndarray, widths, heights) -> np.ndarray:
    """Person masks of every view and frame -> (V,T,H,W) bool.

    ``path``: a perception ``masks`` table or a simulator ``frames`` table (both have ``view``,
    ``frame`` and ``mask``, a PNG path relative to the table's folder). ``frames (T,)`` are the
    fit's frame numbers; views are 0..V-1 with the sizes ``widths``/``heights (V,)``. A frame
    without a row (or an empty path) gets an empty mask, which the silhouette terms skip.
    """
    W, H = int(np.max(widths)), int(np.max(heights))
    if len(set(np.asarray(widths).tolist())) > 1 or len(set(np.asarray(heights).tolist())) > 1:
        raise InputError(f"{path}: the silhouette terms need one image size for all views, "
                         f"got widths {list(widths)} and heights {list(heights)}")
    V = len(widths)
    index = {int(f): i for i, f in enumerate(frames)}
    out = np.zeros((V, len(frames), H, W), bool)
    for (view, frame), png in mask_files(path).items():
        if not 0 <= view < V:
            raise InputError(f"{path}: view {view} but the rig has {V} cameras")
        if frame not in index:
            continue
        m = read_mask(png)
        if m.shape != (H, W):
            raise InputError(f"{png}: mask is {m.shape[1]}x{m.shape[0]}, the camera's image "
                             f"{W}x{H}")
        out[view, index[frame]] = m
    return out


def read_grey_images(frames_df: pd.DataFrame, frames: np.ndarray, widths, heights,
                     path: str | os.PathLike) -> np.ndarray:
    """Grey images (V,T,H,W) uint8 of every view and fit frame from a ``frames`` table read
    by :func:`read_frames` (``path`` names it in errors). A frame without an image stays black
    (its flow pairs then find nothing to follow)."""
    import cv2

    V = len(widths)
    W, H = int(np.max(widths)), int(np.max(heights))
    index = {int(f): i for i, f in enumerate(frames)}
    out = np.zeros((V, len(frames), H, W), np.uint8)
    for view, frame, img in frames_df[["view", "frame", "image_path"]].itertuples(index=False):
        if not 0 <= int(view) < V:
            raise InputError(f"{path}: view {int(view)} but the rig has {V} cameras")
        if int(frame) not in index:
            continue
        rgb = read_rgb(img)
        if rgb.shape[:2] != (H, W):
            raise InputError(f"{img}: image is {rgb.shape[1]}x{rgb.shape[0]}, the camera's "
                             f"{W}x{H}")
        out[int(view), index[int(frame)]] = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return out


def rig_from_frames(frames_df: pd.DataFrame, path: str | os.PathLike) -> Rig:
    """Image sizes per view from each view's first image (no calibration); K is a placeholder
    (identity focal) to be replaced by approximate intrinsics; R = I, t = 0."""
    views = np.unique(frames_df["view"].to_numpy())
    if not np.array_equal(views, np.arange(len(views))):
        raise InputError(f"{path}: views must be 0..{len(views) - 1}, got {views.tolist()}")
    w, h = [], []
    for v in views:
        img_path = frames_df[frames_df["view"] == v]["image_path"].iloc[0]
        img = read_rgb(img_path)
        h.append(img.shape[0])
        w.append(img.shape[1])
    V = len(views)
    return Rig(K=np.tile(np.eye(3), (V, 1, 1)), R=np.tile(np.eye(3), (V, 1, 1)),
               t=np.zeros((V, 3)), width=np.asarray(w), height=np.asarray(h))


def smplx_table(params: dict[str, np.ndarray], scene: str, frames: np.ndarray,
                provenance: np.ndarray, num_keypoints: np.ndarray) -> pd.DataFrame:
    """Rows of the ``smplx_params`` table plus ``provenance`` and ``num_keypoints`` columns."""
    rows = {"scene": [scene] * len(frames), "frame": np.asarray(frames, np.int32)}
    for name in SMPLX_BLOCKS:
        arr = np.asarray(params[name], np.float32)
        if not np.isfinite(arr).all():
            raise ValueError(f"non-finite values in fitted block {name!r}")
        rows[name] = list(arr)
    rows["provenance"] = np.asarray(provenance, dtype=object)
    rows["num_keypoints"] = np.asarray(num_keypoints, np.int32)
    return pd.DataFrame(rows)


def cameras_table(rig: Rig, scene: str, status: list[str]) -> pd.DataFrame:
    """Rows of the ``cameras`` table (static: frame -1) plus a ``fit_status`` column."""
    V = rig.num_views
    vals = np.concatenate([rig.K.reshape(-1), rig.R.reshape(-1), rig.t.reshape(-1)])
    if not np.isfinite(vals).all():
        raise ValueError("non-finite fitted camera values")
    return pd.DataFrame({
        "scene": [scene] * V, "view": np.arange(V, dtype=np.int32),
        "frame": np.full(V, -1, np.int32), "width": np.asarray(rig.width, np.int32),
        "height": np.asarray(rig.height, np.int32), "fx": rig.K[:, 0, 0], "fy": rig.K[:, 1, 1],
        "cx": rig.K[:, 0, 2], "cy": rig.K[:, 1, 2], "R": list(rig.R.reshape(V, 9)),
        "t": list(rig.t.reshape(V, 3)), "fit_status": list(status),
    })


def write_outputs(out_dir: Path, smplx: pd.DataFrame, cams: pd.DataFrame,
                  meta: dict[str, str]) -> tuple[Path, Path]:
    """Write ``smplx_fit.parquet`` and ``cameras_fit.parquet`` atomically."""
    p1 = write_table(smplx, out_dir / "smplx_fit.parquet", "smplx_params", metadata=meta)
    p2 = write_table(cams, out_dir / "cameras_fit.parquet", "cameras", metadata=meta)
    return p1, p2


def read_calibrated_extrinsics(calibration: str | os.PathLike | None, view: int | None = None
                               ) -> tuple[np.ndarray, np.ndarray]:
    """(R (V,3,3), t (V,3)) of a calibrated rig's cameras table, for ``camera_init:
    calibrated`` (only camera ``view`` when given); an InputError names the file when it has
    no usable extrinsics."""
    if not calibration:
        raise InputError("fit.multiview.camera_init: calibrated needs the calibrated cameras: "
                         "pass --calibration (a cameras table with R and t), or choose "
                         "another camera_init")
    rig, _ = read_rig(calibration, with_extrinsics=True)
    ortho = np.abs(np.einsum("vij,vkj->vik", rig.R, rig.R) - np.eye(3)).max(axis=(1, 2))
    bad = np.nonzero((ortho > 1e-4) | (np.linalg.det(rig.R) < 0))[0]
    if len(bad):
        raise InputError(f"{calibration}: camera(s) {bad.tolist()} have an R that is not a "
                         "rotation (world-to-camera, det +1); fit.multiview.camera_init "
                         "calibrated uses R and t as they are")
    if rig.num_views > 1 and np.ptp(camera_centres(rig.R, rig.t), axis=0).max() < 1e-6:
        raise InputError(f"{calibration}: every camera sits at the same place - the table has "
                         "no calibrated extrinsics; choose another fit.multiview.camera_init")
    if view is not None:
        return rig.R[view:view + 1], rig.t[view:view + 1]
    return rig.R, rig.t
