# Stage: the Gaussian-splat avatar (train-avatar) and its evaluation (evaluate-avatar).
# A variant is the `avatar` config section with a named profile and overrides applied: demo,
# quality, the ablation rows and the sweep points; signsplat.plan resolves them (each resolved
# config is trained once) and picks the SMPL-X source. No science here.
from signsplat.plan import DEFAULT_VARIANTS


def avatar_inputs(wildcards):
    files = {"frames": frames_table(wildcards), "body": rules.body_model.output[0]}
    if wildcards.scene in VIDEOS:  # footage: the perception stage's masks
        files["frames"] = f"{RESULTS}/{wildcards.scene}/perception/masked_frames.parquet"
    if PLAN.smplx_source(wildcards.variant, wildcards.scene) == "fitted":
        files["smplx"] = f"{RESULTS}/{wildcards.scene}/fit/smplx_fit.parquet"
        files["cameras"] = f"{RESULTS}/{wildcards.scene}/fit/cameras_fit.parquet"
    else:
        files["smplx"] = f"{input_dir(wildcards.scene)}/smplx_gt.parquet"
        files["cameras"] = f"{input_dir(wildcards.scene)}/cameras.parquet"
    return files


def avatar_train_params(wildcards):
    return as_json(PLAN.train_section(wildcards.variant, wildcards.scene))


def avatar_eval_params(wildcards):
    return as_json(PLAN.eval_section(wildcards.variant, wildcards.scene))


wildcard_constraints:
    variant="|".join(PLAN.variants),


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
    priority: AVATAR
    threads: job_threads
    resources:
        mem_mb=6000,
        runtime=120,
    shell:
        "{PY} -m signsplat train-avatar --body {input.body:q} --frames {input.frames:q}"
        " --cameras {input.cameras:q} --smplx {input.smplx:q} --config-json {params.cfg:q}"
        " --variant {wildcards.variant} --out {params.out:q} --resume --no-progress"
        " --threads {threads} --device {DEVICE}"
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
    threads: job_threads
    resources:
        mem_mb=4000,
        runtime=60,
    shell:
        "{PY} -m signsplat evaluate-avatar --body {input.body:q} --frames {input.frames:q}"
        " --cameras {input.cameras:q} --smplx {input.smplx:q} --config-json {params.cfg:q}"
        " --variant {wildcards.variant} --checkpoint {input.checkpoint:q} --out {params.out:q}"
        " --threads {threads} --device {DEVICE}"
        " > {log} 2>&1"


# The files an evaluated avatar variant leaves (expanded over scene and variant).
AVATAR_EVAL_FILES = [rules.evaluate_avatar.output.metrics, rules.evaluate_avatar.output.views]
QUALITY_OUTPUTS = expand(AVATAR_EVAL_FILES, scene=PLAN.quality_scene, variant="quality")


rule quality:
    localrule: True
    input:
        QUALITY_OUTPUTS,
