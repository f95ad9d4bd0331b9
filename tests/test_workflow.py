"""The workflow: `snakemake -n` plans the default config; the simulate rule runs on a tiny scene."""

import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from workflow_runs import snakemake as run_snakemake
from workflow_runs import tiny_config, tiny_local_run

from signsplat.avatar.config import resolve
from signsplat.io.tables import read_table, write_table
from signsplat.report.variants import ablation_plan, sweep_plan

ROOT = Path(__file__).resolve().parents[1]


def snakemake(*args, timeout=900):
    return run_snakemake("--cores", "1", *args, timeout=timeout)


def job_counts(stdout: str) -> dict[str, int]:
    """Parse the 'Job stats' table of a dry run."""
    lines = stdout.splitlines()
    start = lines.index("Job stats:")
    counts = {}
    for line in lines[start + 3:]:
        parts = line.split()
        if len(parts) != 2 or not parts[1].isdigit():
            break
        counts[parts[0]] = int(parts[1])
    return counts


def planned_jobs(stdout: str, rule: str) -> list[str]:
    """What a dry run with -p prints for each planned job of ``rule`` (input, output,
    wildcards, command)."""
    return [job for job in stdout.split("\nrule ") if job.startswith(f"{rule}:")]


def jobs_by_scene(stdout: str, rule: str) -> dict[str, str]:
    """:func:`planned_jobs` of ``rule`` by their ``scene`` wildcard."""
    return {re.search(r"wildcards: .*\bscene=(\w+)", job).group(1): job
            for job in planned_jobs(stdout, rule)}


def test_dry_run_lists_the_jobs_of_the_default_config(tmp_path):
    cache = tmp_path / "c"  # an empty model cache: only MediaPipe's hand models are fetched
    over = tmp_path / "over.yaml"
    over.write_text(yaml.safe_dump({"results": str(tmp_path),
                                    "perception": {"pretrained": {"cache": str(cache)}}}))
    res = snakemake("-n", "-p", "--configfile", "config/config.yaml", str(over))
    assert res.returncode == 0, res.stderr + res.stdout
    counts = job_counts(res.stdout)
    # the sheet's two synthetic sequences (studio6: 6 cameras, single: 1): one chain each,
    # COLMAP only for the multi-view one, one stitching job for all sentences, one report;
    # MediaPipe's models once, for both sequences' right-hand fingers (their dominant_hand)
    per_sequence = ("simulate", "segment", "detect_keypoints", "perception_eval", "fit_smplx",
                    "train_avatar", "evaluate_avatar")
    assert counts == {"body_model": 1, "gloss_library": 1, "colmap_compare": 1,
                      "stitch_video": 1, "report": 1, "all": 1, "fetch_mediapipe": 1,
                      "total": 21,
                      **{rule: 2 for rule in per_sequence}}
    detect = jobs_by_scene(res.stdout, "detect_keypoints")
    assert sorted(detect) == ["single", "studio6"]
    assert all("--detectors shipped" in job for job in detect.values())
    # both sheet rows name the right hand: the landmarker in the model's hand crops, its hand
    # model alone (no pose chain)
    for scene in ("studio6", "single"):
        assert f"{cache}/hand_landmark_full.onnx" in detect[scene].split("output:")[0]
        assert "pose_landmark_full.onnx" not in detect[scene]
        assert '"hands": "mediapipe", "input_size"' in detect[scene]
        assert '"hand_sides": ["right"]' in detect[scene]
    # the masks do not depend on the keypoints' settings (the dominant hand's among them)
    segment = jobs_by_scene(res.stdout, "segment")
    assert segment and not any('"hand_sides"' in job or '"wide_model"' in job
                               for job in segment.values())
    # every output of the plan is under the results folder the command line gave
    outputs = re.findall(r"^    output: (.+)$", res.stdout, re.M)
    assert outputs and all(o.startswith(str(tmp_path)) for line in outputs
                           for o in line.split(", ") if not o.startswith("reports/"))


