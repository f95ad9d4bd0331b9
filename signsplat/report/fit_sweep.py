"""The fit's accuracy against its time (``snakemake fit_sweep``): one row per fit of the sweep,
its errors against the simulator's truth beside the seconds it cost, the Pareto fronts, a
figure and the report's section.

Rows come from the workflow's files: ``{scene}/fit/fit_eval.parquet`` for the config's own fit
(the point ``default``), ``{scene}/fit_sweep/{point}/fit_eval.parquet`` for the others, and
the seconds from the Snakemake benchmark files (``fit_smplx``, ``fit_sweep_{point}``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.fit.sweep import AXES, DEFAULT_POINT
from signsplat.io.tables import Table, register_table
from signsplat.report.collect import read_benchmarks, read_parquet
from signsplat.report.fit_suite import fit_errors

#: the errors a fit is judged by on the sweep (lower is better), with their plot labels
CRITERIA = {"body_mpjpe_mm": "body MPJPE (mm)", "hands_mpjpe_mm": "hands MPJPE (mm)",
            "camera_rotation_deg": "camera rotation error (deg)"}

FIT_SWEEP = register_table(Table(
    "fit_sweep",
    "The multi-view fit of one sequence with one costly setting changed at a time (config "
    "fit_sweep), one row per fit; errors against the simulator's ground truth.",
    {
        "setting": "str the point: default (the config's own fit) or the axis and its value",
        "swept": "str the axis changed from the default (silhouette_iterations, flow, "
                 "lm_iterations; default)",
        "silhouette_iterations": "int64 Adam steps of the stage with the mask terms (0 = no "
                                 "such stage)",
        "flow": "str that stage's optical-flow term: none or the OpenCV DIS preset",
        "lm_iterations": "int64 iterations of the Levenberg-Marquardt stage",
        "seconds": "float64 the x axis: wall-clock seconds of the fit rule (Snakemake "
                   "benchmark; NaN when the file is missing)",
        "cpu_seconds": "float64 CPU seconds of the fit rule (Snakemake benchmark)",
        "body_mpjpe_mm": "float64 body MPJPE (mm)",
        "body_pa_mpjpe_mm": "float64 body PA-MPJPE (mm)",
        "hands_mpjpe_mm": "float64 hands MPJPE (mm, wrist-rooted)",
        "hands_pa_mpjpe_mm": "float64 hands PA-MPJPE (mm)",
        "camera_rotation_deg": "float64 mean camera rotation error (degrees)",
        "camera_centre_m": "float64 mean camera centre error (m)",
        "image_error_px": "float64 mean px between the fitted and the true body in the images",
        "pareto": "bool no other point is at least as fast and at least as good in body, "
                  "hands and camera error, and better in one",
        "pareto_body": "bool on the front of (seconds, body_mpjpe_mm)",
        "pareto_hands": "bool on the front of (seconds, hands_mpjpe_mm)",
        "pareto_cameras": "bool on the front of (seconds, camera_rotation_deg)",
    },
))


def point_files(point: str) -> tuple[str, str]:
    """A point's fit folder below ``{results}/{scene}`` and its benchmark job name."""
    if point == DEFAULT_POINT:
        return "fit", "fit_smplx"
    return f"fit_sweep/{point}", f"fit_sweep_{point}"


def fit_sweep_table(results: str | Path, scene: str, points: dict[str, dict]) -> pd.DataFrame:
    """``points``: point name -> ``{"swept": axis, <axis>: value, ...}``. A point whose fit
    has no ``fit_eval.parquet`` raises :class:`FileNotFoundError` naming it."""
    from signsplat.report.plots import nondominated, pareto_front

    results = Path(results)
    bench = read_benchmarks(results / "_benchmarks")
    rows = []
    for name, values in points.items():
        folder, job = point_files(name)
        path = results / scene / folder / "fit_eval.parquet"
        ev = read_parquet(path)
        if ev is None:
            raise FileNotFoundError(f"{path}: the fit of sweep point {name!r} is missing "
                                    "(run `snakemake fit_sweep`)")
        b = bench[(bench["job"] == job) & (bench["scene"] == scene)]
        rows.append({"setting": name, "swept": values.get("swept", name),
                     **{a: values[a] for a in AXES},
                     "seconds": float(b["seconds"].iloc[0]) if len(b) else float("nan"),
                     "cpu_seconds": float(b["cpu_seconds"].iloc[0]) if len(b) else float("nan"),
                     **fit_errors(ev)})
    df = pd.DataFrame(rows)[[c for c in FIT_SWEEP.columns if not c.startswith("pareto")]]
    df["pareto"] = nondominated(np.c_[df["seconds"], df[list(CRITERIA)]])
    for key, col in (("body", "body_mpjpe_mm"), ("hands", "hands_mpjpe_mm"),
                     ("cameras", "camera_rotation_deg")):
        df[f"pareto_{key}"] = pareto_front(df["seconds"], df[col], lower_is_better=True)
    return df


def fit_sweep_plot(df: pd.DataFrame, path: str | Path, title: str = "") -> Path:
    """Body, hands and camera error against the fit's seconds, the front of each, the
    config's own fit starred."""
    from signsplat.report.plots import accuracy_vs_time

    return accuracy_vs_time(df, Path(path), metrics=tuple(CRITERIA), label="setting",
                            highlight=DEFAULT_POINT, title=title,
                            xlabel="fit wall-clock seconds (Snakemake benchmark)",
                            lower_is_better=tuple(CRITERIA), highlight_label="config's fit",
                            ylabels=CRITERIA)


def fit_sweep_section(tables: dict[str, pd.DataFrame], assets):
    """The report's section (:class:`signsplat.report.html.Section`) for the sweep tables of
    the sequences that have one, or None when none has."""
    from signsplat.report.html import Figure, Section

    tables = {k: v for k, v in tables.items() if v is not None and len(v)}
    if not tables:
        return None
    sec = Section("fit_sweep", "3b. SMPL-X fitting: accuracy versus time",
                  "Each point is one fit of the sequence with one costly setting changed from "
                  "the config's own fit (star): the silhouette stage's steps (0 = keypoints "
                  "only), its optical flow (none or an OpenCV DIS preset), the "
                  "Levenberg-Marquardt iterations. x: wall-clock seconds of the fit rule; y: "
                  "errors against the simulator's truth. Red: the front (no other fit is "
                  "both faster and at least as accurate). `snakemake fit_sweep` writes it.")
    for name, df in tables.items():
        path = fit_sweep_plot(df, assets.path(f"{name}_fit_sweep"), title=name)
        on = df[df["pareto"]]["setting"].tolist()
        default_on = bool(df.loc[df["setting"] == DEFAULT_POINT, "pareto"].any())
        sec.figures.append(Figure(assets.rel(path), f"{name}: fit errors against seconds; on "
                                  f"the joint front: {', '.join(on)} (the config's fit "
                                  f"{'is' if default_on else 'is not'} on it)",
                                  float(df["seconds"].sum()), "fit seconds, all points"))
        sec.add_table(f"{name}: the fit sweep", df)
    return sec
