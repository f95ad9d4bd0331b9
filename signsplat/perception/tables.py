"""Tables of the perception stages (registered with :func:`signsplat.io.tables.register_table`)."""

from __future__ import annotations

from signsplat.io.tables import Table, register_table

MASKS_TABLE = register_table(Table(
    "masks",
    "Predicted person masks: one row per view and frame (the PNG holds the mask itself).",
    {
        "scene": "str sequence name",
        "view": "int32 camera index",
        "frame": "int32 frame index",
        "mask": "str path of the 0/255 mask PNG, relative to the table's folder",
        "area": "int64 foreground pixels",
        "x0": "float32 box left edge in pixels (first foreground column; NaN when empty)",
        "y0": "float32 box top edge in pixels (first foreground row; NaN when empty)",
        "x1": "float32 box right edge in pixels (one past the last column; NaN when empty)",
        "y1": "float32 box bottom edge in pixels (one past the last row; NaN when empty)",
        "confidence": "float32 mean alpha over the mask's pixels in [0, 1] (0 when empty)",
    },
    metadata={"model": "path of the segmentation ONNX file"},
))

EVAL_TABLE = register_table(Table(
    "perception_eval",
    "Perception accuracy and speed of one scene against ground truth (one row per metric).",
    {
        "scene": "str sequence name",
        "metric": "str mask_iou | pck@0.05 | mean_px_error | fps | stage_fps",
        "part": "str all | body | feet | face | left_hand | right_hand | segment | keypoints "
                "| total",
        "value": "float64 the metric (IoU and PCK in [0, 1], error in pixels, frames/s)",
        "count": "int64 frames or keypoints the value is computed over",
    },
))
