"""Held-out poses carried from the training frames' fine-tuning (signsplat.avatar.poses)."""

import math

import numpy as np
import pytest
import torch

from signsplat.avatar.poses import carry_corrections, interpolation_weights


def test_weights_interpolate_between_the_nearest_training_frames():
    frames = np.array([0, 1, 2, 3, 4, 5, 6])
    known = np.array([1, 1, 0, 0, 1, 0, 1], bool)
    w = interpolation_weights(frames, known).numpy()
    np.testing.assert_allclose(w.sum(1), 1.0)
    for i in np.flatnonzero(known):
        assert w[i, i] == 1.0 and w[i].sum() == 1.0
    # frame 2 lies a third of the way from frame 1 to frame 4, frame 3 two thirds
    assert w[2, 1] == pytest.approx(2 / 3) and w[2, 4] == pytest.approx(1 / 3)
    assert w[3, 1] == pytest.approx(1 / 3) and w[3, 4] == pytest.approx(2 / 3)
    assert w[5, 4] == pytest.approx(0.5) and w[5, 6] == pytest.approx(0.5)
    # no weight on a held-out frame
    assert (w[:, ~known] == 0).all()


def test_weights_follow_frame_numbers_not_positions_and_hold_at_the_ends():
    frames = np.array([30, 0, 10, 40, 20])  # unsorted, gaps of 10
    known = np.array([1, 0, 1, 0, 1], bool)
    w = interpolation_weights(frames, known).numpy()
    assert w[1, 2] == 1.0  # frame 0: before every training frame, takes frame 10's
    assert w[3, 0] == 1.0  # frame 40: after every training frame, takes frame 30's
    # frames known at 10, 20, 30: each weights only itself
    np.testing.assert_array_equal(w[[0, 2, 4]][:, [0, 2, 4]], np.eye(3))


def test_no_training_frame_means_no_correction():
    fitted = {"body_pose": torch.randn(4, 63)}
    tuned = {"body_pose": fitted["body_pose"] + 1.0}
    out = carry_corrections(fitted, tuned, np.arange(4), np.zeros(4, bool))
    assert interpolation_weights(np.arange(4), np.zeros(4, bool)).abs().sum() == 0
    # every frame held out: nothing is known of the fine-tuning, so each is rendered as fitted
    torch.testing.assert_close(out["body_pose"], fitted["body_pose"])


def test_a_smooth_correction_is_recovered_on_the_held_out_frames():
    torch.manual_seed(0)
    f = 12
    frames = np.arange(f)
    train = (frames - 2) % 5 != 0  # frames 2 and 7 held out, as the split does
    fitted = {name: torch.randn(f, k) for name, k in
              (("global_orient", 3), ("body_pose", 63), ("transl", 3), ("expression", 10))}
    fitted["betas"] = torch.randn(f, 10)
    slope = {name: torch.randn(1, v.shape[1]) * 1e-2 for name, v in fitted.items()}
    t = torch.arange(f, dtype=torch.float32)[:, None]
    true_corr = {name: 0.05 + slope[name] * t for name in fitted}  # linear in time
    tuned = {name: fitted[name] + true_corr[name] * torch.as_tensor(train)[:, None]
             for name in fitted if name != "betas"}
    tuned["betas"] = torch.randn(1, 10)  # shared block: returned as it is
    out = carry_corrections(fitted, tuned, frames, train)
    for name in ("global_orient", "body_pose", "transl", "expression"):
        # training frames keep their tuned values exactly; held-out ones get the correction
        torch.testing.assert_close(out[name][train], tuned[name][train])
        torch.testing.assert_close(out[name][~train], (fitted[name] + true_corr[name])[~train])
    torch.testing.assert_close(out["betas"], tuned["betas"])


def test_hard_cases_stay_finite_axis_angle_near_pi_and_missing_fit_values():
    # global orientation near pi (a subject facing an OpenCV camera) on both sides of the flip,
    # and a fit with a NaN block (no hand keypoints): corrections stay finite and small
    frames = np.arange(5)
    train = np.array([1, 1, 0, 1, 1], bool)
    near_pi = torch.tensor([[math.pi - 1e-4, 0, 0], [math.pi, 0, 0], [math.pi, 0, 0],
                            [-math.pi + 1e-4, 0, 0], [math.pi + 1e-4, 0, 0]])
    hands = torch.zeros(5, 45)
    hands[1] = float("nan")
    fitted = {"global_orient": near_pi, "right_hand_pose": hands}
    tuned = {"global_orient": near_pi + 1e-3, "right_hand_pose": torch.zeros(5, 45) + 1e-3}
    out = carry_corrections(fitted, tuned, frames, train)
    for v in out.values():
        assert torch.isfinite(v).all()
    torch.testing.assert_close(out["global_orient"][2], near_pi[2] + 1e-3)
    # the NaN fit of frame 1 counts as no correction: frame 2 gets half of frame 3's
    torch.testing.assert_close(out["right_hand_pose"][2], torch.full((45,), 0.5e-3))


def test_bad_shapes_are_refused():
    with pytest.raises(ValueError, match="1-D"):
        interpolation_weights(np.arange(4), np.ones(3, bool))
