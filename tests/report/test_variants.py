"""The ablation and sweep variants: each ablation flips exactly one avatar switch of the shared
base, each sweep point changes exactly one setting of the centre."""

import pytest

from signsplat.avatar.config import resolve
from signsplat.config import deep_merge
from signsplat.report.variants import (SWITCH_FIELDS, ablation_plan, sweep_plan, sweep_values,
                                       switch_values)


def _diff(a, b, prefix=()):
    """Paths of the leaves that differ between two nested dicts."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k), b.get(k)
        if isinstance(va, dict) and isinstance(vb, dict):
            out += _diff(va, vb, prefix + (k,))
        elif va != vb:
            out.append(prefix + (k,))
    return out


def test_deep_merge_keeps_sibling_keys_and_does_not_touch_its_inputs():
    base = {"train": {"iterations": 10, "threads": 1}, "profile": "demo"}
    over = {"train": {"iterations": 20}, "model": {"hidden": 8}}
    out = deep_merge(base, over)
    assert out == {"train": {"iterations": 20, "threads": 1}, "profile": "demo",
                   "model": {"hidden": 8}}
    assert base["train"]["iterations"] == 10 and "model" not in base


def test_every_ablation_flips_exactly_one_switch_of_the_base():
    base = {"train": {"iterations": 12}}
    plan = ablation_plan(base, "fitted")
    assert [p.label for p in plan][0] == "full"
    full = resolve(plan[0].overrides)
    assert full["train"]["iterations"] == 12 and full["profile"] == "demo"
    expected = {"abl_no_reg": ("regularize", "enabled"), "abl_no_dens": ("strategy", "enabled"),
                "abl_no_acc": ("train", "accumulate"), "abl_no_disp": ("model", "displacement"),
                "abl_static": ("model", "pose_dependent"),
                "abl_gt_smplx": ("train", "smplx_source")}
    assert [p.name for p in plan[1:]] == list(expected)
    for p in plan[1:]:
        cfg = resolve(p.overrides)
        assert _diff(full, cfg) == [expected[p.name]], p.name
    assert resolve(plan[-1].overrides)["train"]["smplx_source"] == "ground_truth"
    assert switch_values(full) == {"regularize": True, "densify": True, "accumulate": True,
                                   "displacement": True, "pose_dependent": True,
                                   "smplx_source": "fitted"}
    assert set(SWITCH_FIELDS) == {"regularize", "densify", "accumulate", "displacement",
                                  "pose_dependent"}


def test_the_full_row_is_the_papers_model_whatever_the_demo_or_base_switch_off():
    assert resolve({"profile": "demo"})["regularize"]["enabled"] is False  # the demo's choice
    plan = ablation_plan({"strategy": {"enabled": False}}, "fitted")
    assert switch_values(resolve(plan[0].overrides)) == {
        "regularize": True, "densify": True, "accumulate": True, "displacement": True,
        "pose_dependent": True, "smplx_source": "fitted"}
    no_dens = next(p for p in plan if p.name == "abl_no_dens")
    assert switch_values(resolve(no_dens.overrides))["densify"] is False


def test_ablation_source_row_is_the_other_source_or_absent():
    plan = ablation_plan({"train": {"smplx_source": "ground_truth"}}, "ground_truth")
    assert plan[-1].name == "abl_fitted_smplx" and plan[-1].label == "fitted SMPL-X"
    assert resolve(plan[-1].overrides)["train"]["smplx_source"] == "fitted"
    assert [p.name for p in ablation_plan({}, "fitted", with_source=False)][-1] == "abl_static"


def test_sweep_points_change_one_setting_of_the_centre():
    plan = sweep_plan({"train": {"log_every": 3}},
                      {"iterations": [50, 90], "resolution": [64], "max_points": [300]})
    names = [p.name for p in plan]
    assert names == ["sw_base", "sw_iterations50", "sw_iterations90", "sw_resolution64",
                     "sw_max_points300"]
    centre = resolve(plan[0].overrides)
    paths = {"iterations": ("train", "iterations"), "resolution": ("train", "resolution"),
             "max_points": ("strategy", "max_points")}
    for p in plan[1:]:
        cfg = resolve(p.overrides)
        assert _diff(centre, cfg) == [paths[p.values["swept"]]], p.name
        assert cfg["train"]["log_every"] == 3  # the base is under every point
    v = sweep_values(resolve(plan[3].overrides), native_size=256)
    assert v == {"iterations": centre["train"]["iterations"], "resolution": 64,
                 "max_points": centre["strategy"]["max_points"]}
    assert sweep_values(centre, native_size=256)["resolution"] == 256  # 0 = native


def test_sweep_rejects_an_unknown_axis_by_name():
    with pytest.raises(ValueError, match=r"unknown axis \['lr'\]; allowed"):
        sweep_plan({}, {"lr": [1]})
