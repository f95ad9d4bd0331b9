"""benchmarks/hand_budget.py: SMPL-X tables that swap one part of the signing arm."""

import numpy as np
import pandas as pd
from benchmark_scripts import load_benchmark

from signsplat.body.joints import SMPLX_JOINT_NAMES


def _table(value: float, frames: int = 3) -> pd.DataFrame:
    return pd.DataFrame({"frame": range(frames),
                         "body_pose": [np.full(63, value) for _ in range(frames)],
                         "jaw_pose": [np.full(3, value) for _ in range(frames)],
                         "leye_pose": [np.full(3, value) for _ in range(frames)],
                         "reye_pose": [np.full(3, value) for _ in range(frames)],
                         "expression": [np.full(10, value) for _ in range(frames)],
                         "betas": [np.full(10, value) for _ in range(frames)],
                         "left_hand_pose": [np.full(45, value) for _ in range(frames)],
                         "right_hand_pose": [np.full(45, value) for _ in range(frames)],
                         "transl": [np.full(3, value) for _ in range(frames)]})


def test_the_arm_swap_takes_exactly_the_signing_sides_four_joints_and_fingers():
    mix = load_benchmark("hand_budget").mix
    base, donor = _table(0.0), _table(1.0)
    out = mix(base, donor, ("fingers", "arm"), "right")
    body = np.stack(out["body_pose"]).reshape(3, 21, 3)
    took = {SMPLX_JOINT_NAMES[j + 1] for j in np.flatnonzero(body[0, :, 0] == 1.0)}
    assert took == {"right_collar", "right_shoulder", "right_elbow", "right_wrist"}
    assert (body[:, :, 0] == body[:, :, 2]).all()  # whole joints, every frame
    assert (np.stack(out["right_hand_pose"]) == 1.0).all()
    assert (np.stack(out["left_hand_pose"]) == 0.0).all()
    assert (np.stack(out["transl"]) == 0.0).all()
    assert (np.stack(base["body_pose"]) == 0.0).all()  # the base table is left as it was


def test_the_finger_swap_leaves_the_arm_and_the_other_hand():
    mix = load_benchmark("hand_budget").mix
    out = mix(_table(0.0), _table(1.0), ("fingers",), "left")
    assert (np.stack(out["body_pose"]) == 0.0).all()
    assert (np.stack(out["left_hand_pose"]) == 1.0).all()
    assert (np.stack(out["right_hand_pose"]) == 0.0).all()


def test_the_head_swap_takes_neck_head_jaw_eyes_and_expression_with_the_arm_or_alone():
    mix = load_benchmark("hand_budget").mix
    for parts, joints in ((("head",), {"neck", "head"}),
                          (("head", "fingers", "arm"), {"neck", "head", "right_collar",
                                                        "right_shoulder", "right_elbow",
                                                        "right_wrist"})):
        out = mix(_table(0.0), _table(1.0), parts, "right")
        body = np.stack(out["body_pose"]).reshape(3, 21, 3)
        assert {SMPLX_JOINT_NAMES[j + 1] for j in np.flatnonzero(body[0, :, 0] == 1.0)} == joints
        for col in ("jaw_pose", "leye_pose", "reye_pose", "expression"):
            assert (np.stack(out[col]) == 1.0).all()
        assert (np.stack(out["right_hand_pose"]) == float("fingers" in parts)).all()
        assert (np.stack(out["left_hand_pose"]) == 0.0).all()
        assert (np.stack(out["betas"]) == 0.0).all()


def test_the_shape_swap_takes_the_betas_only():
    mix = load_benchmark("hand_budget").mix
    out = mix(_table(0.0), _table(1.0), ("shape",), "right")
    assert (np.stack(out["betas"]) == 1.0).all()
    for col in ("body_pose", "expression", "right_hand_pose", "left_hand_pose", "transl"):
        assert (np.stack(out[col]) == 0.0).all()


def test_the_finger_offset_and_the_varying_rest_add_up_to_the_donors_fingers():
    mix = load_benchmark("hand_budget").mix
    base, donor = _table(0.5), _table(0.0)
    donor["right_hand_pose"] = [np.full(45, v) for v in (1.0, 2.0, 6.0)]  # mean offset 2.5
    offset = np.stack(mix(base, donor, ("fingers_offset",), "right")["right_hand_pose"])
    varying = np.stack(mix(base, donor, ("fingers_varying",), "right")["right_hand_pose"])
    assert (offset == 3.0).all()  # the base's 0.5 and the mean difference
    np.testing.assert_array_equal(varying[:, 0], [-1.5, -0.5, 3.5])
    np.testing.assert_array_equal(offset + varying - 0.5, np.stack(donor["right_hand_pose"]))
    assert (np.stack(mix(base, donor, ("fingers_offset",), "right")["left_hand_pose"]) == 0.5).all()


def test_the_thumb_stays_the_bases_when_the_other_fingers_are_swapped():
    mix = load_benchmark("hand_budget").mix
    out = np.stack(mix(_table(0.0), _table(1.0), ("fingers_but_thumb",), "right")
                   ["right_hand_pose"]).reshape(3, 15, 3)
    kept = {SMPLX_JOINT_NAMES[40 + j] for j in range(15) if (out[:, j] == 0.0).all()}
    assert kept == {"right_thumb1", "right_thumb2", "right_thumb3"}
    assert (np.delete(out, [12, 13, 14], axis=1) == 1.0).all()


def test_settings_replace_only_their_training_keys_and_unknown_keys_are_named():
    import json
    from pathlib import Path

    import pytest
    sections = load_benchmark("hand_budget").demo_sections
    config = str(Path(__file__).resolve().parents[2] / "config" / "config.yaml")
    train, evals = sections(config, "studio6")
    longer, evals2 = sections(config, "studio6", {"iterations": 1234, "finetune_smplx": False})
    train, longer = json.loads(train), json.loads(longer)
    assert longer["train"].pop("iterations") == 1234
    assert train["train"].pop("iterations") != 1234
    assert longer["train"].pop("finetune_smplx") is False
    assert train["train"].pop("finetune_smplx") is True
    assert longer == train and evals2 == evals
    with pytest.raises(SystemExit, match="pose_knot_spacin.*not a training setting"):
        sections(config, "studio6", {"pose_knot_spacin": 4})