def _jobs_by_rule(stdout: str, field: str, by_scene: bool = False) -> dict:
    """rule (or with ``by_scene`` (rule, scene wildcard)) -> the values of ``field`` over its
    jobs in a dry run with -p: ``threads`` from the printed command's `--threads`,
    ``priority`` from the job's lines (0 when absent)."""
    out: dict = {}
    for block in re.split(r"^\[.*\]$", stdout, flags=re.M):
        rule = re.search(r"^(?:local)?rule (\w+):$", block, re.M)
        pattern = r"--threads (\d+)" if field == "threads" else rf"^\s+{field}: (\d+)$"
        m = re.search(pattern, block, re.M)
        if rule and (m or field != "threads"):
            key = rule.group(1)
            if by_scene:
                scene = re.search(r"^\s+wildcards: .*\bscene=(\w+)", block, re.M)
                key = (key, scene.group(1) if scene else None)
            out.setdefault(key, set()).add(int(m.group(1)) if m else 0)
    return out


def test_the_default_run_s_avatars_share_two_cores_after_every_fit(tmp_path):
    """On 2 cores the default config's two avatars train side by side, one thread each
    (signsplat.plan.job_threads), and only once no stage before a fit can run (priorities);
    the stages up to the multi-view fit keep two threads, the single-view sequence's
    keypoints and fit take one (signsplat.plan.Plan.chain_threads), so they run beside the
    other avatar; the two scenes render side by side; the stitched video comes before the
    evaluations; the models studio6's keypoints need are fetched among the stages before the
    fits; a study target (quality) keeps two threads."""
    empty = {"pretrained": {"cache": str(tmp_path / "c")}}  # the models are to be fetched
    res = run_snakemake("--cores", "2", "-n", "-p", "--config", f"results={tmp_path}",
                        f"perception={empty}")
    assert res.returncode == 0, res.stderr + res.stdout
    threads = _jobs_by_rule(res.stdout, "threads")
    for rule in ("simulate", "train_avatar", "evaluate_avatar", "stitch_video",
                 "perception_eval"):
        assert threads.get(rule) == {1}, (rule, threads)
    assert threads.get("segment") == {2}, threads
    by_scene = _jobs_by_rule(res.stdout, "threads", by_scene=True)
    for rule in ("detect_keypoints", "fit_smplx"):
        assert by_scene[(rule, "studio6")] == {2} and by_scene[(rule, "single")] == {1}
    prio = _jobs_by_rule(res.stdout, "priority")
    before = {p for rule in ("simulate", "fetch_mediapipe", "segment", "detect_keypoints",
                             "fit_smplx")
              for p in prio[rule]}
    assert min(before) > max(prio["train_avatar"]) > max(prio["colmap_compare"]), prio
    # the two-thread fit outranks any two one-thread jobs before the avatars (Snakemake starts
    # the ready jobs with the largest sum of priorities), so single's chain cannot delay it
    prio_by = _jobs_by_rule(res.stdout, "priority", by_scene=True)
    one_thread = {p for (rule, scene), ps in prio_by.items() for p in ps
                  if (rule, scene) != ("fit_smplx", "studio6")
                  and by_scene.get((rule, scene), {1}) == {1}}
    assert min(prio_by[("fit_smplx", "studio6")]) > 2 * max(one_thread), prio_by
    assert prio_by[("fit_smplx", "single")] == prio["detect_keypoints"]
    assert prio["stitch_video"] == prio["train_avatar"]
    assert max(prio["perception_eval"]) < min(prio["train_avatar"]), prio
    res = run_snakemake("--cores", "2", "-n", "-p", "quality", "--config",
                        f"results={tmp_path}")
    assert res.returncode == 0, res.stderr + res.stdout
    assert _jobs_by_rule(res.stdout, "threads")["train_avatar"] == {2}


