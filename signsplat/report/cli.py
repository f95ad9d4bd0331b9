"""``signsplat report``: the HTML report, and the ablation / sweep summaries.

- ``signsplat report [html] --results results --out reports/index.html`` writes the report
  (assets in ``reports/assets/``); stages that did not run get a section saying so.
- ``signsplat report ablations --results R --scene S --variants-json '[{"label": "full",
  "iterations": 300, "variant": "abl_full_i300", "regularize": true, ...}, ...]'
  --out R/S/ablations.parquet``
- ``signsplat report regularizer --results R --scene S --variants-json '[{"scale": 0.3,
  "iterations": 300, "variant": "abl_reg0p3_i300"}, ...]' --out R/S/regularizer.parquet
  --plot R/S/regularizer.png``
- ``signsplat report sweep --results R --scene S --settings-json '{"sw_it150": {...}}'
  --out R/S/sweep.parquet --plot R/S/sweep.png --demo demo``
- ``signsplat report fit-sweep --results R --scene S --points-json '{"default": {...},
  "sil250": {"swept": "silhouette_iterations", ...}}' --out R/S/fit_sweep.parquet
  --plot R/S/fit_sweep.png``
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from signsplat.config import REPO_ROOT


def _html(argv: list[str]) -> int:
    from signsplat.report.html import write_report

    p = argparse.ArgumentParser(prog="signsplat report", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--results", default="results", help="results folder of a workflow run")
    p.add_argument("--out", default="reports/index.html")
    p.add_argument("--scenes-dir", default=str(REPO_ROOT / "config" / "scenes"),
                   help="scene YAMLs (effects listed when sim/spec.json is absent)")
    p.add_argument("--demo", default="demo", help="setting highlighted on the sweep plot")
    p.add_argument("--title", default="SignSplat report")
    p.add_argument("--tables", default=None,
                   help="also write every table of the report as TSV files in this folder")
    p.add_argument("--benchmarks-json", default=None,
                   help='rule -> {"benchmark": pattern, "log": pattern} ({"segment": '
                   '{"benchmark": "results/_benchmarks/{scene}/segment.tsv", "log": '
                   '"results/_logs/{scene}/segment.log"}, ...}): names the rule of each job in '
                   'the cost tables and finds its SLURM step')
    p.add_argument("--fit-suite", default=None,
                   help="the fit suite's table (benchmarks/fit_suite.py writes "
                        "benchmarks/results/fit_suite.parquet): a section for it when it exists")
    p.add_argument("--avatar-fronts", default=None,
                   help="the avatar's front before and after a change "
                        "(benchmarks/bench_avatar_fronts.py writes "
                        "benchmarks/results/avatar_fronts.parquet): shown when it exists")
    a = p.parse_args(argv)
    patterns = json.loads(a.benchmarks_json) if a.benchmarks_json else None
    out = write_report(a.results, a.out, a.scenes_dir, a.demo, a.title, a.tables, patterns,
                       a.fit_suite, a.avatar_fronts)
    print(f"report: {Path(out).resolve()}")
    return 0


def _write(df, a, table: str) -> None:
    """A study table to ``--out`` (Parquet) and ``--tsv`` when given, and on the console."""
    from signsplat.report.runs import write_parquet, write_tsv

    write_parquet(df, Path(a.out), table)
    if a.tsv:
        write_tsv(df, Path(a.tsv))
    print(df.to_string(index=False))


def _study_args(argv: list[str], name: str, json_arg: str, json_help: str,
                plot: bool) -> argparse.Namespace:
    """The arguments every study table command takes: --results, --scene, its JSON plan,
    --out, --plot (when it draws one), --demo, --tsv."""
    p = argparse.ArgumentParser(prog=f"signsplat report {name}")
    p.add_argument("--results", required=True)
    p.add_argument("--scene", required=True)
    p.add_argument(json_arg, required=True, help=json_help)
    p.add_argument("--out", required=True)
    p.add_argument("--plot", required=plot, default=None)
    p.add_argument("--demo", default="demo")
    p.add_argument("--tsv", default=None, help="the same table as TSV (snakemake --report)")
    return p.parse_args(argv)


def _ablations(argv: list[str]) -> int:
    from signsplat.report.runs import ablation_table, ssim_finding

    a = _study_args(argv, "ablations", "--variants-json",
                    '[{"label": ..., "iterations": ..., "variant": ..., switches}, ...]', False)
    df = ablation_table(Path(a.results), a.scene, json.loads(a.variants_json))
    _write(df, a, "ablations")
    print(ssim_finding(df))
    return 0


def _regularizer(argv: list[str]) -> int:
    from signsplat.report.plots import regularizer_tradeoff
    from signsplat.report.runs import regularizer_table

    a = _study_args(argv, "regularizer", "--variants-json",
                    '[{"scale": ..., "iterations": ..., "variant": ...}, ...]', True)
    df = regularizer_table(Path(a.results), a.scene, json.loads(a.variants_json))
    _write(df, a, "regularizer_sweep")
    regularizer_tradeoff(df, Path(a.plot), title=a.scene)
    return 0


def _sweep(argv: list[str]) -> int:
    from signsplat.report.plots import accuracy_vs_time
    from signsplat.report.runs import sweep_table

    a = _study_args(argv, "sweep", "--settings-json",
                    '{"avatar variant": {"swept": "iterations", "iterations": 150, '
                    '"resolution": 256, "max_points": 40000}, ...}', True)
    df = sweep_table(Path(a.results), a.scene, json.loads(a.settings_json))
    _write(df, a, "sweep")
    accuracy_vs_time(df, Path(a.plot), label="setting", highlight=a.demo, title=a.scene)
    return 0


def _fit_sweep(argv: list[str]) -> int:
    from signsplat.report.fit_sweep import fit_sweep_plot, fit_sweep_table

    a = _study_args(argv, "fit-sweep", "--points-json",
                    '{"sil250": {"swept": "silhouette_iterations", "silhouette_iterations": '
                    '250, "flow": "medium", "lm_iterations": 60}, ...}', True)
    df = fit_sweep_table(Path(a.results), a.scene, json.loads(a.points_json))
    _write(df, a, "fit_sweep")
    fit_sweep_plot(df, Path(a.plot), title=a.scene)
    return 0


def report(argv: list[str]) -> int:
    commands = {"html": _html, "ablations": _ablations, "regularizer": _regularizer,
                "sweep": _sweep, "fit-sweep": _fit_sweep}
    if argv and argv[0] in commands:
        return commands[argv[0]](argv[1:])
    return _html(argv)
