"""MediaPipe's geometry (crops of rotated regions, their projection back, ROIs from points,
SSD decoding) and the mapping of its landmarks to COCO-WholeBody 133. No model needed."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from signsplat.body.joints import (COCO_WHOLEBODY_NAMES, KP_FACE, KP_FEET, KP_LEFT_HAND,
                                   KP_RIGHT_HAND)
from signsplat.perception.pretrained import mediapipe as mp
from signsplat.perception.pretrained.wholebody import (BLAZEPOSE_NAMES, FACE68_FROM_MESH,
                                                       HandResult, WholeBodyResult,
                                                       left_hand_prob, mirror_sides,
                                                       to_coco_wholebody)


def _mediapipe_crop(image, roi: mp.Roi, size: int) -> np.ndarray:
    """MediaPipe's own CPU recipe: the rotated rectangle's corners (OpenCV boxPoints, angle in
    degrees) mapped onto the tensor's corners by a perspective warp."""
    rect = ((roi.cx, roi.cy), (roi.w, roi.h), np.degrees(roi.rotation))
    src = cv2.boxPoints(rect).astype(np.float32)
    dst = np.array([[0, size], [0, 0], [size, 0], [size, size]], np.float32)
    m = cv2.getPerspectiveTransform(src, dst)
    return cv2.warpPerspective(image, m, (size, size), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REPLICATE)


@pytest.mark.parametrize("rotation", [0.0, 0.4, -1.2, 2.9])
def test_crop_matches_mediapipes_rotated_rect_recipe(rotation):
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.integers(0, 256, (180, 240, 3), dtype=np.uint8), (7, 7), 2)
    roi = mp.Roi(130.0, 85.0, 90.0, 90.0, rotation)
    ours = mp.crop(image, roi, (64, 64), (0.0, 255.0))[0].transpose(1, 2, 0)
    theirs = _mediapipe_crop(image, roi, 64).astype(np.float32)
    assert np.abs(ours - theirs).max() <= 1.01  # uint8 rounding of the two warps


def test_projection_round_trip_and_corners():
    roi = mp.Roi(50.0, -20.0, 80.0, 40.0, 0.7)
    pts = np.random.default_rng(1).uniform(0, 128, (10, 2))
    back = mp.image_to_crop(mp.crop_to_image(pts, roi, (128, 64)), roi, (128, 64))
    np.testing.assert_allclose(back, pts, atol=1e-9)
    c = roi.corners()
    np.testing.assert_allclose(c.mean(0), [50.0, -20.0])
    np.testing.assert_allclose(np.linalg.norm(c[1] - c[0]), 80.0)  # top edge: the width
    np.testing.assert_allclose(np.linalg.norm(c[3] - c[0]), 40.0)
    # rotation turns the crop's +x axis by the angle in image coordinates (y down)
    d = c[1] - c[0]
    np.testing.assert_allclose(np.arctan2(d[1], d[0]), 0.7)


def test_alignment_roi_is_upright_for_a_standing_body():
    hip, head_side = np.array([100.0, 200.0]), np.array([100.0, 120.0])  # scale point above
    roi = mp.alignment_roi(hip, head_side, np.pi / 2)
    assert roi.rotation == pytest.approx(0.0)
    assert (roi.cx, roi.cy, roi.w, roi.h) == pytest.approx((100.0, 200.0, 160.0, 160.0))
    lying = mp.alignment_roi(hip, hip + [80.0, 0.0], np.pi / 2)  # scale point to the right
    assert lying.rotation == pytest.approx(np.pi / 2)
    # the crop's "up" (-v) points from the hip to the scale point
    up = mp.crop_to_image(np.array([[0.5, 0.0]]), lying, (1, 1))[0] - [lying.cx, lying.cy]
    assert up[0] > 0 and abs(up[1]) < 1e-9


def test_transform_roi_shifts_along_its_own_axes_then_squares_and_scales():
    roi = mp.Roi(0.0, 0.0, 40.0, 20.0, np.pi / 2)
    out = mp.transform_roi(roi, 2.0, 2.0, shift_y=-0.1)
    # shift_y -0.1 of the height (20) along the crop's y axis, which points to image -x here
    assert (out.cx, out.cy) == pytest.approx((2.0, 0.0))
    assert (out.w, out.h, out.rotation) == pytest.approx((80.0, 80.0, np.pi / 2))


