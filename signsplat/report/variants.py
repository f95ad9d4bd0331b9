"""The avatar variants behind the ``ablations`` and ``sweep`` workflow targets (plain data).

A variant is the ``avatar`` config section with overrides applied (see workflow/rules/avatar.smk).
Ablation variants start from the paper's full model: the demo profile plus the config's
``ablations.base`` with every switch on (:data:`FULL_MODEL`; the demo profile itself leaves
regularisation off). Each row then flips exactly one switch of the avatar schema (paper Table 5,
plus the displacement of eq. 3, the static mesh-anchored baseline and the SMPL-X source).
Sweep variants change one of training iterations, image resolution or point budget of the
``sweep.base`` setting at a time (a one-factor-at-a-time sweep around the centre).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

from signsplat.config import deep_merge

# The avatar-schema fields of the ablation's switches, read back as the switch columns of
# ablations.parquet.
SWITCH_FIELDS = {"regularize": ("regularize", "enabled"), "densify": ("strategy", "enabled"),
                 "accumulate": ("train", "accumulate"), "displacement": ("model", "displacement"),
                 "pose_dependent": ("model", "pose_dependent")}
# (variant name, row label, the switch of SWITCH_FIELDS the row turns off; None: the full row)
_ROWS: list[tuple[str, str, str | None]] = [
    ("abl_full", "full", None),
    ("abl_no_reg", "w/o regularisation", "regularize"),
    ("abl_no_dens", "w/o densification", "densify"),
    ("abl_no_acc", "w/o loss accumulation", "accumulate"),
    ("abl_no_disp", "w/o displacement (eq. 3)", "displacement"),
    ("abl_static", "w/o pose-dependent networks (static mesh-anchored)", "pose_dependent"),
]


def _switch(name: str, on: bool) -> dict:
    section, key = SWITCH_FIELDS[name]
    return {section: {key: on}}


# The paper's full model: every switch on, whatever the demo profile or ablations.base say.
FULL_MODEL = functools.reduce(deep_merge, (_switch(n, True) for n in SWITCH_FIELDS), {})
SWEEP_AXES = {"iterations": ("train", "iterations"), "resolution": ("train", "resolution"),
              "max_points": ("strategy", "max_points")}


def _get(cfg: dict, path: tuple[str, str]) -> Any:
    return cfg[path[0]][path[1]]


@dataclass
class Planned:
    """One ablation row or sweep point: its label, the variant's overrides of the ``avatar``
    section, and the values shown beside its scores."""

    label: str
    name: str
    overrides: dict
    values: dict = field(default_factory=dict)


def ablation_plan(base: dict, base_source: str, with_source: bool = True) -> list[Planned]:
    """The ablation rows. ``base``: avatar overrides shared by every row (over the demo profile);
    ``base_source``: the SMPL-X source the resolved base trains on (``fitted`` or
    ``ground_truth``); ``with_source``: add the row that trains on the other source (only when
    the sequence has ground truth). Every row starts from :data:`FULL_MODEL`, so a switch in
    ``base`` is overridden."""
    start = deep_merge(deep_merge({"profile": "demo"}, base), FULL_MODEL)
    rows = [Planned(label, name, deep_merge(start, _switch(off, False) if off else {}))
            for name, label, off in _ROWS]
    if with_source:
        other = "ground_truth" if base_source == "fitted" else "fitted"
        name = "abl_gt_smplx" if other == "ground_truth" else "abl_fitted_smplx"
        label = ("ground-truth SMPL-X" if other == "ground_truth" else "fitted SMPL-X")
        rows.append(Planned(label, name, deep_merge(start, {"train": {"smplx_source": other}})))
    return rows


#: The regulariser's variance weights (one per Gaussian parameter it acts on).
REGULARIZER_WEIGHTS = ("w_scale", "w_rotation", "w_opacity", "w_color", "w_sh_rest")


def regularizer_plan(full: dict, scales: list[float], resolved_full: dict
                     ) -> list[tuple[float, dict]]:
    """The full model's overrides with the regulariser's variance weights times each scale
    (``resolved_full``: the full model's resolved config, whose weights are scaled; 0 = the
    regulariser off): ``[(scale, overrides), ...]``."""
    weights = resolved_full["regularize"]
    out = []
    for scale in scales:
        reg = {"enabled": scale > 0}
        if scale > 0:
            reg.update({w: float(weights[w]) * scale for w in REGULARIZER_WEIGHTS})
        out.append((float(scale), deep_merge(full, {"regularize": reg})))
    return out


def switch_values(resolved: dict) -> dict:
    """The switch columns (:data:`SWITCH_FIELDS` and smplx_source) of a
    resolved avatar config."""
    out = {k: bool(_get(resolved, p)) for k, p in SWITCH_FIELDS.items()}
    out["smplx_source"] = resolved["train"]["smplx_source"]
    return out


def ablation_columns(rows: list[dict], variants: dict[str, dict]) -> list[dict]:
    """The rows of ``ablations.parquet`` before scoring: label, budget, variant and switch
    columns, from the plan's rows (``{"label", "iterations", "variant"}``) and the resolved
    configs ``{name: avatar section}``. The SMPL-X source is not among them: the table reads
    what each variant trained on from its metrics."""
    out = []
    for row in rows:
        switches = switch_values(variants[row["variant"]])
        switches.pop("smplx_source")
        out.append({"label": row["label"], "iterations": row["iterations"],
                    "variant": row["variant"], **switches})
    return out


def sweep_plan(base: dict, axes: dict[str, list[int]]) -> list[Planned]:
    """The sweep points: the centre (demo profile + ``base``) and, for every axis in ``axes``
    (iterations, resolution, max_points), one point per listed value with only that value
    changed. Names: ``sw_base``, ``sw_iterations{v}``, ``sw_resolution{v}``, ``sw_max_points{v}``.
    ``values`` holds the axis that moved (``swept``) and its value."""
    unknown = sorted(set(axes) - set(SWEEP_AXES))
    if unknown:
        raise ValueError(f"sweep: unknown axis {unknown}; allowed {sorted(SWEEP_AXES)}")
    start = deep_merge({"profile": "demo"}, base)
    points = [Planned("centre", "sw_base", start, {"swept": "centre"})]
    for axis, values in axes.items():
        section, key = SWEEP_AXES[axis]
        for v in values:
            points.append(Planned(f"{axis}={v}", f"sw_{axis}{int(v)}",
                                  deep_merge(start, {section: {key: int(v)}}),
                                  {"swept": axis}))
    return points


def sweep_values(resolved: dict, native_size: int) -> dict:
    """Iterations, image side in pixels (``native_size`` when the resolution is 0 = native) and
    point budget of a resolved avatar config."""
    res = int(resolved["train"]["resolution"])
    return {"iterations": int(resolved["train"]["iterations"]),
            "resolution": res if res > 0 else int(native_size),
            "max_points": int(resolved["strategy"]["max_points"])}
