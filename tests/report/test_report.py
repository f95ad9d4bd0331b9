"""The report generator: collecting tables, the Pareto front, close-ups, ablation/sweep
summaries and the HTML page (without a browser; see test_browser.py for the real page)."""

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from signsplat.io.images import read_rgb
from signsplat.io.tables import read_table
from signsplat.report import plots, runs
from signsplat.report.collect import collect, read_benchmarks
from signsplat.report.html import closeups, write_report

from .conftest import build_results, keypoints_table


def test_pareto_front_matches_brute_force_definition():
    rng = np.random.default_rng(0)
    s, q = rng.uniform(1, 100, 40), rng.uniform(10, 30, 40)
    s[5], q[5] = np.nan, 99.0  # NaN never on the front even with the best quality
    front = plots.pareto_front(s, q)
    for i in range(40):
        dominated = any(j != i and s[j] <= s[i] and q[j] >= q[i] and (s[j] < s[i] or q[j] > q[i])
                        for j in range(40) if np.isfinite(s[j]))
        assert front[i] == (np.isfinite(s[i]) and not dominated)
    assert plots.pareto_front([1, 2, 3], [10, 9, 11]).tolist() == [True, False, True]


def test_benchmarks_are_read_per_scene_and_job(results_dir):
    b = read_benchmarks(results_dir / "_benchmarks")
    row = b[(b.job == "train_avatar_demo") & (b.scene == "tiny")]
    assert len(row) == 1 and row.seconds.iloc[0] == pytest.approx(900.0)
    assert b[b.job == "body_model"].scene.iloc[0] == ""


def test_collect_finds_every_stage(results_dir):
    res = collect(results_dir)
    t = res.scenes["tiny"]
    assert t.perception_eval is not None and t.fit_eval is not None and t.colmap is not None
    assert set(t.avatar_metrics) == {"demo", "abl_full", "abl_no_reg", "sw_it150"}
    assert len(t.fit_overlays) == 1 and len(t.sim_images) == 2
    assert len(res.stitch_tables) == 1 and len(res.stitch_videos) == 1


def test_ablation_and_sweep_tables_use_benchmark_seconds(results_dir):
    a = runs.ablation_table(results_dir, "tiny", [
        {"label": "full", "iterations": 300, "variant": "abl_full"},
        {"label": "w/o reg", "iterations": 300, "variant": "abl_no_reg"}])
    # one row per variant and split the evaluation scored, in the given order
    assert list(zip(a.variant, a.split)) == [("full", "novel_pose"), ("full", "novel_view"),
                                             ("w/o reg", "novel_pose"), ("w/o reg", "novel_view")]
    assert set(a.test_views) == {"1"} and set(a.iterations) == {300}
    assert a.set_index(["variant", "split"]).loc[("full", "novel_view"), "psnr"] == \
        pytest.approx(22.0 - 1.2)
    full = a[a.split == "novel_pose"].set_index("variant").loc["full"]
    assert full.psnr == pytest.approx(22.0)  # no refinement, full image
    assert full.hand_psnr == pytest.approx(22.0 - 2.0)  # mean of -3 and -1 offsets
    assert full.train_seconds == pytest.approx(200.0)  # the benchmark, not train_seconds (195)
    assert full.points == 1300
    assert "lpips" not in a.columns  # LPIPS not available -> no column
    sw = runs.sweep_table(results_dir, "tiny", {"sw_it150": {"iterations": 150},
                                                "abl_full": {"iterations": 300},
                                                "demo": {"iterations": 1500}})
    # x axis = training seconds (benchmark), evaluation seconds kept beside them
    assert sw.seconds.tolist() == pytest.approx([100.0, 200.0, 900.0])
    assert sw.eval_seconds.tolist() == pytest.approx([6.0, 6.0, 6.0])
    assert sw.pareto_psnr.tolist() == [True, True, True]
    assert sw.set_index("setting").loc["abl_full", "iterations"] == 300


