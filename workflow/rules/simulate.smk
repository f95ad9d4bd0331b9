# Stage 1: synthetic signer scenes (embedded default), only the effects a scene declares.
import re

from signsplat.synth.scene import check_scene

# Fail at parse time (also under `snakemake -n`) on unknown effects or effect options.
for _name, _spec in SCENES.items():
    check_scene(_spec, f"config/scenes/{_name}.yaml")


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
        masks=directory(f"{RESULTS}/{{scene}}/sim/masks"),
    wildcard_constraints:
        scene="|".join(re.escape(s) for s in SCENES) or "(?!)",
    params:
        scene=scene_spec,
        out=lambda w: f"{RESULTS}/{w.scene}/sim",
    log:
        f"{RESULTS}/_logs/{{scene}}/simulate.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/simulate.tsv"
    priority: BEFORE_AVATAR
    threads: job_threads
    resources:
        mem_mb=3000,
        runtime=30,
    shell:
        "{PY} -m signsplat simulate --scene-json {params.scene:q} --body {input.body:q}"
        " --glosses {input.glosses:q} --out {params.out:q} --threads {threads}"
        " > {log} 2>&1"

