"""What one workflow run does, decided from its config: the planning behind the rules.

:func:`plan` reads the validated config (and the user's config before the schema filled its
defaults, under which a named avatar profile applies) and returns a :class:`Plan`: the run's
sequences, the default multi-view scene, the fit mode of each sequence, and the avatar
variants: the ``demo`` and ``quality`` profiles, the ablation rows and the sweep points
(:mod:`signsplat.report.variants`), each trained once per resolved config. The ``.smk`` files
only wire rules to it; nothing here touches a file but the config's own.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

from signsplat.avatar.config import EVAL_ONLY_KEYS
from signsplat.avatar.config import resolve as resolve_avatar
from signsplat.config import ConfigError, deep_merge, load_sequences
from signsplat.fit.mode import fit_mode, mode_config
from signsplat.fit.sweep import AXES as FIT_SWEEP_AXES
from signsplat.fit.sweep import FitPoint, sweep_points
from signsplat.report.variants import (ablation_plan, regularizer_plan, sweep_plan,
                                       sweep_values)

#: The variants `rule all` trains (the quality profile is asked for by `snakemake quality`).
DEFAULT_VARIANTS = ("demo",)
#: Threads a job of a multi-threaded stage (torch, OpenCV, ONNX Runtime) asks for at most.
STAGE_THREADS = 2
PROFILE_VARIANTS = {"demo": {"profile": "demo"}, "quality": {"profile": "quality"}}


@dataclass
class Plan:
    """The run's sequences and avatar variants (see :func:`plan`)."""

    sequences: dict[str, dict]
    #: variant name -> its overrides of the user's ``avatar`` section
    variant_overrides: dict[str, dict] = field(default_factory=dict)
    #: variant name -> resolved avatar section (schema defaults, profile, overrides)
    variants: dict[str, dict] = field(default_factory=dict)
    #: ablation rows in table order: {"label", "iterations", "variant", "overrides"}
    ablations: list[dict] = field(default_factory=list)
    #: the regulariser's weight sweep: {"scale", "iterations", "variant"}
    regularizer: list[dict] = field(default_factory=list)
    #: sweep variant -> the values shown beside its scores
    sweep: dict[str, dict] = field(default_factory=dict)
    #: the fit's sweep: point name -> :class:`~signsplat.fit.sweep.FitPoint` (``default`` is
    #: the config's own fit); empty when no multi-view sequence is there to sweep
    fit_sweep: dict[str, FitPoint] = field(default_factory=dict)
    fit_sweep_scene: str | None = None
    #: why the config's fit cannot be swept (the sweep's axes would be ambiguous); raised only
    #: when the fit sweep is asked for, so that every other target still runs
    fit_sweep_error: str | None = None
    ablation_scene: str | None = None
    sweep_scene: str | None = None
    quality_scene: str | None = None
    #: where the config came from, for error messages
    source: str = "config/config.yaml"

    @property
    def scenes(self) -> dict[str, dict]:
        """Synthetic sequences: name -> validated scene spec."""
        return {n: r["scene"] for n, r in self.sequences.items() if r["source"] == "synthetic"}

    @property
    def videos(self) -> dict[str, dict]:
        """Footage sequences: name -> sheet row."""
        return {n: r for n, r in self.sequences.items() if r["source"] == "video"}

    def num_views(self, sequence: str) -> int:
        return self.sequences[sequence]["num_views"]

    @property
    def multiview_scenes(self) -> list[str]:
        """Synthetic sequences with more than one camera (the COLMAP comparison's)."""
        return [n for n in self.scenes if self.num_views(n) > 1]

    @property
    def default_scene(self) -> str | None:
        """The default multi-view scene: the first synthetic sequence with more than one
        camera, else the first synthetic one, else the first sequence."""
        return (self.multiview_scenes or list(self.scenes) or list(self.sequences) or [None])[0]

    def fit_mode(self, sequence: str, fit_config: dict) -> str:
        """``multiview`` or ``singleview`` (:func:`signsplat.fit.mode.fit_mode`)."""
        return fit_mode(fit_config, self.num_views(sequence))

    @property
    def fit_sweep_values(self) -> dict[str, dict]:
        """Fit sweep point -> ``{"swept": axis, <each axis>: value}`` (its table's columns)."""
        return {n: {"swept": pt.axis, **pt.values} for n, pt in self.fit_sweep.items()}

    def fit_sweep_config(self, point: str) -> dict:
        """A fit sweep point's ``fit`` section for the sweep's sequence (its mode only)."""
        return mode_config(self.fit_sweep[point].fit, self.num_views(self.fit_sweep_scene))

    def smplx_source(self, variant: str, sequence: str) -> str:
        """Where a variant's SMPL-X and cameras come from on a sequence: ``fitted`` (the fit
        stage) or ``ground_truth`` (the simulator's; footage has none)."""
        want = self.variants[variant]["train"]["smplx_source"]
        if want == "ground_truth" and sequence not in self.scenes:
            raise ConfigError(
                f"avatar variant {variant!r} asks for train.smplx_source: ground_truth, but "
                f"sequence {sequence!r} is footage with no ground-truth SMPL-X; allowed here: "
                "fitted (for the studies: set it in ablations.base / sweep.base of the config)")
        return want

    def avatar_section(self, variant: str, sequence: str) -> dict:
        """A variant's resolved avatar section with the SMPL-X source of the sequence."""
        cfg = copy.deepcopy(self.variants[variant])
        cfg["train"]["smplx_source"] = self.smplx_source(variant, sequence)
        return cfg

    def train_section(self, variant: str, sequence: str) -> dict:
        """The training's config: without the settings only the evaluation reads, so that
        changing them re-runs the evaluation and not the training."""
        cfg = self.avatar_section(variant, sequence)
        cfg["eval"] = {k: v for k, v in cfg["eval"].items() if k not in EVAL_ONLY_KEYS}
        return cfg

    def eval_section(self, variant: str, sequence: str) -> dict:
        """The evaluation's config; sweep points are scored at the native image size, so that
        scores compare across training resolutions."""
        cfg = self.avatar_section(variant, sequence)
        if variant in self.sweep:
            cfg["train"]["resolution"] = 0
        return cfg

    def add_variant(self, name: str, overrides: dict, base: dict) -> str:
        """Register a variant; the name of an earlier one with the same resolved config
        instead when there is one (it is trained once)."""
        resolved = resolve_avatar(deep_merge(base, overrides), f"avatar variant {name!r}")
        for known, cfg in self.variants.items():
            if cfg == resolved:
                return known
        self.variant_overrides[name] = overrides
        self.variants[name] = resolved
        return name

    def job_threads(self, cores: int | None) -> int:
        """Threads of one job of a multi-threaded stage when the run's sequences share
        ``cores`` (:func:`job_threads`; None: every job has cores of its own, as on a
        cluster)."""
        return job_threads(len(self.sequences), cores)

    def chain_threads(self, sequence: str, cores: int | None) -> int:
        """Threads of a sequence's keypoint and fit jobs when the run's sequences share
        ``cores``: a multi-view sequence keeps STAGE_THREADS (its fit is the longest job before
        the avatars and gains from a second thread); a single-view sequence takes its share
        (:meth:`job_threads`), so that its short chain runs beside another sequence's avatar
        instead of holding every core while that avatar waits."""
        if self.num_views(sequence) > 1:
            return STAGE_THREADS
        return self.job_threads(cores)

    def study_scene(self, config: dict, key: str) -> str | None:
        """Config ``<key>.scene``, or the default multi-view scene."""
        scene = config[key]["scene"]
        if scene is None:
            return self.default_scene
        if scene not in self.sequences:
            raise ConfigError(f"{self.source}: {key}.scene = {scene!r} is not a sequence "
                              f"of this run; allowed: {sorted(self.sequences)}")
        return scene


