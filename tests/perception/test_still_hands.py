"""Clearing a neighbour's hand that stays put while the signer's wrist moves
(signsplat.perception.still_hands), on hand-made keypoint tracks."""

from __future__ import annotations

import numpy as np
import pytest

from signsplat.body.joints import KP_LEFT_HAND, KP_RIGHT_HAND, NUM_KEYPOINTS
from signsplat.perception.still_hands import (WRIST, drop_still_hands, hand_tracks,
                                              still_hand_frames)

PALM = 20.0  # wrist to middle knuckle, px


def clip(hand_wrists, pose_wrists, side="left", score=0.9, wrist_score=0.9):
    """(T,) frames, (T, 133, 2), (T, 133): one hand of palm length PALM at ``hand_wrists`` and
    the pose's wrist of that side at ``pose_wrists`` (NaN rows = no hand)."""
    hand_wrists, pose_wrists = np.asarray(hand_wrists, float), np.asarray(pose_wrists, float)
    t = len(hand_wrists)
    xy = np.full((t, NUM_KEYPOINTS, 2), np.nan)
    sc = np.zeros((t, NUM_KEYPOINTS))
    ids = list(KP_LEFT_HAND if side == "left" else KP_RIGHT_HAND)
    fingers = np.linspace(0, 2 * PALM, 21)[:, None] * np.array([[0.0, -1.0]])
    for i, w in enumerate(hand_wrists):
        if np.all(np.isfinite(w)):
            pts = w + fingers
            pts[9] = w + [0.0, -PALM]
            xy[i, ids] = pts
            sc[i, ids] = score
    xy[:, WRIST[side]] = pose_wrists
    sc[:, WRIST[side]] = wrist_score
    return np.arange(t), xy, sc


def wander(t, step, rng, start=(100.0, 100.0)):
    return np.asarray(start) + np.cumsum(rng.normal(0.0, step, (t, 2)), axis=0)


def test_a_still_hand_beside_a_moving_wrist_is_cleared_and_the_signers_kept():
    rng = np.random.default_rng(0)
    moving = wander(40, 8.0, rng)
    # frames 0-19: his hand follows his wrist; 20-39: a hand 90 px away that hardly moves
    hand = np.concatenate([moving[:20] + rng.normal(0, 1.0, (20, 2)),
                           np.array([190.0, 60.0]) + rng.normal(0, 0.3, (20, 2))])
    frames, xy, sc = clip(hand, moving)
    drop = still_hand_frames(frames, xy, sc, "left", ratio=5)
    assert not drop[:20].any() and drop[20:].all()
    xy2, sc2, cleared = drop_still_hands(frames, xy, sc, ratio=5)
    assert cleared == {"left": 20, "right": 0}
    ids = list(KP_LEFT_HAND)
    assert np.all(sc2[20:, ids] == 0) and np.isnan(xy2[20:, ids]).all()
    np.testing.assert_array_equal(sc2[:20], sc[:20])
    assert np.all(sc[20:, ids] > 0), "the input is not changed"
    # off
    assert not still_hand_frames(frames, xy, sc, "left", ratio=0).any()


def test_a_resting_hand_with_a_jittery_wrist_is_kept():
    """His hand at rest (1 px steps) while the pose's wrist jitters 3-4 px: below the
    minimum motion, the pose cannot tell, and nothing is cleared."""
    rng = np.random.default_rng(1)
    hand = np.array([140.0, 225.0]) + rng.normal(0, 0.7, (12, 2))
    pose = np.array([147.0, 221.0]) + rng.normal(0, 2.5, (12, 2))
    frames, xy, sc = clip(hand, pose)
    assert not still_hand_frames(frames, xy, sc, "left", ratio=5).any()


def test_an_unsure_wrist_does_not_decide():
    rng = np.random.default_rng(2)
    moving = wander(20, 8.0, rng)
    hand = np.array([190.0, 60.0]) + rng.normal(0, 0.3, (20, 2))
    frames, xy, sc = clip(hand, moving, wrist_score=0.2)
    assert not still_hand_frames(frames, xy, sc, "left", ratio=5).any()
    frames, xy, sc = clip(hand, moving, wrist_score=0.9)
    assert still_hand_frames(frames, xy, sc, "left", ratio=5).all()


def test_tracks_break_at_gaps_and_jumps():
    frames = np.array([0, 1, 2, 5, 6, 7, 8])
    wrist = np.array([[0, 0], [1, 0], [2, 0], [3, 0], [4, 0], [100, 0], [101, 0]], float)
    tracks = hand_tracks(frames, wrist, max_gap=2, max_step=10.0)
    assert [t.tolist() for t in tracks] == [[0, 1, 2], [3, 4], [5, 6]]
    assert hand_tracks(np.array([], int), np.zeros((0, 2)), 2, 10.0) == []


@pytest.mark.parametrize("case", ["no_hands", "one_frame", "nan_pose", "zero_palm", "empty"])
def test_degenerate_views_clear_nothing_and_stay_finite(case):
    rng = np.random.default_rng(3)
    t = {"one_frame": 1, "empty": 0}.get(case, 10)
    hand = np.array([190.0, 60.0]) + rng.normal(0, 0.3, (t, 2))
    pose = wander(t, 8.0, rng)
    if case == "no_hands":
        hand[:] = np.nan
    if case == "nan_pose":
        pose[:] = np.nan
    frames, xy, sc = clip(hand, pose)
    if case == "zero_palm":
        ids = list(KP_LEFT_HAND)
        xy[:, ids] = hand[:, None, :]
    with np.errstate(all="raise"):
        xy2, sc2, cleared = drop_still_hands(frames, xy, sc, ratio=5)
    assert cleared == {"left": 0, "right": 0}
    np.testing.assert_array_equal(sc2, sc)
    assert np.isfinite(sc2).all()