def test_closeup_crops_are_centred_on_the_keypoints(results_dir, tmp_path):
    res = collect(results_dir)
    t = res.scenes["tiny"]
    kp = pd.read_parquet(t.keypoints_2d)
    img = t.avatar_images["demo"][0]
    out = closeups(img, kp, t.cameras, {p: tmp_path / f"{p}.png"
                                        for p in ("left_hand", "right_hand", "face")})
    assert set(out) == {"left_hand", "right_hand", "face"}
    crop = read_rgb(out["left_hand"])
    side = crop.shape[0]
    assert crop.shape[1] == 3 * side  # gt | render | error crops side by side
    for k in range(3):  # the red marker (pixels 14..18, 38..42) sits at each tile's centre
        tile = crop[:, k * side:(k + 1) * side]
        ys, xs = np.nonzero((tile[..., 0] == 255) & (tile[..., 1] == 0))
        assert len(ys) == 25
        assert abs(ys.mean() - side / 2) <= 1.5 and abs(xs.mean() - side / 2) <= 1.5


def test_report_has_every_section_and_seconds_beside_every_figure(results_dir, tmp_path):
    out = write_report(results_dir, tmp_path / "rep" / "index.html")
    page = out.read_text()
    for sid in ("scene", "perception", "fit", "colmap", "avatar", "ablations", "sweep",
                "stitch", "runtimes"):
        assert f'id="{sid}"' in page
    figures = re.findall(r"<figure>(.*?)</figure>", page, re.S)
    assert len(figures) >= 10
    for f in figures:
        assert re.search(r'class="secs">[0-9.]+ s<', f), f
        src = re.search(r'src="([^"]+)"', f).group(1)
        assert not src.startswith(("/", "http")) and (out.parent / src).is_file()
    assert "900.0 s" in page  # demo training seconds from its benchmark file
    assert "Not available" not in page  # every stage of the fixture is shown


def test_avatar_table_states_its_protocol_and_shows_refinement_beside(results_dir, tmp_path):
    page = write_report(results_dir, tmp_path / "rep" / "index.html").read_text()
    section = page.split('id="avatar"')[1].split("<section")[0]
    assert "background replaced by rgb(1,1,1)" in section
    assert "test frames: (frame - 5) % 10 == 0" in section
    assert "interpolated from their neighbours" in section and "SMPL-X: fitted" in section
    assert "psnr refined" in section and "ssim refined" in section
    # the fixture scores refined frames 1 dB above unrefined: both figures are in the table
    demo = section.split("tiny / demo: training")[1].split("</table>")[0]
    head = re.findall(r"<th>([^<]*)</th>", demo)
    full = next(r for r in re.findall(r"<tr>(.*?)</tr>", demo, re.DOTALL) if "<td>full</td>" in r)
    row = dict(zip(head, re.findall(r"<td>([^<]*)</td>", full)))
    assert float(row["psnr"]) == 24 and float(row["psnr refined"]) == 25, row
    # each PSNR beside its standard error over the images (the fixture's 0.25 and 0.5 dB)
    assert head.index("psnr ±") == head.index("psnr") + 1
    assert float(row["psnr ±"]) == 0.25 and float(row["psnr ± refined"]) == 0.5, row


def test_temporary_files_of_a_killed_writer_are_not_read(tmp_path):
    # a writer killed outright (SIGKILL) leaves its atomic_path temporary beside the target:
    # the report must skip it, not fail on a half-written video or show a half-written image
    root = build_results(tmp_path / "results")
    (root / "stitched" / ".hello2.mp4.k3j1.tmp.mp4").write_bytes(b"not a video")
    images = root / "tiny" / "eval" / "demo" / "images"
    (images / ".f0004_v01.png.x8d.tmp.png").write_bytes(b"half")
    res = collect(root)
    assert [p.name for p in res.stitch_videos] == ["hello.mp4"]
    assert all(not p.name.startswith(".") for p in res.scenes["tiny"].avatar_images["demo"])
    assert write_report(root, tmp_path / "rep" / "index.html").is_file()


def test_report_of_a_partial_run_says_which_stages_did_not_run(tmp_path):
    root = build_results(tmp_path / "results", full=False)
    page = write_report(root, tmp_path / "rep" / "index.html").read_text()
    for sid in ("perception", "fit", "colmap", "avatar", "ablations", "sweep", "stitch"):
        section = page.split(f'id="{sid}"')[1].split("<section")[0]
        assert "Not available" in section, sid
    assert "Not available" not in page.split('id="scene"')[1].split("<section")[0]
    assert 'id="runtimes"' in page and "12.2 s" in page  # simulate benchmark (12.25 s)


