"""One signer in a crowded frame: the rules (largest, central, box), keeping the choice over
time (head-box tracking, patience), the sheet's signer column, and cutting the mask to the
signer. No model needed."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from signsplat.config import validate
from signsplat.perception.detectors import perception_for
from signsplat.perception.pretrained import mediapipe as mp
from signsplat.perception.pretrained.select import (HEAD, SignerRule, SignerSelector,
                                                    body_boxes, confused_pose, parse_signer,
                                                    person_mask, skeleton_distance)
from signsplat.perception.pretrained.wholebody import BLAZEPOSE_NAMES

CFG = validate({}, "stages/perception.schema.yaml")
FRAME = (400, 200)


def det(*people):
    """Detections of people given as (hip_x, hip_y, half body size, head_x); best first."""
    boxes, kps = [], []
    for hx, hy, half, head_x in people:
        boxes.append([head_x - 10, 20, head_x + 10, 40])
        kps.append([[hx, hy], [hx, hy - half], [hx, hy - half / 2], [hx, hy - half]])
    return mp.Detections(np.array(boxes, float), np.array(kps, float),
                         np.linspace(0.9, 0.6, len(people)))


def rule(name="largest", box=None, patience=2):
    return SignerRule.from_config({**CFG["signer"], "rule": name, "box": box,
                                   "patience": patience})


def test_rules_pick_largest_central_and_boxed():
    people = det((60, 150, 60, 60), (210, 150, 40, 210), (330, 150, 90, 330))
    assert SignerSelector(rule("largest")).choose(people, FRAME) == (2, "largest")
    assert SignerSelector(rule("central")).choose(people, FRAME) == (1, "central")
    boxed = SignerSelector(rule("box", (0, 0, 120, 200)))
    assert boxed.choose(people, FRAME) == (0, "box")
    nobody = SignerSelector(rule("box", (390, 0, 10, 10)))
    assert nobody.choose(det((60, 150, 60, 60)), FRAME) == (None, "")
    b = body_boxes(people)
    np.testing.assert_allclose(b[2], [240, 60, 420, 240])


def test_choice_is_kept_while_the_head_is_tracked():
    sel = SignerSelector(rule("largest"))
    assert sel.choose(det((100, 150, 50, 100), (300, 150, 40, 300)), FRAME)[0] == 0
    # the other person grows larger and the detector lists them first: still the same signer
    assert sel.choose(det((300, 150, 90, 302), (102, 150, 50, 103)), FRAME) == (1, "tracked")


def test_patience_waits_for_a_lost_signer_then_rechooses():
    sel = SignerSelector(rule("largest", patience=2))
    sel.choose(det((100, 150, 50, 100), (300, 150, 40, 300)), FRAME)
    other_only = det((300, 150, 40, 300))
    assert sel.choose(other_only, FRAME) == (None, "")  # signer missed: no signer
    assert sel.choose(det((101, 150, 50, 101), (300, 150, 40, 300)), FRAME) == (0, "tracked")
    for _ in range(2):
        assert sel.choose(other_only, FRAME) == (None, "")
    assert sel.choose(other_only, FRAME) == (0, "largest")  # patience used up


def test_sheet_signer_column():
    assert parse_signer("central") == {"rule": "central", "box": None}
    assert parse_signer("10,20,30.5,40") == {"rule": "box", "box": [10.0, 20.0, 30.5, 40.0]}
    for bad in ("biggest", "1,2,3", "1,2,0,4"):
        with pytest.raises(ValueError, match="largest.*central.*x,y,w,h"):
            parse_signer(bad)
    row = {"sequence": "c", "source": "video", "signer": "5,6,7,8"}
    cfg = perception_for(row, CFG)
    assert cfg["signer"]["rule"] == "box" and cfg["signer"]["box"] == [5.0, 6.0, 7.0, 8.0]
    assert CFG["signer"]["rule"] == "largest"  # the shared section is left as it was
    plain = perception_for({"sequence": "c", "source": "video"}, CFG)
    assert plain["signer"] is CFG["signer"]  # no signer column: the config's rule
    assert SignerRule.from_config(cfg["signer"]).box == (5.0, 6.0, 7.0, 8.0)
    with pytest.raises(ValueError, match="needs a box"):
        SignerRule.from_config({**CFG["signer"], "rule": "box", "box": None})


def test_mask_is_cut_to_the_signer():
    h, w = 60, 100
    _, xx = np.mgrid[:h, :w]
    signer = np.where(np.abs(xx - 30) < 15, 0.9, 0.05).astype(np.float32)  # columns 16-44
    other = np.where(np.abs(xx - 55) < 15, 0.95, 0.05).astype(np.float32)  # columns 41-69
    region = person_mask(signer, [other], body_size=100.0, margin=0.03)
    assert region[:, 13:41].all()  # the signer grown by 3 px on the free side ...
    assert not region[:, :13].any()
    assert not region[:, 41:].any()  # ... and not where the other one is more likely


def _pose(x: float, arm_visible: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """BlazePose landmarks (39, 2) and visibility of an upright person centred on column x
    (shoulders at row 20, hips at 50, ears at 8) whose left arm hangs out to x + 14."""
    pts = np.full((39, 2), np.nan)
    vis = np.ones(39)
    for name, (dx, y) in {"nose": (0, 10), "left_ear": (4, 8), "right_ear": (-4, 8),
                          "left_shoulder": (8, 20), "right_shoulder": (-8, 20),
                          "left_hip": (6, 50), "right_hip": (-6, 50),
                          "left_elbow": (12, 35), "left_wrist": (14, 48)}.items():
        pts[BLAZEPOSE_NAMES.index(name)] = (x + dx, y)
    if not arm_visible:
        vis[[BLAZEPOSE_NAMES.index("left_elbow"), BLAZEPOSE_NAMES.index("left_wrist")]] = 0.1
    return pts, vis


def test_pixels_both_claim_go_to_the_nearer_skeleton():
    """Two people the segmentation claims with certainty, overlapping in columns 36-44 (as the
    pose model segments everyone in its crop): the columns nearer the other's skeleton leave
    the signer's mask. With probabilities alone the tie keeps them all."""
    h, w = 60, 100
    _, xx = np.mgrid[:h, :w]
    signer = np.where(np.abs(xx - 28) <= 16, 1.0, 0.0).astype(np.float32)  # columns 12-44
    other = np.where(np.abs(xx - 52) <= 16, 1.0, 0.0).astype(np.float32)  # columns 36-68
    bones = [skeleton_distance(*_pose(x, arm_visible=False), (h, w)) for x in (28, 52)]
    region = person_mask(signer, [other], 100.0, 0.0, bones[0], [bones[1]])
    assert region[25, 12:36].all()  # the signer's own columns
    assert not region[25, 42:].any()  # nearer the other's torso (x 44-60) than the signer's
    assert region[25, 36:41].all()  # the shared columns up to half way between the two
    assert person_mask(signer, [other], 100.0, 0.0)[25, 12:45].all()  # the tie: all kept
    # the signer's visible arm (x 40-42 at rows 35-48) reaches into the other's columns: kept
    arm = skeleton_distance(*_pose(28), (h, w))
    with_arm = person_mask(signer, [other], 100.0, 0.0, arm, [bones[1]])
    assert with_arm[40, 40:43].all() and not region[40, 40:43].all()


