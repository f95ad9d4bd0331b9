"""Scene specs: schema errors, the camera rig and the composed motion."""

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from signsplat.config import ConfigError, load_scene, validate
from signsplat.io.tables import write_table
from signsplat.synth import scene as sc
from signsplat.synth.simulate import project

ROOT = Path(__file__).resolve().parents[2]


def spec(**over):
    base = {"cameras": {"count": 4}, "motion": {"glosses": ["HELLO"]}}
    base.update(over)
    return validate(base, "scene.schema.yaml", "test")


@pytest.mark.parametrize("name", sorted({"studio6", "single", "tiny"} | {
    p.stem for p in (ROOT / "config" / "scenes").glob("*.yaml")}))
def test_shipped_scenes_are_valid(name):
    s = load_scene(ROOT / "config" / "scenes" / f"{name}.yaml")
    assert s["name"] == name
    from signsplat.synth.effects import build_effects
    build_effects(s["effects"])  # effect names and options are valid too


@pytest.mark.parametrize("over, words", [
    ({"cameras": {"layout": "grid"}}, ["cameras.layout", "'arc'", "'ring'"]),
    ({"cameras": {"count": 0}}, ["cameras.count", ">= 1"]),
    ({"cameras": {"zoom": 2}}, ["cameras", "zoom", "fov_degrees"]),
    ({"render": {"supersample": 9}}, ["render.supersample", "<= 4"]),
    ({"fps": -1}, ["fps", "> 0"]),
    ({"effects": [3]}, ["effects.0"]),
])
def test_schema_errors_name_the_key_and_what_is_allowed(over, words):
    data = {"cameras": {}, "motion": {}}
    data.update(over)
    with pytest.raises(ConfigError) as err:
        validate(data, "scene.schema.yaml", "scene.yaml")
    for w in words:
        assert w in str(err.value), str(err.value)


def test_look_at_points_the_camera_at_the_target():
    eye, target = np.array([1.0, 1.5, 2.0]), np.array([0.0, 1.0, 0.0])
    R, t = sc.look_at(eye, target)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ eye + t, 0, atol=1e-12)
    pc = R @ target + t
    np.testing.assert_allclose(pc[:2], 0, atol=1e-12)
    assert pc[2] == pytest.approx(np.linalg.norm(target - eye))
    assert (R @ [0, 1, 0])[1] < 0  # world up is image up (camera y points down)


def test_arc_rig_geometry_and_intrinsics():
    s = spec(cameras={"count": 5, "arc_degrees": 120, "distance": 2.5, "height": 1.4,
                      "target": [0.0, 1.2, 0.1], "width": 320, "height_px": 240,
                      "fov_degrees": 30})
    rig = sc.camera_rig(s["cameras"])
    assert len(rig) == 5
    centres = np.array([c.center for c in rig])
    np.testing.assert_allclose(centres[:, 1], 1.4)
    np.testing.assert_allclose(np.hypot(centres[:, 0], centres[:, 2] - 0.1), 2.5)
    angles = np.degrees(np.arctan2(centres[:, 0], centres[:, 2] - 0.1))
    np.testing.assert_allclose(angles, [-60, -30, 0, 30, 60], atol=1e-9)
    for c in rig:
        assert c.K[0, 0] == c.K[1, 1] == pytest.approx(120 / np.tan(np.radians(15)))
        assert (c.K[0, 2], c.K[1, 2]) == (159.5, 119.5)
        uv, z = project(np.array([[0.0, 1.2, 0.1]]), c)
        np.testing.assert_allclose(uv[0], [159.5, 119.5], atol=1e-9)
    # the frontal camera sees the signer's left (+x) on the image right
    uv, _ = project(np.array([[0.3, 1.2, 0.1], [-0.3, 1.2, 0.1]]), rig[2])
    assert uv[0, 0] > 159.5 > uv[1, 0]


def test_ring_rig_and_single_camera():
    ring = sc.camera_rig(spec(cameras={"count": 4, "layout": "ring"})["cameras"])
    centres = np.array([c.center for c in ring])
    np.testing.assert_allclose(centres[:, [0, 2]], [[0, 2], [2, 0], [0, -2], [-2, 0]],
                               atol=1e-9)
    single = sc.camera_rig(spec(cameras={"count": 1, "arc_degrees": 150})["cameras"])
    np.testing.assert_allclose(single[0].center[[0, 2]], [0, 2], atol=1e-12)


def test_default_scenes_frame_the_signing_space():
    for name in ("studio6", "single"):
        s = load_scene(ROOT / "config" / "scenes" / f"{name}.yaml")
        cams = s["cameras"]
        # metres per pixel at the target distance (vertical)
        mpp = 2 * cams["distance"] * np.tan(np.radians(cams["fov_degrees"] / 2)) \
            / cams["height_px"]
        assert 0.003 <= mpp <= 0.005, (name, mpp)


