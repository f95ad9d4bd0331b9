# Stage: the Gaussian-splat avatar (train-avatar) and its evaluation (evaluate).
# The `avatar` config section is validated against workflow/schemas/stages/avatar.schema.yaml;
# a variant is that section with a named profile and overrides applied (deep merge): demo,
# quality, the ablation variants (config `ablations`: demo profile + `ablations.base` + one
# switch flipped) and the sweep variants (config `sweep`: one of iterations, resolution, point
# budget changed). A variant whose resolved config equals an earlier one is that variant (the
# full ablation with an empty base is `demo`, trained once). No science here.
import copy

from signsplat.avatar.config import EVAL_ONLY_KEYS, resolve as resolve_avatar_config
from signsplat.config import deep_merge
from signsplat.report.variants import ablation_plan, sweep_plan, sweep_values

AVATAR_BASE = USER_CONFIG.get("avatar", {})  # before defaults: profiles apply under it
AVATAR_VARIANTS = {
    "demo": {"profile": "demo"},
    "quality": {"profile": "quality"},
}
# Variants built by `rule all` (the quality profile is asked for explicitly).
AVATAR_DEFAULT_VARIANTS = ["demo"]
_RESOLVED = {}


def avatar_variant_config(variant):
    """The resolved (validated, defaults filled) avatar section of a variant."""
    if variant not in _RESOLVED:
        _RESOLVED[variant] = resolve_avatar_config(
            deep_merge(AVATAR_BASE, AVATAR_VARIANTS[variant]), f"avatar variant {variant!r}")
    return copy.deepcopy(_RESOLVED[variant])


def add_avatar_variant(name, overrides):
    """Register a variant; returns the name of an existing variant with the same resolved
    config instead when there is one."""
    AVATAR_VARIANTS[name] = overrides
    mine = avatar_variant_config(name)
    for known in AVATAR_VARIANTS:
        if known != name and avatar_variant_config(known) == mine:
            del AVATAR_VARIANTS[name]
            del _RESOLVED[name]
            return known
    return name


def study_scene(key):
    """Sequence of the ablation / sweep study: config `<key>.scene`, or the default
    multi-view scene (the first synthetic sequence with more than one camera)."""
    scene = config[key]["scene"]
    if scene is None:
        multi = [n for n in SCENES if num_views(n) > 1]
        return (multi or list(SCENES) or list(SEQUENCES) or [None])[0]
    if scene not in SEQUENCES:
        raise ValueError(f"config/config.yaml: {key}.scene = {scene!r} is not a sequence of "
                         f"this run; allowed: {sorted(SEQUENCES)}")
    return scene


ABLATION_SCENE = study_scene("ablations")
# label -> {"variant": name, "switches": {...}}; rows of ablations.parquet in this order.
ABLATIONS = {}
_abl_base = resolve_avatar_config(deep_merge(AVATAR_BASE, deep_merge(
    {"profile": "demo"}, config["ablations"]["base"])), "config key 'ablations.base'")
for _p in ablation_plan(config["ablations"]["base"], _abl_base["train"]["smplx_source"],
                        with_source=ABLATION_SCENE in SCENES):
    _name = add_avatar_variant(_p.name, _p.overrides)
    ABLATIONS[_p.label] = {"variant": _name, "overrides": _p.overrides}

SWEEP_SCENE = study_scene("sweep")
# variant -> the values shown beside its scores (swept axis, iterations, resolution, points).
SWEEP = {}
_native = (SCENES[SWEEP_SCENE]["cameras"]["width"] if SWEEP_SCENE in SCENES else 0)
for _p in sweep_plan(config["sweep"]["base"], {k: config["sweep"][k] for k in
                                                 ("iterations", "resolution", "max_points")}):
    _name = add_avatar_variant(_p.name, _p.overrides)
    if _name not in SWEEP:
        SWEEP[_name] = {**_p.values, **sweep_values(avatar_variant_config(_name), _native)}
# the `make demo` configuration is always a point of the sweep (starred on the plot)
if "demo" not in SWEEP:
    SWEEP["demo"] = {"swept": "demo", **sweep_values(avatar_variant_config("demo"), _native)}
# Sweep variants are evaluated at the native image size (scores comparable across resolutions).
NATIVE_EVAL_VARIANTS = set(SWEEP)


def avatar_smplx_source(wildcards):
    """fitted when the fitting stage can provide it (default), else ground truth."""
    want = avatar_variant_config(wildcards.variant)["train"]["smplx_source"]
    if want == "fitted" and hasattr(rules, "fit_smplx"):
        return "fitted"
    if wildcards.scene not in SCENES:
        if want == "ground_truth":
            raise ValueError(
                f"avatar variant {wildcards.variant!r} asks for train.smplx_source: "
                f"ground_truth, but sequence {wildcards.scene!r} is footage with no ground-truth "
                f"SMPL-X; allowed here: fitted (for the studies: set it in ablations.base / "
                f"sweep.base of the config)")
        return "fitted"
    return "ground_truth"