def test_report_command_writes_the_page(results_dir, tmp_path):
    from signsplat.cli import main

    out = tmp_path / "r" / "index.html"
    assert main(["report", "--results", str(results_dir), "--out", str(out)]) == 0
    assert out.is_file() and any((out.parent / "assets").iterdir())
    sweep_out, plot = tmp_path / "sweep.parquet", tmp_path / "sweep.png"
    point = {"swept": "iterations", "resolution": 64, "max_points": 40000}
    settings = {"sw_it150": {"iterations": 150, **point}, "demo": {"iterations": 1500, **point}}
    assert main(["report", "sweep", "--results", str(results_dir), "--scene", "tiny",
                 "--settings-json", json.dumps(settings),
                 "--out", str(sweep_out), "--plot", str(plot)]) == 0
    sw = read_table(sweep_out, "sweep")  # registered columns all present
    assert sw.setting.tolist() == ["sw_it150", "demo"] and read_rgb(plot).shape[0] > 100
    abl_out = tmp_path / "ablations.parquet"
    on = {"regularize": True, "densify": True, "accumulate": True, "displacement": True,
          "pose_dependent": True}
    variants = [{"label": "w/o reg", "iterations": 300, "variant": "abl_no_reg", **on,
                 "regularize": False},
                {"label": "full", "iterations": 300, "variant": "abl_full", **on}]
    assert main(["report", "ablations", "--results", str(results_dir), "--scene", "tiny",
                 "--variants-json", json.dumps(variants), "--out", str(abl_out)]) == 0
    a = read_table(abl_out, "ablations")
    assert a.variant.tolist() == ["w/o reg"] * 2 + ["full"] * 2  # the given order
    assert a.regularize.tolist() == [False, False, True, True] and a.densify.all()
    reg_out, reg_plot = tmp_path / "regularizer.parquet", tmp_path / "regularizer.png"
    scales = [{"scale": 0, "iterations": 300, "variant": "abl_no_reg"},
              {"scale": 1, "iterations": 300, "variant": "abl_full"}]
    assert main(["report", "regularizer", "--results", str(results_dir), "--scene", "tiny",
                 "--variants-json", json.dumps(scales), "--out", str(reg_out),
                 "--plot", str(reg_plot)]) == 0
    r = read_table(reg_out, "regularizer_sweep")
    assert r.scale.tolist() == [0.0, 0.0, 1.0, 1.0] and read_rgb(reg_plot).shape[0] > 100


def test_incomplete_sweep_settings_are_refused_by_the_table_schema(results_dir, tmp_path,
                                                                    capsys):
    from signsplat.cli import main

    out = tmp_path / "s.parquet"
    assert main(["report", "sweep", "--results", str(results_dir), "--scene", "tiny",
                 "--settings-json", '{"demo": {"iterations": 1500}}',
                 "--out", str(out), "--plot", str(tmp_path / "s.png")]) != 0
    err = capsys.readouterr().err
    assert str(out) in err and "max_points" in err and "swept" in err
    assert not out.exists()


def test_missing_variant_names_the_file(results_dir):
    with pytest.raises(FileNotFoundError, match="abl_nothing/metrics.parquet"):
        runs.ablation_table(results_dir, "tiny",
                            [{"label": "full", "iterations": 300, "variant": "abl_nothing"}])


def test_winners_per_budget_and_split_say_who_beats_the_full_model():
    df = pd.DataFrame({
        "variant": ["full", "w/o reg", "w/o dens"] * 2, "iterations": 300,
        "split": ["novel_pose"] * 3 + ["novel_view"] * 3,
        "psnr": [30.0, 31.0, 29.0, 25.0, 24.0, 24.5], "ssim": [0.90, 0.93, 0.85, 0.80, 0.78, 0.79]})
    w = runs.winners(df).set_index("split")
    assert w.loc["novel_pose", "best_ssim"] == "w/o reg"
    assert w.loc["novel_pose", "full_margin_ssim"] == pytest.approx(-0.03)
    assert w.loc["novel_view", "best_psnr"] == "full"
    assert w.loc["novel_view", "full_margin_psnr"] == pytest.approx(0.5)
    text = runs.ssim_finding(df)
    assert "novel_pose at 300 steps: w/o reg beats the full model on SSIM by 0.0300" in text
    assert "novel_view at 300 steps: the full model is best on SSIM (0.8000, +0.0100" in text
    df.loc[1, "ssim"] = 0.80
    assert "novel_pose at 300 steps: the full model is best on SSIM (0.9000, +0.0500" in \
        runs.ssim_finding(df)
    assert "cannot be checked" in runs.ssim_finding(df[df.variant != "full"])