def test_a_pose_with_its_head_on_the_signer_is_confused():
    """Another pose whose head lies on the signer's head or torso bones (within the reach) has
    taken the signer for part of itself; a neighbour whose shoulder touches the signer's has
    not. The mask then leaves the confused one's bones out: the tie keeps the signer."""
    h, w = 60, 100
    signer_pts, signer_vis = _pose(28, arm_visible=False)
    core = skeleton_distance(signer_pts, signer_vis, (h, w), limbs=False)
    beside, _ = _pose(52)  # shoulders 8 px from the signer's, head 24 px away
    assert not confused_pose(beside, core, reach=6.0)
    onto = beside.copy()
    onto[list(HEAD)] -= (20, 0)  # the head drawn on the signer's shoulder line
    assert confused_pose(onto, core, reach=6.0)
    assert not confused_pose(np.full((39, 2), np.nan), core, reach=6.0)
    ones = np.ones((h, w), np.float32)
    region = person_mask(ones, [ones], 100.0, 0.0,
                         skeleton_distance(signer_pts, signer_vis, (h, w)), [None])
    assert region.all()


def test_skeleton_distance_without_usable_bones_is_infinite():
    pts, vis = _pose(30)
    assert np.isfinite(skeleton_distance(pts, vis, (60, 100))).all()
    assert np.isinf(skeleton_distance(np.full((39, 2), np.nan), vis, (60, 100))).all()
    far = skeleton_distance(pts + 1e9, vis, (60, 100))  # every bone far outside the frame
    assert np.isinf(far).all()


