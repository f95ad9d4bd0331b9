"""MediaPipe's body, hand and face landmarks in the COCO-WholeBody 133 layout.

Layout (``signsplat.body.joints``): body 17, feet 6, face 68, left hand 21, right hand 21.

- Body 17 from BlazePose's 33 points (nose, eyes, ears, shoulders, elbows, wrists, hips,
  knees, ankles). BlazePose's "left" is the subject's left, as in COCO (checked on a real
  photo: its left shoulder lies on the image's right for a person facing the camera).
- Feet: the big toe is BlazePose's foot index point (the tip of the foot), the heel its heel;
  BlazePose has no small-toe point, so COCO's small toes get score 0 (x, y NaN).
- Face 68 (iBUG/dlib order) from the 468-point face mesh by the usual correspondence of mesh
  vertices to iBUG-68 landmarks (the one mesh-to-dlib table that circulates with MediaPipe's
  face-mesh topology; jaw 0-16 from the cheek/jaw contour, brows, nose bridge and base, eye
  corners/lids, outer and inner lips). The table below is ours, written out and checked
  point by point against the simulator's iBUG-68 ground truth (tests).
- Hands: MediaPipe's 21 points are in COCO-WholeBody's order already (wrist, then thumb,
  index, middle, ring, pinky from base to tip).

Sides are the figure's own as it appears in the frames (for a camera recording, the signer's
own sides; for a mirrored selfie preview, the mirror image's): they come from BlazePose, and the
fit needs them consistent with the image geometry.

Handedness: the hand model's handedness output is the probability of MediaPipe's label
"Left", and MediaPipe labels assuming a mirrored (selfie) image, where the person's left hand
looks like a right hand. So on any frame "Left" means "looks like a right hand here", and
:func:`left_hand_prob` = 1 - output is the probability that the hand is the figure's left hand
(in a camera recording, the signer's left). Hands are assigned by the pose's sides; this
probability is kept as a check (:class:`HandResult`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from signsplat.body.joints import (COCO_BODY_NAMES, KP_BODY, KP_FACE, KP_FEET, KP_LEFT_HAND,
                                   KP_RIGHT_HAND, NUM_KEYPOINTS)

# BlazePose's 33 landmarks (MediaPipe pose_landmark_topology); "left" is the subject's left.
BLAZEPOSE_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)
# BlazePose point for each COCO body keypoint: the point of the same name.
POSE_TO_COCO_BODY = tuple(BLAZEPOSE_NAMES.index(n) for n in COCO_BODY_NAMES)
# BlazePose point for each COCO foot keypoint: big toe <- foot index (the tip of the foot),
# heel <- heel; BlazePose has no small toe (None).
POSE_TO_COCO_FEET = tuple(
    BLAZEPOSE_NAMES.index(n) if n else None
    for n in ("left_foot_index", None, "left_heel", "right_foot_index", None, "right_heel"))
# BlazePose's wrist, pinky knuckle and index knuckle per side (the hand's region from the pose).
POSE_HAND_POINTS = {side: tuple(BLAZEPOSE_NAMES.index(f"{side}_{p}")
                                for p in ("wrist", "pinky", "index"))
                    for side in ("left", "right")}
# BlazePose's elbow per side (a forearm's length measures how far a tracked hand may be).
POSE_ELBOW = {side: BLAZEPOSE_NAMES.index(f"{side}_elbow") for side in ("left", "right")}
# BlazePose's face points (nose .. mouth corners), from which the face's region comes.
POSE_FACE_POINTS = tuple(range(BLAZEPOSE_NAMES.index("mouth_right") + 1))
POSE_LEFT_EYE = BLAZEPOSE_NAMES.index("left_eye")
POSE_RIGHT_EYE = BLAZEPOSE_NAMES.index("right_eye")

# Face-mesh vertex for each iBUG-68 landmark (subject's right = image left for a frontal face).
FACE68_FROM_MESH = (
    # jaw contour 0-16, from the subject's right ear down to the chin and up to the left ear
    162, 234, 93, 58, 172, 136, 149, 148, 152, 377, 378, 365, 397, 288, 323, 454, 389,
    # right brow 17-21 (outer -> inner), left brow 22-26 (inner -> outer)
    71, 63, 105, 66, 107, 336, 296, 334, 293, 301,
    # nose bridge 27-30 (top -> tip), nose base 31-35 (right -> left)
    168, 197, 5, 4, 75, 97, 2, 326, 305,
    # right eye 36-41 (outer corner, upper lid, inner corner, lower lid)
    33, 160, 158, 133, 153, 144,
    # left eye 42-47 (inner corner, upper lid, outer corner, lower lid)
    362, 385, 387, 263, 373, 380,
    # outer lips 48-59 (right corner, upper lip, left corner, lower lip)
    61, 39, 37, 0, 267, 269, 291, 405, 314, 17, 84, 181,
    # inner lips 60-67
    78, 82, 13, 312, 308, 317, 14, 87,
)
assert len(FACE68_FROM_MESH) == 68


def left_hand_prob(handedness: float) -> float:
    """P(the hand is the figure's left hand) from the hand model's handedness output, the
    probability of MediaPipe's "Left", which assumes a mirrored image (see the module)."""
    return 1.0 - float(handedness)


@dataclass
class HandResult:
    """21 landmarks (image pixels), presence probability and P(figure's left hand) from the
    hand model's handedness (:func:`left_hand_prob`)."""

    points: np.ndarray
    presence: float
    left_prob: float


@dataclass
class WholeBodyResult:
    """One person's landmarks in image pixels with their probabilities.

    pose: (33, 2); pose_visibility: (33,); hands: side -> HandResult or None;
    face: (468, 2) or None; face_presence: probability."""

    pose: np.ndarray
    pose_visibility: np.ndarray
    hands: dict
    face: np.ndarray | None = None
    face_presence: float = 0.0


def _other_side(name: str) -> str:
    for a, b in (("left", "right"), ("right", "left")):
        if a in name:
            return name.replace(a, b)
    return name


def mirror_sides(result: WholeBodyResult, width: int) -> WholeBodyResult:
    """What the keypointer should find in the horizontally flipped frame: x -> width - x and
    the figure's sides swapped (BlazePose's left/right pairs, the hands with their left-hand
    probabilities complemented: a flipped left hand looks like a right hand). The face mesh is
    dropped (its vertex ids have no side mapping here)."""
    flip, off = np.array([[-1.0, 1.0]]), np.array([[float(width), 0.0]])
    swap = [BLAZEPOSE_NAMES.index(_other_side(n)) for n in BLAZEPOSE_NAMES]
    hands = {}
    for side, other in (("left", "right"), ("right", "left")):
        h = result.hands.get(other)
        hands[side] = None if h is None else HandResult(h.points * flip + off, h.presence,
                                                        1.0 - h.left_prob)
    return WholeBodyResult(result.pose[swap] * flip + off, result.pose_visibility[swap], hands)


def to_coco_wholebody(result: WholeBodyResult | None, min_score: float = 0.0
                      ) -> tuple[np.ndarray, np.ndarray]:
    """COCO-WholeBody keypoints (133, 2) float32 (NaN = none) and scores (133,) float32.

    Body and feet scores are BlazePose's visibility probabilities, hand points take the hand's
    presence and face points the face's presence. Scores at or below ``min_score`` become 0
    with NaN positions; missing parts (None) and the small toes score 0."""
    xy = np.full((NUM_KEYPOINTS, 2), np.nan, np.float32)
    sc = np.zeros(NUM_KEYPOINTS, np.float32)
    if result is None:
        return xy, sc
    body = list(KP_BODY)
    xy[body] = result.pose[list(POSE_TO_COCO_BODY)]
    sc[body] = result.pose_visibility[list(POSE_TO_COCO_BODY)]
    for kp, src in zip(KP_FEET, POSE_TO_COCO_FEET):
        if src is not None:
            xy[kp] = result.pose[src]
            sc[kp] = result.pose_visibility[src]
    for side, ids in (("left", KP_LEFT_HAND), ("right", KP_RIGHT_HAND)):
        hand = result.hands.get(side)
        if hand is not None:
            xy[list(ids)] = hand.points
            sc[list(ids)] = hand.presence
    if result.face is not None:
        xy[list(KP_FACE)] = result.face[list(FACE68_FROM_MESH)]
        sc[list(KP_FACE)] = result.face_presence
    off = ~(sc > min_score)
    sc[off] = 0.0
    xy[off] = np.nan
    return xy, sc
