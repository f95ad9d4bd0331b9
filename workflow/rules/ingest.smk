# Stage 1 for real footage: frames of one video (or image folder) per camera. A camera input
# that is a fetched asset (the example clip in perception.pretrained.cache) is made by
# perception.smk's fetch_assets rule first (ASSET_FILES is defined there; read at DAG time).


def camera_inputs(wildcards):
    cams = [c.strip() for c in VIDEOS[wildcards.scene]["cameras"].split(";") if c.strip()]
    return [c for c in cams if c in ASSET_FILES.values()]


rule extract_frames:
    input:
        cameras=camera_inputs,
    output:
        frames=f"{RESULTS}/{{scene}}/frames/frames.parquet",
        images=directory(f"{RESULTS}/{{scene}}/frames/images"),
    params:
        seq=lambda w: as_json({k: v for k, v in VIDEOS[w.scene].items()}),
    log:
        f"{RESULTS}/_logs/{{scene}}/extract_frames.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/extract_frames.tsv"
    priority: BEFORE_AVATAR
    threads: 1
    resources:
        mem_mb=2000,
        runtime=60,
    shell:
        "{PY} -m signsplat extract-frames --sequence-json {params.seq:q}"
        " --out {RESULTS}/{wildcards.scene}/frames > {log} 2>&1"

