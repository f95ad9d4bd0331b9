# Stage 1: synthetic signer scenes (embedded default), only the effects a scene declares.


rule simulate:
    input:
        body=rules.body_model.output[0],
        glosses=rules.gloss_library.output[0],
    output:
        frames=f"{RESULTS}/{{scene}}/sim/frames.parquet",
        cameras=f"{RESULTS}/{{scene}}/sim/cameras.parquet",
        smplx=f"{RESULTS}/{{scene}}/sim/smplx_gt.parquet",
        keypoints=f"{RESULTS}/{{scene}}/sim/keypoints_gt.parquet",
        images=directory(f"{RESULTS}/{{scene}}/sim/images"),
    params:
        scene=scene_spec,
    log:
        f"{RESULTS}/_logs/{{scene}}/simulate.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/simulate.tsv"
    threads: 2
    resources:
        mem_mb=4000,
        runtime=30,
    shell:
        "{PY} -m signsplat simulate --scene-json {params.scene:q} --body {input.body}"
        " --glosses {input.glosses} --out {RESULTS}/{wildcards.scene}/sim --threads {threads}"
        " > {log} 2>&1"


FINAL_OUTPUTS.extend(expand(rules.simulate.output.frames, scene=list(SCENES)))

