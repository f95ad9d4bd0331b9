# SignSplat workflow: a table of contents. Stages live in workflow/rules/*.smk; the science
# lives in the signsplat library, which each rule calls through `python -m signsplat <stage>`.
from snakemake.utils import min_version

min_version("9.0")


configfile: "config/config.yaml"


report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"
include: "workflow/rules/assets.smk"
include: "workflow/rules/simulate.smk"
include: "workflow/rules/ingest.smk"
include: "workflow/rules/perception.smk"
include: "workflow/rules/fit.smk"
include: "workflow/rules/colmap.smk"
include: "workflow/rules/avatar.smk"
include: "workflow/rules/stitch.smk"
include: "workflow/rules/report.smk"


rule all:
    input:
        final_outputs(),
    default_target: True
