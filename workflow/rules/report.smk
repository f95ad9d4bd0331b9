# The HTML report (config report.html, default reports/index.html) over every stage's outputs;
# stages that did not run get a section saying so. Included last: it asks for everything the
# other stages put in `all`. Also the three study targets (not part of `all`):
#   snakemake ablations   -> {results}/{scene}/ablations.parquet (paper Table 5)
#   snakemake sweep       -> {results}/{scene}/sweep.parquet + sweep.png (accuracy vs time)
#   snakemake fit_sweep   -> {results}/{scene}/fit_sweep.parquet + fit_sweep.png (the fit's)
# Their variants and fits are planned by signsplat.plan (PLAN.ablations, PLAN.sweep,
# PLAN.fit_sweep); seconds come from the train_avatar / evaluate_avatar / fit_smplx /
# fit_sweep_point benchmark files. No science here.

from signsplat.report.fit_sweep import point_files
from signsplat.report.variants import ablation_columns

REPORT_HTML = config["report"]["html"]
REPORT_TABLES = os.path.join(os.path.dirname(REPORT_HTML), "tables")  # TSV copies


def variant_files(scene, variants):
    return {
        "metrics": expand(rules.evaluate_avatar.output.metrics, scene=scene, variant=variants),
        "logs": expand(rules.train_avatar.output.log, scene=scene, variant=variants),
    }


rule ablation_table:
    input:
        **variant_files(PLAN.ablation_scene, sorted({r["variant"] for r in PLAN.ablations})),
    output:
        table=f"{RESULTS}/{{scene}}/ablations.parquet",
        tsv=report(f"{RESULTS}/{{scene}}/ablations.tsv", caption="../report/ablations.rst",
                   category="6. Ablations"),
    params:
        # not as_json: the row order (full first) is kept
        variants=json.dumps(ablation_columns(PLAN.ablations, PLAN.variants)),
    log:
        f"{RESULTS}/_logs/{{scene}}/ablation_table.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/ablation_table.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    shell:
        "{PY} -m signsplat report ablations --results {RESULTS} --scene {wildcards.scene}"
        " --variants-json {params.variants:q} --out {output.table:q} --tsv {output.tsv:q}"
        " > {log} 2>&1"


rule regularizer_table:
    input:
        **variant_files(PLAN.ablation_scene, sorted({r["variant"] for r in PLAN.regularizer})),
    output:
        table=f"{RESULTS}/{{scene}}/regularizer.parquet",
        tsv=report(f"{RESULTS}/{{scene}}/regularizer.tsv", caption="../report/regularizer.rst",
                   category="6. Ablations"),
        plot=report(f"{RESULTS}/{{scene}}/regularizer.png", caption="../report/regularizer.rst",
                    category="6. Ablations"),
    params:
        variants=as_json(PLAN.regularizer),
    log:
        f"{RESULTS}/_logs/{{scene}}/regularizer_table.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/regularizer_table.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    shell:
        "{PY} -m signsplat report regularizer --results {RESULTS} --scene {wildcards.scene}"
        " --variants-json {params.variants:q} --out {output.table:q} --plot {output.plot:q}"
        " --tsv {output.tsv:q} > {log} 2>&1"


rule sweep_table:
    input:
        **variant_files(PLAN.sweep_scene, list(PLAN.sweep)),
    output:
        table=f"{RESULTS}/{{scene}}/sweep.parquet",
        tsv=report(f"{RESULTS}/{{scene}}/sweep.tsv", caption="../report/sweep_table.rst",
                   category="7. Accuracy versus time"),
        plot=report(f"{RESULTS}/{{scene}}/sweep.png", caption="../report/sweep.rst",
                    category="7. Accuracy versus time"),
    params:
        settings=as_json(PLAN.sweep),
    log:
        f"{RESULTS}/_logs/{{scene}}/sweep_table.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/sweep_table.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    shell:
        "{PY} -m signsplat report sweep --results {RESULTS} --scene {wildcards.scene}"
        " --settings-json {params.settings:q} --out {output.table:q} --plot {output.plot:q}"
        " --tsv {output.tsv:q} --demo demo > {log} 2>&1"


def fit_sweep_evals(wildcards):
    return [f"{RESULTS}/{wildcards.scene}/{point_files(p)[0]}/fit_eval.parquet"
            for p in PLAN.fit_sweep]


