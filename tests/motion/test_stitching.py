"""Motion stitching: SLERP hard cases, adaptive transitions, holds, streaming memory."""

import math
import tracemalloc

import numpy as np
import pytest
import roma
import torch
from scipy.spatial.transform import Rotation, Slerp

from signsplat.motion import stitching as M
from signsplat.motion.clips import GlossClip


def _clip(name, body, kind="sign", n=3, expr=None, fps=25.0, **extra):
    body = np.asarray(body, np.float32).reshape(-1)
    poses = {"body_pose": np.tile(body, (n, 1)),
             "left_hand_pose": np.zeros((n, 45), np.float32),
             "right_hand_pose": np.zeros((n, 45), np.float32),
             "jaw_pose": np.zeros((n, 3), np.float32),
             "expression": np.tile(np.asarray(expr if expr is not None else np.zeros(10),
                                              np.float32), (n, 1))}
    poses.update({k: np.asarray(v, np.float32) for k, v in extra.items()})
    return GlossClip(name, (name.lower(),), kind, fps, "flat", poses)


def _body(joint, aa):
    b = np.zeros(63)
    b[3 * joint:3 * joint + 3] = aa
    return b


def test_slerp_matches_scipy_and_stays_unit_norm():
    rng = np.random.default_rng(0)
    a = Rotation.random(30, random_state=1).as_rotvec()
    b = Rotation.random(30, random_state=2).as_rotvec()
    steps = np.sort(rng.uniform(0, 1, 9))
    out = M.slerp_blocks({"body_pose": a.reshape(-1)}, {"body_pose": b.reshape(-1)}, steps)
    got = out["body_pose"].reshape(9, 30, 3)
    for j in range(30):
        ref = Slerp([0, 1], Rotation.from_rotvec([a[j], b[j]]))(steps)
        d = (Rotation.from_rotvec(got[:, j]) * ref.inv()).magnitude()
        assert d.max() < 1e-9
    q = roma.rotvec_to_unitquat(torch.as_tensor(got.reshape(-1, 3)))
    np.testing.assert_allclose(q.norm(dim=-1).numpy(), 1.0, atol=1e-12)


def test_identical_poses_zero_angle_slerp():
    pose = {"body_pose": _body(3, [0.3, -0.2, 0.1]), "expression": np.ones(10)}
    out = M.slerp_blocks(pose, pose, np.linspace(0, 1, 7))
    assert np.isfinite(out["body_pose"]).all()
    np.testing.assert_allclose(out["body_pose"], np.tile(pose["body_pose"], (7, 1)), atol=1e-12)
    cfg = M.StitchConfig(min_transition=2, max_transition=10)
    assert M.transition_length(pose, pose, cfg) == 2  # zero motion -> clamped to the minimum


def test_antipodal_quaternions_are_the_same_rotation():
    """q and -q describe one rotation: shortest-arc SLERP stays on it (no 360-degree spin)."""
    aa = np.array([0.0, 0.0, 2.5])
    aa_equiv = -aa / np.linalg.norm(aa) * (2 * math.pi - np.linalg.norm(aa))  # same rotation
    pa, pb = {"jaw_pose": aa}, {"jaw_pose": aa_equiv}
    assert M.max_angle_deg(pa, pb) < 1e-6
    out = M.slerp_blocks(pa, pb, np.linspace(0, 1, 11))["jaw_pose"]
    d = (Rotation.from_rotvec(out) * Rotation.from_rotvec(aa).inv()).magnitude()
    assert d.max() < 1e-6
    # explicitly antipodal quaternions through roma
    q = roma.rotvec_to_unitquat(torch.tensor([[0.4, -0.3, 0.2]], dtype=torch.float64))
    mid = roma.unitquat_slerp(q, -q, torch.tensor([0.5], dtype=torch.float64))
    assert roma.unitquat_geodesic_distance(mid[0], q).max() < 1e-6