def test_default_workflow_profile_is_picked_up(tmp_path):
    """Snakemake 9 loads profiles/default (beside the Snakefile or in the working directory)
    with no option given: its `printshellcmds: true` shows each job's command in a dry run;
    with the profile switched off the command is not shown."""
    default = yaml.safe_load((ROOT / "profiles" / "default" / "config.yaml").read_text())
    assert default["printshellcmds"] is True
    target = str(tmp_path / "results" / "_assets" / "gloss_library.parquet")
    res = snakemake("-n", target, "--config", f"results={tmp_path / 'results'}")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "Using workflow specific profile profiles/default" in res.stderr
    assert "-m signsplat gloss-library" in res.stdout
    res = snakemake("-n", target, "--config", f"results={tmp_path / 'results'}",
                    "--workflow-profile", "none")
    assert res.returncode == 0, res.stderr[-3000:]
    assert "-m signsplat gloss-library" not in res.stdout


def test_dry_run_rejects_an_unknown_effect(tmp_path):
    spec = tmp_path / "bad.yaml"
    spec.write_text("cameras: {count: 1}\nmotion: {glosses: [HELLO]}\n"
                    "effects: [lighting, bloom]\n")
    sheet = tmp_path / "sequences.tsv"
    sheet.write_text(f"sequence\tsource\tspec\nbadfx\tsynthetic\t{spec}\n")
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(tmp_path), "sequences": str(sheet),
                                   "scenes": []}))
    res = snakemake("-n", "--configfile", str(cfg))
    assert res.returncode != 0
    out = res.stdout + res.stderr
    assert "bloom" in out and "camera_jitter" in out


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    """The session's local run of the two tiny sequences (tests/workflow_runs.py)."""
    return tiny_local_run(tmp_path_factory)


@pytest.mark.slow
def test_simulate_rule_ran_on_the_tiny_scene(tiny_run):
    results = tiny_run / "results"
    sim = results / "tiny" / "sim"
    for name in ("frames", "cameras", "smplx_gt", "keypoints_gt"):
        assert (sim / f"{name}.parquet").is_file()
    assert len(list((sim / "images").rglob("*.png"))) == 2 * 4
    assert len(list((sim / "masks").rglob("*.png"))) == 2 * 4
    log = (results / "_logs" / "tiny" / "simulate.log").read_text()
    assert "ms per frame per view" in log
    assert (results / "_benchmarks" / "tiny" / "simulate.tsv").is_file()
    # nothing left to do: a dry run of the finished run plans no job
    res = snakemake("-n", "--configfile", str(tiny_run / "config.yaml"))
    assert res.returncode == 0 and "Nothing to be done" in res.stdout + res.stderr, \
        res.stdout[-3000:]


