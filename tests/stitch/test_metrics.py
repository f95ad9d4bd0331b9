"""Join metrics of stitched tracks: transition frames, peak angular velocity and jerk."""

import math

import numpy as np
import pytest

from signsplat.motion import stitching as M
from signsplat.motion.clips import GlossClip
from signsplat.stitch import metrics as X


def _const(name, angle_deg, n=6):
    body = np.zeros((n, 63), np.float32)
    body[:, 45] = math.radians(angle_deg)  # head pitch
    return GlossClip(name, (name.lower(),), "sign", 25.0, "flat", {"body_pose": body})


def test_peak_velocity_of_an_eased_transition():
    cfg = M.StitchConfig(deg_per_frame=6.0, min_transition=0, max_transition=50)
    track = M.stitch_clips([_const("A", 0), _const("B", 60)], cfg)
    df = X.join_metrics(track, fps=25.0)
    assert len(df) == 1 and df.transition_frames[0] == 10
    # cubic ease: peak speed 1.5x the mean speed 60 deg / 11 steps
    expected = 1.5 * 60.0 / 11 * 25.0
    assert df.peak_velocity_deg_s[0] == pytest.approx(expected, rel=0.05)
    assert df.from_gloss[0] == "A" and df.to_gloss[0] == "B"


def test_transitions_lower_velocity_and_jerk_than_a_cut():
    clips = [_const("A", 0), _const("B", 60), _const("C", -30)]
    smooth = X.join_metrics(M.stitch_clips(clips, M.StitchConfig()), fps=25.0)
    cut = X.join_metrics(M.stitch_clips(clips, M.StitchConfig(min_transition=0,
                                                                max_transition=0)), fps=25.0)
    assert (cut.transition_frames == 0).all() and (smooth.transition_frames > 0).all()
    assert (smooth.peak_velocity_deg_s < 0.3 * cut.peak_velocity_deg_s).all()
    assert (smooth.peak_jerk_deg_s3 < 0.2 * cut.peak_jerk_deg_s3).all()


def test_real_glosses_and_empty_track(gloss_library):
    names = ["HELLO", "ME", "E", "D"]
    track = M.stitch_clips([gloss_library[g] for g in names])
    df = X.join_metrics(track, fps=25.0)
    assert list(df.from_gloss) == names[:-1] and list(df.to_gloss) == names[1:]
    assert np.isfinite(df[["peak_velocity_deg_s", "peak_jerk_deg_s3"]].to_numpy()).all()
    assert X.join_metrics(M.stitch_clips([]), fps=25.0).empty
