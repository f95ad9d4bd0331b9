"""The fit sweep's table, fronts, figure and report section (signsplat.report.fit_sweep)."""

import json

import numpy as np
import pandas as pd
import pytest

import signsplat.fit.evaluate  # noqa: F401  (registers the fit_eval table)
from signsplat.io.tables import read_table, write_table
from signsplat.report import plots
from signsplat.report.fit_sweep import fit_sweep_table, point_files

# point -> (seconds, body mm, hands mm, camera deg); sil500 is slower and worse than sil250
POINTS = {"default": (900.0, 11.0, 5.0, 0.4), "sil0": (150.0, 20.0, 7.0, 0.6),
          "sil250": (400.0, 13.0, 5.5, 0.45), "sil500": (600.0, 14.0, 6.0, 0.5),
          "lm20": (850.0, 11.0, 5.0, 0.5)}


def _values(name):
    sil = {"sil0": 0, "sil250": 250, "sil500": 500}.get(name, 1000)
    swept = "default" if name == "default" else (
        "lm_iterations" if name == "lm20" else "silhouette_iterations")
    return {"swept": swept, "silhouette_iterations": sil, "flow": "none" if sil == 0 else
            "medium", "lm_iterations": 20 if name == "lm20" else 60}


def _fake(root, scene="studio6", points=POINTS):
    for name, (secs, body, hands, rot) in points.items():
        folder, job = point_files(name)
        d = root / scene / folder
        d.mkdir(parents=True)
        rows = [("camera_rotation", "cameras", rot), ("camera_centre", "cameras", 0.01),
                ("mpjpe", "body", body), ("pa_mpjpe", "body", body / 2),
                ("mpjpe", "hands", hands), ("pa_mpjpe", "hands", hands / 2),
                ("image_error", "all", 1.2)]
        ev = pd.DataFrame([(scene, "multiview", "detected", m, p, v, "x", secs, secs / 60)
                           for m, p, v in rows],
                          columns=["scene", "mode", "keypoints", "metric", "part", "value",
                                   "unit", "seconds_total", "seconds_per_frame"])
        write_table(ev, d / "fit_eval.parquet", "fit_eval")
        b = root / "_benchmarks" / scene
        b.mkdir(parents=True, exist_ok=True)
        (b / f"{job}.tsv").write_text(f"s\tcpu_time\n{secs}\t{secs * 1.5}\n")


def test_table_puts_each_fits_errors_beside_its_seconds_and_marks_the_fronts(tmp_path):
    _fake(tmp_path)
    df = fit_sweep_table(tmp_path, "studio6", {n: _values(n) for n in POINTS})
    write_table(df, tmp_path / "fit_sweep.parquet", "fit_sweep")  # the documented columns
    df = read_table(tmp_path / "fit_sweep.parquet", "fit_sweep").set_index("setting")
    assert df.loc["sil250", "seconds"] == 400.0 and df.loc["sil250", "cpu_seconds"] == 600.0
    assert df.loc["sil250", "body_mpjpe_mm"] == 13.0 and df.loc["sil0", "hands_mpjpe_mm"] == 7.0
    assert df.loc["sil0", "flow"] == "none" and df.loc["lm20", "lm_iterations"] == 20
    # sil500 is slower than sil250 and worse in every error: on no front
    assert not df.loc["sil500", ["pareto", "pareto_body", "pareto_hands",
                                 "pareto_cameras"]].any()
    # lm20 is as accurate as the default in body and hands, faster, worse in cameras:
    # on the joint front and on the body front; the default stays on the joint front
    # (best cameras) but leaves the body front (lm20 is faster for the same body error)
    assert df.loc["lm20", "pareto"] and df.loc["lm20", "pareto_body"]
    assert df.loc["default", "pareto"] and not df.loc["default", "pareto_body"]
    assert df.loc["default", "pareto_cameras"] and df.loc["sil0", "pareto"]


def test_a_missing_fit_names_the_point(tmp_path):
    _fake(tmp_path, points={"default": POINTS["default"]})
    with pytest.raises(FileNotFoundError, match=r"fit_sweep/sil0/fit_eval.parquet.*'sil0'"):
        fit_sweep_table(tmp_path, "studio6", {n: _values(n) for n in ("default", "sil0")})


def test_nondominated_matches_brute_force_in_three_criteria():
    rng = np.random.default_rng(1)
    c = rng.uniform(0, 1, (30, 3))
    c[4, 1] = np.nan
    front = plots.nondominated(c)
    for i in range(30):
        dominated = any(j != i and (c[j] <= c[i]).all() and (c[j] < c[i]).any()
                        for j in range(30) if np.isfinite(c[j]).all())
        assert front[i] == (np.isfinite(c[i]).all() and not dominated)
    assert plots.pareto_front([1, 2, 3], [5, 4, 6], lower_is_better=True).tolist() == \
        [True, True, False]


def test_the_report_shows_the_sweep_beside_the_fit(tmp_path):
    """The HTML report gains section 3b (table, figure, which fits are on the front) when a
    sequence has its fit_sweep.parquet, and has no such section otherwise."""
    from signsplat.cli import main

    for name in ("with", "without"):
        results = tmp_path / name / "results"
        _fake(results)
        if name == "with":
            assert main(["report", "fit-sweep", "--results", str(results), "--scene", "studio6",
                         "--points-json", json.dumps({n: _values(n) for n in POINTS}),
                         "--out", str(results / "studio6" / "fit_sweep.parquet"),
                         "--plot", str(results / "studio6" / "fit_sweep.png")]) == 0
            assert (results / "studio6" / "fit_sweep.png").stat().st_size > 5000
        out = tmp_path / name / "index.html"
        assert main(["report", "html", "--results", str(results), "--out", str(out),
                     "--tables", str(tmp_path / name / "tables")]) == 0
        page = out.read_text()
        shown = "3b. SMPL-X fitting: accuracy versus time" in page
        assert shown == (name == "with"), name
        if shown:
            assert "on the joint front: default, sil0, sil250, lm20 (the config&#39;s fit is " \
                "on it)" in page
            tsv = tmp_path / name / "tables" / "fit_sweep_00_studio6.tsv"
            assert pd.read_csv(tsv, sep="\t")["setting"].tolist() == list(POINTS)