@pytest.mark.slow
def test_keypoint_offsets_command_on_the_tiny_scene(tiny_run, tmp_path, capsys):
    """`signsplat keypoint-offsets` on a finished scene writes the table the fit reads; a
    folder without a finished scene is a clear error."""
    from signsplat.cli import main
    from signsplat.fit.keypoint_offsets import offsets_array, read_offsets

    results = tiny_run / "results"
    out = tmp_path / "offsets.parquet"
    args = ["--body", str(results / "_assets" / "body_model.npz"), "--detector", "shipped",
            "--out", str(out), "--min-observations", "1"]
    assert main(["keypoint-offsets", "--scenes", str(results / "tiny"), *args]) == 0
    table = read_offsets(out)
    assert len(table) > 5 and np.isfinite(offsets_array(table)).all()
    # on the whole the offsets bring the detections closer (a point's inliers at the last
    # trim can differ with and without its offset, so not every row need improve)
    assert table["rms_after_px"].mean() < table["rms_before_px"].mean()
    assert table.attrs["detector"] == "shipped"
    assert main(["keypoint-offsets", "--scenes", str(tmp_path / "nowhere"), *args]) == 2
    assert "nowhere" in capsys.readouterr().err
    # a body file with more shape coefficients than 10 (two more, zero, so the same body) and
    # a scene whose true body uses them: each scene is posed with its own count
    arrays = dict(np.load(results / "_assets" / "body_model.npz"))
    n = int(arrays["num_shape_dirs"])
    sd = arrays["shapedirs"]
    arrays["shapedirs"] = np.concatenate([sd[:, :, :n], np.zeros(sd.shape[:2] + (2,)),
                                          sd[:, :, n:]], axis=2)
    arrays["num_shape_dirs"] = np.array(n + 2)
    arrays["shape_names"] = np.concatenate([arrays["shape_names"], ["extra0", "extra1"]])
    body = tmp_path / "body_more_betas.npz"
    np.savez(body, **arrays)
    other = tmp_path / "more_betas"
    for name in ("sim/cameras.parquet", "perception/keypoints.parquet"):
        (other / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(results / "tiny" / name, other / name)
    gt = read_table(results / "tiny" / "sim" / "smplx_gt.parquet", "smplx_params")
    gt["betas"] = [np.concatenate([b, [0.0, 0.0]]) for b in gt["betas"]]
    write_table(gt, other / "sim" / "smplx_gt.parquet", "smplx_params")
    args[1] = str(body)
    assert main(["keypoint-offsets", "--scenes", str(results / "tiny"), str(other),
                 *args]) == 0, capsys.readouterr().err
    assert np.isfinite(offsets_array(read_offsets(out))).all()


# A tiny ablation study and sweep (merged over config/config.yaml's sections: the default
# bases' other keys stay), fitted like the demo avatar, so the full model and the sweep centre
# are `demo`.
STUDIES = {
    "ablations": {"base": {"train": {"smplx_source": "fitted"}}, "iterations": [4],
                  "test_views": [1], "regularizer_scales": [0, 0.5, 1]},
    "sweep": {"base": {"train": {"iterations": 4, "smplx_source": "fitted"}},
              "iterations": [2], "resolution": [], "max_points": []},
}


def tiny_study_config(tmp_path, **extra) -> Path:
    """The session run's config (tests/workflow_runs.py: two tiny sequences, the smallest fit,
    avatar and stitching settings) with the tiny studies, results and report under tmp_path."""
    path = tiny_config(tmp_path)
    path.write_text(yaml.safe_dump({**yaml.safe_load(path.read_text()), **STUDIES, **extra}))
    return path


def planned_variants(stdout: str, rule: str) -> set[str]:
    """The `variant` wildcard of every planned job of a rule in a dry run."""
    return {m.group(1) for j in planned_jobs(stdout, rule)
            for m in [re.search(r"wildcards: .*variant=([A-Za-z0-9_]+)", j)] if m}


def _default_studies():
    cfg = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    return cfg["ablations"], cfg["sweep"]


def test_dry_run_of_the_ablations_target_plans_one_variant_per_switch(tmp_path):
    res = snakemake("-n", "-p", "ablations", "--config", f"results={tmp_path}")
    assert res.returncode == 0, res.stderr + res.stdout
    counts = job_counts(res.stdout)
    assert counts["ablation_table"] == 1 and counts["ablations"] == 1
    # with an empty ablations.base the full model is the demo variant (trained once)
    base = _default_studies()[0]["base"]
    full = "demo" if base == {} else "abl_full"
    # the source row trains on the SMPL-X source the base does not use
    on_gt = base.get("train", {}).get("smplx_source") == "ground_truth"
    source_row = "abl_fitted_smplx" if on_gt else "abl_gt_smplx"
    budgets = _default_studies()[0]["iterations"]
    rows = {full, "abl_no_reg", "abl_no_dens", "abl_no_acc", "abl_no_disp", "abl_static",
            source_row}
    # every row at each budget, and the regulariser's scales besides 0 and 1 (which are the
    # rows without and with it)
    scales = [s for s in _default_studies()[0]["regularizer_scales"] if s not in (0, 1)]
    assert planned_variants(res.stdout, "train_avatar") == {
        f"{r}_i{b}" for r in rows for b in budgets} | {
        f"abl_reg{s:g}_i{b}".replace(".", "p") for s in scales for b in budgets}
    assert counts["fit_smplx"] == 1  # one of the rows trains on fitted SMPL-X
    assert counts["regularizer_table"] == 1
    assert f"{tmp_path}/studio6/ablations.parquet" in res.stdout
    # every row holds out the same cameras (novel-view scores)
    views = _default_studies()[0]["test_views"]
    cmds = [line for line in res.stdout.splitlines() if "train-avatar" in line]
    assert cmds and all(f'"test_views": {views}' in c for c in cmds)


def test_dry_run_of_the_quality_target_trains_the_quality_profile_once(tmp_path):
    from signsplat.avatar.config import PROFILES

    res = snakemake("-n", "-p", "quality", "--config", f"results={tmp_path}")
    assert res.returncode == 0, res.stderr + res.stdout
    assert planned_variants(res.stdout, "train_avatar") == {"quality"}
    assert planned_variants(res.stdout, "evaluate_avatar") == {"quality"}
    assert f"{tmp_path}/studio6/eval/quality/metrics.parquet" in res.stdout
    assert "single/avatar/quality" not in res.stdout  # one sequence, the multi-view one
    # the training job is given the quality profile's settings
    cmd = next(line for line in res.stdout.splitlines() if "train-avatar" in line)
    want = PROFILES["quality"]["train"]["iterations"]
    assert '"profile": "quality"' in cmd and f'"iterations": {want}' in cmd, cmd[:300]


def test_dry_run_of_the_sweep_target_plans_the_default_settings(tmp_path):
    res = snakemake("-n", "sweep", "--config", f"results={tmp_path}")
    assert res.returncode == 0, res.stderr + res.stdout
    ablations, sweep = _default_studies()
    # the centre is an already declared variant when its config equals one: with equal study
    # bases, the ablation row whose switches are the demo profile's
    centre_cfg = resolve(sweep_plan(sweep["base"], {})[0].overrides)
    same = [p.name for p in ablation_plan(ablations["base"], "ground_truth")
            if resolve(p.overrides) == centre_cfg]
    centre = "demo" if sweep["base"] == {} else (same[0] if same else "sw_base")
    expected = {"demo", centre} | {f"sw_{axis}{v}"
                                   for axis in ("iterations", "resolution", "max_points")
                                   for v in sweep[axis]}
    assert planned_variants(res.stdout, "train_avatar") == expected
    assert planned_variants(res.stdout, "evaluate_avatar") == expected
    assert job_counts(res.stdout)["sweep_table"] == 1
    assert f"{tmp_path}/studio6/sweep.png" in res.stdout


def test_dry_run_of_the_fit_sweep_plans_one_fit_per_changed_setting(tmp_path):
    """`snakemake fit_sweep`: the config's own fit (fit_smplx) and one fit_sweep_point per
    value of config fit_sweep that differs from it, each with its stages, then the table."""
    from signsplat.config import validate
    from signsplat.fit.sweep import AXES, axis_values, point_name

    res = snakemake("-n", "-p", "fit_sweep", "--config", f"results={tmp_path}")
    assert res.returncode == 0, res.stderr + res.stdout
    axes = validate({}, "config.schema.yaml")["fit_sweep"]
    centre = axis_values(validate({}, "stages/fit.schema.yaml"))
    expected = {point_name(a, v) for a in AXES for v in axes[a] if v != centre[a]}
    jobs = planned_jobs(res.stdout, "fit_sweep_point")
    planned = {re.search(r"point=([A-Za-z0-9_]+)", j).group(1): j for j in jobs}
    assert set(planned) == expected and len(expected) >= 4
    counts = job_counts(res.stdout)
    assert counts["fit_smplx"] == 1 and counts["fit_sweep_table"] == 1
    if "sil0" in planned:  # the keypoint stages only: no silhouette stage in its config
        assert '"name": "silhouette"' not in planned["sil0"]
        assert '"name": "silhouette"' in next(j for n, j in planned.items() if n != "sil0")
    assert f"{tmp_path}/studio6/fit_sweep.png" in res.stdout


def test_a_fit_the_sweep_cannot_edit_stops_only_the_fit_sweep(tmp_path):
    """Two stages with mask terms: the default run still plans its fits; `snakemake
    fit_sweep` fails naming both stages."""
    from signsplat.config import validate

    stages = validate({}, "stages/fit.schema.yaml")["multiview"]["stages"]
    again = {**next(s for s in stages if s.get("silhouette")), "name": "silhouette_again"}
    overlay = tmp_path / "two_silhouettes.yaml"
    overlay.write_text(yaml.safe_dump({"fit": {"multiview": {"stages": stages + [again]}}}))
    args = ("--configfile", str(overlay), "--config", f"results={tmp_path}")
    res = snakemake("-n", *args)
    assert res.returncode == 0, res.stderr + res.stdout
    assert job_counts(res.stdout)["fit_smplx"] == 2
    res = snakemake("-n", "fit_sweep", *args)
    assert res.returncode != 0
    assert "['silhouette', 'silhouette_again']" in res.stderr + res.stdout


def test_the_fit_gets_the_keypoint_offsets_of_its_sequence_s_detectors(tmp_path):
    """config fit.keypoint_offsets names a table per detector set: each fit of keypoints
    found by that set takes it as an input and passes it to `signsplat fit`."""
    table = tmp_path / "shipped_offsets.parquet"
    table.write_bytes(b"")
    res = snakemake("-n", "-p", "--config", f"results={tmp_path}",
                    f'fit={{"keypoint_offsets": {{"shipped": "{table}"}}}}')
    assert res.returncode == 0, res.stderr + res.stdout
    fits = planned_jobs(res.stdout, "fit_smplx")
    assert len(fits) == 2
    for job in fits:  # an input (a new table re-runs the fit) and the command's argument
        assert str(table) in job.split("output:")[0]
        assert f"--keypoint-offsets' '{table}'" in job
    # the default config: both sequences' right fingers are MediaPipe's (their sheet rows'
    # dominant_hand), fitted with the shipped pretrained table's finger rows
    res = snakemake("-n", "-p", "--config", f"results={tmp_path}")
    fits = jobs_by_scene(res.stdout, "fit_smplx")
    for scene in ("studio6", "single"):
        assert ("--keypoint-offsets' 'models/pretrained_keypoint_offsets.parquet'"
                " '--keypoint-offsets-fingers' 'right'") in fits[scene]
    # MediaPipe's right fingers in the shipped keypoints: the pretrained table's finger rows
    res = snakemake("-n", "-p", "--config", f"results={tmp_path}",
                    f'fit={{"keypoint_offsets": {{"pretrained": "{table}"}}}}',
                    'perception={"keypoints": {"hands": "mediapipe", "hand_sides": ["right"]}}')
    assert res.returncode == 0, res.stderr + res.stdout
    fits = planned_jobs(res.stdout, "fit_smplx")
    assert len(fits) == 2
    for job in fits:
        assert f"--keypoint-offsets' '{table}' '--keypoint-offsets-fingers' 'right'" in job


def test_tiny_study_config_reuses_equal_variants_and_names_a_bad_scene(tmp_path):
    cfg = tiny_study_config(tmp_path)
    res = snakemake("-n", "ablations", "sweep", "--configfile", str(cfg))
    assert res.returncode == 0, res.stderr + res.stdout
    assert planned_variants(res.stdout, "train_avatar") == {
        "demo", "abl_full_i4", "abl_no_reg_i4", "abl_no_dens_i4", "abl_no_acc_i4",
        "abl_no_disp_i4", "abl_static_i4", "abl_gt_smplx_i4", "abl_reg0p5_i4", "sw_iterations2"}
    bad = tiny_study_config(tmp_path, ablations={"scene": "nowhere", "base": {}})
    res = snakemake("-n", "ablations", "--configfile", str(bad))
    assert res.returncode != 0
    out = res.stdout + res.stderr
    assert "ablations.scene" in out and "'nowhere'" in out and "['tiny', 'tiny1']" in out
    # the error names the files the config came from
    line = next(x for x in out.splitlines() if "ablations.scene = 'nowhere'" in x)
    assert str(bad) in line and "config/config.yaml" in line, line


@pytest.mark.slow
def test_tiny_sweep_stitch_and_reports_run_end_to_end(tmp_path, tiny_run):
    """Real run on the tiny scene, from a copy of the session's finished run (its tiny demo
    avatar, trained, evaluated and signing a sentence): one sweep point is trained and
    evaluated beside the demo avatar, the sweep table and plot written, the HTML report shows
    them and the stitched video, and `snakemake --report` works."""
    results = tmp_path / "results"
    page = tmp_path / "report" / "index.html"
    shutil.copytree(tiny_run / "results", results)  # times kept: the copies are up to date
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump({**yaml.safe_load((tiny_run / "config.yaml").read_text()),
                                   **STUDIES, "results": str(results),
                                   "report": {"html": str(page)}}))
    stitched = results / "tiny" / "stitched" / "stitch_eval.parquet"
    res = snakemake("sweep", str(stitched), "--configfile", str(cfg), timeout=1800)
    assert res.returncode == 0, res.stderr[-4000:]
    # only the sweep point and its table ran: the demo avatar (the sweep's centre) is reused
    assert job_counts(res.stdout + res.stderr) == {
        "train_avatar": 1, "evaluate_avatar": 1, "sweep_table": 1, "sweep": 1, "total": 4}
    # the report takes the study tables that exist when its DAG is built (as `make sweep`
    # does, it runs after them; in one call with them the order would be up to the scheduler)
    res = snakemake(str(page), "--configfile", str(cfg), timeout=1800)
    assert res.returncode == 0, res.stderr[-4000:]
    sweep = pd.read_parquet(results / "tiny" / "sweep.parquet")
    assert sorted(sweep.setting) == ["demo", "sw_iterations2"]
    assert set(sweep.iterations) == {4, 2} and set(sweep.resolution) == {64}
    # seconds come from the benchmark files of the training jobs
    for _, row in sweep.iterrows():
        bench = results / "_benchmarks" / "tiny" / f"train_avatar_{row.setting}.tsv"
        assert row.seconds == pytest.approx(pd.read_csv(bench, sep="\t")["s"].mean())
    assert np.isfinite(sweep.psnr).all() and np.isfinite(sweep.seconds).all()
    # the front flags of the table's own (seconds, score) pairs: on it unless another setting
    # is no slower and no worse, and better in one
    for score in ("psnr", "ssim"):
        for _, row in sweep.iterrows():
            others = sweep[sweep.setting != row.setting]
            beaten = ((others.seconds <= row.seconds) & (others[score] >= row[score])
                      & ((others.seconds < row.seconds) | (others[score] > row[score]))).any()
            assert row[f"pareto_{score}"] == (not beaten), (score, row.setting)
    assert (results / "tiny" / "sweep.png").stat().st_size > 5000
    # the stitched video of the trained avatar, its 2D baseline and table
    ev = pd.read_parquet(stitched)
    assert len(ev) and (stitched.parent / "why-are-you-sad-5e802843.mp4").is_file()
    assert (stitched.parent / "why-are-you-sad-5e802843.baseline2d.mp4").is_file()
    html = page.read_text()
    stitch = html.split('id="stitch"')[1].split("<section")[0]
    assert "Not available" not in stitch and "stitch_eval.parquet" in stitch
    assert "2D baseline" in stitch and stitch.count("<figure>") == 8  # 4 frames x 2 videos
    sweep_sec = html.split('id="sweep"')[1].split("<section")[0]
    assert "Not available" not in sweep_sec and "sw_iterations2" in sweep_sec
    # Snakemake's own report over the finished outputs, with the captions
    out = tmp_path / "snakemake.html"
    res = snakemake("--report", str(out), "sweep", str(stitched), str(page),
                    "--configfile", str(cfg))
    assert res.returncode == 0, res.stderr[-4000:]
    assert out.stat().st_size > 100_000
    text = out.read_text(errors="replace")
    for words in ("Accuracy versus time", "Stitched video", "Pareto front"):
        assert words in text, words