def avatar_inputs(wildcards):
    files = {"frames": frames_table(wildcards), "body": rules.body_model.output[0]}
    if wildcards.scene in VIDEOS:  # footage: the perception stage's masks
        files["frames"] = f"{RESULTS}/{wildcards.scene}/perception/masked_frames.parquet"
    if avatar_smplx_source(wildcards) == "fitted":
        files["smplx"] = f"{RESULTS}/{wildcards.scene}/fit/smplx_fit.parquet"
        files["cameras"] = f"{RESULTS}/{wildcards.scene}/fit/cameras_fit.parquet"
    else:
        files["smplx"] = f"{input_dir(wildcards.scene)}/smplx_gt.parquet"
        files["cameras"] = f"{input_dir(wildcards.scene)}/cameras.parquet"
    return files


def avatar_section(wildcards):
    """The variant's avatar config with the SMPL-X source of its scene (a dict)."""
    cfg = avatar_variant_config(wildcards.variant)
    cfg["train"]["smplx_source"] = avatar_smplx_source(wildcards)
    return cfg


def avatar_train_params(wildcards):
    """The training config, without the settings only the evaluation reads (so that changing
    them re-runs the evaluation, not the training)."""
    cfg = avatar_section(wildcards)
    cfg["eval"] = {k: v for k, v in cfg["eval"].items() if k not in EVAL_ONLY_KEYS}
    return as_json(cfg)


def avatar_eval_params(wildcards):
    """The whole config; sweep variants load the evaluation images at the native size."""
    cfg = avatar_section(wildcards)
    if wildcards.variant in NATIVE_EVAL_VARIANTS:
        cfg["train"]["resolution"] = 0
    return as_json(cfg)


wildcard_constraints:
    variant="|".join(AVATAR_VARIANTS),


rule train_avatar:
    input:
        unpack(avatar_inputs),
    output:
        checkpoint=f"{RESULTS}/{{scene}}/avatar/{{variant}}/checkpoint.pt",
        ply=f"{RESULTS}/{{scene}}/avatar/{{variant}}/avatar.ply",
        log=f"{RESULTS}/{{scene}}/avatar/{{variant}}/train_log.parquet",
    params:
        cfg=avatar_train_params,
        out=f"{RESULTS}/{{scene}}/avatar/{{variant}}",
    log:
        f"{RESULTS}/_logs/{{scene}}/train_avatar_{{variant}}.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/train_avatar_{{variant}}.tsv"
    threads: 2
    resources:
        mem_mb=6000,
        runtime=120,
    shell:
        "{PY} -m signsplat train-avatar --body {input.body:q} --frames {input.frames:q}"
        " --cameras {input.cameras:q} --smplx {input.smplx:q} --config-json {params.cfg:q}"
        " --variant {wildcards.variant} --out {params.out:q} --resume --no-progress"
        " > {log} 2>&1"


rule evaluate_avatar:
    input:
        unpack(avatar_inputs),
        checkpoint=rules.train_avatar.output.checkpoint,
    output:
        metrics=f"{RESULTS}/{{scene}}/eval/{{variant}}/metrics.parquet",
        views=f"{RESULTS}/{{scene}}/eval/{{variant}}/views.parquet",
        images=report(directory(f"{RESULTS}/{{scene}}/eval/{{variant}}/images"),
                      patterns=["{name}.png"], caption="../report/avatar_images.rst",
                      category="5. Avatar", subcategory="{variant}"),
    params:
        cfg=avatar_eval_params,
        out=f"{RESULTS}/{{scene}}/eval/{{variant}}",
    log:
        f"{RESULTS}/_logs/{{scene}}/evaluate_{{variant}}.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/evaluate_{{variant}}.tsv"
    threads: 2
    resources:
        mem_mb=4000,
        runtime=60,
    shell:
        "{PY} -m signsplat evaluate --body {input.body:q} --frames {input.frames:q}"
        " --cameras {input.cameras:q} --smplx {input.smplx:q} --config-json {params.cfg:q}"
        " --variant {wildcards.variant} --checkpoint {input.checkpoint:q} --out {params.out:q}"
        " > {log} 2>&1"


# The files an evaluated avatar variant leaves (expanded over scene and variant).
AVATAR_EVAL_FILES = [rules.evaluate_avatar.output.metrics, rules.evaluate_avatar.output.views]
QUALITY_SCENE = study_scene("quality")
QUALITY_OUTPUTS = expand(AVATAR_EVAL_FILES, scene=QUALITY_SCENE, variant="quality")


rule quality:
    localrule: True
    input:
        QUALITY_OUTPUTS,


FINAL_OUTPUTS.extend(expand(AVATAR_EVAL_FILES, scene=list(SEQUENCES),
                            variant=AVATAR_DEFAULT_VARIANTS))
