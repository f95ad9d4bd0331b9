"""What can be measured of the perception stages on real footage, which has no ground truth.

Rows of table ``footage_quality`` (one per metric and part):

- ``detection_rate``: the share of frames in which a part is found. A keypoint counts as found
  when it scores at least ``min_score``. Body: at least two thirds of the upper-body points
  (COCO 0-10: nose, eyes, ears, shoulders, elbows, wrists). Face: at least half of its 68
  points. Hands: the share of the frames in which the hand is *visible* in which it is found
  (at least half of its 21 points); a hand counts as visible when the pose's wrist scores at
  least ``min_score`` and the hand's expected centre, the wrist moved on along the forearm by
  half the elbow-to-wrist distance, lies inside the frame (a hand hanging out of the bottom of
  the frame is not visible; one hidden in a pocket cannot be told from the pose and counts as
  visible).
- ``visible_rate``: for the hands, the share of frames in which the hand is visible.
- ``jitter_px``: the median over keypoints and frames of the second difference
  ``|x[t+1] - 2 x[t] + x[t-1]|`` (pixels, scaled to a 256-pixel frame height), where the point
  is found in all three frames: what a still signer would show as noise.

Every frame of the ``frames`` table counts (a frame without a person counts as not found).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.body.joints import KP_BODY, KP_FACE, KP_LEFT_HAND, KP_RIGHT_HAND, NUM_KEYPOINTS
from signsplat.io.tables import Table, read_table, register_table, write_table
from signsplat.perception.tables import MASKS_TABLE  # noqa: F401  (registers 'masks')

QUALITY_TABLE = register_table(Table(
    "footage_quality",
    "Perception on footage without ground truth: detection rates and keypoint jitter "
    "(signsplat.perception.quality).",
    {
        "scene": "str sequence name",
        "metric": "str detection_rate | visible_rate | jitter_px",
        "part": "str body | face | left_hand | right_hand",
        "value": "float64 a share of frames in [0, 1], or pixels at a 256-pixel frame height",
        "count": "int64 frames (rates) or point triples (jitter) the value is over",
    },
    metadata={"min_score": "keypoints scoring at least this count as found",
              "height": "frame height in pixels the jitter was scaled from"},
))

UPPER_BODY = tuple(range(11))  # nose .. wrists
WRIST_ELBOW = {"left_hand": (9, 7), "right_hand": (10, 8)}
PARTS = {"body": KP_BODY, "face": KP_FACE, "left_hand": KP_LEFT_HAND,
         "right_hand": KP_RIGHT_HAND}


def keypoint_arrays(kp: pd.DataFrame, frames: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(T, 133, 2) positions and (T, 133) scores of one view, in frame order, for every frame
    of ``frames`` (NaN / 0 where the keypoints table has no row)."""
    order = frames.sort_values("frame")["frame"].to_numpy()
    k = NUM_KEYPOINTS
    idx = pd.MultiIndex.from_arrays([np.repeat(order, k), np.tile(np.arange(k), len(order))])
    s = kp.set_index(["frame", "kp"])
    xy = np.stack([s["x"].reindex(idx).to_numpy(np.float64),
                   s["y"].reindex(idx).to_numpy(np.float64)], -1).reshape(len(order), k, 2)
    sc = np.nan_to_num(s["score"].reindex(idx).to_numpy(np.float64)).reshape(len(order), k)
    return xy, sc


def hand_visible(xy: np.ndarray, sc: np.ndarray, side: str, size_wh: tuple[int, int],
                 min_score: float) -> np.ndarray:
    """(T,) bool: the pose says the hand is in view (module docstring)."""
    w, e = WRIST_ELBOW[side]
    centre = xy[:, w] + 0.5 * (xy[:, w] - xy[:, e])
    inside = np.all((centre >= 0) & (centre < np.asarray(size_wh, float)), axis=1)
    return (sc[:, w] >= min_score) & np.nan_to_num(inside, nan=False).astype(bool) \
        & np.isfinite(centre).all(axis=1)


def hand_found(sc: np.ndarray, side: str, min_score: float) -> np.ndarray:
    """(T,) bool: at least half of the hand's 21 points score ``min_score`` or more."""
    return (sc[:, list(PARTS[side])] >= min_score).mean(1) >= 0.5


