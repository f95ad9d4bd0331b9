"""Import of user gloss clips and hand-mean conventions."""

import numpy as np
import pandas as pd
import pytest

from signsplat.errors import InputError
from signsplat.motion import clips as C
from signsplat.motion import stitching as M
from signsplat.motion.clips import GlossClip, load_gloss_library
from signsplat.stitch import library as L


def _means():
    rng = np.random.default_rng(0)
    return {"left": rng.normal(0, 0.2, 45), "right": rng.normal(0, 0.2, 45)}


def test_mano_flat_round_trip():
    means = _means()
    pose = np.random.default_rng(1).normal(0, 0.3, (7, 45)).astype(np.float32)
    flat = L.convert_hand_pose(pose, "mano", "flat", means["left"])
    np.testing.assert_allclose(flat, pose + means["left"], atol=1e-6)
    back = L.convert_hand_pose(flat, "flat", "mano", means["left"])
    np.testing.assert_allclose(back, pose, atol=1e-6)
    np.testing.assert_array_equal(L.convert_hand_pose(pose, "flat", "flat", None), pose)
    with pytest.raises(ValueError, match="MANO mean"):
        L.convert_hand_pose(pose, "mano", "flat", None)
    with pytest.raises(ValueError):
        L.convert_hand_pose(pose, "mano", "weird", means["left"])


def test_hands_mean_from_model_arrays():
    arrays = {"hands_meanl": np.arange(45.0), "hands_meanr": -np.arange(45.0)}
    m = L.hands_mean(arrays)
    assert m["left"][3] == 3 and m["right"][3] == -3


def _signavatars(n, seed=0):
    rng = np.random.default_rng(seed)
    arr = rng.normal(0, 0.2, (n, L.SIGNAVATARS_WIDTH))
    return arr


def test_import_signavatars_cuts_clips_and_keeps_provenance(tmp_path):
    arr = _signavatars(30)
    np.save(tmp_path / "seq.npy", arr)
    bounds = [("hello", 0, 10, "hello;hi"), ("bye", 12, 30, "bye")]
    clips = L.import_signavatars(tmp_path / "seq.npy", bounds, fps=30.0, hand_mean="mano",
                                 source="my studio", licence="CC-BY-4.0")
    assert set(clips) == {"HELLO", "BYE"}
    c = clips["BYE"]
    assert c.num_frames == 18 and c.fps == 30.0 and c.hand_mean == "mano"
    assert c.source == "my studio" and c.licence == "CC-BY-4.0"
    assert clips["HELLO"].words == ("hello", "hi")
    np.testing.assert_allclose(c.poses["global_orient"], arr[12:30, 0:3], atol=1e-6)
    np.testing.assert_allclose(c.poses["left_hand_pose"], arr[12:30, 66:111], atol=1e-6)
    np.testing.assert_allclose(c.poses["right_hand_pose"], arr[12:30, 111:156], atol=1e-6)
    np.testing.assert_allclose(c.poses["jaw_pose"], arr[12:30, 156:159], atol=1e-6)
    np.testing.assert_allclose(c.poses["betas"], arr[12:30, 159:169], atol=1e-6)
    np.testing.assert_allclose(c.poses["expression"], arr[12:30, 169:179], atol=1e-6)
    np.testing.assert_allclose(c.poses["transl"], arr[12:30, 179:182], atol=1e-6)
    with pytest.raises(InputError, match="182"):
        L.import_signavatars(arr[:, :100], bounds, 30.0, "flat", "x", "y")
    with pytest.raises(InputError, match="ends at frame"):
        L.import_signavatars(arr, [("x", 0, 99)], 30.0, "flat", "x", "y")
    with pytest.raises(InputError, match="start < end"):
        L.import_signavatars(arr, [("x", 5, 5)], 30.0, "flat", "x", "y")


def test_mano_clips_are_offset_by_the_mean_exactly_once():
    means = _means()
    arr = _signavatars(20)
    clips = L.import_signavatars(arr, [("A1", 0, 10), ("B1", 10, 20)], 25.0, "mano", "s", "l")
    merged = L.merge_libraries(clips, means=means)
    assert all(c.hand_mean == "flat" for c in merged.values())
    twice = L.merge_libraries(merged, means=means)  # converting again changes nothing
    np.testing.assert_array_equal(twice["A1"].poses["left_hand_pose"],
                                  merged["A1"].poses["left_hand_pose"])
    out = M.stitch_clips([merged["A1"], merged["B1"]])
    np.testing.assert_allclose(out["left_hand_pose"][2], arr[0, 66:111] + means["left"],
                               atol=1e-5)  # first frame after the start hold
    with pytest.raises(ValueError, match="MANO mean"):
        L.merge_libraries(clips)


def test_import_fitted_table_and_write_library(tmp_path):
    n = 12
    rng = np.random.default_rng(2)
    df = pd.DataFrame({
        "scene": ["fit"] * n, "frame": np.arange(n, dtype=np.int32)[::-1],
        **{b: list(rng.normal(0, 0.1, (n, k)).astype(np.float32)) for b, k in
           [("betas", 10), ("expression", 10), ("global_orient", 3), ("body_pose", 63),
            ("jaw_pose", 3), ("leye_pose", 3), ("reye_pose", 3), ("left_hand_pose", 45),
            ("right_hand_pose", 45), ("transl", 3)]},
    })
    df.attrs["hand_mean"] = "flat"
    bounds = pd.DataFrame({"gloss": ["go", "come"], "start": [0, 6], "end": [6, 12]})
    clips = L.import_fitted(df, bounds, fps=25.0, source="fit of video.mp4", licence="own")
    order = df.sort_values("frame")
    np.testing.assert_allclose(clips["COME"].poses["body_pose"],
                               np.stack(order.body_pose.iloc[6:12]), atol=1e-7)
    path = C.write_library(clips.values(), tmp_path / "imported.parquet")
    back = load_gloss_library(path)
    assert back["GO"].source == "fit of video.mp4" and back["GO"].num_frames == 6
    np.testing.assert_allclose(back["GO"].poses["transl"], clips["GO"].poses["transl"])


def test_stitching_imported_with_synthetic(gloss_library):
    arr = _signavatars(10)
    user = L.import_signavatars(arr, [("custom", 0, 10)], 25.0, "flat", "s", "l")
    lib = L.merge_libraries(gloss_library, user)
    out = M.stitch_clips([lib["HELLO"], lib["CUSTOM"]])
    assert np.isfinite(out["body_pose"]).all()
    assert set(out["label"]) == {"HELLO", "CUSTOM", "transition"}
    assert isinstance(lib["HELLO"], GlossClip)


def test_imported_betas_are_averaged_and_held():
    arr = _signavatars(20)
    clips = L.import_signavatars(arr, [("A1", 0, 8), ("B1", 8, 20)], 25.0, "flat", "s", "l")
    out = M.stitch_clips([clips["A1"], clips["B1"]])
    expected = arr[:, 159:169].mean(0)
    np.testing.assert_allclose(out["betas"], np.tile(expected, (len(out["betas"]), 1)),
                               atol=1e-5)
