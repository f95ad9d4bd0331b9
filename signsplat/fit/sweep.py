"""The fit's accuracy-versus-time sweep: fit configs one costly setting away from the config's.

Three axes (config ``fit_sweep``, README "The report"), all of the multi-view fit:

- ``silhouette_iterations``: Adam steps of the stage with the mask terms (0 = the stage is
  left out, so neither masks nor images are read and no optical flow is computed);
- ``flow``: that stage's optical-flow term, ``none`` (weight 0) or an OpenCV DIS preset;
- ``lm_iterations``: iterations of the Levenberg-Marquardt stage.

:func:`sweep_points` returns the config's own fit (``default``) and one point per listed value
that differs from it. Plain data, no heavy import: the Snakefile plans with it at parse time.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

from signsplat.config import ConfigError

AXES = ("silhouette_iterations", "flow", "lm_iterations")
#: the config's own fit: the workflow's ``fit_smplx`` result is this point
DEFAULT_POINT = "default"
_SHORT = {"silhouette_iterations": "sil", "flow": "flow_", "lm_iterations": "lm"}


@dataclass(frozen=True)
class FitPoint:
    """One fit of the sweep: its name, the axis it changes (``default`` for the centre), the
    values of every axis, and the whole ``fit`` section it runs with."""

    name: str
    axis: str
    values: dict[str, Any]
    fit: dict


def _stage_index(stages: list[dict], kind: str, source: str) -> int | None:
    """The multi-view stage an axis edits: the one with mask terms (``silhouette``) or the
    Levenberg-Marquardt one (``lm``); None when there is none, an error when there are two."""
    if kind == "silhouette":
        found = [i for i, s in enumerate(stages) if s.get("silhouette")]
    else:
        found = [i for i, s in enumerate(stages) if s.get("optimizer") == "lm"]
    if len(found) > 1:
        what = "a silhouette setting" if kind == "silhouette" else "optimizer: lm"
        raise ConfigError(f"{source}: the fit sweep edits the one stage of "
                          f"fit.multiview.stages with {what}; found "
                          f"{[stages[i]['name'] for i in found]}")
    return found[0] if found else None


def axis_values(fit: dict, source: str = "config") -> dict[str, Any]:
    """The values of the three axes in a validated ``fit`` section: a left-out silhouette
    stage counts as 0 iterations and flow ``none``; no Levenberg-Marquardt stage as 0."""
    mv = fit["multiview"]
    stages = mv["stages"]
    lm = _stage_index(stages, "lm", source)
    sil = _stage_index(stages, "silhouette", source)
    flow = "none"
    if sil is not None and stages[sil].get("flow", 0) > 0:
        flow = mv["flow"]["preset"]
    return {"silhouette_iterations": 0 if sil is None else stages[sil]["iterations"],
            "flow": flow, "lm_iterations": 0 if lm is None else stages[lm]["iterations"]}


def applies(centre: dict[str, Any], axis: str) -> bool:
    """Whether an axis can be changed from ``centre``'s values: the silhouette and flow axes
    need a silhouette stage, the flow axis its flow term, the LM axis an LM stage (a sweep
    does not add stages or terms)."""
    if axis == "lm_iterations":
        return centre["lm_iterations"] > 0
    if axis == "flow":
        return centre["flow"] != "none"
    return centre["silhouette_iterations"] > 0


def with_value(fit: dict, axis: str, value: Any, source: str = "config") -> dict:
    """A copy of the ``fit`` section with one axis set to ``value``."""
    out = copy.deepcopy(fit)
    mv = out["multiview"]
    stages = mv["stages"]
    if axis == "lm_iterations":
        stages[_stage_index(stages, "lm", source)]["iterations"] = int(value)
    elif axis == "silhouette_iterations":
        i = _stage_index(stages, "silhouette", source)
        if int(value) == 0:
            del stages[i]
        else:
            stages[i]["iterations"] = int(value)
    elif axis == "flow":
        stage = stages[_stage_index(stages, "silhouette", source)]
        if value == "none":
            stage["flow"] = 0
        else:
            if not stage.get("flow"):
                raise ConfigError(f"{source}: fit_sweep.flow = {value!r} needs a flow weight "
                                  f"in the stage {stage['name']!r} of fit.multiview.stages; "
                                  "it has none (allowed there: none)")
            mv["flow"]["preset"] = value
    else:
        raise ConfigError(f"{source}: unknown fit sweep axis {axis!r}; allowed: {list(AXES)}")
    return out


def point_name(axis: str, value: Any) -> str:
    return f"{_SHORT[axis]}{value}"


def sweep_points(fit: dict, axes: dict[str, list], source: str = "config") -> list[FitPoint]:
    """The config's own fit and, for each axis in ``axes`` and each of its values, the fit
    with that one value changed; values equal to the config's own give no extra point, nor
    do axes whose stage the config's fit does not have (:func:`applies`)."""
    centre = axis_values(fit, source)
    points = [FitPoint(DEFAULT_POINT, DEFAULT_POINT, centre, fit)]
    for axis in AXES:
        if not applies(centre, axis):
            continue
        for value in axes.get(axis, []):
            if value == centre[axis]:
                continue
            changed = with_value(fit, axis, value, source)
            points.append(FitPoint(point_name(axis, value), axis,
                                   axis_values(changed, source), changed))
    return points