def test_180_degree_difference_is_finite_and_reaches_the_end():
    a = {"body_pose": _body(0, [0.0, 0.0, 0.0])}
    b = {"body_pose": _body(0, [math.pi, 0.0, 0.0])}
    assert M.max_angle_deg(a, b) == pytest.approx(180.0, abs=1e-6)
    steps = np.linspace(0, 1, 21)
    out = M.slerp_blocks(a, b, steps)["body_pose"][:, :3]
    assert np.isfinite(out).all()
    ang = np.linalg.norm(out, axis=1)
    np.testing.assert_allclose(ang, steps * math.pi, atol=1e-9)  # constant speed along one axis
    assert Rotation.from_rotvec(out[-1]).magnitude() == pytest.approx(math.pi)


def test_transition_length_adaptive_and_clamped():
    cfg = M.StitchConfig(deg_per_frame=5.0, min_transition=3, max_transition=12)
    base = {"body_pose": _body(15, [0, 0, 0])}
    small = {"body_pose": _body(15, [math.radians(20), 0, 0])}
    medium = {"body_pose": _body(15, [math.radians(42), 0, 0])}
    huge = {"body_pose": _body(15, [math.radians(170), 0, 0])}
    assert M.transition_length(base, small, cfg) == 4
    assert M.transition_length(base, medium, cfg) == 9
    assert M.transition_length(base, huge, cfg) == 12
    assert M.transition_length(base, base, cfg) == 3
    # the largest joint difference decides, in any block
    hands = dict(base, right_hand_pose=np.r_[np.zeros(42), 0, 0, math.radians(30)])
    assert M.transition_length(base | {"right_hand_pose": np.zeros(45)}, hands, cfg) == 6
    with pytest.raises(ValueError):
        M.StitchConfig(min_transition=5, max_transition=2)


def test_ease_in_out_time_warp():
    s = np.linspace(0, 1, 101)
    w = M.ease_in_out(s)
    assert w[0] == 0 and w[-1] == 1 and np.all(np.diff(w) >= 0)
    assert np.diff(w)[0] < np.diff(s)[0] / 10  # slow start
    a, b = {"expression": np.zeros(10)}, {"expression": np.ones(10)}
    frames = M.transition(a, b, M.StitchConfig(min_transition=9, max_transition=9))
    e = frames["expression"][:, 0]
    np.testing.assert_allclose(e, M.ease_in_out(np.arange(1, 10) / 10))  # linear after the warp


def test_sequence_labels_holds_and_held_globals():
    a = _clip("HELLO", _body(15, [0.5, 0, 0]), n=4, expr=np.ones(10),
              global_orient=np.tile([0, 0.2, 0], (4, 1)), transl=np.tile([0, 0, 1.0], (4, 1)))
    b = _clip("YOU", _body(15, [-0.5, 0, 0]), n=5,
              global_orient=np.tile([0, -0.2, 0], (5, 1)), transl=np.tile([0, 0, 3.0], (5, 1)))
    cfg = M.StitchConfig(deg_per_frame=10.0, min_transition=2, max_transition=20,
                         hold_start=1, hold_end=2)
    out = M.stitch_clips([a, b], cfg, betas=np.arange(10))
    labels = list(out["label"])
    n_tr = M.transition_length({"body_pose": a.poses["body_pose"][-1]},
                               {"body_pose": b.poses["body_pose"][0]}, cfg)
    assert n_tr == 6  # 57.3 degrees / 10
    assert labels == ["HELLO"] * (1 + 4 + 2) + ["transition"] * n_tr + ["YOU"] * (1 + 5 + 2)
    T = len(labels)
    for block, k in M.FRAME_BLOCKS.items():
        assert out[block].shape == (T, k)
    # averaged over every frame of every clip (4 frames at z=1, 5 at z=3) and held
    np.testing.assert_allclose(out["transl"], np.tile([0, 0, 19 / 9], (T, 1)), atol=1e-6)
    go = Rotation.from_rotvec(out["global_orient"])
    assert go.magnitude().max() < 0.03  # mean of +-0.2 rad (weighted 4:5) is ~-0.02
    np.testing.assert_array_equal(out["betas"], np.tile(np.arange(10), (T, 1)))
    # transitions only use the last pose of a and the first of b: monotone in between
    tr = out["body_pose"][np.array(labels) == "transition", 45]
    assert np.all(np.diff(tr) < 0) and tr[0] < 0.5 and tr[-1] > -0.5


