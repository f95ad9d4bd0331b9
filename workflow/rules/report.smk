# The HTML report (reports/index.html) over every stage's outputs; stages that did not run get
# a section saying so. Included last: it asks for everything the other stages put in `all`.

REPORT_INPUTS = list(FINAL_OUTPUTS)


rule report:
    input:
        REPORT_INPUTS,
    output:
        "reports/index.html",
    log:
        f"{RESULTS}/_logs/report.log",
    benchmark:
        f"{RESULTS}/_benchmarks/report.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    shell:
        "{PY} -m signsplat report html --results {RESULTS} --out {output} > {log} 2>&1"


FINAL_OUTPUTS.append(rules.report.output[0])