def test_pad_roi_letterboxes_a_wide_frame():
    roi, pad = mp.pad_roi(mp.Roi(540.0, 360.0, 1080.0, 720.0), (224, 224))
    assert (roi.w, roi.h) == (1080.0, 1080.0)
    assert pad == pytest.approx((0.0, 1 / 6))


def test_hand_roi_follows_the_hand_rotation():
    rng = np.random.default_rng(2)
    # a hand pointing up: wrist at the bottom, knuckles above it
    hand = np.zeros((21, 2))
    hand[:, 0] = rng.uniform(-30, 30, 21)
    hand[:, 1] = -rng.uniform(10, 90, 21)
    hand[0] = [0.0, 0.0]
    hand[[5, 9, 13]] = [[-15.0, -60.0], [0.0, -62.0], [15.0, -60.0]]
    for angle in (0.0, 0.8, -2.0):
        r = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        pts = hand @ r.T + [200.0, 150.0]
        roi = mp.hand_landmarks_roi(pts)
        assert mp.normalize_radians(roi.rotation - angle) == pytest.approx(0.0, abs=1e-9)
        inside = mp.image_to_crop(pts[list(mp.HAND_ROI_POINTS)], roi, (1, 1))
        assert np.all((inside >= -1e-9) & (inside <= 1 + 1e-9))


def test_ssd_anchor_grids():
    pose = mp.ssd_anchors(224, (8, 16, 32, 32, 32))
    face = mp.ssd_anchors(128, (8, 16, 16, 16))
    assert pose.shape == (2254, 2) and face.shape == (896, 2)
    np.testing.assert_allclose(pose[0], [0.5 / 28, 0.5 / 28])
    np.testing.assert_allclose(pose[1], pose[0])  # two anchors per cell on the first layer
    np.testing.assert_allclose(pose[-1], [6.5 / 7, 6.5 / 7])  # six per cell on the last grid


def test_decode_and_weighted_nms():
    anchors = np.array([[0.25, 0.25], [0.26, 0.25], [0.75, 0.75]])
    raw = np.zeros((3, 6))
    raw[:, 2:4] = 20.0  # 20 x 20 pixel boxes at the anchors of a 100-pixel input
    raw[:, 4:6] = [[1.0, 2.0], [3.0, 2.0], [0.0, 0.0]]  # one keypoint
    scores = np.array([2.0, 0.0, 1.0])  # logits: 0.88, 0.5, 0.73
    det = mp.decode_detections(raw, scores, anchors, 100, 1, min_score=0.5)
    assert len(det) == 3
    out = mp.weighted_nms(det, 0.3)
    assert len(out) == 2
    w = np.array([1 / (1 + np.exp(-2.0)), 0.5])
    x_kp = (w[0] * (25.0 + 1.0) + w[1] * (26.0 + 3.0)) / w.sum()
    assert out.keypoints[0, 0, 0] == pytest.approx(x_kp)
    assert out.scores[0] == pytest.approx(w[0])
    assert out.keypoints[1, 0] == pytest.approx([75.0, 75.0])


def test_heatmap_refinement_moves_to_the_blob_and_keeps_weak_points():
    hm = np.full((2, 64, 64), -10.0)
    yy, xx = np.mgrid[:64, :64]
    hm[0] = 12.0 * np.exp(-((xx - 20.0) ** 2 + (yy - 30.0) ** 2) / 4.0) - 6.0
    pts = np.array([[22.0 * 4, 29.0 * 4], [10.0, 10.0]])  # 256-pixel input, 4 pixels per cell
    out = mp.refine_from_heatmap(pts, hm, (256, 256))
    assert out[0] == pytest.approx([20.0 * 4, 30.0 * 4], abs=1.0)
    assert np.all(out[1] == pts[1])  # peak probability below 0.5: unchanged


def _fake_result():
    pose = np.stack([np.arange(33.0), np.zeros(33)], 1)  # x = BlazePose index
    vis = np.full(33, 0.9)
    hands = {s: HandResult(np.stack([np.arange(21.0) + off, np.ones(21)], 1), 0.8, 0.5)
             for s, off in (("left", 100.0), ("right", 200.0))}
    face = np.stack([np.arange(468.0), np.full(468, 2.0)], 1)
    return WholeBodyResult(pose, vis, hands, face, 0.7)


