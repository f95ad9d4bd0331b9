"""signsplat.plan: what a run does, decided from its config (no Snakemake needed)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from signsplat.avatar.config import EVAL_ONLY_KEYS
from signsplat.config import ConfigError, validate
from signsplat.plan import plan
from signsplat.report.variants import SWITCH_FIELDS

ROOT = Path(__file__).resolve().parents[1]


def _config(tmp_path, sheet_rows=None, **over):
    user = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    user.update(over)
    if sheet_rows is not None:
        sheet = tmp_path / "sequences.tsv"
        sheet.write_text("sequence\tsource\tspec\tcameras\n" + "".join(
            "\t".join(r) + "\n" for r in sheet_rows))
        user["sequences"] = str(sheet)
    return validate(copy.deepcopy(user), "config.schema.yaml"), user


def test_default_config_plans_the_demo_studies_and_the_default_scene(tmp_path):
    cfg, user = _config(tmp_path)
    p = plan(cfg, user, root=ROOT)
    assert list(p.sequences) == ["studio6", "single"]
    assert p.default_scene == p.ablation_scene == p.sweep_scene == p.quality_scene == "studio6"
    assert p.multiview_scenes == ["studio6"]
    assert p.fit_mode("studio6", cfg["fit"]) == "multiview"
    assert p.fit_mode("single", cfg["fit"]) == "singleview"
    assert {"demo", "quality"} <= set(p.variants)
    assert p.variants["quality"]["train"]["iterations"] > p.variants["demo"]["train"]["iterations"]
    # the full model, one row per switch off and the SMPL-X source row, at each budget; each
    # a distinct variant
    budgets = cfg["ablations"]["iterations"]
    n = len(SWITCH_FIELDS) + 2
    assert [r["label"] for r in p.ablations[::n]] == ["full"] * len(budgets)
    assert len(p.ablations) == n * len(budgets)
    assert len({r["variant"] for r in p.ablations}) == n * len(budgets)
    assert [r["iterations"] for r in p.ablations] == [b for b in budgets for _ in range(n)]
    assert {tuple(p.variants[r["variant"]]["train"]["test_views"]) for r in p.ablations} == \
        {tuple(cfg["ablations"]["test_views"])}
    # the regulariser's sweep: scale 0 is the row without it, scale 1 the full model
    rows = {(r["label"], r["iterations"]): r["variant"] for r in p.ablations}
    for r in p.regularizer:
        if r["scale"] == 0:
            assert r["variant"] == rows[("w/o regularisation", r["iterations"])]
        elif r["scale"] == 1:
            assert r["variant"] == rows[("full", r["iterations"])]
        else:
            reg = p.variants[r["variant"]]["regularize"]
            full = p.variants[rows[("full", r["iterations"])]]["regularize"]
            assert reg["w_scale"] == pytest.approx(r["scale"] * full["w_scale"])
    assert p.sweep["demo"]["swept"] == "demo"


def test_equal_resolved_configs_are_one_variant(tmp_path):
    """With an empty ablation base the full model minus regularisation is the demo profile
    (which leaves regularisation off): the row points at `demo`, trained once."""
    cfg, user = _config(tmp_path, ablations={"scene": None, "base": {}, "iterations": [],
                                             "test_views": [], "regularizer_scales": []})
    p = plan(cfg, user, root=ROOT)
    rows = {r["label"]: r["variant"] for r in p.ablations}
    assert rows["w/o regularisation"] == "demo" and "abl_no_reg" not in p.variants
    assert rows["full"] == "abl_full"


def test_held_out_cameras_the_study_sequence_lacks_are_left_out(tmp_path):
    cfg, user = _config(tmp_path, ablations={"scene": "single", "base": {},
                                             "test_views": [1, 3], "iterations": [300],
                                             "regularizer_scales": []})
    p = plan(cfg, user, root=ROOT)  # one camera: nothing to hold out, novel poses only
    assert {tuple(p.variants[r["variant"]]["train"]["test_views"]) for r in p.ablations} == {()}


def test_the_user_avatar_section_is_under_every_variant(tmp_path):
    cfg, user = _config(tmp_path, avatar={"train": {"log_every": 7}})
    p = plan(cfg, user, root=ROOT)
    assert {v["train"]["log_every"] for v in p.variants.values()} == {7}


def test_sections_for_training_and_evaluation(tmp_path):
    cfg, user = _config(tmp_path)
    p = plan(cfg, user, root=ROOT)
    train = p.train_section("demo", "studio6")
    assert not set(EVAL_ONLY_KEYS) & set(train["eval"])
    sweep_point = next(v for v in p.sweep if v != "demo" and
                       p.variants[v]["train"]["resolution"] not in (0,))
    assert p.eval_section(sweep_point, "studio6")["train"]["resolution"] == 0
    assert p.eval_section("quality", "studio6")["train"]["resolution"] == \
        p.variants["quality"]["train"]["resolution"]


def test_footage_runs_fitted_and_names_what_is_wrong(tmp_path):
    cfg, user = _config(tmp_path, sheet_rows=[("clip", "video", "", "a.mp4"),
                                              ("solo", "synthetic", "config/scenes/single.yaml", "")])
    p = plan(cfg, user, root=ROOT)
    assert p.videos == {"clip": p.sequences["clip"]} and list(p.scenes) == ["solo"]
    assert p.default_scene == "solo"  # no multi-view scene: the first synthetic one
    assert p.smplx_source("demo", "clip") == "fitted"
    gt = next(r["variant"] for r in p.ablations
              if p.variants[r["variant"]]["train"]["smplx_source"] == "ground_truth")
    with pytest.raises(ConfigError, match=rf"{gt}.*'clip' is footage.*allowed here: fitted"):
        p.smplx_source(gt, "clip")


def test_a_study_on_an_unknown_sequence_names_the_key_and_the_choices(tmp_path):
    cfg, user = _config(tmp_path, sweep={"scene": "nowhere", "base": {}, "iterations": [],
                                         "resolution": [], "max_points": []})
    with pytest.raises(ConfigError, match=r"sweep.scene = 'nowhere'.*\['single', 'studio6'\]"):
        plan(cfg, user, root=ROOT)


def test_the_fit_sweep_runs_on_a_multi_view_sequence_with_its_own_mode_config(tmp_path):
    cfg, user = _config(tmp_path)
    p = plan(cfg, user, root=ROOT)
    assert p.fit_sweep_scene == "studio6"
    assert "default" in p.fit_sweep and len(p.fit_sweep) > 1
    assert p.fit_sweep["default"].fit == cfg["fit"]
    point = next(n for n in p.fit_sweep if n != "default")
    section = p.fit_sweep_config(point)
    assert "singleview" not in section and section["multiview"] == \
        p.fit_sweep[point].fit["multiview"]
    assert p.fit_sweep_values[point]["swept"] == p.fit_sweep[point].axis
    # a single-camera sequence named for it: the key, the value and the allowed ones
    cfg, user = _config(tmp_path, fit_sweep={"scene": "single"})
    with pytest.raises(ConfigError, match=r"fit_sweep.scene = 'single'.*allowed: \['studio6'\]"):
        plan(cfg, user, root=ROOT)
    # no multi-view sequence, or the single-view fit forced: nothing to sweep, no error
    cfg, user = _config(tmp_path, [("solo", "synthetic", "config/scenes/single.yaml", "")])
    assert plan(cfg, user, root=ROOT).fit_sweep == {}
    cfg, user = _config(tmp_path, fit={"mode": "singleview"})
    assert plan(cfg, user, root=ROOT).fit_sweep == {}
    # two stages an axis could edit: the plan keeps the reason for the fit sweep's target
    stages = cfg["fit"]["multiview"]["stages"]
    again = {**next(s for s in stages if s.get("silhouette")), "name": "silhouette_again"}
    cfg, user = _config(tmp_path, fit={"multiview": {"stages": stages + [again]}})
    p = plan(cfg, user, root=ROOT)
    assert p.fit_sweep == {} and p.fit_sweep_scene is None
    assert "['silhouette', 'silhouette_again']" in p.fit_sweep_error


def test_job_threads_share_the_local_cores_between_sequences():
    from signsplat.plan import STAGE_THREADS, job_threads

    assert STAGE_THREADS == 2
    # two sequences on two cores: one thread per job, so both chains run side by side
    assert job_threads(2, 2) == 1
    # one sequence, or cores enough for every chain: the stage's own two threads
    assert job_threads(1, 2) == 2
    assert job_threads(2, 4) == 2 and job_threads(3, 16) == 2
    # more sequences than cores: still one thread
    assert job_threads(5, 2) == 1 and job_threads(3, 4) == 1
    # no local cores given (a cluster: each job has its own): the stage's own
    assert job_threads(10, None) == 2


def test_a_single_view_chain_shares_the_cores_and_a_multi_view_fit_keeps_two(tmp_path):
    cfg, user = _config(tmp_path)
    p = plan(cfg, user, root=ROOT)  # studio6 (6 cameras) and single (1)
    # two sequences on two cores: single's keypoints and fit take one thread, beside an avatar
    assert p.chain_threads("studio6", 2) == 2 and p.chain_threads("single", 2) == 1
    # cores enough for both chains, or a cluster's own allocations: two threads each
    assert p.chain_threads("single", 4) == 2 and p.chain_threads("single", None) == 2
    assert p.chain_threads("studio6", None) == 2