def test_report_tables_are_also_written_as_tsv(results_dir, tmp_path):
    tables = tmp_path / "tables"
    tables.mkdir()
    (tables / "stale.tsv").write_text("old\n")  # a file of an earlier report goes away
    page = write_report(results_dir, tmp_path / "index.html", tables_dir=tables).read_text()
    files = sorted(p.name for p in tables.glob("*.tsv"))
    assert "stale.tsv" not in files
    assert len(files) == page.count("<table")  # one TSV per table shown
    abl = [f for f in files if f.startswith("ablations_")]
    assert len(abl) == 3  # winners per split, every row, the regulariser's sweep
    df = pd.read_csv(tables / abl[1], sep="\t")
    assert df.variant.tolist() == ["full", "full", "w/o regularisation", "w/o regularisation"]
    assert df.psnr.iloc[0] == pytest.approx(22.0)


def test_report_shows_psnr_per_camera_and_names_a_camera_far_below_the_others(results_dir,
                                                                             tmp_path):
    page = write_report(results_dir, tmp_path / "rep" / "index.html").read_text()
    assert "whole-image PSNR per camera" in page
    assert "view 2 on novel_pose (6.2 dB below)" in page
    for c in range(4):
        assert f"view {c}</th>" in page


def test_footage_section_shows_rates_reprojection_and_heldout_scores(tmp_path):
    from signsplat.io.images import write_png
    from signsplat.io.tables import write_table
    from signsplat.perception.quality import QUALITY_TABLE  # noqa: F401  (registers)
    from signsplat.perception.stages import persons_frame

    root = build_results(tmp_path / "r", scene="clip")
    perc = root / "clip" / "perception"
    q = pd.DataFrame([("clip", "detection_rate", "body", 0.97, 40),
                      ("clip", "detection_rate", "right_hand", 0.85, 20),
                      ("clip", "jitter_px", "face", 0.45, 300)],
                     columns=["scene", "metric", "part", "value", "count"])
    write_table(q.astype({"count": "int64"}), perc / "quality.parquet", "footage_quality")
    write_png(perc / "overlays" / "0000.png", np.zeros((64, 96, 3), np.uint8))  # 64 px high
    people = [dict(scene="clip", view=0, frame=f, person=j, score=0.9, hip_x=10.0 + 50 * j,
                   hip_y=40.0, scale_x=10.0, scale_y=10.0, head_x0=0.0, head_y0=0.0,
                   head_x1=5.0, head_y1=5.0, chosen=j == 0,
                   chosen_by=("box" if f == 0 else "tracked") if j == 0 else "")
              for f in range(3) for j in range(2)]
    write_table(persons_frame(people), perc / "persons.parquet", "persons")
    m = pd.read_parquet(root / "clip" / "eval" / "demo" / "metrics.parquet")
    masked = m[m["protocol"] == "bg_replaced"].assign(protocol="mask_only")
    masked["value"] = masked["value"] - 3.0
    write_table(pd.concat([m, masked], ignore_index=True),
                root / "clip" / "eval" / "demo" / "metrics.parquet", "avatar_metrics")
    page = write_report(root, tmp_path / "rep" / "index.html").read_text()
    assert 'id="footage"' in page
    section = page.split('id="footage"')[1].split("<section")[0]
    rows = dict(re.findall(r"<td>([^<]+)</td>\s*<td>([^<]+)</td>", section))
    assert float(rows["detection_rate (body)"]) == 0.97
    assert float(rows["people per frame (mean)"]) == 2.0
    assert float(rows["signer taken by: tracked"]) == 2.0
    # the fit's 2.1 px reprojection at a 64-pixel frame height is 8.4 px at 256
    assert float(rows["fit reprojection error (all), px at 256 px height"]) == pytest.approx(8.4)
    assert float(rows["avatar demo: held-out psnr (masked)"]) == 21.0  # 24 dB minus 3
    assert float(rows["avatar demo: training seconds"]) == 895.0
    assert re.search(r'class="secs">[0-9.]+ s<', section)
    track = re.search(r'src="(assets/[0-9a-f]*_?clip_signer_track.png)"', section)
    assert track and (tmp_path / "rep" / track.group(1)).stat().st_size > 1000


