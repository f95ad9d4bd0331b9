"""Loading and checking body-model files in the official SMPL-X .npz layout."""

from __future__ import annotations

import numpy as np
import pytest

from signsplat.body.model_file import (REQUIRED_KEYS, BodyModelFileError, load_model_arrays,
                                       split_shapedirs, write_model_file)
from signsplat.errors import InputError


def test_fake_official_file_loads(fake_path):
    arrays = load_model_arrays(fake_path)
    assert arrays["kintree_table"][0, 0] == -1  # 2**32-1 root normalised
    assert arrays["kintree_table"].dtype == np.int64
    assert arrays["f"].dtype == np.int64
    assert split_shapedirs(arrays) == (10, 10)
    assert "vt" in arrays  # optional keys kept


@pytest.mark.parametrize("key", ["posedirs", "J_regressor", "hands_meanl", "lmk_bary_coords"])
def test_missing_key_names_key_and_file(tmp_path, key, make_fake_arrays):
    arrays = make_fake_arrays()
    del arrays[key]
    path = tmp_path / "broken.npz"
    np.savez(path, **arrays)
    with pytest.raises(BodyModelFileError) as err:
        load_model_arrays(path)
    assert key in str(err.value) and str(path) in str(err.value)
    assert isinstance(err.value, InputError)


@pytest.mark.parametrize("key,bad,expected", [
    ("posedirs", lambda a: a[:, :, :480], "(330, 3, 486)"),
    ("weights", lambda a: a[:, :54], "(330, 55)"),
    ("J_regressor", lambda a: a[:, :-5], "(55, 330)"),
    ("v_template", lambda a: a[:, :2], "(330, 3)"),
    ("kintree_table", lambda a: a[:, :50], "(2, 55)"),
])
def test_wrong_shape_reports_expected_and_found(tmp_path, key, bad, expected, make_fake_arrays):
    arrays = make_fake_arrays()
    found = bad(arrays[key])
    arrays[key] = found
    path = tmp_path / "bad_shape.npz"
    np.savez(path, **arrays)
    with pytest.raises(BodyModelFileError) as err:
        load_model_arrays(path)
    msg = str(err.value)
    if key == "v_template":  # the first array fixes V; the template is checked against (V, 3)
        assert "'v_template'" in msg and "(330, 2)" in msg
    else:
        assert f"'{key}'" in msg and expected in msg and str(tuple(found.shape)) in msg


def test_out_of_range_faces(tmp_path, make_fake_arrays):
    arrays = make_fake_arrays()
    arrays["f"] = arrays["f"].astype(np.int64)
    arrays["f"][0, 0] = 10_000
    path = tmp_path / "faces.npz"
    np.savez(path, **arrays)
    with pytest.raises(BodyModelFileError, match="'f'"):
        load_model_arrays(path)


def test_pickled_arrays_are_refused(tmp_path, make_fake_arrays):
    arrays = make_fake_arrays()
    obj = np.empty(1, dtype=object)
    obj[0] = {"chumpy": True}
    arrays["shapedirs"] = obj
    path = tmp_path / "pickled.npz"
    np.savez(path, **arrays)
    with pytest.raises(BodyModelFileError, match="pickle"):
        load_model_arrays(path)


def test_not_found_and_not_npz(tmp_path):
    with pytest.raises(BodyModelFileError, match="not found"):
        load_model_arrays(tmp_path / "nope.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(BodyModelFileError, match="junk.npz"):
        load_model_arrays(junk)


def test_nan_values_are_refused(tmp_path, make_fake_arrays):
    arrays = make_fake_arrays()
    arrays["v_template"][3, 1] = np.nan
    path = tmp_path / "nan.npz"
    np.savez(path, **arrays)
    with pytest.raises(BodyModelFileError, match="v_template"):
        load_model_arrays(path)


@pytest.mark.parametrize("n,extra,expected", [
    (400, {}, (300, 100)), (20, {}, (10, 10)),
    (16, {"num_shape_dirs": np.array(12), "num_expression_dirs": np.array(4)}, (12, 4)),
])
def test_shapedirs_split(n, extra, expected):
    arrays = {"shapedirs": np.zeros((5, 3, n)), **extra}
    assert split_shapedirs(arrays) == expected


def test_write_model_file_round_trip(tmp_path, make_fake_arrays):
    arrays = make_fake_arrays()
    arrays["kintree_table"] = arrays["kintree_table"].astype(np.int64)
    arrays["kintree_table"][0, 0] = -1
    path = write_model_file(tmp_path / "sub" / "model.npz", arrays)
    raw = np.load(path)
    assert raw["kintree_table"][0, 0] == 2**32 - 1  # official convention on disk
    back = load_model_arrays(path)
    for key in REQUIRED_KEYS:
        np.testing.assert_array_equal(np.asarray(back[key], np.float64),
                                      np.asarray(arrays[key], np.float64))
    assert not list(path.parent.glob(".*tmp*"))  # atomic: no temporary file left


def test_optional_pickled_keys_are_skipped(tmp_path, make_fake_arrays):
    """Official SMPLX_*.npz files store joint2num/part2num as pickled dicts: not needed."""
    arrays = make_fake_arrays()
    d = np.empty((), dtype=object)
    d[()] = {"pelvis": 0}
    arrays["joint2num"] = d
    arrays["part2num"] = d
    path = tmp_path / "official_like.npz"
    np.savez(path, **arrays)
    loaded = load_model_arrays(path)
    assert "joint2num" not in loaded and "v_template" in loaded
