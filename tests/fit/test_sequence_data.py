"""Gap filling, table reading/writing with errors naming the file, and the hand gimbal lock."""

import numpy as np
import pandas as pd
import pytest
import torch

from signsplat.body import hand_limits as hl
from signsplat.errors import InputError
from signsplat.fit import data as fit_data
from signsplat.fit import sequence
from signsplat.fit.bodyfit import FitParams
from signsplat.io.tables import write_table


def _params(T):
    rng = np.random.default_rng(0)
    return {"global_orient": rng.normal(0, 0.3, (T, 3)), "transl": rng.normal(0, 1, (T, 3)),
            "body_pose": rng.normal(0, 0.2, (T, 63)), "betas": np.ones((T, 10))}


def test_fill_gaps_interpolates_inside_and_holds_at_the_ends():
    p = _params(8)
    fitted = np.array([False, True, True, False, False, True, True, False])
    out, prov = sequence.fill_gaps(p, fitted)
    assert prov.tolist() == ["missing", "fitted", "fitted", "interpolated", "interpolated",
                             "fitted", "fitted", "missing"]
    assert np.allclose(out["transl"][3], p["transl"][2] + (p["transl"][5] - p["transl"][2]) / 3)
    assert np.allclose(out["global_orient"][0], p["global_orient"][1])
    assert np.allclose(out["body_pose"][7], p["body_pose"][6])
    assert all(np.isfinite(v).all() for v in out.values())
    # fitted frames untouched; slerp of a rotation stays between its ends
    assert np.allclose(out["global_orient"][1], p["global_orient"][1])
    with pytest.raises(ValueError):
        sequence.fill_gaps(p, np.zeros(8, bool))


def test_contiguous_triplets_break_at_frame_gaps():
    assert sequence.contiguous_triplets(np.array([0, 1, 2, 4, 5, 6])).tolist() == [True, False, False,
                                                                            True]


def _kp_df(rows):
    return pd.DataFrame(rows, columns=["scene", "view", "frame", "kp", "x", "y", "score"]).astype(
        {"view": "int32", "frame": "int32", "kp": "int16", "x": "float32", "y": "float32",
         "score": "float32"})


def test_read_keypoints_layout_and_missing_rows(tmp_path):
    path = tmp_path / "kp.parquet"
    write_table(_kp_df([("s", 0, 3, 5, 10.0, 20.0, 0.9), ("s", 1, 5, 132, 1.0, 2.0, np.nan)]),
                path, "keypoints")
    obs, frames = fit_data.read_keypoints(path, 2)
    assert obs.shape == (2, 3, 133, 3) and frames.tolist() == [3, 4, 5]
    assert obs[0, 0, 5].tolist() == pytest.approx([10, 20, 0.9])
    assert (obs[:, 1, :, 2] == 0).all()  # frame 4 has no person: all unknown
    with pytest.raises(InputError, match="kp.parquet"):
        fit_data.read_keypoints(path, 1)  # view 1 beyond a 1-camera rig


@pytest.mark.parametrize("bad", ["kp_range", "duplicate", "missing_column", "not_parquet"])
def test_bad_keypoint_files_name_the_file(tmp_path, bad):
    path = tmp_path / f"{bad}.parquet"
    rows = [("s", 0, 0, 1, 1.0, 1.0, 1.0)]
    if bad == "kp_range":
        write_table(_kp_df([("s", 0, 0, 140, 1.0, 1.0, 1.0)]), path, "keypoints")
    elif bad == "duplicate":
        write_table(_kp_df(rows * 2), path, "keypoints")
    elif bad == "missing_column":
        _kp_df(rows).drop(columns=["score"]).to_parquet(path)
    else:
        path.write_text("garbage")
    with pytest.raises(InputError, match=f"{bad}.parquet"):
        fit_data.read_keypoints(path, 1)


def test_missing_file_named(tmp_path):
    with pytest.raises(InputError, match="nope.parquet"):
        fit_data.read_rig(tmp_path / "nope.parquet")