def test_fronts_before_and_after_are_each_code_s_own_and_shown_in_the_sweep_section(
        results_dir, tmp_path):
    """benchmarks/bench_avatar_fronts.py's table: scores and benchmark seconds per setting,
    each code's own Pareto front (abl_full is beaten only by the other code's point), and the
    accuracy-versus-time section draws both when the table exists."""
    from signsplat.io.tables import write_table
    from signsplat.report.html import Assets, sweep_section

    points = pd.DataFrame(
        [("before", "aaaa", "sw_it150", "iterations 150"), ("before", "aaaa", "abl_full", "centre"),
         ("after", "bbbb", "abl_no_reg", "centre"), ("after", "bbbb", "demo", "iterations 1500")],
        columns=["code", "commit", "variant", "setting"]).assign(scene="tiny",
                                                                 measured="2026-11-27")
    df = runs.fronts_table(points, {"before": results_dir, "after": results_dir})
    assert df.seconds.tolist() == pytest.approx([100.0, 200.0, 190.0, 900.0])
    assert df.psnr.tolist() == pytest.approx([20.0, 22.0, 22.5, 24.0])
    assert df.pareto_psnr.tolist() == [True, True, True, True]
    table = tmp_path / "avatar_fronts.parquet"
    write_table(df, table, "avatar_fronts")  # the registered columns
    res = collect(results_dir)
    assets = Assets(tmp_path / "report")
    plain = sweep_section(res, assets, "demo")
    shown = sweep_section(res, assets, "demo", table)
    assert len(shown.figures) == len(plain.figures) + 1
    fig = shown.figures[0]
    assert "before = aaaa, after = bbbb" in fig.caption and "2026-11-27" in fig.caption
    assert fig.seconds == pytest.approx(1390.0)
    assert (tmp_path / "report" / fig.src).stat().st_size > 5000
    assert [c for c, _ in shown.frames][0] == "the front before and after (benchmark)"
    assert sweep_section(res, assets, "demo", tmp_path / "none.parquet").figures == plain.figures


def test_fit_table_says_when_the_fit_took_the_detector_s_own_keypoints(tmp_path):
    """A fit_eval written with the keypoint_offsets it used (signsplat.fit.run's metadata):
    the report's fit table names the table; without it, the caption says nothing of it. The
    same for the legs the fit kept at the rest pose (metadata legs_held)."""
    from signsplat.io.tables import write_table
    from signsplat.report.html import Assets, fit_section

    root = build_results(tmp_path / "r")
    path = root / "tiny" / "fit" / "fit_eval.parquet"
    plain = fit_section(collect(root), Assets(tmp_path / "a"))
    assert "own keypoints" not in plain.tables[0][0]
    write_table(read_table(path, "fit_eval"), path, "fit_eval",
                metadata={"keypoint_offsets": "models/pretrained_keypoint_offsets.parquet"})
    moved = fit_section(collect(root), Assets(tmp_path / "b"))
    assert "own keypoints, pretrained_keypoint_offsets.parquet" in moved.tables[0][0]
    assert "rest pose" not in moved.tables[0][0]
    write_table(read_table(path, "fit_eval"), path, "fit_eval",
                metadata={"legs_held": "left, right"})
    held = fit_section(collect(root), Assets(tmp_path / "c"))
    assert "legs no view sees (left, right) kept at the rest pose" in held.tables[0][0]


def test_perception_section_names_each_sequence_s_keypointer_and_what_it_reported(tmp_path):
    """The detected keypoints' metadata (signsplat.perception.stages.detect_sequence): the
    report's perception section says which keypointer and model each sequence took, and the
    keypointer's note (here: how many frames took MediaPipe's fingers); a run whose keypoints
    carry no metadata shows no such table."""
    from signsplat.io.tables import write_table
    from signsplat.report.html import perception_section

    root = build_results(tmp_path / "r")
    plain = perception_section(collect(root))
    assert not any("which keypointer" in title for title, _ in plain.frames)
    note = "MediaPipe's hands (crop: model) taken in 5 of 8 frames (right)"
    write_table(keypoints_table("tiny").drop(columns=["visible", "depth"]),
                root / "tiny" / "perception" / "keypoints.parquet", "keypoints",
                metadata={"model": "models/keypoints.onnx + models/cache", "note": note,
                          "source": "onnx+mediapipe"})
    sec = perception_section(collect(root))
    title, table = sec.frames[0]
    assert "which keypointer" in title and "taken in 5 of 8 frames" in sec.tables[0][1]
    assert table.to_dict("records") == [{
        "sequence": "tiny", "keypointer": "onnx+mediapipe",
        "model": "models/keypoints.onnx + models/cache", "note": note}]
