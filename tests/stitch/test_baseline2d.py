"""The 2D baseline: keypoints of the gloss frames, linear 2D transitions, skeleton drawing."""

from __future__ import annotations

import numpy as np
import pytest
from tiny_avatar import FAST, SIZE, rig_cameras

from signsplat.body.keypoints import WholeBodyRegressor
from signsplat.io.video import VideoWriter, iter_frames
from signsplat.motion.stitching import TRANSITION, stitch_frames
from signsplat.stitch.animate import Identity
from signsplat.stitch.baseline2d import (
    LEFT_HAND_BONES,
    METRIC_BONES,
    SKELETON_BONES,
    baseline_keypoints,
    draw_skeleton,
    interpolate_transition,
    project_keypoints,
    render_baseline,
)
from signsplat.stitch.evaluate import BoneStats

IDENT = Identity(np.zeros(10, np.float32))


def test_interpolate_transition_is_linear_and_excludes_ends():
    a = np.array([[0.0, 0.0], [10.0, 0.0]])
    b = np.array([[4.0, 8.0], [10.0, 20.0]])
    lin = interpolate_transition(a, b, 3, ease=False)
    assert lin.shape == (3, 2, 2)
    np.testing.assert_allclose(lin[:, 0], [[1, 2], [2, 4], [3, 6]])
    eased = interpolate_transition(a, b, 3, ease=True)
    np.testing.assert_allclose(eased[1], (a + b) / 2)  # the ease is symmetric
    assert np.linalg.norm(eased[0] - a) < np.linalg.norm(lin[0] - a)  # slow start
    assert interpolate_transition(a, b, 0).shape == (0, 2, 2)


def test_linear_2d_interpolation_shortens_a_turning_bone():
    """The paper's point: a bone turning by 90 degrees is ~30% shorter half way."""
    a = np.array([[0.0, 0.0], [10.0, 0.0]])
    b = np.array([[0.0, 0.0], [0.0, 10.0]])
    mid = interpolate_transition(a, b, 1, ease=False)[0]
    assert np.linalg.norm(mid[1] - mid[0]) == pytest.approx(10 / np.sqrt(2))
    stats = BoneStats([(0, 1)])
    stats.add(np.stack([a, mid, b]))
    assert stats.summary()["bone_max_rel_range"] > 0.3


def test_baseline_keypoints_follow_the_3d_track(tiny_body, gloss_library):
    cam = rig_cameras()[1]
    reg = WholeBodyRegressor(tiny_body)
    clips = [gloss_library[g] for g in ("HELLO", "BOOK", "WHERE")]
    frames = list(stitch_frames(clips, FAST))
    out = list(baseline_keypoints(iter(frames), tiny_body, reg, cam, IDENT, batch=7,
                                  ease=False))
    assert [f.label for f, _ in out] == [f.label for f in frames]
    kps = np.stack([kp for _, kp in out])
    assert kps.shape == (len(frames), 133, 2) and np.isfinite(kps).all()
    gloss = [i for i, f in enumerate(frames) if f.label != TRANSITION]
    direct = project_keypoints(tiny_body, reg, [frames[i] for i in gloss], IDENT, cam)[0]
    np.testing.assert_allclose(kps[gloss], direct, atol=1e-3)  # float32 batching
    # each transition is the straight segment between its neighbours, evenly spaced
    labels = np.array([f.label for f in frames])
    tr = np.nonzero(labels == TRANSITION)[0]
    runs = np.split(tr, np.nonzero(np.diff(tr) > 1)[0] + 1)
    assert len(runs) == 2
    for run in runs:
        a, b = kps[run[0] - 1], kps[run[-1] + 1]
        n = len(run)
        for k, i in enumerate(run, start=1):
            np.testing.assert_allclose(kps[i], a + (b - a) * k / (n + 1), atol=1e-6)


def test_draw_skeleton_draws_valid_bones_only():
    kp = np.full((133, 2), np.nan)
    kp[5], kp[7] = [4.0, 4.0], [28.0, 4.0]  # left shoulder -> left elbow
    img = draw_skeleton(kp, SIZE, SIZE)
    assert img.shape == (SIZE, SIZE, 3) and img.dtype == np.uint8
    assert (img[4, 8:24] < 200).all()  # the bone is drawn
    assert (img[20:] == 255).all()  # nothing else
    valid = np.ones(133, bool)
    valid[7] = False
    assert (draw_skeleton(kp, SIZE, SIZE, valid) == 255).all()
    assert len(set(SKELETON_BONES)) == len(SKELETON_BONES)
    assert len(LEFT_HAND_BONES) == 20 and set(LEFT_HAND_BONES) <= set(METRIC_BONES)


def test_render_baseline_writes_a_skeleton_video(tmp_path, tiny_body, gloss_library):
    cam = rig_cameras()[1]
    reg = WholeBodyRegressor(tiny_body)
    clips = [gloss_library[g] for g in ("HELLO", "BOOK")]
    n = sum(1 for _ in stitch_frames(clips, FAST))
    bones = BoneStats(METRIC_BONES)
    with VideoWriter(tmp_path / "b.mp4", 25) as w:
        stats = render_baseline(stitch_frames(clips, FAST), tiny_body, reg, cam, w, IDENT,
                                on_frame=lambda f, kp: bones.add(kp))
    assert stats.frames == n == bones.frames
    video = [img for _, img in iter_frames(tmp_path / "b.mp4")]
    assert len(video) == n and (video[0] < 200).any()
    assert bones.summary()["bone_max_rel_range"] > 1e-3  # 2D bones change length
