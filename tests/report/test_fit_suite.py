"""The suite table, its Done-when summary and figure (signsplat.report.fit_suite)."""

import json

import pandas as pd

import signsplat.fit.evaluate  # noqa: F401  (registers the fit_eval table)
from signsplat.io.tables import read_table, write_table
from signsplat.report.fit_suite import plot_suite, scene_row, suite_table, summarise

SPEC3 = {"max_frames": 24, "cameras": {"count": 3, "distance": 2.0, "width": 192,
                                       "height_px": 160,
                                       "views": [{"azimuth_degrees": -50.0},
                                                 {"azimuth_degrees": 0.0},
                                                 {"azimuth_degrees": 50.0}]},
         "effects": ["lighting", {"occluder": {"views": [1]}}]}
SPEC2 = {"max_frames": 24, "cameras": {"count": 2, "layout": "arc", "arc_degrees": 60,
                                       "distance": 2.5}, "effects": []}


def _fake(root, scene, rot, centre, body, status, fit_s=100.0, doubtful=0, sides=None,
          held=None):
    d = root / scene / "fit"
    d.mkdir(parents=True)
    rows = [("camera_rotation", "cameras", rot), ("camera_centre", "cameras", centre),
            ("mpjpe", "body", body), ("mpjpe", "body_seen", body - 2.0),
            ("mpjpe", "hands", 9.0)]
    ev = pd.DataFrame([(scene, "multiview", "detected", m, p, v, "x", 1.0, 1.0)
                       for m, p, v in rows],
                      columns=["scene", "mode", "keypoints", "metric", "part", "value", "unit",
                               "seconds_total", "seconds_per_frame"])
    write_table(ev, d / "fit_eval.parquet", "fit_eval")
    (d / "fit_log.json").write_text(json.dumps({"camera_status": status,
                                                "log": {"camera_init": "sfm",
                                                        "camera_init_doubtful": doubtful,
                                                        "camera_mask_sides": sides or {},
                                                        "cameras_held": held or {}},
                                                "provenance": {"fitted": 24}}))
    b = root / "_benchmarks" / scene
    b.mkdir(parents=True)
    for job, s in (("simulate", 10.0), ("segment", 5.0), ("detect_keypoints", 5.0),
                   ("fit_smplx", fit_s)):
        (b / f"{job}.tsv").write_text(f"s\tcpu_time\n{s}\t{s}\n")


def test_rows_targets_and_summary(tmp_path):
    _fake(tmp_path, "good", 0.4, 0.01, 14.0, ["sfm"] * 3, held={"a": [0, 2], "b": [1]})
    _fake(tmp_path, "far", 3.0, 0.01, 14.0, ["sfm"] * 3)
    _fake(tmp_path, "unplaced", 0.4, 0.01, 14.0, ["sfm", "unplaced", "sfm"])
    _fake(tmp_path, "pair", 4.0, 0.05, 30.0, ["sfm"] * 2)
    rows = [scene_row(tmp_path, s, SPEC3) for s in ("good", "far", "unplaced", "crashed")]
    rows.append(scene_row(tmp_path, "pair", SPEC2))
    df = suite_table(rows)
    write_table(df, tmp_path / "suite.parquet", "fit_suite")  # the documented columns
    df = read_table(tmp_path / "suite.parquet", "fit_suite").set_index("scene")
    assert df.loc["good", "meets_target"] and df.loc["good", "status"] == "ok"
    assert not df.loc["far", "meets_target"]
    assert not df.loc["unplaced", "meets_target"] and df.loc["unplaced", "unplaced"] == 1
    assert df.loc["crashed", "status"].startswith("no fit output")
    assert not df.loc["pair", "meets_target"]  # two cameras: reported, no target
    assert df.loc["good", "arc_deg"] == 100.0 and df.loc["pair", "arc_deg"] == 60.0
    assert df.loc["good", "image"] == "192x160" and df.loc["good", "effects"] == \
        "lighting,occluder"
    assert df.loc["good", "pipeline_seconds"] == 120.0
    assert df.loc["good", "body_seen_mpjpe_mm"] == 12.0
    assert df["cameras_held"].tolist() == [2, 0, 0, 0, 0]
    s = summarise(df.reset_index())
    assert (s["multi_camera_scenes"], s["meeting_targets"], s["failed_or_nan"]) == (4, 1, 1)
    assert s["share_meeting_targets"] == 0.25
    assert [r["scene"] for r in s["two_camera"]] == ["pair"]
    path = plot_suite(df.reset_index(), tmp_path / "suite.svg")
    assert path.stat().st_size > 1000 and "<svg" in path.read_text()[:400]


