"""Summaries of the ablation and sweep runs: one row per avatar variant, from the files the
workflow wrote (``eval/{variant}/metrics.parquet``, ``avatar/{variant}/train_log.parquet``) and
the wall-clock seconds of the Snakemake ``benchmark:`` files (never a hand timer)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from signsplat.io.atomic import atomic_path
from signsplat.io.tables import Table, register_table, write_table
from signsplat.report.collect import read_benchmarks, read_parquet
from signsplat.report.variants import SWITCH_FIELDS

_SCORES = {
    "psnr": "float64 dB, full image, background replaced, no test-time refinement (held-out "
            "frames, novel pose, unless the table has a split column)",
    "ssim": "float64 same images as psnr",
    "hand_psnr": "float64 dB, mean of the left- and right-hand crop PSNR, same images",
    "train_seconds": "float64 wall-clock seconds of train_avatar (Snakemake benchmark file; "
                     "NaN when the file is missing)",
    "eval_seconds": "float64 wall-clock seconds of evaluate_avatar (Snakemake benchmark file)",
    "points": "int64 Gaussians at the end of training (last train_log row; -1 if no log)",
    "smplx_source": "str SMPL-X the variant trained on: fitted or ground_truth",
}
ABLATIONS_TABLE = register_table(Table(
    "ablations",
    "One row per (ablation variant, training budget, split) of a sequence (paper Table 5), "
    "same frames, cameras and seed for every variant. A column lpips (float64, full image) is "
    "present only when LPIPS was computed for some variant.",
    {"variant": "str row label (full, w/o regularisation, ...)",
     "iterations": "int64 training steps (the study's budget)",
     "split": "str novel_pose (held-out frames, training cameras) | novel_view (training "
              "frames, held-out cameras) | novel_pose_view (both held out)",
     "test_views": "str the held-out cameras, comma-separated ('' = none)",
     "avatar_variant": "str the avatar variant trained (results/{scene}/avatar/{variant})",
     "regularize": "bool neighbourhood variance regularisation on",
     "densify": "bool adaptive density control on",
     "accumulate": "bool loss accumulation over poses on",
     "displacement": "bool the displacement network of the vertices (paper eq. 3) on",
     "pose_dependent": "bool pose-dependent networks on (off = static mesh-anchored)",
     **_SCORES},
    extra_columns=True,
))
REGULARIZER_TABLE = register_table(Table(
    "regularizer_sweep",
    "The full model with the regulariser's variance weights scaled (0 = off), one row per "
    "(scale, training budget, split) of the ablation sequence.",
    {"scale": "float64 factor on regularize.w_scale, w_rotation, w_opacity, w_color, w_sh_rest",
     "iterations": "int64 training steps",
     "split": "str as in the ablations table",
     "avatar_variant": "str the avatar variant trained",
     **_SCORES},
    extra_columns=True,
))
SWEEP_TABLE = register_table(Table(
    "sweep",
    "One row per accuracy-versus-time setting of a sequence. A column lpips is present only "
    "when LPIPS was computed.",
    {"setting": "str the avatar variant (demo = the `make demo` configuration)",
     "swept": "str the axis changed from the sweep centre (iterations, resolution, max_points; "
              "centre; demo)",
     "iterations": "int64 training iterations",
     "resolution": "int64 training image side in pixels (evaluation at the native size)",
     "max_points": "int64 point budget of the density control",
     **_SCORES,
     "seconds": "float64 the x axis: training wall-clock seconds (= train_seconds)",
     "pareto_psnr": "bool on the Pareto front of (seconds, psnr)",
     "pareto_ssim": "bool on the Pareto front of (seconds, ssim)"},
    extra_columns=True,
))

FRONTS_TABLE = register_table(Table(
    "avatar_fronts",
    "The sweep's settings (ground-truth SMPL-X, demo left out) trained by two versions of the "
    "code one after the other on one machine (benchmarks/bench_avatar_fronts.py): one row per "
    "(code, setting).",
    {"code": "str before | after",
     "commit": "str the commit that trained it",
     "measured": "str the date of the run (YYYY-MM-DD)",
     "scene": "str the sequence",
     "variant": "str the avatar variant trained (results/{scene}/avatar/{variant})",
     "setting": "str the sweep axis and value changed from its centre, or centre",
     **{k: v for k, v in _SCORES.items() if k != "smplx_source"},
     "seconds": "float64 the x axis: training wall-clock seconds (= train_seconds)",
     "pareto_psnr": "bool on its code's Pareto front of (seconds, psnr)",
     "pareto_ssim": "bool on its code's Pareto front of (seconds, ssim)"},
))


def image_scores(metrics: pd.DataFrame, split: str = "novel_pose") -> dict[str, float]:
    """PSNR / SSIM / LPIPS of the full image and the mean hand-crop PSNR of one split, under the
    paper's protocol (background replaced, no test-time refinement)."""
    m = metrics[metrics["split"] == split]
    if "protocol" in m:
        m = m[m["protocol"] == "bg_replaced"]
    if "refine" in m:
        m = m[~m["refine"].astype(bool)]

    def value(part, metric):
        v = m[(m["part"].isin(part)) & (m["metric"] == metric)]["value"]
        return float(v.mean()) if len(v) else float("nan")

    return {"psnr": value(["full"], "psnr"), "ssim": value(["full"], "ssim"),
            "lpips": value(["full"], "lpips"),
            "hand_psnr": value(["left_hand", "right_hand"], "psnr")}


