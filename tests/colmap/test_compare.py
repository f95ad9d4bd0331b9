"""The comparison table end to end through the CLI, and its planning / config helpers."""

import json

import numpy as np
import pandas as pd
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from signsplat.cli import main
from signsplat.colmap.compare import CompareConfig, evenly, plan_runs
from signsplat.config import ConfigError, validate
from signsplat.errors import InputError
from signsplat.io.tables import read_table, write_table

FAST = {"num_static_frames": 1, "sequence_frames": 2}


def _fake_fit(cameras: pd.DataFrame, noise_deg: float, seed: int = 0) -> pd.DataFrame:
    """Ground-truth cameras in another similarity frame, each rotated by ``noise_deg``."""
    rng = np.random.default_rng(seed)
    A = Rotation.random(random_state=seed).as_matrix()
    s, b = 0.5, np.array([0.3, -1.0, 2.0])
    rows = []
    for r in cameras.itertuples(index=False):
        R = np.asarray(r.R).reshape(3, 3)
        t = np.asarray(r.t)
        R_est, t_est = R @ A, (R @ b + t) / s  # same camera, world x_gt = s A x_est + b
        axis = rng.normal(size=3)
        d = Rotation.from_rotvec(np.radians(noise_deg) * axis / np.linalg.norm(axis)).as_matrix()
        R_est, t_est = d @ R_est, d @ t_est  # rotate about the camera centre
        rows.append(r._asdict() | {"R": R_est.ravel().tolist(), "t": t_est.ravel().tolist()})
    return pd.DataFrame(rows).astype({"view": "int32", "frame": "int32"})


def test_cli_writes_table_plys_and_fit_row(textured_rig, tmp_path, capsys):
    cams = read_table(textured_rig / "cameras.parquet", "cameras")
    fit_df = _fake_fit(cams, 0.5)
    fit_df["fit_status"] = ["no_detections"] + ["pnp"] * (len(fit_df) - 1)
    fit = write_table(fit_df, tmp_path / "cameras_fit.parquet", "cameras",
                      metadata={"mode": "multiview", "keypoints": "ground_truth"})
    pd.DataFrame({  # the fitting stage's long layout (table fit_eval)
        "scene": "textured", "mode": "multiview", "keypoints": "ground_truth",
        "metric": ["reprojection", "reprojection", "camera_rotation", "seconds", "cpu_seconds"],
        "part": ["all", "left_hand", "cameras", "all", "all"],
        "value": [1.5, 3.0, 0.4, 12.5, 20.0], "unit": ["px", "px", "deg", "s", "s"],
        "seconds_total": 12.5,
        "seconds_per_frame": 6.25}).to_parquet(tmp_path / "fit_eval.parquet")
    out = tmp_path / "colmap" / "colmap_compare.parquet"
    code = main(["colmap-compare", "--frames", str(textured_rig / "frames.parquet"),
                 "--cameras", str(textured_rig / "cameras.parquet"), "--fit-cameras", str(fit),
                 "--fit-eval", str(tmp_path / "fit_eval.parquet"), "--out", str(out),
                 "--threads", "2",
                 "--config-json", json.dumps(FAST | {"settings": [{"name": "known_intrinsics"}]})])
    assert code == 0
    df = read_table(out, "colmap_compare")
    assert list(df["method"]) == ["colmap_static_frame_0", "colmap_sequence", "smplx_camera_solve"]
    assert df["seconds"].notna().all()
    colmap = df[df["method"] != "smplx_camera_solve"]
    assert (colmap["status"] == "ok").all()
    assert list(colmap["images"]) == [8, 16] and (colmap["registered"] >= 7).all()
    assert (colmap["rot_error_deg"] < 1.0).all()
    fit_row = df[df["method"] == "smplx_camera_solve"].iloc[0]
    assert fit_row["registered"] == 7 and pd.isna(fit_row["points3d"])  # one without pose
    assert fit_row["setting"] == "multiview_ground_truth"
    assert fit_row["status"].startswith("ok (1 camera")
    assert fit_row["rot_error_deg"] == pytest.approx(0.5, abs=0.15)  # the injected noise
    assert fit_row["seconds"] == 12.5 and fit_row["reproj_error_px"] == 1.5
    assert fit_row["cpu_seconds"] == 20.0
    assert (colmap["cpu_seconds"] > 0).all()
    assert fit_row["focal_error_pct"] == pytest.approx(0.0)
    for rel in colmap["ply"]:
        cloud = trimesh.load(out.parent / rel)
        assert len(cloud.vertices) > 100
    best = trimesh.load(out.parent / "points.ply")
    assert len(best.vertices) == colmap["points3d"].max()
    # world frame: nearly all points inside the 4 m wide room (a few SfM outliers may not be)
    assert (np.abs(best.vertices[:, 0]) < 2.1).mean() > 0.95
    printed = capsys.readouterr().out
    assert "smplx_camera_solve" in printed and "seconds" in printed


def test_cli_textureless_scene_records_failures(flat_rig, tmp_path):
    out = tmp_path / "colmap_compare.parquet"
    code = main(["colmap-compare", "--frames", str(flat_rig / "frames.parquet"),
                 "--cameras", str(flat_rig / "cameras.parquet"), "--out", str(out),
                 "--fit-eval", str(tmp_path / "absent.parquet"),
                 "--config-json", json.dumps(FAST)])
    assert code == 0
    df = read_table(out, "colmap_compare")
    assert len(df) == 6 and set(df["setting"]) == {"known_intrinsics", "estimated_intrinsics",
                                                   "known_intrinsics_relaxed"}
    assert df["status"].str.startswith("failed").all()
    assert (df["registered"] < 2).all() and df["rot_error_deg"].isna().all()
    assert df["seconds"].notna().all() and (df["ply"] == "").all()
    assert b"element vertex 0\n" in (tmp_path / "points.ply").read_bytes()


