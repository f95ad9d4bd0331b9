"""One home per default: the fit's dataclasses take their values from the validated config
(workflow/schemas/stages/fit.schema.yaml), and the fit mode has one answer."""

from dataclasses import dataclass

import numpy as np
import pytest

from signsplat.config import assert_defaults_match, default_mismatches, validate
from signsplat.errors import InputError
from signsplat.fit.mode import fit_mode, mode_config
from signsplat.fit.objective import Weights
from signsplat.fit.solver import Problem, Stage, make_problem, stage_config

FIT = "stages/fit.schema.yaml"


def test_the_helper_names_a_code_default_that_differs():
    @dataclass
    class Old:
        kernel: str
        sigma_px: float = 10.0  # the schema says 8
        unrelated: int = 3  # not a key of the section: not compared

    bad = default_mismatches(Old, {"kernel": "huber", "sigma_px": 8.0})
    assert bad == ["Old.sigma_px: code 10.0, schema 8.0"]
    with pytest.raises(AssertionError, match="sigma_px"):
        assert_defaults_match(Old, {"sigma_px": 8.0})
    assert_defaults_match(Old, {"sigma_px": 10.0})


def test_fit_dataclasses_match_the_schema_defaults(kpm):
    cfg = validate({}, FIT)
    weights = Weights.from_config(cfg["weights"])  # every weight comes from the schema
    assert weights.smooth_pose == cfg["weights"]["smooth_pose"]
    assert_defaults_match(Weights, cfg["weights"])
    with pytest.raises(ValueError, match="missing.*'shape'"):
        Weights.from_config({k: v for k, v in cfg["weights"].items() if k != "shape"})
    # a stage's defaults (the schema's $defs/stage), and every stage of the default lists
    written = stage_config(name="x", iterations=1, lr=0.1, groups=["root"])
    assert_defaults_match(Stage, written)
    assert Stage.from_config(written).smooth is True  # the schema's default
    stages = (cfg["multiview"]["stages"] + cfg["singleview"]["init_stages"]
              + cfg["singleview"]["refine_stages"])
    for s in stages:
        st = Stage.from_config(s)
        assert st.final_lr_fraction == s["final_lr_fraction"]
        assert st.warm_start == s["warm_start"] and st.optimizer == s["optimizer"]
    # the robust kernel: the problem takes the schema's scale (no second copy in the solver)
    assert_defaults_match(Problem, cfg["robust"])
    problem = make_problem(kpm, np.zeros((1, 3, 133, 3)), cfg)
    assert (problem.kernel, problem.sigma_px) == (cfg["robust"]["kernel"],
                                                  cfg["robust"]["sigma_px"])
    changed = validate({"robust": {"sigma_px": 3.5}}, FIT)
    assert make_problem(kpm, np.zeros((1, 3, 133, 3)), changed).sigma_px == 3.5


def test_fit_mode_has_one_answer():
    auto = validate({}, FIT)
    assert fit_mode(auto, 1) == "singleview" and fit_mode(auto, 2) == "multiview"
    forced = validate({"mode": "singleview"}, FIT)
    assert fit_mode(forced, 6) == "singleview"
    with pytest.raises(InputError, match="at least 2 cameras"):
        fit_mode(validate({"mode": "multiview"}, FIT), 1)
    # the workflow passes a scene only its mode's settings
    assert "singleview" not in mode_config(auto, 6) and "multiview" in mode_config(auto, 6)
    assert "multiview" not in mode_config(auto, 1)
