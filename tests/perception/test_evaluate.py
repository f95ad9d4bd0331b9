"""Metric definitions of perception_eval."""

from __future__ import annotations

import numpy as np

from signsplat.perception.evaluate import keypoint_errors, mask_area_bias, mask_iou


def test_mask_iou():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert mask_iou(a, b) == 1.0
    a[:2] = True
    b[1:3] = True
    assert mask_iou(a, b) == 4 / 12


def _areas(masks):
    return [int(m.sum()) for m in masks]


def test_mask_area_bias_is_pooled_and_signed():
    gt = np.zeros((10, 10), bool)
    gt[3:7, 3:7] = True                   # 16 px
    grown = np.zeros_like(gt)
    grown[2:8, 2:8] = True                # 36 px: the outline one pixel further out
    shrunk = np.zeros_like(gt)
    shrunk[4:6, 4:6] = True               # 4 px
    full = np.ones_like(gt)               # 100 px
    assert mask_area_bias(_areas([grown]), _areas([gt])) == 20 / 16
    assert mask_area_bias(_areas([shrunk]), _areas([gt])) == -12 / 16
    # pooled over the frames, not a mean of the frames' ratios (which would be 0.625)
    assert mask_area_bias(_areas([grown, full]), _areas([gt, full])) == 20 / 116
    assert np.isnan(mask_area_bias([5], [0]))


def test_pck_and_pixel_error_per_part():
    gt = np.zeros((2, 133, 2))
    pred = gt.copy()
    pred[:, 0:17, 0] = 4.0      # body: 4 px off
    pred[0, 91:112, 0] = 6.0    # left hand frame 0: 6 px off
    pred[1, 91:112] = np.nan    # left hand frame 1: missing
    vis = np.ones((2, 133), bool)
    vis[:, 112:133] = False     # right hand invisible: no figures
    size = np.array([100.0, 100.0])  # threshold 5 px
    res = keypoint_errors(pred, gt, vis, size, 0.05)
    assert res["body"]["pck"] == 1.0 and np.isclose(res["body"]["err"], 4.0)
    assert res["left_hand"]["pck"] == 0.0 and res["left_hand"]["n"] == 42
    assert res["left_hand"]["n_err"] == 21 and np.isclose(res["left_hand"]["err"], 6.0)
    assert res["face"]["pck"] == 1.0
    assert np.isnan(res["right_hand"]["pck"]) and res["right_hand"]["n"] == 0
