# Shared assets of the embedded default: the body model and the gloss library.


rule body_model:
    output:
        f"{RESULTS}/_assets/body_model.npz",
    params:
        cfg=as_json(config["body_model"]),
    log:
        f"{RESULTS}/_logs/body_model.log",
    benchmark:
        f"{RESULTS}/_benchmarks/body_model.tsv"
    threads: 1
    resources:
        mem_mb=4000,
        runtime=20,
    shell:
        "{PY} -m signsplat body-model --config-json {params.cfg:q} --out {output} > {log} 2>&1"


rule gloss_library:
    output:
        f"{RESULTS}/_assets/gloss_library.parquet",
    params:
        cfg=as_json(config["gloss_library"]),
    log:
        f"{RESULTS}/_logs/gloss_library.log",
    benchmark:
        f"{RESULTS}/_benchmarks/gloss_library.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    shell:
        "{PY} -m signsplat gloss-library --config-json {params.cfg:q} --out {output} > {log} 2>&1"