def test_letters_use_letter_holds():
    cfg = M.StitchConfig(hold_start=3, hold_end=3, letter_hold=1, min_transition=1,
                         max_transition=1)
    seq = [_clip("A", _body(0, [0.1, 0, 0]), "letter", 2), _clip("B", _body(0, [0.2, 0, 0]),
                                                                 "letter", 2)]
    labels = list(M.stitch_clips(seq, cfg)["label"])
    assert labels == ["A"] * (3 + 2 + 1) + ["transition"] + ["B"] * (2 + 3)


def test_empty_sequence_and_bad_inputs():
    out = M.stitch_clips([])
    assert out["body_pose"].shape == (0, 63) and len(out["label"]) == 0
    clip = _clip("X", np.zeros(63))
    mano = GlossClip("Y", ("y",), "sign", 25.0, "mano", dict(clip.poses))
    with pytest.raises(ValueError, match="hand_mean"):
        list(M.stitch_frames([clip, mano]))
    with pytest.raises(ValueError, match="fps"):
        list(M.stitch_frames([clip, _clip("Z", np.zeros(63), fps=30.0)], fps=25.0))


def _peak_memory(clips, cfg):
    tracemalloc.start()
    n = 0
    for _ in M.stitch_frames(clips, cfg):
        n += 1
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return n, peak


def test_long_sequence_streams_with_flat_memory(gloss_library):
    names = ["HELLO", "ME", "SCHOOL", "GO", "NOT", "A", "B", "C", "WHERE"]
    short = [gloss_library[g] for g in names * 2]
    long = [gloss_library[g] for g in names * 20]
    cfg = M.StitchConfig()
    _peak_memory(short[:3], cfg)  # warm caches
    n_short, peak_short = _peak_memory(short, cfg)
    n_long, peak_long = _peak_memory(long, cfg)
    assert n_long > 8 * n_short
    # A stream holds a few frames whatever the length; holding every frame of the long
    # sequence takes megabytes. The slack covers what the interpreter allocates on its own
    # (caches, arenas), which depends on the tests that ran before in the same worker.
    assert peak_long < 2 * peak_short + 500_000, (peak_short, peak_long)


def test_write_stitched_table_streams_to_parquet(tmp_path, gloss_library):
    from signsplat.io.tables import read_table

    clips = [gloss_library[g] for g in ("HELLO", "FRIEND", "E")]
    frames = M.stitch_frames(clips, M.StitchConfig())
    path = tmp_path / "stitched.parquet"
    n = M.write_stitched_table(frames, path, scene="demo", chunk=16)
    df = read_table(path, "smplx_params")
    assert len(df) == n and df.frame.tolist() == list(range(n))
    assert df.attrs["hand_mean"] == "flat"
    ref = M.stitch_clips(clips, M.StitchConfig())
    np.testing.assert_array_equal(np.stack(df.body_pose), ref["body_pose"])
    assert set(df.label) == {"HELLO", "FRIEND", "E", "transition"}
    assert M.write_stitched_table(iter(()), tmp_path / "empty.parquet", "x") == 0
    assert len(read_table(tmp_path / "empty.parquet", "smplx_params")) == 0


def test_zero_length_transitions_are_allowed():
    a = _clip("A", _body(0, [0.5, 0, 0]))
    b = _clip("B", _body(0, [-0.5, 0, 0]))
    cfg = M.StitchConfig(min_transition=0, max_transition=0, hold_start=0, hold_end=0)
    out = M.stitch_clips([a, b], cfg)
    assert list(out["label"]) == ["A"] * 3 + ["B"] * 3
    assert M.slerp_blocks({"body_pose": np.zeros(63)}, {"body_pose": np.ones(63)},
                          np.zeros(0))["body_pose"].shape == (0, 63)