def test_dry_run_passes_a_footage_calibration_to_the_fit(tmp_path):
    """Footage with a calibration file: the fit gets the extracted cameras table (intrinsics,
    and extrinsics with camera_init calibrated); footage without one gets none."""
    sheet = tmp_path / "sequences.tsv"
    calib = tmp_path / "calib.yaml"
    calib.write_text("views: []\n")
    sheet.write_text("sequence\tsource\tcameras\tcalibration\n"
                     f"withcal\tvideo\t{tmp_path}/a.mp4;{tmp_path}/b.mp4\t{calib}\n"
                     f"nocal\tvideo\t{tmp_path}/a.mp4;{tmp_path}/b.mp4\t\n")
    cfg = tmp_path / "config.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(tmp_path / "r"), "sequences": str(sheet),
                                   "scenes": []}))
    res = snakemake(str(tmp_path / "r" / "withcal" / "fit" / "smplx_fit.parquet"),
                    str(tmp_path / "r" / "nocal" / "fit" / "smplx_fit.parquet"),
                    "-n", "-p", "--configfile", str(cfg))
    assert res.returncode == 0, res.stderr[-3000:] + res.stdout[-3000:]
    fits = [line for line in res.stdout.splitlines() if " -m signsplat fit " in line]
    assert len(fits) == 2
    with_cal = [f for f in fits if "/withcal/" in f]
    no_cal = [f for f in fits if "/nocal/" in f]
    assert re.search(r"--calibration'? '?" + re.escape(f"{tmp_path}/r/withcal/frames/cameras.parquet"),
                     with_cal[0]), with_cal[0][-300:]
    assert "--calibration" not in no_cal[0]
    # a multi-view fit's params carry no single-view settings (changing those re-runs nothing)
    assert all('"multiview"' in f and '"singleview"' not in f for f in fits)


