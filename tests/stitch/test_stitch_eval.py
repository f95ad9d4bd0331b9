"""stitch_eval: bone-length statistics, 3D vs 2D bone-length variation, the table."""

from __future__ import annotations

import numpy as np
import pytest
from tiny_avatar import FAST, CountingWriter, rig_cameras, tiny_renderer

from signsplat.body.keypoints import WholeBodyRegressor
from signsplat.io.tables import read_table
from signsplat.motion.stitching import stitch_clips, stitch_frames
from signsplat.stitch.animate import RenderStats, render_track
from signsplat.stitch.baseline2d import METRIC_BONES, baseline_keypoints
from signsplat.stitch.evaluate import (
    FACE_BONES,
    POSE_BONES,
    SMPLX_BONES,
    BoneStats,
    StitchObserver,
    sentence_eval,
    summary_lines,
    write_stitch_eval,
)
from signsplat.stitch.metrics import join_metrics


def test_bone_stats_against_direct_computation():
    g = np.random.default_rng(0)
    pts = g.normal(size=(40, 5, 3))
    bones = [(0, 1), (1, 2), (3, 4)]
    s = BoneStats(bones)
    for chunk in np.array_split(pts, 7):  # streamed in uneven chunks
        s.add(chunk)
    L = np.stack([np.linalg.norm(pts[:, a] - pts[:, b], axis=-1) for a, b in bones], 1)
    want_range = ((L.max(0) - L.min(0)) / L.mean(0)).max()
    want_cv = (L.std(0) / L.mean(0)).mean()
    got = s.summary()
    assert s.frames == 40
    assert got["bone_max_rel_range"] == pytest.approx(want_range, rel=1e-9)
    assert got["bone_mean_cv"] == pytest.approx(want_cv, rel=1e-6)
    rigid = BoneStats(bones)
    rigid.add(np.repeat(pts[:1], 10, 0))
    assert rigid.summary() == {"bone_max_rel_range": 0.0, "bone_mean_cv": 0.0}
    assert BoneStats(bones).summary()["bone_max_rel_range"] == 0.0


def test_bone_sets_partition_the_skeleton():
    assert sorted(POSE_BONES + FACE_BONES) == sorted(SMPLX_BONES) and len(SMPLX_BONES) == 54
    assert len(FACE_BONES) == 5


def test_3d_stitching_keeps_bone_lengths_2d_baseline_does_not(tiny_body, gloss_library):
    """The paper's comparison on the same glosses, camera and timing."""
    cam = rig_cameras()[1]
    reg = WholeBodyRegressor(tiny_body)
    r = tiny_renderer(tiny_body, cam)
    clips = [gloss_library[g] for g in ("HELLO", "HOUSE", "WHERE", "BOOK")]
    obs = StitchObserver(reg, cam)
    stats = render_track(stitch_frames(clips, FAST), r, CountingWriter(), batch=8,
                         on_batch=obs)
    b2 = BoneStats(METRIC_BONES)
    for _, kp in baseline_keypoints(stitch_frames(clips, FAST), tiny_body, reg, cam,
                                    r.identity):
        b2.add(kp)
    assert obs.bones_3d.frames == b2.frames == stats.frames
    assert obs.bones_3d.summary()["bone_max_rel_range"] < 1e-5
    assert b2.summary()["bone_max_rel_range"] > 1e-3
    assert obs.bones_projected.summary()["bone_max_rel_range"] > 0  # foreshortening

    track = stitch_clips(clips, FAST)
    df = sentence_eval("tiny", "s1", track, 25.0, obs.bones_3d, obs.bones_projected, b2,
                       stats, RenderStats(10, 0.5, 1.0, 0.4), text="hello house",
                       bones_face=obs.bones_face)
    jm = join_metrics(track, 25.0)
    tf = df[df.metric == "transition_frames"]
    assert list(tf["join"]) == list(jm["join"]) == [0, 1, 2]
    np.testing.assert_array_equal(tf.value.to_numpy(), jm.transition_frames.to_numpy())
    assert list(tf.from_gloss) == ["HELLO", "HOUSE", "WHERE"]
    whole = df[df["join"] == -1].set_index(["method", "metric"]).value
    assert whole[("stitch_3d", "frames")] == len(track["label"])
    assert whole[("stitch_3d", "bone_max_rel_range")] < 1e-5
    assert whole[("baseline_2d", "bone_max_rel_range")] > 1e-3
    assert whole[("baseline_2d", "draw_fps")] == pytest.approx(10.0)
    assert whole[("stitch_3d", "render_fps")] == pytest.approx(stats.render_fps)
    assert "render" in summary_lines(df)[0]


def test_stitch_eval_table_round_trip(tmp_path, gloss_library):
    track = stitch_clips([gloss_library["HELLO"], gloss_library["BOOK"]], FAST)
    a = sentence_eval("tiny", "a", track, 25.0)
    b = sentence_eval("tiny", "b", stitch_clips([gloss_library["NAME"]], FAST), 25.0)
    path = write_stitch_eval([a, b], tmp_path / "stitch_eval.parquet")
    df = read_table(path, "stitch_eval")
    assert set(df.sentence) == {"a", "b"}
    assert df["join"].dtype == np.int64 and df["value"].dtype == np.float64
    # a single gloss has no join, but its frame count is still reported
    assert (df[df.sentence == "b"].metric == "frames").all()
    empty = read_table(write_stitch_eval([], tmp_path / "empty.parquet"), "stitch_eval")
    assert len(empty) == 0
