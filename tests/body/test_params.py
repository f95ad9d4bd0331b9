"""smplx_params table <-> tensors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from signsplat.body.joints import PARAM_BLOCKS
from signsplat.body.params import params_from_table, params_to_table
from signsplat.errors import InputError
from signsplat.io.tables import read_table, write_table


def test_round_trip_through_parquet(tmp_path):
    T = 7
    gen = torch.Generator().manual_seed(0)
    params = {name: torch.randn(T, size, generator=gen) for name, size in PARAM_BLOCKS}
    params["betas"] = params["betas"][:1]  # constant shape, repeated per frame
    frames = np.arange(10, 10 + T)
    df = params_to_table(params, "scene_a", frames)
    path = write_table(df, tmp_path / "smplx.parquet", "smplx_params",
                       metadata={"hand_mean": "flat", "body_model": "proxy"})
    back = read_table(path, "smplx_params")
    assert back.attrs["hand_mean"] == "flat"
    shuffled = back.iloc[::-1]  # rows come back sorted by frame
    got = params_from_table(shuffled)
    np.testing.assert_array_equal(got["frame"].numpy(), frames)
    for name, size in PARAM_BLOCKS:
        assert got[name].shape == (T, size)
        want = params[name].expand(T, -1) if name == "betas" else params[name]
        torch.testing.assert_close(got[name], want)


def test_missing_blocks_are_zeros_and_sizes_checked():
    df = params_to_table({"body_pose": np.ones((2, 63))}, "s")
    assert list(df["frame"]) == [0, 1] and (df["scene"] == "s").all()
    got = params_from_table(df, dtype=torch.float64)
    assert got["jaw_pose"].dtype == torch.float64 and not got["jaw_pose"].any()
    assert got["body_pose"].sum() == 126
    with pytest.raises(ValueError, match="body_pose"):
        params_to_table({"body_pose": np.ones((2, 60))}, "s")
    with pytest.raises(ValueError, match="frames"):
        params_to_table({"body_pose": np.ones((2, 63)), "transl": np.ones((3, 3))}, "s")


def test_bad_table_names_the_column():
    df = params_to_table({"body_pose": np.ones((2, 63))}, "s")
    df["left_hand_pose"] = [np.ones(44, np.float32)] * 2
    with pytest.raises(InputError, match="left_hand_pose"):
        params_from_table(df)
    good = params_to_table({"body_pose": np.ones((2, 63))}, "s")
    with pytest.raises(InputError, match="transl"):
        params_from_table(good.drop(columns=["transl"]))
