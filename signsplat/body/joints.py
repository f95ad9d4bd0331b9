"""Skeleton conventions shared by every stage: SMPL-X joints and COCO-WholeBody keypoints.

SMPL-X has 55 joints: 22 body joints (pelvis .. right wrist), jaw, left eye, right eye,
15 left-hand joints and 15 right-hand joints. Pose parameters are axis-angle per joint
relative to the parent joint; ``body_pose`` covers joints 1..21 (63 values), the hand poses
joints 25..39 and 40..54 (45 values each).

COCO-WholeBody has 133 keypoints: body 17, feet 6, face 68, left hand 21, right hand 21.
"""

from __future__ import annotations

SMPLX_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck",
    "left_collar", "right_collar", "head", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "jaw", "left_eye",
    "right_eye",
    "left_index1", "left_index2", "left_index3", "left_middle1", "left_middle2",
    "left_middle3", "left_pinky1", "left_pinky2", "left_pinky3", "left_ring1",
    "left_ring2", "left_ring3", "left_thumb1", "left_thumb2", "left_thumb3",
    "right_index1", "right_index2", "right_index3", "right_middle1", "right_middle2",
    "right_middle3", "right_pinky1", "right_pinky2", "right_pinky3", "right_ring1",
    "right_ring2", "right_ring3", "right_thumb1", "right_thumb2", "right_thumb3",
)
NUM_JOINTS = 55
NUM_BODY_JOINTS = 21  # joints 1..21, the ``body_pose`` block
NUM_HAND_JOINTS = 15

SMPLX_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 15, 15, 15,
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38,
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53,
)
JOINT_INDEX = {name: i for i, name in enumerate(SMPLX_JOINT_NAMES)}
LEFT_HAND_JOINTS = tuple(range(25, 40))
RIGHT_HAND_JOINTS = tuple(range(40, 55))
FINGERS = ("index", "middle", "pinky", "ring", "thumb")  # SMPL-X order within a hand
COCO_FINGERS = ("thumb", "index", "middle", "ring", "pinky")  # COCO-WholeBody order

# Parameter blocks of one SMPL-X frame, in the order used by flat vectors, with sizes.
# ``betas`` and ``expression`` sizes are those of the shipped default (10 each).
POSE_BLOCKS: tuple[tuple[str, int], ...] = (
    ("global_orient", 3), ("body_pose", 63), ("jaw_pose", 3), ("leye_pose", 3),
    ("reye_pose", 3), ("left_hand_pose", 45), ("right_hand_pose", 45),
)
PARAM_BLOCKS: tuple[tuple[str, int], ...] = (
    ("betas", 10), ("expression", 10), *POSE_BLOCKS, ("transl", 3),
)

# --- COCO-WholeBody (133) -----------------------------------------------------------------
COCO_BODY_NAMES = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
)
COCO_FOOT_NAMES = (
    "left_big_toe", "left_small_toe", "left_heel", "right_big_toe", "right_small_toe",
    "right_heel",
)
_HAND21 = ("wrist",) + tuple(
    f"{finger}{k}" for finger in COCO_FINGERS for k in (1, 2, 3, 4)
)
COCO_WHOLEBODY_NAMES: tuple[str, ...] = (
    COCO_BODY_NAMES + COCO_FOOT_NAMES + tuple(f"face_{i}" for i in range(68))
    + tuple(f"left_hand_{n}" for n in _HAND21) + tuple(f"right_hand_{n}" for n in _HAND21)
)
NUM_KEYPOINTS = 133
KP_BODY = tuple(range(0, 17))
KP_FEET = tuple(range(17, 23))
KP_FACE = tuple(range(23, 91))
KP_LEFT_HAND = tuple(range(91, 112))
KP_RIGHT_HAND = tuple(range(112, 133))
KEYPOINT_PARTS = {
    "body": KP_BODY, "feet": KP_FEET, "face": KP_FACE,
    "left_hand": KP_LEFT_HAND, "right_hand": KP_RIGHT_HAND,
}

# Vertex part labels stored in a body-model file's ``part_labels`` (V,) array.
PART_NAMES = ("body", "head", "left_hand", "right_hand")
PART_BODY, PART_HEAD, PART_LEFT_HAND, PART_RIGHT_HAND = range(4)
