"""Metric definitions of perception_eval."""

from __future__ import annotations

import numpy as np

from signsplat.perception.evaluate import keypoint_errors, mask_iou


def test_mask_iou():
    a = np.zeros((4, 4), bool)
    b = np.zeros((4, 4), bool)
    assert mask_iou(a, b) == 1.0
    a[:2] = True
    b[1:3] = True
    assert mask_iou(a, b) == 4 / 12


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