def job_threads(chains: int, cores: int | None, wanted: int = STAGE_THREADS) -> int:
    """Threads of one job when ``chains`` independent chains of jobs (one per sequence) share
    ``cores``: ``wanted``, or each chain's share of the cores where they are fewer than
    ``chains * wanted`` (at least one). Two one-thread jobs side by side do more than two
    threads in one job, which scale less than twice (docs/architecture.md)."""
    if cores is None or chains < 2:
        return wanted
    return max(1, min(wanted, cores // chains))


def plan(config: dict, user_config: dict | None = None, root: str = ".",
         source: str = "config/config.yaml") -> Plan:
    """The plan of a run. ``config``: the validated workflow config (defaults filled);
    ``user_config``: the config as the user gave it, whose ``avatar`` section the profiles
    apply under (default: ``config``'s); ``source``: the config's files, named in errors."""
    user_avatar: dict[str, Any] = (user_config if user_config is not None else config).get(
        "avatar", {})
    p = Plan(load_sequences(config, root), source=source)
    for name, over in PROFILE_VARIANTS.items():
        p.add_variant(name, over, user_avatar)
    p.ablation_scene = p.study_scene(config, "ablations")
    p.sweep_scene = p.study_scene(config, "sweep")
    p.quality_scene = p.study_scene(config, "quality")

    _plan_ablations(p, config["ablations"], user_avatar)
    _plan_fit_sweep(p, config)

    native = (p.scenes[p.sweep_scene]["cameras"]["width"] if p.sweep_scene in p.scenes else 0)
    axes = {k: config["sweep"][k] for k in ("iterations", "resolution", "max_points")}
    for point in sweep_plan(config["sweep"]["base"], axes):
        name = p.add_variant(point.name, point.overrides, user_avatar)
        p.sweep.setdefault(name, {**point.values, **sweep_values(p.variants[name], native)})
    # the `make demo` configuration is always a point of the sweep (starred on the plot)
    p.sweep.setdefault("demo", {"swept": "demo", **sweep_values(p.variants["demo"], native)})
    return p


def _plan_fit_sweep(p: Plan, config: dict) -> None:
    """The fit sweep's sequence (a multi-view one) and its points."""
    cfg = config["fit_sweep"]
    scene = cfg["scene"]
    if scene is None:
        scene = (p.multiview_scenes or [None])[0]
    else:
        allowed = [n for n in p.sequences if p.num_views(n) > 1]
        if scene not in allowed:
            raise ConfigError(f"{p.source}: fit_sweep.scene = {scene!r} is not a multi-view "
                              f"sequence of this run (the swept stages are the multi-view "
                              f"fit's); allowed: {allowed}")
    if scene is None or config["fit"]["mode"] == "singleview":
        return
    axes = {axis: cfg[axis] for axis in FIT_SWEEP_AXES}
    try:
        points = sweep_points(config["fit"], axes, p.source)
    except ConfigError as e:
        p.fit_sweep_error = str(e)
        return
    p.fit_sweep_scene = scene
    p.fit_sweep = {pt.name: pt for pt in points}


def _plan_ablations(p: Plan, cfg: dict, user_avatar: dict) -> None:
    """The ablation rows (every switch off in turn, the other SMPL-X source) and the
    regulariser's weight sweep, at each training budget, with the held-out cameras."""
    # the held-out cameras the study's sequence has, while one is left to train on (a
    # single-camera sequence keeps every camera: its rows score novel poses only)
    n = p.num_views(p.ablation_scene) if p.ablation_scene is not None else 0
    views = sorted({v for v in cfg["test_views"] if v < n})
    if len(views) >= n:
        views = []
    for iterations in cfg["iterations"] or [None]:
        extra = {"train": {"test_views": views}}
        if iterations is not None:
            extra["train"]["iterations"] = iterations
        base = deep_merge(cfg["base"], extra)
        source = resolve_avatar(deep_merge(user_avatar, deep_merge({"profile": "demo"}, base)),
                                "config key 'ablations.base'")["train"]["smplx_source"]
        suffix = "" if iterations is None else f"_i{iterations}"
        rows = ablation_plan(base, source, with_source=p.ablation_scene in p.scenes)
        names = {}
        for row in rows:
            names[row.label] = p.add_variant(row.name + suffix, row.overrides, user_avatar)
            p.ablations.append({"label": row.label, "variant": names[row.label],
                                "iterations": p.variants[names[row.label]]["train"]["iterations"],
                                "overrides": row.overrides})
        full = next(r for r in rows if r.label == "full")
        resolved_full = p.variants[names["full"]]
        for scale, over in regularizer_plan(full.overrides, cfg["regularizer_scales"],
                                            resolved_full):
            name = p.add_variant(f"abl_reg{scale:g}{suffix}".replace(".", "p"), over,
                                 user_avatar)
            p.regularizer.append({"scale": scale, "variant": name,
                                  "iterations": resolved_full["train"]["iterations"]})
