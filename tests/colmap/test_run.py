"""COLMAP runs on rendered rigs (signsplat.colmap.run, compare rows): success, recorded failure."""

import json
from pathlib import Path

import numpy as np
import pytest

from signsplat.colmap.compare import (MAPPER_KEYS, GroundTruth, RunSpec, colmap_row,
                                      image_inputs)
from signsplat.colmap.run import ColmapOptions, run_colmap
from signsplat.config import schema_defaults
from signsplat.io.tables import read_table

# the workflow's SIFT and mapper thresholds (the colmap schema's defaults)
MAPPER = {k: v for k, v in schema_defaults("stages/colmap.schema.yaml").items()
          if k in MAPPER_KEYS}


def _inputs(folder: Path, frame: int = 0):
    frames = read_table(folder / "frames.parquet", "frames")
    gt = GroundTruth(read_table(folder / "cameras.parquet", "cameras"))
    views = sorted(frames["view"].unique())
    return image_inputs(frames, folder, gt, [(int(v), frame) for v in views]), gt


def _run(folder: Path, known: bool = True, **kw):
    images, gt = _inputs(folder)
    result = run_colmap(images, ColmapOptions(**{**MAPPER, **kw}, known_intrinsics=known,
                                                    num_threads=2))
    row, al = colmap_row(folder.name, RunSpec("colmap_static_frame_0", 0, ()), "test", known,
                         images, result, gt)
    return result, row, al


@pytest.mark.parametrize("known, isolate", [(True, False), (False, True)])
def test_textured_rig_registers_and_aligns(textured_rig, known, isolate):
    """Both settings; one in this process, one in a spawned child (same code path otherwise)."""
    result, row, al = _run(textured_rig, known, isolate=isolate)
    assert result.status == "ok"
    assert row["registered"] >= 7 and row["images"] == 8
    assert row["views_registered"] == row["registered"]
    assert result.num_initial_pairs >= 1
    assert row["points3d"] > 100
    assert row["reproj_error_px"] < 1.0
    assert row["rot_error_deg_max"] < 1.0
    assert row["centre_error_m_max"] < 0.05
    assert row["alignment"] == "umeyama"
    assert row["seconds"] > 0 and row["cpu_seconds"] > 0
    if known:  # fixed intrinsics come back unchanged (pixel-centre convention round trip)
        images, _ = _inputs(textured_rig)
        K = images[0].K
        fx, fy, cx, cy = result.intrinsics[images[0].name]
        np.testing.assert_allclose([fx, fy, cx, cy], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
        assert np.isnan(row["focal_error_pct"])
    else:
        assert row["focal_error_pct"] < 5.0
    # the aligned points lie inside the room (x in [-2, 2], y in [0, 2.5], z in [-1.5, 1.5])
    pts = al.similarity.apply(result.points)
    inside = ((np.abs(pts[:, 0]) < 2.1) & (pts[:, 1] > -0.1) & (pts[:, 1] < 2.6)
              & (np.abs(pts[:, 2]) < 1.6))
    assert inside.mean() > 0.95


def test_textureless_rig_is_a_recorded_failure(flat_rig):
    result, row, al = _run(flat_rig)
    assert result.status.startswith("failed")
    assert row["registered"] < 2 and al is None
    assert np.isnan(row["rot_error_deg"]) and np.isnan(row["centre_error_m"])
    assert np.isnan(row["reproj_error_px"])
    assert np.isfinite(row["seconds"])


def test_nearly_coincident_cameras_do_not_initialise(coincident_rig):
    """Pure rotation: plenty of matches but no triangulation angle -> failure, recorded."""
    result, row, _ = _run(coincident_rig)
    assert result.num_features > 1000  # it is not for lack of texture
    assert result.status.startswith("failed") and row["registered"] < 2
    assert np.isnan(row["centre_error_m"])


def test_single_image_fails_without_running(textured_rig):
    images, _ = _inputs(textured_rig)
    result = run_colmap(images[:1], ColmapOptions(**MAPPER))
    assert result.status.startswith("failed") and result.registered == 0


def test_timeout_kills_the_child_and_is_recorded(textured_rig):
    result, row, _ = _run(textured_rig, timeout_seconds=0.05)
    assert result.status.startswith("failed: timeout")
    assert row["registered"] == 0 and row["seconds"] < 5.0


class _DiesWhenUnpickled:
    """Stands in for a C++ abort: the child process exits while loading its arguments."""

    def __reduce__(self):
        import os

        return (os._exit, (3,))


def test_a_dying_child_is_a_recorded_crash(textured_rig):
    images, _ = _inputs(textured_rig)
    result = run_colmap(images + [_DiesWhenUnpickled()], ColmapOptions(**MAPPER, num_threads=1))
    assert result.status.startswith("crashed") and "exit code 3" in result.status
    assert result.registered == 0 and result.num_images == 9


def test_settings_of_one_image_set_share_features_and_matches(textured_rig, tmp_path,
                                                              monkeypatch):
    """A run copies what an earlier run of the same images left in share_dir: the features
    (same max_num_features) and the matches (same cameras too); the results are those of a run
    that made its own, and the seconds include the copied steps' time."""
    import pycolmap

    images, _ = _inputs(textured_rig)
    calls = []
    for name in ("extract_features", "match_exhaustive"):
        real = getattr(pycolmap, name)
        monkeypatch.setattr(pycolmap, name,
                            lambda *a, _f=real, _n=name, **k: calls.append(_n) or _f(*a, **k))

    def run(known, share, **kw):
        options = ColmapOptions(**{**MAPPER, **kw}, known_intrinsics=known, num_threads=1,
                                isolate=False)
        return run_colmap(images, options, share_dir=share)

    share = tmp_path / "share"
    share.mkdir()
    first = run(True, share)
    assert calls == ["extract_features", "match_exhaustive"]
    relaxed = run(True, share, abs_pose_min_num_inliers=15)  # another mapper, same database
    assert calls == ["extract_features", "match_exhaustive"]
    estimated = run(False, share)  # other cameras: matched again on the same features
    assert calls == ["extract_features", "match_exhaustive", "match_exhaustive"]
    (made,) = share.glob("matches_*_known.json")  # what extraction and matching took
    assert first.seconds >= json.loads(made.read_text())["seconds"] > 0
    assert relaxed.seconds >= json.loads(made.read_text())["seconds"]

    for shared, own in ((relaxed, run(True, None, abs_pose_min_num_inliers=15)),
                        (estimated, run(False, None))):
        assert shared.status == own.status == "ok"
        assert shared.num_features == own.num_features
        assert shared.num_verified_pairs == own.num_verified_pairs
        assert sorted(shared.poses) == sorted(own.poses)
        np.testing.assert_allclose(shared.points, own.points)