def test_smplx_table_refuses_nan():
    p = {n: np.zeros((2, k)) for n, k in [("betas", 10), ("expression", 10), ("global_orient", 3),
                                          ("body_pose", 63), ("jaw_pose", 3), ("leye_pose", 3),
                                          ("reye_pose", 3), ("left_hand_pose", 45),
                                          ("right_hand_pose", 45), ("transl", 3)]}
    df = fit_data.smplx_table(p, "s", np.arange(2), np.array(["fitted"] * 2), np.array([5, 6]))
    assert df["num_keypoints"].tolist() == [5, 6]
    p["transl"][1, 0] = np.nan
    with pytest.raises(ValueError, match="transl"):
        fit_data.smplx_table(p, "s", np.arange(2), np.array(["fitted"] * 2), np.array([5, 6]))


@pytest.mark.parametrize("angle", [np.pi / 2, -np.pi / 2])
def test_gimbal_lock_hand_pose_gives_finite_parameters_and_gradients(angle):
    """A hand pose whose Euler middle angle (abduction) is +-90 deg: the conversions used to
    initialise the fit stay finite, and so do the gradients of the pose w.r.t. the free
    parameters and of the Euler->axis-angle map at the singularity itself."""
    lim = hl.hand_limits("left")
    eul = torch.zeros(1, 15, 3, dtype=torch.float64)
    eul[..., 1] = angle  # ZYX: flexion, abduction (middle) = +-90 deg, twist
    eul[..., 0] = 0.3
    eul.requires_grad_(True)
    aa = hl.euler_to_axis_angle(eul, hl.EULER_ORDER)
    back = hl.axis_angle_to_euler(aa, hl.EULER_ORDER)
    back.sum().backward()
    assert torch.isfinite(eul.grad).all()
    pose = aa.detach().reshape(1, 45).repeat(3, 1)
    params = FitParams(3, 10, 10, dtype=torch.float64, init={"left_hand_pose": pose.numpy()})
    assert torch.isfinite(params.left_free).all()
    out, _ = params.hand_poses()
    (out ** 2).sum().backward()
    assert torch.isfinite(params.left_free.grad).all()
    assert hl.within_limits(out.detach().numpy(), "left").all()


@pytest.mark.parametrize("frames", [slice(2, 5), torch.tensor([1, 4])])
def test_a_chunks_hand_poses_are_the_sequences_for_those_frames_and_move_only_them(frames):
    """The fit's chunks convert the hands of their own frames only, both hands in one call:
    the same poses and anatomical angles as each hand's of the whole sequence at those frames,
    gradient on those frames alone."""
    rng = np.random.default_rng(1)
    params = FitParams(6, 10, 10, dtype=torch.float64)
    with torch.no_grad():
        for side in ("left", "right"):
            shape = (6, params.limits[side].num_free)
            getattr(params, f"{side}_free").copy_(torch.as_tensor(rng.normal(0, 1, shape)))
    picked = np.arange(6)[frames if isinstance(frames, slice) else frames.numpy()]
    for side in ("left", "right"):
        assert torch.allclose(params.hand_anatomical(side, frames),
                              params.hand_anatomical(side).detach()[frames], atol=1e-12)
    inputs = params.model_inputs(frames)  # both hands converted in one call
    for side in ("left", "right"):
        own = hl.free_to_hand_pose(getattr(params, f"{side}_free").detach(),
                                   params.limits[side])  # this hand alone, every frame
        assert torch.allclose(inputs[f"{side}_hand_pose"], own[frames], atol=1e-12)
    (inputs["left_hand_pose"].sum() + inputs["right_hand_pose"].sum()).backward()
    for side in ("left", "right"):
        moved = getattr(params, f"{side}_free").grad.abs().sum(1).numpy() > 0
        assert np.flatnonzero(moved).tolist() == picked.tolist()