SPLITS = ("novel_pose", "novel_view", "novel_pose_view")


def _benchmark_seconds(bench: pd.DataFrame, scene: str, job: str) -> float:
    sel = bench[(bench["job"] == job) & (bench["scene"] == scene)]
    return float(sel["seconds"].iloc[0]) if len(sel) else float("nan")


def variant_rows(results: Path, scene: str, variant: str, bench: pd.DataFrame | None = None,
                 splits: tuple[str, ...] = ("novel_pose",)) -> list[dict]:
    """Quality per split (those the evaluation scored), seconds and final point count of one
    trained and evaluated variant."""
    results = Path(results)
    if bench is None:
        bench = read_benchmarks(results / "_benchmarks")
    path = results / scene / "eval" / variant / "metrics.parquet"
    metrics = read_parquet(path)
    if metrics is None:
        raise FileNotFoundError(f"{path}: metrics of avatar variant {variant!r} not found "
                                "(train and evaluate it first)")
    log = read_parquet(results / scene / "avatar" / variant / "train_log.parquet")
    common = {"scene": scene, "variant": variant,
              "train_seconds": _benchmark_seconds(bench, scene, f"train_avatar_{variant}"),
              "eval_seconds": _benchmark_seconds(bench, scene, f"evaluate_{variant}"),
              "points": int(log["num_points"].iloc[-1]) if log is not None and len(log) else -1,
              "smplx_source": str(metrics["smplx_source"].iloc[0])
              if "smplx_source" in metrics and len(metrics) else "",
              "test_views": _test_views(metrics)}
    return [{**common, "split": split, **image_scores(metrics, split)} for split in splits
            if split in set(metrics["split"])]


def _test_views(metrics: pd.DataFrame) -> str:
    """The held-out cameras of an evaluation, from its split rule ('... test views: [1, 3]')."""
    if "split_rule" not in metrics or not len(metrics):
        return ""
    rule = str(metrics["split_rule"].iloc[0])
    return rule.split("test views:")[-1].strip(" []").replace(" ", "") \
        if "test views:" in rule else ""


def variant_row(results: Path, scene: str, variant: str,
                bench: pd.DataFrame | None = None) -> dict:
    """The novel-pose scores, seconds and final point count of one variant."""
    rows = variant_rows(results, scene, variant, bench)
    if not rows:
        raise ValueError(f"avatar variant {variant!r} of {scene!r} has no novel_pose scores")
    return rows[0]


def _drop_missing_lpips(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=["lpips"]) if df["lpips"].isna().all() else df


def ablation_table(results: Path, scene: str, rows: list[dict]) -> pd.DataFrame:
    """``rows``: the study's rows in order, each ``{"label", "iterations", "variant"}`` and the
    switch columns (:data:`signsplat.report.variants.SWITCH_FIELDS`;
    :func:`signsplat.report.variants.ablation_columns`). One table row per (row, split
    scored)."""
    bench = read_benchmarks(Path(results) / "_benchmarks")
    out = []
    for spec in rows:
        switches = {k: spec.get(k) for k in SWITCH_FIELDS}
        for r in variant_rows(results, scene, spec["variant"], bench, SPLITS):
            out.append({**r, **switches, "variant": spec["label"],
                        "iterations": int(spec["iterations"]), "avatar_variant": spec["variant"]})
    cols = ["variant", "iterations", "split", "test_views", "avatar_variant", *SWITCH_FIELDS,
            "smplx_source", "psnr", "ssim", "lpips", "hand_psnr", "train_seconds",
            "eval_seconds", "points"]
    return _drop_missing_lpips(pd.DataFrame(out, columns=cols))


def regularizer_table(results: Path, scene: str, rows: list[dict]) -> pd.DataFrame:
    """``rows``: ``{"scale", "iterations", "variant"}`` of the regulariser's weight sweep; one
    table row per (row, split scored)."""
    bench = read_benchmarks(Path(results) / "_benchmarks")
    out = [{**r, "scale": float(spec["scale"]), "iterations": int(spec["iterations"]),
            "avatar_variant": spec["variant"]}
           for spec in rows for r in variant_rows(results, scene, spec["variant"], bench, SPLITS)]
    cols = ["scale", "iterations", "split", "avatar_variant", "smplx_source", "psnr", "ssim",
            "lpips", "hand_psnr", "train_seconds", "eval_seconds", "points"]
    return _drop_missing_lpips(pd.DataFrame(out, columns=cols))