def test_dry_run_of_the_footage_config_uses_the_pretrained_detectors(tmp_path):
    """`make footage`: the example clip's row takes the pretrained detectors with its signer
    box, the frames resized at ingest, a single-view fit, the demo avatar and the footage
    measures; the clip and the models come from the fetch rules when the cache lacks them."""
    cache = tmp_path / "cache"
    cfg = tmp_path / "over.yaml"
    cfg.write_text(yaml.safe_dump({"results": str(tmp_path / "r"),
                                   "perception": {"pretrained": {"cache": str(cache)}}}))
    sheet = (ROOT / "config" / "footage.tsv").read_text().replace(
        "models/cache/demovideo.mp4", f"{cache}/demovideo.mp4")
    (tmp_path / "footage.tsv").write_text(sheet)
    over = yaml.safe_load((ROOT / "config" / "footage.yaml").read_text())
    over["sequences"] = str(tmp_path / "footage.tsv")
    over["report"] = {"html": str(tmp_path / "report" / "index.html")}
    (tmp_path / "footage.yaml").write_text(yaml.safe_dump(over))
    res = snakemake("-n", "-p", "--configfile", "config/config.yaml",
                    str(tmp_path / "footage.yaml"), str(cfg))
    assert res.returncode == 0, res.stderr[-3000:] + res.stdout[-3000:]
    counts = job_counts(res.stdout)
    for rule in ("fetch_modnet", "fetch_mediapipe", "fetch_assets", "extract_frames", "segment",
                 "detect_keypoints", "perception_quality", "fit_smplx", "train_avatar",
                 "evaluate_avatar", "report"):
        assert counts.get(rule) == 1, (rule, counts)
    assert "simulate" not in counts
    seg = [line for line in res.stdout.splitlines() if " -m signsplat segment " in line][0]
    assert "--detectors pretrained" in seg and '"box": [213.0, 14.0, 150.0, 242.0]' in seg
    # the fit fits MediaPipe's own keypoints (fit.keypoint_offsets.pretrained)
    fit = [line for line in res.stdout.splitlines() if " -m signsplat fit " in line][0]
    assert "--keypoint-offsets' 'models/pretrained_keypoint_offsets.parquet'" in fit
