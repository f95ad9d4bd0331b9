# Stage: the Gaussian-splat avatar (train-avatar) and its evaluation (evaluate).
# The `avatar` config section is validated against workflow/schemas/stages/avatar.schema.yaml;
# a variant is that section with a named profile applied (demo, quality). Ablation variants
# can be added to AVATAR_VARIANTS as further overrides. No science here.
import copy

from signsplat.avatar.config import resolve as resolve_avatar_config

AVATAR_BASE = config.get("avatar", {})
AVATAR_VARIANTS = {
    "demo": {"profile": "demo"},
    "quality": {"profile": "quality"},
}
# Variants built by `rule all` (the quality profile is asked for explicitly).
AVATAR_DEFAULT_VARIANTS = ["demo"]


def avatar_variant_config(variant):
    """The resolved (validated, defaults filled) avatar section of a variant."""
    merged = copy.deepcopy(AVATAR_BASE)
    merged.update(AVATAR_VARIANTS[variant])
    return resolve_avatar_config(merged, f"avatar variant {variant!r}")


def avatar_smplx_source(wildcards):
    """fitted when the fitting stage can provide it (default), else ground truth."""
    want = avatar_variant_config(wildcards.variant)["train"]["smplx_source"]
    if want == "fitted" and hasattr(rules, "fit_smplx"):
        return "fitted"
    if wildcards.scene not in SCENES:
        if want == "ground_truth":
            raise ValueError(f"scene {wildcards.scene!r} has no ground-truth SMPL-X")
        return "fitted"
    return "ground_truth"


def avatar_inputs(wildcards):
    files = {"frames": frames_table(wildcards), "body": rules.body_model.output[0]}
    if avatar_smplx_source(wildcards) == "fitted":
        files["smplx"] = f"{RESULTS}/{wildcards.scene}/fit/smplx_fit.parquet"
        files["cameras"] = f"{RESULTS}/{wildcards.scene}/fit/cameras_fit.parquet"
    else:
        files["smplx"] = f"{input_dir(wildcards.scene)}/smplx_gt.parquet"
        files["cameras"] = f"{input_dir(wildcards.scene)}/cameras.parquet"
    return files


def avatar_params(wildcards):
    cfg = avatar_variant_config(wildcards.variant)
    cfg["train"]["smplx_source"] = avatar_smplx_source(wildcards)
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
        cfg=avatar_params,
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
        images=directory(f"{RESULTS}/{{scene}}/eval/{{variant}}/images"),
    params:
        cfg=avatar_params,
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


FINAL_OUTPUTS.extend(
    expand(rules.evaluate_avatar.output.metrics, scene=list(SEQUENCES),
           variant=AVATAR_DEFAULT_VARIANTS)
)