def test_gloss_motion_is_stitched_with_holds_and_smooth_transitions(gloss_library_path):
    from signsplat.motion.clips import load_gloss_library

    lib = load_gloss_library(gloss_library_path)
    s = spec(motion={"glosses": ["HELLO", "BOOK"], "hold_frames": 2, "transition_frames": 4},
             signer={"betas": [0.3], "expression_scale": 0.5})
    m = sc.build_motion(s, gloss_library_path)
    hello, book = lib["HELLO"].poses, lib["BOOK"].poses
    T = len(m["body_pose"])
    n1, n2 = len(hello["body_pose"]), len(book["body_pose"])
    assert T >= n1 + n2 + 4 * 2 + 4
    # the first gloss is played as recorded after its start hold
    np.testing.assert_allclose(m["body_pose"][2:2 + n1], hello["body_pose"], atol=1e-5)
    np.testing.assert_allclose(m["body_pose"][:2], np.repeat(hello["body_pose"][:1], 2, 0),
                               atol=1e-5)
    np.testing.assert_allclose(m["right_hand_pose"][-2 - n2:-2], book["right_hand_pose"],
                               atol=1e-5)
    np.testing.assert_allclose(m["expression"][2:2 + n1], 0.5 * hello["expression"], atol=1e-5)
    # no jump from one gloss to the next: the transition spreads the change over frames
    for block in ("body_pose", "right_hand_pose"):
        jump = np.abs(hello[block][-1] - book[block][0]).max()
        clip_step = max(np.abs(np.diff(c[block], axis=0)).max() for c in (hello, book))
        step = np.abs(np.diff(m[block], axis=0)).max()
        assert step <= max(clip_step, 0.25 * jump) + 1e-6, block
    np.testing.assert_array_equal(m["global_orient"], 0)
    np.testing.assert_array_equal(m["transl"], 0)
    np.testing.assert_allclose(m["betas"], [[0.3] + [0] * 9] * T)
    with pytest.raises(sc.SceneError, match="NOPE"):
        sc.build_motion(spec(motion={"glosses": ["HELLO", "NOPE"]}), gloss_library_path)


def test_params_at_interpolates_between_frames():
    params = {"body_pose": np.zeros((3, 63), np.float32), "transl": np.zeros((3, 3), np.float32)}
    params["body_pose"][1, 0] = 0.4
    params["transl"][1] = [1.0, 0, 0]
    mid = sc.params_at(params, 0.5)
    assert mid["body_pose"].shape == (1, 63)
    assert mid["body_pose"][0, 0] == pytest.approx(0.2, abs=1e-6)
    assert mid["transl"][0, 0] == pytest.approx(0.5)
    np.testing.assert_array_equal(sc.params_at(params, 7.0)["transl"], params["transl"][2:3])


def test_build_motion_from_a_tracks_table(tmp_path):
    T = 7
    df = pd.DataFrame({
        "scene": ["x"] * T, "frame": np.arange(T, dtype=np.int32),
        "betas": [np.zeros(10, np.float32)] * T,
        "expression": [np.full(10, 0.1, np.float32)] * T,
        "global_orient": [np.zeros(3, np.float32)] * T,
        "body_pose": [np.full(63, i * 0.01, np.float32) for i in range(T)],
        "jaw_pose": [np.zeros(3, np.float32)] * T, "leye_pose": [np.zeros(3, np.float32)] * T,
        "reye_pose": [np.zeros(3, np.float32)] * T,
        "left_hand_pose": [np.zeros(45, np.float32)] * T,
        "right_hand_pose": [np.zeros(45, np.float32)] * T,
        "transl": [np.zeros(3, np.float32)] * T,
    })
    path = write_table(df, tmp_path / "tracks.parquet", "smplx_params")
    s = spec(motion={"tracks": str(path)}, max_frames=5,
             signer={"betas": [0.5, -0.5], "expression_scale": 2.0})
    m = sc.build_motion(s, None, num_betas=10, num_expression=10)
    assert {k: v.shape for k, v in m.items()} == {
        "betas": (5, 10), "expression": (5, 10), "global_orient": (5, 3), "body_pose": (5, 63),
        "jaw_pose": (5, 3), "leye_pose": (5, 3), "reye_pose": (5, 3),
        "left_hand_pose": (5, 45), "right_hand_pose": (5, 45), "transl": (5, 3)}
    np.testing.assert_allclose(m["betas"][:, :3], [[0.5, -0.5, 0]] * 5)
    np.testing.assert_allclose(m["expression"], 0.2, rtol=1e-6)
    np.testing.assert_allclose(m["body_pose"][:, 0], np.arange(5) * 0.01, rtol=1e-6)


def test_motion_needs_glosses_or_tracks():
    with pytest.raises(sc.SceneError, match="glosses"):
        sc.build_motion(spec(motion={}), None)


def test_gloss_motion_is_resampled_to_the_scene_frame_rate(gloss_library_path):
    base = spec(motion={"glosses": ["HELLO"], "hold_frames": 0, "transition_frames": 0})
    fast = spec(motion={"glosses": ["HELLO"], "hold_frames": 0, "transition_frames": 0},
                fps=50)
    m25 = sc.build_motion(base, gloss_library_path)
    m50 = sc.build_motion(fast, gloss_library_path)
    n25, n50 = len(m25["body_pose"]), len(m50["body_pose"])
    assert n50 == 2 * (n25 - 1) + 1  # same duration, twice the frames
    np.testing.assert_allclose(m50["body_pose"][::2], m25["body_pose"], atol=1e-5)


def test_even_azimuths_cover_the_arc_or_the_ring():
    az, gap = sc.even_azimuths(4, 120.0)
    np.testing.assert_allclose(az, [-60, -20, 20, 60])
    assert gap == 40.0
    az, gap = sc.even_azimuths(6, 360.0)  # a ring starts at the front, no camera twice
    np.testing.assert_allclose(az, [0, 60, 120, 180, 240, 300])
    assert gap == 60.0
    az, gap = sc.even_azimuths(1, 90.0)
    np.testing.assert_allclose(az, [0.0])
    assert np.isfinite(gap)