def test_cli_missing_fit_cameras_names_the_file(textured_rig, tmp_path, capsys):
    code = main(["colmap-compare", "--frames", str(textured_rig / "frames.parquet"),
                 "--cameras", str(textured_rig / "cameras.parquet"),
                 "--fit-cameras", str(tmp_path / "nope.parquet"),
                 "--out", str(tmp_path / "x.parquet")])
    assert code == 2 and "nope.parquet" in capsys.readouterr().err


def test_plan_runs_static_steps_and_sequence():
    frames = pd.DataFrame({"view": np.repeat(np.arange(3), 10), "frame": np.tile(np.arange(10), 3)})
    runs = plan_runs(frames, CompareConfig.from_dict({"num_static_frames": 3,
                                                      "sequence_frames": 4}))
    assert [r.method for r in runs] == ["colmap_static_frame_0", "colmap_static_frame_4",
                                        "colmap_static_frame_9", "colmap_sequence"]
    assert runs[1].keys == ((0, 4), (1, 4), (2, 4))
    assert len(runs[-1].keys) == 12 and runs[-1].frame == -1
    assert [r.method for r in plan_runs(frames, CompareConfig.from_dict(
        {"static_frames": [5], "sequence_frames": 0}))] == ["colmap_static_frame_5"]
    assert evenly(list(range(5)), 10) == list(range(5))


def test_schema_defaults_build_the_config():
    cfg = CompareConfig.from_dict({})
    assert cfg == CompareConfig.from_dict(validate({}, "stages/colmap.schema.yaml"))
    assert [s.name for s in cfg.settings] == ["known_intrinsics", "estimated_intrinsics",
                                              "known_intrinsics_relaxed"]
    with pytest.raises(ConfigError, match="bogus"):
        CompareConfig.from_dict({"bogus": 1})
    with pytest.raises(InputError, match="unique"):
        CompareConfig.from_dict({"settings": [{"name": "a"}, {"name": "a"}]})


def test_setting_overrides_apply_on_top_of_the_base():
    cfg = CompareConfig.from_dict(validate(
        {"init_min_num_inliers": 50, "settings": [
            {"name": "plain"}, {"name": "loose", "known_intrinsics": False,
                                "init_min_num_inliers": 10}]},
        "stages/colmap.schema.yaml"))
    plain, loose = (cfg.options(st, threads=1) for st in cfg.settings)
    assert plain.init_min_num_inliers == 50 and plain.known_intrinsics
    assert loose.init_min_num_inliers == 10 and not loose.known_intrinsics
    assert loose.min_model_size == plain.min_model_size == 10


def test_cli_rejects_a_bad_config_naming_the_key(textured_rig, tmp_path, capsys):
    code = main(["colmap-compare", "--frames", str(textured_rig / "frames.parquet"),
                 "--cameras", str(textured_rig / "cameras.parquet"),
                 "--out", str(tmp_path / "x.parquet"),
                 "--config-json", json.dumps({"sequence_frames": -1})])
    assert code == 2 and "sequence_frames" in capsys.readouterr().err


def test_fit_row_without_fit_eval_says_seconds_unknown(textured_rig):
    from signsplat.colmap.compare import GroundTruth, fit_rows

    cams = read_table(textured_rig / "cameras.parquet", "cameras")
    (row,) = fit_rows("textured", _fake_fit(cams, 0.0), GroundTruth(cams), None)
    assert row["registered"] == 8 and row["rot_error_deg_max"] < 1e-6
    assert row["centre_error_m_max"] < 1e-9 and np.isnan(row["seconds"])
    assert "seconds unknown" in row["status"]


def test_module_entry_point_runs_isolated_children(flat_rig, tmp_path):
    """`python -m signsplat colmap-compare` (as the workflow calls it) with spawned children."""
    import subprocess
    import sys

    out = tmp_path / "t.parquet"
    cfg = {"num_static_frames": 1, "sequence_frames": 0, "settings": [{"name": "k"}]}
    proc = subprocess.run(
        [sys.executable, "-m", "signsplat", "colmap-compare", "--frames",
         str(flat_rig / "frames.parquet"), "--cameras", str(flat_rig / "cameras.parquet"),
         "--out", str(out), "--config-json", json.dumps(cfg)],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    df = read_table(out, "colmap_compare")
    assert len(df) == 1 and df["status"].iloc[0].startswith("failed")
    assert "colmap_static_frame_0" in proc.stdout  # the table is printed at the end
    assert "Elapsed time" in proc.stderr or "SIFT" in proc.stderr  # pycolmap's log is kept


def test_ground_truth_without_a_camera_names_the_file(textured_rig):
    from signsplat.colmap.compare import GroundTruth

    cams = read_table(textured_rig / "cameras.parquet", "cameras")
    gt = GroundTruth(cams[cams["view"] != 3], "cams.parquet")
    with pytest.raises(InputError, match="cams.parquet: no camera for view 3"):
        gt.pose(3, 0)
    np.testing.assert_allclose(gt.pose(2, 17)[1], cams[cams["view"] == 2]["t"].iloc[0])
