"""Perception accuracy beside time, against the simulator's ground truth.

Metrics (one row each in ``eval.parquet``, table ``perception_eval``):

- ``mask_iou``: mean over frames of |pred & gt| / |pred | gt| (1 when both are empty).
- ``mask_area_bias``: (sum of |pred| - sum of |gt|) / sum of |gt| over the frames: how much
  larger (> 0) or smaller the predicted masks are. An outline drawn half a pixel outside the
  true one barely moves the IoU but biases the fit's mask terms (docs/fit.md).
- ``pck@0.05`` per part (body, feet, face, left_hand, right_hand): the fraction of keypoints
  visible in the ground truth whose prediction lies within 0.05 x the person box size, where
  the box is the ground-truth mask's box and its size is max(width, height) in pixels. A
  keypoint with no prediction (score 0) counts as a miss.
- ``mean_px_error`` per part: mean pixel distance over visible keypoints that have a prediction.
- ``fps``: frames per second of segmentation, keypoints and both together, timing the model
  calls with their pre- and post-processing on in-memory frames (no PNG I/O), batch as in the
  stages, with the stage's thread count; ``stage_fps``: the stages' own wall-clock throughput
  from their timings tables, I/O included (when given).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.body.joints import KEYPOINT_PARTS, NUM_KEYPOINTS
from signsplat.io.images import read_mask, read_rgb
from signsplat.io.tables import read_table, write_table
from signsplat.perception.contracts import KeypointSpec, SegmenterSpec, load_segmenter
from signsplat.perception.keypoints import box_from_mask
from signsplat.perception.segment import mask_stats, segment_batch
from signsplat.perception.tables import EVAL_TABLE, MASKS_TABLE  # noqa: F401  (registers)

PCK_ALPHA = 0.05


def mask_iou(pred: np.ndarray, gt: np.ndarray) -> float:
    """IoU of two (H, W) bool masks; 1.0 when both are empty."""
    union = np.logical_or(pred, gt).sum()
    return 1.0 if union == 0 else float(np.logical_and(pred, gt).sum() / union)


def mask_area_bias(pred_areas, gt_areas) -> float:
    """Relative area bias of predicted masks against their ground truth, pooled over the
    frames, from the masks' areas in pixels (one per frame): (sum pred - sum gt) / sum gt;
    NaN when every ground truth is empty."""
    gt, pred = float(np.sum(gt_areas)), float(np.sum(pred_areas))
    return float("nan") if gt == 0 else (pred - gt) / gt


def keypoint_errors(pred: np.ndarray, gt: np.ndarray, visible: np.ndarray,
                    size: np.ndarray, alpha: float = PCK_ALPHA) -> dict[str, dict]:
    """Per-part PCK and mean pixel error.

    pred, gt: (N, K, 2) pixels (pred NaN = no prediction); visible: (N, K) bool;
    size: (N,) normalising box size in pixels. Returns {part: {pck, n, err, n_err}}.
    """
    dist = np.linalg.norm(pred - gt, axis=-1)  # NaN where no prediction
    hit = np.nan_to_num(dist, nan=np.inf) <= alpha * size[:, None]
    out = {}
    for part, idx in KEYPOINT_PARTS.items():
        idx = list(idx)
        v = visible[:, idx]
        d = dist[:, idx][v]
        found = d[np.isfinite(d)]
        out[part] = {"pck": float(hit[:, idx][v].mean()) if v.any() else float("nan"),
                     "n": int(v.sum()),
                     "err": float(found.mean()) if found.size else float("nan"),
                     "n_err": int(found.size)}
    return out


def _frame_arrays(df: pd.DataFrame, keys: pd.DataFrame, col: str) -> np.ndarray:
    """(N, K) array of ``col`` for the (view, frame) rows of ``keys`` (NaN where missing)."""
    k = NUM_KEYPOINTS
    full = pd.MultiIndex.from_arrays(
        [np.repeat(keys["view"].to_numpy(), k), np.repeat(keys["frame"].to_numpy(), k),
         np.tile(np.arange(k), len(keys))], names=["view", "frame", "kp"])
    s = df.set_index(["view", "frame", "kp"])[col].astype(np.float64)
    return s.reindex(full).to_numpy().reshape(len(keys), k)


def accuracy(sim_dir: str | os.PathLike, perception_dir: str | os.PathLike) -> pd.DataFrame:
    """Accuracy rows (scene, metric, part, value, count) of a scene's perception outputs."""
    sim_dir, perception_dir = Path(sim_dir), Path(perception_dir)
    frames = read_table(sim_dir / "frames.parquet", "frames")
    masks = read_table(perception_dir / "masks.parquet", "masks")
    gt_kp = read_table(sim_dir / "keypoints_gt.parquet", "keypoints")
    kp = read_table(perception_dir / "keypoints.parquet", "keypoints")
    scene = str(frames["scene"].iloc[0])
    keys = frames.merge(masks[["view", "frame", "mask"]], on=["view", "frame"],
                        suffixes=("", "_pred")).sort_values(["view", "frame"])
    ious, sizes, pred_areas, gt_areas = [], [], [], []
    for _, r in keys.iterrows():
        gt = read_mask(sim_dir / r["mask"])
        pred = read_mask(perception_dir / r["mask_pred"])
        ious.append(mask_iou(pred, gt))
        pred_areas.append(int(pred.sum()))
        gt_areas.append(int(gt.sum()))
        box = box_from_mask(gt)
        sizes.append(np.nan if box is None else max(box[2] - box[0], box[3] - box[1]))
    rows = [(scene, "mask_iou", "all", float(np.mean(ious)), len(ious)),
            (scene, "mask_area_bias", "all", mask_area_bias(pred_areas, gt_areas), len(ious))]
    if "visible" not in gt_kp.columns:
        gt_kp = gt_kp.assign(visible=gt_kp["score"] > 0.5)
    gxy = np.stack([_frame_arrays(gt_kp, keys, "x"), _frame_arrays(gt_kp, keys, "y")], -1)
    vis = np.nan_to_num(_frame_arrays(gt_kp, keys, "visible"), nan=0).astype(bool)
    vis &= np.isfinite(gxy).all(-1) & np.isfinite(np.array(sizes))[:, None]
    pxy = np.stack([_frame_arrays(kp, keys, "x"), _frame_arrays(kp, keys, "y")], -1)
    res = keypoint_errors(pxy, gxy, vis, np.nan_to_num(np.array(sizes), nan=1.0))
    for part, m in res.items():
        rows.append((scene, f"pck@{PCK_ALPHA:g}", part, m["pck"], m["n"]))
        rows.append((scene, "mean_px_error", part, m["err"], m["n_err"]))
    return pd.DataFrame(rows, columns=["scene", "metric", "part", "value", "count"])


