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

PERSONS_TABLE = register_table(Table(
    "persons",
    "People the pretrained person detector found per frame, and which one was taken as the "
    "signer (signsplat.perception.pretrained.select); no rows with the shipped detectors.",
    {
        "scene": "str sequence name",
        "view": "int32 camera index",
        "frame": "int32 frame index",
        "person": "int16 index in the frame: the detections at pretrained.keypoints."
                  "min_detection_score (best score first), then the signer where only the pose "
                  "model's tracking found them, then the neighbours scored from "
                  "perception.signer.others_min_score (cut out of the signer's mask)",
        "score": "float32 detector score in [0, 1]; NaN for a signer only tracking found",
        "hip_x": "float32 mid-hip point x in pixels (the body region's centre)",
        "hip_y": "float32 mid-hip point y in pixels",
        "scale_x": "float32 full-body size/rotation point x in pixels",
        "scale_y": "float32 full-body size/rotation point y in pixels",
        "head_x0": "float32 head box left edge in pixels",
        "head_y0": "float32 head box top edge in pixels",
        "head_x1": "float32 head box right edge in pixels",
        "head_y1": "float32 head box bottom edge in pixels",
        "appearance": "float32 Bhattacharyya distance of this person's colours above the hips "
                      "to the signer's kept from earlier frames (0 same, 1 disjoint); NaN "
                      "where not measured (no earlier colours, no pose found, or the check "
                      "off)",
        "chosen": "bool this person is the signer (the mask and keypoints are theirs)",
        "chosen_by": "str how: 'tracked' (the pose model's region or the head box of the last "
                     "frame's signer), 'appearance' (another person matched the signer's "
                     "colours better) or the rule (largest | central | box); empty when not "
                     "chosen",
    },
    metadata={"rule": "the signer rule as JSON (rule, box, track_iou, margin, patience, "
                      "appearance_margin, appearance_max, others_min_score)"},
))

EVAL_TABLE = register_table(Table(
    "perception_eval",
    "Perception accuracy and speed of one scene against ground truth (one row per metric).",
    {
        "scene": "str sequence name",
        "metric": "str mask_iou | mask_area_bias | pck@0.05 | mean_px_error | fps | stage_fps",
        "part": "str all | body | feet | face | left_hand | right_hand | segment | keypoints "
                "| total",
        "value": "float64 the metric (IoU and PCK in [0, 1], area bias as a fraction of the true "
                 "area, error in pixels, frames/s)",
        "count": "int64 frames or keypoints the value is computed over",
    },
))