def _person(colour_top, colour_legs, shape=(120, 80)) -> tuple[np.ndarray, np.ndarray]:
    """An HSV image (OpenCV's, from RGB) and the person's region: a body of one RGB colour
    above row 60 and another below it, on grey."""
    image = np.full((*shape, 3), 128, np.uint8)
    region = np.zeros(shape, bool)
    region[10:110, 20:60] = True
    image[10:60, 20:60] = colour_top
    image[60:110, 20:60] = colour_legs
    return cv2.cvtColor(image, cv2.COLOR_RGB2HSV), region


def test_appearance_tells_people_apart_by_their_clothes_above_the_hips():
    from signsplat.perception.pretrained.select import appearance, appearance_distance

    navy, black, white, jeans = (25, 35, 80), (15, 15, 15), (240, 240, 240), (40, 60, 110)
    suit = appearance(*_person(navy, jeans), hip_y=60)
    assert suit is not None and suit.dtype == np.float32 and abs(float(suit.sum()) - 1) < 1e-5
    # the same clothes on top, other legs: the same person's colours
    assert appearance_distance(suit, appearance(*_person(navy, white), hip_y=60)) < 1e-3
    # another shirt, the same legs: another person
    assert appearance_distance(suit, appearance(*_person(black, jeans), hip_y=60)) > 0.9
    # half navy, half white on top: in between
    image, region = _person(navy, jeans)
    image[10:60, 40:60] = cv2.cvtColor(np.array([[white]], np.uint8), cv2.COLOR_RGB2HSV)[0, 0]
    half = appearance_distance(suit, appearance(image, region, hip_y=60))
    assert 0.2 < half < 0.9
    # too little of them above the hips (or a hip above the frame): nothing to compare
    image, region = _person(navy, jeans)
    assert appearance(image, region, hip_y=11) is None
    assert appearance(image, region, hip_y=-5) is None
    assert appearance(image, region, hip_y=float("nan")) is None  # a pose without hips


def test_appearance_switch_needs_a_clearly_better_match():
    from signsplat.perception.pretrained.select import appearance_switch

    assert appearance_switch(0.1, [0.7, 0.6], 0.2, 0.5) is None  # the signer matches best
    assert appearance_switch(0.7, [0.6, 0.2], 0.2, 0.5) == 1  # the second other is the signer
    assert appearance_switch(0.35, [0.2], 0.2, 0.5) is None  # better, but not by the margin
    assert appearance_switch(0.9, [0.6], 0.2, 0.5) is None  # nobody looks like the signer
    assert appearance_switch(0.7, [np.nan, 0.3], 0.2, 0.5) == 1  # unmeasured others skipped
    assert appearance_switch(np.nan, [0.1], 0.2, 0.5) is None  # nothing against the chosen
    assert appearance_switch(0.7, [], 0.2, 0.5) is None
    assert appearance_switch(0.7, [np.nan], 0.2, 0.5) is None


def test_a_pose_nearer_another_person_is_not_the_signers():
    from signsplat.perception.pretrained.keypointer import pose_is_signers

    signer, others = (100.0, 200.0), np.array([[160.0, 200.0], [40.0, 210.0]])
    assert pose_is_signers((110, 195), signer, others)
    assert not pose_is_signers((150, 200), signer, others)  # the first other's
    assert not pose_is_signers((60, 205), signer, others)  # the second other's
    assert pose_is_signers((150, 200), signer, np.zeros((0, 2)))  # nobody else: kept
    assert pose_is_signers((150, 200), signer, None)
    assert pose_is_signers((110, 195), signer, [[np.nan, np.nan]])  # unknown: ignored
    assert not pose_is_signers((np.nan, 195), signer, others)