def test_report_section_when_the_suite_has_run(tmp_path):
    """The report gains the suite's section (table, figure, the unplaced views named) only when
    the suite's table exists."""
    from signsplat.report.fit_suite import fit_suite_section
    from signsplat.report.html import Assets

    _fake(tmp_path, "good", 0.4, 0.01, 14.0, ["sfm"] * 3)
    _fake(tmp_path, "unplaced", 0.4, 0.01, 14.0, ["sfm", "unplaced", "sfm"], doubtful=2,
          sides={"0": {"iou_here": 0.2, "iou_there": 0.8, "turned": True},
                 "2": {"iou_here": 0.7, "iou_there": 0.5, "turned": False}})
    df = suite_table([scene_row(tmp_path, s, SPEC3) for s in ("good", "unplaced")])
    table = tmp_path / "bench" / "fit_suite.parquet"
    assets = Assets(tmp_path / "report")
    assert fit_suite_section(table, assets, table.with_suffix(".svg")) is None  # not run
    write_table(df, table, "fit_suite")
    plot_suite(df, table.with_suffix(".svg"))
    sec = fit_suite_section(table, assets, table.with_suffix(".svg"))
    assert "1 of 2 scenes with 3 or more cameras" in sec.intro
    assert "could not be placed" in sec.intro and "unplaced (1)" in sec.intro
    assert "may face the signer from the other side" in sec.intro
    assert sec.frames[0][1]["doubtful"].tolist() == [0, 2]
    assert sec.frames[0][1]["mask_turned"].tolist() == [0, 1]
    assert sec.frames[0][1]["mask_kept"].tolist() == [0, 1]
    assert "unplaced (2; by their person masks 1 turned around, 1 kept where placed)" \
        in sec.intro
    assert "joints two or more cameras see, body MPJPE <= 25 mm on 2 of 2" in sec.intro
    assert [c for c, _ in sec.frames] == ["per scene"]
    assert sec.frames[0][1]["scene"].tolist() == ["good", "unplaced"]
    assert len(sec.figures) == 1 and (tmp_path / "report" / sec.figures[0].src).exists()
    assert sec.frames[0][1]["body_seen_mpjpe_mm"].tolist() == [12.0, 12.0]
    # a table written before the column existed still gets its section
    df.drop(columns=["body_seen_mpjpe_mm", "mask_turned", "mask_kept"]).to_parquet(table)
    sec = fit_suite_section(table, assets)
    assert "body_seen_mpjpe_mm" not in sec.frames[0][1] and "body_mpjpe_mm" in sec.frames[0][1]
    assert "joints two or more cameras see" not in sec.intro
    assert "unplaced (2)." in sec.intro  # no masks' verdict in a table from before the check


def test_the_report_command_shows_the_suite(tmp_path):
    """`signsplat report html --fit-suite T` puts the section in the page and its table among
    the TSV copies; without the option the page has no such section."""
    from signsplat.cli import main

    _fake(tmp_path / "suite", "good", 0.4, 0.01, 14.0, ["sfm"] * 3)
    table = tmp_path / "fit_suite.parquet"
    write_table(suite_table([scene_row(tmp_path / "suite", "good", SPEC3)]), table, "fit_suite")
    (tmp_path / "results").mkdir()
    for name, extra in (("with", ["--fit-suite", str(table)]), ("without", [])):
        out = tmp_path / name / "index.html"
        assert main(["report", "html", "--results", str(tmp_path / "results"), "--out",
                     str(out), "--tables", str(tmp_path / name / "tables"), *extra]) == 0
        page = out.read_text()
        shown = "generalisation suite" in page
        assert shown == (name == "with"), name
        assert (tmp_path / name / "tables" / "fit_suite_00_per_scene.tsv").exists() == shown


def test_collecting_again_keeps_the_run_s_wall_clock(tmp_path):
    """`benchmarks/fit_suite.py --collect-only` rebuilds the table from finished results; the
    wall clock and notes the run itself recorded stay (a rebuild takes no time of its own)."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    _fake(tmp_path, "issue29", 4.0, 0.01, 30.0, ["sfm"] * 3)
    out = tmp_path / "fit_suite.parquet"
    cmd = [sys.executable, str(repo / "benchmarks" / "fit_suite.py"), "--collect-only",
           "--scenes", "issue29", "--results", str(tmp_path), "--out", str(out)]
    subprocess.run(cmd, check=True, capture_output=True, cwd=repo)
    first = read_table(out, "fit_suite")
    assert float(first.attrs["wall_seconds"]) < 60  # no run: only the collection's own time
    # the run's table written before a column existed: its notes still carry over
    old = first.drop(columns="body_seen_mpjpe_mm")
    meta = {**first.attrs, "wall_seconds": "5400", "note": "two runs"}
    import pyarrow as pa
    import pyarrow.parquet as pq
    arrow = pa.Table.from_pandas(old, preserve_index=False)
    pq.write_table(arrow.replace_schema_metadata({b"signsplat.meta": json.dumps(meta).encode()}),
                   out)
    res = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=repo)
    again = read_table(out, "fit_suite")
    assert again.attrs["wall_seconds"] == "5400" and again.attrs["note"] == "two runs"
    assert "1.50 h wall clock" in res.stdout
    assert again.loc[0, "camera_rotation_deg"] == 4.0