def test_mapping_to_coco_wholebody_133():
    xy, sc = to_coco_wholebody(_fake_result())
    names = COCO_WHOLEBODY_NAMES
    for k in range(17):  # body: the BlazePose point of the same name
        assert BLAZEPOSE_NAMES[int(xy[k, 0])] == names[k]
    feet = dict(zip([names[k] for k in KP_FEET], xy[list(KP_FEET), 0]))
    assert BLAZEPOSE_NAMES[int(feet["left_big_toe"])] == "left_foot_index"
    assert BLAZEPOSE_NAMES[int(feet["right_heel"])] == "right_heel"
    for toe in ("left_small_toe", "right_small_toe"):
        k = names.index(toe)
        assert sc[k] == 0 and np.isnan(xy[k]).all()
    # hands keep MediaPipe's order, which is COCO-WholeBody's: wrist, thumb .. pinky tips
    np.testing.assert_array_equal(xy[list(KP_LEFT_HAND), 0], np.arange(21) + 100.0)
    np.testing.assert_array_equal(xy[list(KP_RIGHT_HAND), 0], np.arange(21) + 200.0)
    assert np.all(sc[list(KP_LEFT_HAND)] == np.float32(0.8))
    np.testing.assert_array_equal(xy[list(KP_FACE), 0], np.array(FACE68_FROM_MESH, float))
    assert np.all(sc[list(KP_FACE)] == np.float32(0.7))
    xy0, sc0 = to_coco_wholebody(None)
    assert np.all(sc0 == 0) and np.isnan(xy0).all()


def test_face_table_is_68_distinct_mesh_vertices():
    assert len(FACE68_FROM_MESH) == 68 == len(set(FACE68_FROM_MESH))
    assert all(0 <= v < 468 for v in FACE68_FROM_MESH)


def test_missing_parts_and_min_score_give_zero_and_nan():
    r = _fake_result()
    r.hands["left"], r.face = None, None
    r.pose_visibility[0] = 0.05
    xy, sc = to_coco_wholebody(r, min_score=0.1)
    assert np.all(sc[list(KP_LEFT_HAND)] == 0) and np.isnan(xy[list(KP_LEFT_HAND)]).all()
    assert np.all(sc[list(KP_FACE)] == 0)
    assert sc[0] == 0 and np.isnan(xy[0]).all()
    assert np.all(sc[list(KP_RIGHT_HAND)] > 0)


def test_handedness_convention_and_mirroring():
    # MediaPipe's "Left" assumes a mirrored image: it means "looks like a right hand here"
    assert left_hand_prob(0.9) == pytest.approx(0.1)
    r = _fake_result()
    r.hands["left"].left_prob = 0.95
    m = mirror_sides(r, 640)
    # flipped: the old left hand is the figure's right, mirrored, and looks like a right hand
    np.testing.assert_allclose(m.hands["right"].points[:, 0], 640 - (np.arange(21) + 100.0))
    assert m.hands["right"].left_prob == pytest.approx(0.05)
    i, j = BLAZEPOSE_NAMES.index("left_wrist"), BLAZEPOSE_NAMES.index("right_wrist")
    assert m.pose[i, 0] == 640 - j
    back = mirror_sides(m, 640)
    np.testing.assert_allclose(back.pose, r.pose)
    assert back.hands["left"].left_prob == pytest.approx(0.95)


def test_a_tracked_hand_is_kept_near_the_pose_wrist_or_when_the_wrist_is_unsure():
    from signsplat.perception.pretrained.keypointer import tracked_hand_kept

    wrist, elbow = np.array([100.0, 100.0]), np.array([100.0, 60.0])  # forearm 40 px
    kept = [tracked_hand_kept(wrist + [dx, 0.0], wrist, elbow, 0.9, 0.25, 0.5)
            for dx in (0.0, 9.9, 10.1, 80.0)]
    assert kept == [True, True, False, False]
    # an unsure wrist (fast motion) cannot tell: kept wherever it is
    assert tracked_hand_kept(wrist + [80.0, 0.0], wrist, elbow, 0.3, 0.25, 0.5)
    assert not tracked_hand_kept(np.array([np.nan, 1.0]), wrist, elbow, 0.9, 0.25, 0.5)