def quality_rows(xy: np.ndarray, sc: np.ndarray, size_wh: tuple[int, int],
                 min_score: float = 0.5) -> list[tuple[str, str, float, int]]:
    """(metric, part, value, count) rows for one view's (T, 133, 2) / (T, 133) keypoints."""
    found = sc >= min_score
    t = len(sc)
    rows = []
    body = found[:, list(UPPER_BODY)].sum(1) >= 2 * len(UPPER_BODY) / 3
    rows.append(("detection_rate", "body", float(body.mean()) if t else np.nan, t))
    face = found[:, list(KP_FACE)].mean(1) >= 0.5
    rows.append(("detection_rate", "face", float(face.mean()) if t else np.nan, t))
    for side in ("left_hand", "right_hand"):
        vis = hand_visible(xy, sc, side, size_wh, min_score)
        hand = hand_found(sc, side, min_score)
        rows.append(("detection_rate", side, float(hand[vis].mean()) if vis.any() else np.nan,
                     int(vis.sum())))
        rows.append(("visible_rate", side, float(vis.mean()) if t else np.nan, t))
    scale = 256.0 / size_wh[1]
    for part, ids in PARTS.items():
        ids = list(ids)
        if t < 3:
            rows.append(("jitter_px", part, np.nan, 0))
            continue
        acc = np.linalg.norm(xy[2:, ids] - 2 * xy[1:-1, ids] + xy[:-2, ids], axis=-1)
        ok = found[2:, ids] & found[1:-1, ids] & found[:-2, ids]
        vals = acc[ok] * scale
        rows.append(("jitter_px", part, float(np.median(vals)) if vals.size else np.nan,
                     int(vals.size)))
    return rows


def footage_quality(frames_path: str | os.PathLike, keypoints_path: str | os.PathLike,
                    out_path: str | os.PathLike, min_score: float = 0.5) -> pd.DataFrame:
    """The ``footage_quality`` table of a sequence (views pooled by frame count); writes
    ``out_path``."""
    from signsplat.io.images import read_rgb

    frames_path = Path(frames_path)
    frames = read_table(frames_path, "frames")
    kp = read_table(keypoints_path, "keypoints")
    scene = str(frames["scene"].iloc[0])
    per_view = []
    for view, fv in frames.groupby("view"):
        h, w = read_rgb(frames_path.parent / fv["image"].iloc[0]).shape[:2]
        xy, sc = keypoint_arrays(kp[kp["view"] == view], fv)
        per_view.append((quality_rows(xy, sc, (w, h), min_score), h))
    df = pd.DataFrame([r for rows, _ in per_view for r in rows],
                      columns=["metric", "part", "value", "count"])
    # pool views: count-weighted means
    df["w"] = df["value"] * df["count"]
    df = df.groupby(["metric", "part"], sort=False).agg(w=("w", "sum"), count=("count", "sum"))
    df["value"] = df["w"] / df["count"].where(df["count"] > 0)
    df = df.reset_index()[["metric", "part", "value", "count"]]
    df.insert(0, "scene", scene)
    df = df.astype({"value": "float64", "count": "int64"})
    write_table(df, out_path, "footage_quality",
                metadata={"min_score": str(min_score), "height": str(per_view[0][1])})
    return df


PART_COLOURS = {"body": (255, 64, 64), "face": (255, 220, 0), "left_hand": (0, 160, 255),
                "right_hand": (255, 0, 220)}


def overlay(image: np.ndarray, mask: np.ndarray, xy: np.ndarray, sc: np.ndarray,
            min_score: float = 0.5) -> np.ndarray:
    """RGB uint8 frame with the person mask tinted green and the keypoints scoring at least
    ``min_score`` drawn as dots coloured by part (body red, face yellow, left hand blue, right
    hand magenta)."""
    import cv2

    out = image.astype(np.float32)
    m = mask.astype(bool)
    out[m] = 0.6 * out[m] + 0.4 * np.array([0, 255, 0], np.float32)
    out = out.astype(np.uint8)
    r = max(1, round(image.shape[0] / 160))
    for part, ids in PARTS.items():
        for k in ids:
            if sc[k] >= min_score and np.all(np.isfinite(xy[k])):
                cv2.circle(out, (int(round(xy[k, 0])), int(round(xy[k, 1]))), r,
                           PART_COLOURS[part], -1, lineType=cv2.LINE_AA)
    return out


def write_overlays(frames_path: str | os.PathLike, masks_path: str | os.PathLike,
                   keypoints_path: str | os.PathLike, out_dir: str | os.PathLike,
                   count: int = 4, min_score: float = 0.5) -> list[Path]:
    """``count`` evenly spaced frames of view 0 as overlays ``out_dir/{frame:04d}.png``."""
    from signsplat.io.images import read_mask, read_rgb, write_png

    frames_path, out_dir = Path(frames_path), Path(out_dir)
    frames = read_table(frames_path, "frames")
    masks = read_table(masks_path, "masks")
    kp = read_table(keypoints_path, "keypoints")
    fv = frames[frames["view"] == frames["view"].min()].sort_values("frame")
    pick = fv.iloc[np.unique(np.linspace(0, len(fv) - 1, count).round().astype(int))]
    written = []
    for _, r in pick.iterrows():
        f = int(r["frame"])
        img = read_rgb(frames_path.parent / r["image"])
        mrow = masks[(masks["view"] == r["view"]) & (masks["frame"] == f)]
        mask = read_mask(Path(masks_path).parent / mrow["mask"].iloc[0]) if len(mrow) \
            else np.zeros(img.shape[:2], bool)
        xy, sc = keypoint_arrays(kp[kp["view"] == r["view"]], fv[fv["frame"] == f])
        path = out_dir / f"{f:04d}.png"
        write_png(path, overlay(img, mask, xy[0], sc[0], min_score))
        written.append(path)
    return written