def speed(sim_dir: str | os.PathLike, seg: SegmenterSpec, kps: KeypointSpec, threads: int,
          max_frames: int = 64, repeats: int = 2) -> pd.DataFrame:
    """Frames per second of the two models with pre/post-processing on in-memory frames."""
    sim_dir = Path(sim_dir)
    frames = read_table(sim_dir / "frames.parquet", "frames").head(max_frames)
    scene = str(frames["scene"].iloc[0])
    images = [read_rgb(sim_dir / p) for p in frames["image"]]
    from signsplat.perception.stages import open_keypointer

    smodel, kmodel = load_segmenter(seg, threads), open_keypointer(kps, threads)
    views = frames["view"].astype(int).tolist()
    t_seg = t_kp = 0.0
    for _ in range(repeats):
        for start in range(0, len(images), seg.batch_size):
            batch = images[start:start + seg.batch_size]
            t0 = time.perf_counter()
            alphas = segment_batch(smodel, seg, batch)
            boxes = [None if np.isnan(st["box"][0]) else st["box"]
                     for st in (mask_stats(a, seg.threshold) for a in alphas)]
            t1 = time.perf_counter()
            kmodel.detect(batch, boxes, views[start:start + seg.batch_size])
            t2 = time.perf_counter()
            t_seg += t1 - t0
            t_kp += t2 - t1
    n = len(images) * repeats
    rows = [(scene, "fps", "segment", n / t_seg, n), (scene, "fps", "keypoints", n / t_kp, n),
            (scene, "fps", "total", n / (t_seg + t_kp), n)]
    return pd.DataFrame(rows, columns=["scene", "metric", "part", "value", "count"])


def stage_speed(scene: str, timing_paths: dict[str, str | os.PathLike]) -> pd.DataFrame:
    """Stage throughput (frames / total seconds) from ``timings`` tables, I/O included."""
    rows, total = [], 0.0
    n = 0
    for part, path in timing_paths.items():
        t = read_table(path, "timings")
        row = t[t["step"] == "total"].iloc[0]
        rows.append((scene, "stage_fps", part, row["count"] / row["seconds"], int(row["count"])))
        total += row["seconds"]
        n = int(row["count"])
    if rows:
        rows.append((scene, "stage_fps", "total", n / total, n))
    return pd.DataFrame(rows, columns=["scene", "metric", "part", "value", "count"])


def format_table(df: pd.DataFrame) -> str:
    """A plain-text table: metric, part, value, count per row."""
    lines = [f"{'scene':<10} {'metric':<14} {'part':<11} {'value':>9} {'count':>7}"]
    for _, r in df.iterrows():
        lines.append(f"{r['scene']:<10} {r['metric']:<14} {r['part']:<11} {r['value']:>9.4g} "
                     f"{int(r['count']):>7d}")
    return "\n".join(lines)


def evaluate_scene(sim_dir, perception_dir, out_path, seg: SegmenterSpec, kps: KeypointSpec,
                   threads: int = 2, speed_frames: int = 64,
                   timing_paths: dict | None = None) -> pd.DataFrame:
    """Accuracy + speed of one scene; writes ``out_path`` (table ``perception_eval``)."""
    acc = accuracy(sim_dir, perception_dir)
    parts = [acc, speed(sim_dir, seg, kps, threads, speed_frames)]
    if timing_paths:
        parts.append(stage_speed(str(acc["scene"].iloc[0]), timing_paths))
    df = pd.concat(parts, ignore_index=True).astype({"value": "float64", "count": "int64"})
    write_table(df, out_path, "perception_eval",
                metadata={"segmenter": str(seg.path),
                          "keypoints": str(getattr(kps, "path", getattr(kps, "cache", ""))),
                          "threads": str(threads)})
    return df
