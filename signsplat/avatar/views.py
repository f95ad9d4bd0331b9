"""Whole-image scores per camera (``views.parquet``), and the cameras far below the others.

Pandas only (no torch), so the report can read and judge the table without loading a model.
"""

from __future__ import annotations

import pandas as pd

from signsplat.io.tables import Table, register_table

VIEW_METRICS = register_table(Table(
    "avatar_view_metrics",
    "Avatar whole-image scores per camera (protocol bg_replaced, part full), one row per "
    "(split, refine, view): a camera that scores far below the others shows here, not in the "
    "averages of avatar_metrics.",
    {
        "scene": "str sequence name",
        "variant": "str avatar variant (config name)",
        "split": "str novel_pose | novel_view | novel_pose_view | train",
        "refine": "bool test-time pose refinement on",
        "view": "int64 camera (the view column of the scene's tables)",
        "psnr": "float64 dB, mean over the view's images in the split",
        "ssim": "float64 mean over the view's images in the split",
        "n_images": "int64 images averaged",
        "below_median_db": "float64 median PSNR of the split's views minus this view's",
    },
))

#: a camera this many dB below the median of its split's cameras is named as weak
WEAK_VIEW_DB = 3.0

_COLUMNS = list(VIEW_METRICS.columns)


def per_view(per_image: pd.DataFrame, scene: str, variant: str) -> pd.DataFrame:
    """``avatar_view_metrics`` rows from per-image scores (columns split, refine, frame, view,
    protocol, part, metric, value: what ``Evaluator.run`` returns)."""
    if per_image.empty:
        return pd.DataFrame({c: [] for c in _COLUMNS})
    d = per_image[(per_image["protocol"] == "bg_replaced") & (per_image["part"] == "full")]
    wide = d.pivot_table(index=["split", "refine", "view", "frame"], columns="metric",
                         values="value").reset_index()
    out = wide.groupby(["split", "refine", "view"], sort=True).agg(
        psnr=("psnr", "mean"), ssim=("ssim", "mean"), n_images=("psnr", "size")).reset_index()
    median = out.groupby(["split", "refine"])["psnr"].transform("median")
    out["below_median_db"] = median - out["psnr"]
    out = out.astype({"n_images": "int64", "view": "int64", "refine": bool})
    out.insert(0, "variant", variant)
    out.insert(0, "scene", scene)
    return out[_COLUMNS]


def weak_views(views: pd.DataFrame, threshold_db: float = WEAK_VIEW_DB) -> pd.DataFrame:
    """Rows of cameras more than ``threshold_db`` below the median of their split's cameras,
    in splits with at least three cameras (with two, the median says nothing)."""
    if not len(views):
        return views
    cams = views.groupby(["split", "refine"])["view"].transform("size")
    return views[(cams >= 3) & (views["below_median_db"] > threshold_db)]
