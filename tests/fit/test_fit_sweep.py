"""The fit sweep's points (signsplat.fit.sweep): one costly setting changed at a time from the
config's own fit, and nothing added that the config's fit does not have."""

import copy

import pytest

from signsplat.config import ConfigError, validate
from signsplat.fit.sweep import DEFAULT_POINT, axis_values, sweep_points, with_value

ALL = {"silhouette_iterations": [0, 250, 1000], "flow": ["none", "ultrafast", "medium"],
       "lm_iterations": [20, 60]}


@pytest.fixture(scope="module")
def fit():
    return validate({}, "stages/fit.schema.yaml")


def _stages(cfg):
    return {s["name"]: s for s in cfg["multiview"]["stages"]}


def test_points_change_one_setting_each_and_skip_the_configs_own_values(fit):
    centre = axis_values(fit)
    assert centre == {"silhouette_iterations": 1000, "flow": "medium", "lm_iterations": 60}
    points = {p.name: p for p in sweep_points(fit, ALL)}
    # 1000 steps, medium flow and 60 LM iterations are the config's own: no extra point
    assert list(points) == [DEFAULT_POINT, "sil0", "sil250", "flow_none", "flow_ultrafast",
                            "lm20"]
    assert points[DEFAULT_POINT].fit == fit
    for p in list(points.values())[1:]:
        changed = {k for k in centre if p.values[k] != centre[k]}
        # the silhouette stage left out also leaves its flow out; otherwise one axis moves
        assert changed == ({"silhouette_iterations", "flow"} if p.name == "sil0"
                           else {p.axis})
        assert axis_values(p.fit) == p.values
    assert "silhouette" not in _stages(points["sil0"].fit)
    assert _stages(points["sil250"].fit)["silhouette"]["iterations"] == 250
    assert _stages(points["flow_none"].fit)["silhouette"]["flow"] == 0
    assert points["flow_ultrafast"].fit["multiview"]["flow"]["preset"] == "ultrafast"
    assert _stages(points["lm20"].fit)["joint"]["iterations"] == 20
    # every other setting is the config's own, and the config itself is not modified
    assert fit == validate({}, "stages/fit.schema.yaml")
    other = copy.deepcopy(points["lm20"].fit)
    _stages(other)["joint"]["iterations"] = 60
    assert other == fit


def test_a_fit_without_the_swept_stages_gets_no_points_for_them(fit):
    no_sil = with_value(fit, "silhouette_iterations", 0)
    points = {p.name for p in sweep_points(no_sil, ALL)}
    assert points == {DEFAULT_POINT, "lm20"}
    no_flow = with_value(fit, "flow", "none")
    assert {p.axis for p in sweep_points(no_flow, ALL)} == {DEFAULT_POINT,
                                                            "silhouette_iterations",
                                                            "lm_iterations"}


def test_two_stages_an_axis_could_mean_is_a_clear_error(fit):
    cfg = copy.deepcopy(fit)
    stages = cfg["multiview"]["stages"]
    stages.append({**_stages(cfg)["joint"], "name": "joint_again"})
    with pytest.raises(ConfigError, match=r"optimizer: lm.*\['joint', 'joint_again'\]"):
        sweep_points(cfg, ALL, source="my.yaml")
