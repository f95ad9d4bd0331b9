# Stage 5: the COLMAP comparison (paper 3.1): pycolmap SfM on each chosen time step of the static
# rig and on a subsample of the whole sequence, beside the SMPL-X camera solve of the fit stage.
# Synthetic multi-view scenes only: errors are measured against the simulator's cameras.

COLMAP_CFG = config.get("colmap", {})


rule colmap_compare:
    input:
        frames=f"{RESULTS}/{{scene}}/sim/frames.parquet",
        cameras=f"{RESULTS}/{{scene}}/sim/cameras.parquet",
        images=f"{RESULTS}/{{scene}}/sim/images",
        fit_cameras=f"{RESULTS}/{{scene}}/fit/cameras_fit.parquet",
        fit_eval=f"{RESULTS}/{{scene}}/fit/fit_eval.parquet",
    output:
        table=f"{RESULTS}/{{scene}}/colmap/colmap_compare.parquet",
        ply=f"{RESULTS}/{{scene}}/colmap/points.ply",
        runs=directory(f"{RESULTS}/{{scene}}/colmap/ply"),
    params:
        cfg=as_json(COLMAP_CFG),
    log:
        f"{RESULTS}/_logs/{{scene}}/colmap_compare.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/colmap_compare.tsv"
    # One thread: COLMAP's results are then repeatable run to run (with two they varied).
    threads: 1
    resources:
        mem_mb=4000,
        runtime=60,
    shell:
        "{PY} -m signsplat colmap-compare --frames {input.frames:q} --cameras {input.cameras:q}"
        " --fit-cameras {input.fit_cameras:q} --fit-eval {input.fit_eval:q}"
        " --config-json {params.cfg:q} --out {output.table:q} --ply {output.ply:q}"
        " --ply-dir {output.runs:q} --threads {threads} > {log} 2>&1"

