# Stage 4: SMPL-X fitting (paper 3.1). Mode multiview when the sequence has more than one
# camera, else singleview (signsplat.fit.mode; config fit.mode forces). Keypoints: config
# fit.keypoints = detected (perception stage) or ground_truth (the simulator's
# keypoints_gt.parquet; synthetic scenes only). Person masks (silhouette stage) come from the
# same source. The frames table's images feed the overlays and the optical-flow term.
from signsplat.fit.keypoint_offsets import fit_offsets
from signsplat.fit.mode import mode_config
from signsplat.fit.sweep import DEFAULT_POINT

FIT_CFG = config["fit"]  # validated in common.smk: the schema filled the defaults


def fit_keypoints(wildcards):
    if FIT_CFG["keypoints"] == "ground_truth" and wildcards.scene in SCENES:
        return f"{RESULTS}/{wildcards.scene}/sim/keypoints_gt.parquet"
    return f"{RESULTS}/{wildcards.scene}/perception/keypoints.parquet"


def fit_masks(wildcards):
    # the silhouette stage's person masks: the perception stage's, or with ground-truth
    # keypoints the simulator's (the frames table carries them)
    if FIT_CFG["keypoints"] == "ground_truth" and wildcards.scene in SCENES:
        return frames_table(wildcards)
    return f"{RESULTS}/{wildcards.scene}/perception/masks.parquet"


def sequence_offsets(wildcards):
    """The keypoint_offsets table this sequence's fit uses, and the hand sides whose finger
    rows alone it applies (signsplat.fit.keypoint_offsets.fit_offsets)."""
    keypoints = sequence_perception(wildcards)["keypoints"]
    return fit_offsets(FIT_CFG, detectors(wildcards), keypoints)


def fit_inputs(wildcards):
    files = {
        "keypoints": fit_keypoints(wildcards),
        "frames": frames_table(wildcards),
        "masks": fit_masks(wildcards),
        "body": rules.body_model.output[0],
    }
    offsets, _ = sequence_offsets(wildcards)
    if offsets:  # the detectors' own keypoints (config fit.keypoint_offsets)
        files["keypoint_offsets"] = offsets
    if wildcards.scene in SCENES:
        # cameras.parquet gives image sizes and calibrated intrinsics only (R, t never read);
        # smplx_gt/cameras are the evaluation's ground truth.
        files["calibration"] = f"{RESULTS}/{wildcards.scene}/sim/cameras.parquet"
        files["gt_smplx"] = f"{RESULTS}/{wildcards.scene}/sim/smplx_gt.parquet"
    return files


def fit_config(wildcards):
    """The fit section without the other mode's settings: a change to the multi-view stages
    does not re-run the single-view fits, nor the other way round."""
    return as_json(mode_config(FIT_CFG, PLAN.num_views(wildcards.scene)))


def fit_extra_args(wildcards, input):
    args = []
    if "keypoint_offsets" in input.keys():
        args += ["--keypoint-offsets", input.keypoint_offsets]
        _, fingers = sequence_offsets(wildcards)
        if fingers:  # MediaPipe's fingers in another detector's keypoints
            args += ["--keypoint-offsets-fingers", *fingers]
    if "calibration" in input.keys():
        args += ["--calibration", input.calibration, "--gt-cameras", input.calibration,
                 "--gt-smplx", input.gt_smplx]
    elif VIDEOS.get(wildcards.scene, {}).get("calibration"):
        # footage with a calibration file: extract_frames writes cameras.parquet before
        # frames.parquet (an input), so it exists; intrinsics, and with camera_init
        # calibrated the extrinsics too
        args += ["--calibration", f"{RESULTS}/{wildcards.scene}/frames/cameras.parquet"]
    return " ".join(f"'{a}'" for a in args)


rule fit_smplx:
    input:
        unpack(fit_inputs),
    output:
        smplx=f"{RESULTS}/{{scene}}/fit/smplx_fit.parquet",
        cameras=f"{RESULTS}/{{scene}}/fit/cameras_fit.parquet",
        eval=f"{RESULTS}/{{scene}}/fit/fit_eval.parquet",
        log_json=f"{RESULTS}/{{scene}}/fit/fit_log.json",
        overlays=directory(f"{RESULTS}/{{scene}}/fit/overlays"),
    params:
        cfg=fit_config,
        extra=fit_extra_args,
        betas=config["body_model"]["num_betas"],
        expr=config["body_model"]["num_expression"],
        device=config.get("device", "auto"),
        out=f"{RESULTS}/{{scene}}/fit",
    log:
        f"{RESULTS}/_logs/{{scene}}/fit_smplx.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/fit_smplx.tsv"
    priority: fit_priority
    threads: chain_threads
    resources:
        mem_mb=4000,
        runtime=60,
    shell:
        "{PY} -m signsplat fit --config-json {params.cfg:q} --scene {wildcards.scene}"
        " --keypoints {input.keypoints:q} --frames {input.frames:q} --body {input.body:q}"
        " --masks {input.masks:q}"
        " --num-betas {params.betas}"
        " --num-expression {params.expr} --device {params.device} --threads {threads}"
        " --out-dir {params.out:q} {params.extra} > {log} 2>&1"


# `snakemake fit_sweep`: the fit of the sweep's sequence with one costly setting changed
# (signsplat.plan, PLAN.fit_sweep); the point `default` is fit_smplx's own result.
wildcard_constraints:
    point="|".join(p for p in PLAN.fit_sweep if p != DEFAULT_POINT) or "^$",


use rule fit_smplx as fit_sweep_point with:
    output:
        smplx=f"{RESULTS}/{{scene}}/fit_sweep/{{point}}/smplx_fit.parquet",
        cameras=f"{RESULTS}/{{scene}}/fit_sweep/{{point}}/cameras_fit.parquet",
        eval=f"{RESULTS}/{{scene}}/fit_sweep/{{point}}/fit_eval.parquet",
        log_json=f"{RESULTS}/{{scene}}/fit_sweep/{{point}}/fit_log.json",
        overlays=directory(f"{RESULTS}/{{scene}}/fit_sweep/{{point}}/overlays"),
    params:
        cfg=lambda wildcards: as_json(PLAN.fit_sweep_config(wildcards.point)),
        out=f"{RESULTS}/{{scene}}/fit_sweep/{{point}}",
    log:
        f"{RESULTS}/_logs/{{scene}}/fit_sweep_{{point}}.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/fit_sweep_{{point}}.tsv"