rule fit_sweep_table:
    input:
        fit_sweep_evals,
    output:
        table=f"{RESULTS}/{{scene}}/fit_sweep.parquet",
        tsv=report(f"{RESULTS}/{{scene}}/fit_sweep.tsv", caption="../report/fit_sweep.rst",
                   category="3. Fit"),
        plot=report(f"{RESULTS}/{{scene}}/fit_sweep.png", caption="../report/fit_sweep.rst",
                    category="3. Fit"),
    params:
        points=as_json(PLAN.fit_sweep_values),
    log:
        f"{RESULTS}/_logs/{{scene}}/fit_sweep_table.log",
    benchmark:
        f"{RESULTS}/_benchmarks/{{scene}}/fit_sweep_table.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    shell:
        "{PY} -m signsplat report fit-sweep --results {RESULTS} --scene {wildcards.scene}"
        " --points-json {params.points:q} --out {output.table:q} --plot {output.plot:q}"
        " --tsv {output.tsv:q} > {log} 2>&1"


def fit_sweep_tables(wildcards):
    """The fit sweep's outputs; a fit the sweep cannot edit fails here, not in other runs."""
    if PLAN.fit_sweep_error:
        raise ConfigError(PLAN.fit_sweep_error)
    return expand(rules.fit_sweep_table.output, scene=PLAN.fit_sweep_scene or [])


rule fit_sweep:
    localrule: True
    input:
        fit_sweep_tables,


rule ablations:
    localrule: True
    input:
        expand(rules.ablation_table.output, scene=PLAN.ablation_scene),
        expand(rules.regularizer_table.output, scene=PLAN.ablation_scene) if PLAN.regularizer
        else [],


rule sweep:
    localrule: True
    input:
        expand(rules.sweep_table.output, scene=PLAN.sweep_scene),


def report_inputs(wildcards):
    """Everything in `all`, plus the study tables and the quality avatar once they exist: a
    later run of `all` after `snakemake ablations`, `sweep`, `fit_sweep` or `quality` rewrites the report
    with them."""
    study = expand(rules.ablation_table.output.table, scene=PLAN.ablation_scene)
    study += expand(rules.regularizer_table.output.table, scene=PLAN.ablation_scene)
    study += expand(rules.sweep_table.output.table, scene=PLAN.sweep_scene)
    study += expand(rules.fit_sweep_table.output.table, scene=PLAN.fit_sweep_scene or [])
    study += QUALITY_OUTPUTS
    return final_outputs(report=False) + [f for f in study if os.path.exists(f)]


def benchmark_patterns_json():
    """Rule -> its benchmark and log file patterns: the report's cost tables name each job's
    rule and find the SLURM step that ran it."""
    return as_json({r.name: {"benchmark": str(r.benchmark),
                             "log": str(r.log[0]) if len(r.log) else None}
                    for r in workflow.rules if r.benchmark})


# benchmark tables the report shows when they exist: the fit's generalisation suite
# (benchmarks/fit_suite.py) and the avatar's front before and after a change
# (benchmarks/bench_avatar_fronts.py)
BENCHMARK_TABLES = {"--fit-suite": "fit_suite.parquet", "--avatar-fronts": "avatar_fronts.parquet"}


def benchmark_tables_args(wildcards):
    folder = Path(workflow.basedir) / "benchmarks" / "results"
    return " ".join(f"{opt} '{folder / name}'" for opt, name in BENCHMARK_TABLES.items()
                    if (folder / name).exists())


rule report:
    input:
        report_inputs,
    output:
        html=report(REPORT_HTML, caption="../report/index.rst", category="0. Overview"),
        tables=report(directory(REPORT_TABLES), patterns=["{name}.tsv"],
                      caption="../report/tables.rst", category="9. Tables of the report"),
    params:
        benchmarks=lambda wildcards: benchmark_patterns_json(),
        bench_tables=benchmark_tables_args,
    log:
        f"{RESULTS}/_logs/report.log",
    benchmark:
        f"{RESULTS}/_benchmarks/report.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        "{PY} -m signsplat report html --results {RESULTS} --out {output.html:q}"
        " --tables {output.tables:q} --benchmarks-json {params.benchmarks:q} {params.bench_tables}"
        " > {log} 2>&1"