def winners(df: pd.DataFrame, full: str = "full") -> pd.DataFrame:
    """Per (budget, split) of an ablations table: the best variant on PSNR and on SSIM, the
    full model's scores and its margin to the best other variant (negative: beaten)."""
    out = []
    for (iters, split), g in df.groupby(["iterations", "split"], sort=True):
        row = {"iterations": int(iters), "split": split}
        for metric in ("psnr", "ssim"):
            best = g.loc[g[metric].idxmax()] if g[metric].notna().any() else None
            f = g[g["variant"] == full][metric]
            others = g[g["variant"] != full][metric]
            row[f"best_{metric}"] = "" if best is None else str(best["variant"])
            row[f"full_{metric}"] = float(f.iloc[0]) if len(f) else float("nan")
            row[f"full_margin_{metric}"] = (float(f.iloc[0]) - float(others.max())
                                            if len(f) and others.notna().any() else float("nan"))
        out.append(row)
    return pd.DataFrame(out)


def ssim_finding(df: pd.DataFrame, full: str = "full") -> str:
    """Sentences: per budget and split, is the full model best on SSIM (the paper's finding)
    and on PSNR, and if not, which variant beats it and by how much."""
    if df is None or full not in set(df["variant"]) or df["ssim"].isna().all():
        return "no full-model row with SSIM: the paper's finding cannot be checked"
    lines = []
    for _, w in winners(df, full).iterrows():
        parts = []
        for metric, fmt in (("ssim", ".4f"), ("psnr", ".2f")):
            margin = w[f"full_margin_{metric}"]
            if w[f"best_{metric}"] == full:
                parts.append(f"the full model is best on {metric.upper()} "
                             f"({w[f'full_{metric}']:{fmt}}, {margin:+{fmt}} over the next)")
            elif w[f"best_{metric}"]:
                parts.append(f"{w[f'best_{metric}']} beats the full model on {metric.upper()} "
                             f"by {-margin:{fmt}}")
        lines.append(f"{w['split']} at {w['iterations']} steps: " + "; ".join(parts))
    return ". ".join(lines)


def sweep_table(results: Path, scene: str, settings: dict[str, dict]) -> pd.DataFrame:
    """``settings``: variant name -> the values shown beside its scores (swept, iterations,
    resolution, max_points). ``seconds`` (the x axis) = training seconds from the benchmark
    files; ``pareto_psnr`` / ``pareto_ssim`` mark the settings on the Pareto front."""
    from signsplat.report.plots import pareto_front

    bench = read_benchmarks(Path(results) / "_benchmarks")
    rows = [{"setting": v, **vals, **variant_row(results, scene, v, bench)}
            for v, vals in settings.items()]
    df = pd.DataFrame(rows).drop(columns=["variant"])
    if "lpips" in df:
        df = _drop_missing_lpips(df)
    df["seconds"] = df["train_seconds"]
    df["pareto_psnr"] = pareto_front(df["seconds"], df["psnr"])
    df["pareto_ssim"] = pareto_front(df["seconds"], df["ssim"])
    return df


def fronts_table(points: pd.DataFrame, results: dict[str, Path]) -> pd.DataFrame:
    """``points``: code, commit, measured, scene, variant, setting per trained setting;
    ``results``: code -> the results folder it trained into. The scores and seconds of each
    (``variant_row``) and each code's own Pareto fronts."""
    from signsplat.report.plots import pareto_front

    rows = []
    for _, p in points.iterrows():
        r = variant_row(Path(results[p["code"]]), p["scene"], p["variant"])
        rows.append({**p.to_dict(), **{k: r[k] for k in ("psnr", "ssim", "lpips", "hand_psnr",
                                                         "train_seconds", "eval_seconds",
                                                         "points")}})
    df = pd.DataFrame(rows)
    df["seconds"] = df["train_seconds"]
    for metric in ("psnr", "ssim"):
        df[f"pareto_{metric}"] = False
        for _, g in df.groupby("code", sort=False):
            df.loc[g.index, f"pareto_{metric}"] = pareto_front(g["seconds"], g[metric])
    return df[[c for c in FRONTS_TABLE.columns if c in df]]


def write_parquet(df: pd.DataFrame, path: Path, table: str | None = None) -> Path:
    """``df`` to ``path`` atomically; checked against the registered ``table`` when given."""
    path = Path(path)
    if table is not None:
        return write_table(df, path, table)
    with atomic_path(path) as tmp:
        df.to_parquet(tmp, index=False)
    return path


def write_tsv(df: pd.DataFrame, path: Path) -> Path:
    """``df`` as a tab-separated text table, atomically (for ``snakemake --report``)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        df.to_csv(tmp, sep="\t", index=False)
    return path
