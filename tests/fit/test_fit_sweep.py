"""The fit sweep's points (signsplat.fit.sweep): one costly setting changed at a time from the
config's own fit, and nothing added that the config's fit does not have."""

import copy

import pytest

from signsplat.config import ConfigError, validate
from signsplat.fit.sweep import DEFAULT_POINT, axis_values, sweep_points, with_value

ALL = {"silhouette_iterations": [0, 250, 500, 1000], "flow": ["none", "ultrafast", "medium"],
       "lm_iterations": [20, 60]}


@pytest.fixture(scope="module")
def fit():
    return validate({}, "stages/fit.schema.yaml")


def _stages(cfg):
    return {s["name"]: s for s in cfg["multiview"]["stages"]}


def test_points_change_one_setting_each_and_skip_the_configs_own_values(fit):
    centre = axis_values(fit)
    stages = _stages(fit)
    assert centre == {"silhouette_iterations": stages["silhouette"]["iterations"],
                      "flow": fit["multiview"]["flow"]["preset"],
                      "lm_iterations": stages["joint"]["iterations"]}
    points = {p.name: p for p in sweep_points(fit, ALL)}
    # the config's own values give no extra point
    expected = [DEFAULT_POINT] + [f"{short}{v}" for axis, short in (
        ("silhouette_iterations", "sil"), ("flow", "flow_"), ("lm_iterations", "lm"))
        for v in ALL[axis] if v != centre[axis]]
    assert list(points) == expected and len(expected) == 1 + 3 + 2 + 1
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
    lm = next(n for n in points if n.startswith("lm"))
    assert _stages(points[lm].fit)["joint"]["iterations"] == points[lm].values["lm_iterations"]
    # every other setting is the config's own, and the config itself is not modified
    assert fit == validate({}, "stages/fit.schema.yaml")
    other = copy.deepcopy(points[lm].fit)
    _stages(other)["joint"]["iterations"] = centre["lm_iterations"]
    assert other == fit


def test_a_fit_without_the_swept_stages_gets_no_points_for_them(fit):
    no_sil = with_value(fit, "silhouette_iterations", 0)
    points = {p.name for p in sweep_points(no_sil, ALL)}
    assert points == {DEFAULT_POINT} | {f"lm{v}" for v in ALL["lm_iterations"]
                                        if v != axis_values(fit)["lm_iterations"]}
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
