"""Top-down crop geometry and SimCC decoding (rtmlib/MMPose conventions)."""

from __future__ import annotations

import cv2
import numpy as np

from signsplat.perception.keypoints import (box_from_mask, box_to_center_scale, crop_matrix,
                                            crop_to_image, decode_simcc, fix_aspect_ratio,
                                            scores_to_unit)


def _three_point_matrix(center, scale, out_wh):
    """The crop affine built from three point pairs (centre, top-centre, a 90-degree point)."""
    w, h = out_wh
    src = np.float32([center, center + [0, -scale[0] / 2], center + [-scale[0] / 2, 0]])
    dst = np.float32([[w / 2, h / 2], [w / 2, h / 2 - w / 2], [0, h / 2]])
    return cv2.getAffineTransform(src, dst)


def test_box_from_mask_edges_and_empty():
    m = np.zeros((10, 12), bool)
    assert box_from_mask(m) is None
    m[2:5, 3:9] = True
    np.testing.assert_array_equal(box_from_mask(m), [3, 2, 9, 5])


def test_center_scale_aspect_and_matrix_match_three_point_construction():
    box = np.array([30.0, 10.0, 90.0, 200.0])
    c, s = box_to_center_scale(box, 1.25)
    np.testing.assert_allclose(c, [60, 105])
    np.testing.assert_allclose(s, [75, 237.5])
    s2 = fix_aspect_ratio(s, 288 / 384)
    np.testing.assert_allclose(s2, [237.5 * 0.75, 237.5])  # tall box: height wins
    np.testing.assert_allclose(fix_aspect_ratio(np.array([300.0, 100.0]), 0.75), [300, 400])
    m = crop_matrix(c, s2, (384, 288))
    np.testing.assert_allclose(m, _three_point_matrix(c, s2, (288, 384)), atol=1e-3)


def test_decode_takes_argmax_split_ratio_and_min_of_maxima():
    sx = np.zeros((1, 3, 20), np.float32)
    sy = np.zeros((1, 3, 30), np.float32)
    sx[0, 0, 7], sy[0, 0, 11] = 0.9, 0.6
    sx[0, 1, 3], sy[0, 1, 4] = 0.4, 0.8
    sx[0, 2] -= 1.0  # all negative: no location
    sy[0, 2] -= 1.0
    locs, vals = decode_simcc(sx, sy, 2.0)
    np.testing.assert_allclose(locs[0, 0], [3.5, 5.5])
    np.testing.assert_allclose(locs[0, 1], [1.5, 2.0])
    np.testing.assert_allclose(vals[0, :2], [0.6, 0.4])
    assert np.all(np.isnan(locs[0, 2]))
    np.testing.assert_allclose(scores_to_unit(np.array([-0.5, 0.3, 1.7, np.nan])),
                               [0, 0.3, 1, 0])


def _roundtrip(points, box, hw=(384, 288), r=2.0):
    """Encode image points as one-hot SimCC in the crop, decode, map back to the image."""
    c, s = box_to_center_scale(box, 1.25)
    s = fix_aspect_ratio(s, hw[1] / hw[0])
    m = crop_matrix(c, s, hw)
    crop = points @ m[:, :2].T + m[:, 2]
    k = len(points)
    sx = np.zeros((1, k, int(hw[1] * r)), np.float32)
    sy = np.zeros((1, k, int(hw[0] * r)), np.float32)
    sx[0, np.arange(k), np.round(crop[:, 0] * r).astype(int)] = 1
    sy[0, np.arange(k), np.round(crop[:, 1] * r).astype(int)] = 1
    locs, _ = decode_simcc(sx, sy, r)
    return crop_to_image(locs, c[None], s[None], hw)[0], s


def test_roundtrip_image_crop_simcc_image():
    pts = np.array([[100.0, 50.0], [60.0, 190.0], [35.0, 12.0]])
    back, s = _roundtrip(pts, np.array([30.0, 10.0, 90.0, 200.0]))
    tol = 0.5 / 2 * s[0] / 288 + 1e-6  # half a bin, in image pixels
    np.testing.assert_allclose(back, pts, atol=tol)


def test_hand_outside_the_image_decodes_to_negative_coordinates():
    # person box touching the left edge; a hand 12 px left of the image
    pts = np.array([[-12.0, 80.0], [5.0, 60.0]])
    back, _ = _roundtrip(pts, np.array([0.0, 20.0, 60.0, 180.0]))
    assert back[0, 0] < 0 and np.all(np.isfinite(back))
    np.testing.assert_allclose(back, pts, atol=0.5)
