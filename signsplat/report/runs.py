"""Summaries of the ablation and sweep runs: one row per avatar variant, from the files the
workflow wrote (``eval/{variant}/metrics.parquet``, ``avatar/{variant}/train_log.parquet``) and
the wall-clock seconds of the Snakemake ``benchmark:`` files (never a hand timer)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from signsplat.io.atomic import atomic_path
from signsplat.io.tables import Table, register_table, write_table
from signsplat.report.collect import read_benchmarks, read_parquet

_SCORES = {
    "psnr": "float64 dB, full image, held-out frames (novel pose), background replaced, "
            "no test-time refinement",
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
    "One row per ablation variant of a sequence (paper Table 5), same split and seed. A column "
    "lpips (float64, full image) is present only when LPIPS was computed for some variant.",
    {"variant": "str row label (full, w/o regularisation, ...)",
     "avatar_variant": "str the avatar variant trained (results/{scene}/avatar/{variant})",
     "regularize": "bool neighbourhood variance regularisation on",
     "densify": "bool adaptive density control on",
     "accumulate": "bool loss accumulation over poses on",
     "pose_dependent": "bool pose-dependent networks on (off = static mesh-anchored)",
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


def variant_row(results: Path, scene: str, variant: str,
                bench: pd.DataFrame | None = None) -> dict:
    """Quality, seconds and final point count of one trained and evaluated variant."""
    results = Path(results)
    if bench is None:
        bench = read_benchmarks(results / "_benchmarks")
    path = results / scene / "eval" / variant / "metrics.parquet"
    metrics = read_parquet(path)
    if metrics is None:
        raise FileNotFoundError(f"{path}: metrics of avatar variant {variant!r} not found "
                                "(train and evaluate it first)")
    log = read_parquet(results / scene / "avatar" / variant / "train_log.parquet")

    def secs(job):
        sel = bench[(bench["job"] == job) & (bench["scene"] == scene)]
        return float(sel["seconds"].iloc[0]) if len(sel) else float("nan")

    return {"scene": scene, "variant": variant, **image_scores(metrics),
            "train_seconds": secs(f"train_avatar_{variant}"),
            "eval_seconds": secs(f"evaluate_{variant}"),
            "points": int(log["num_points"].iloc[-1]) if log is not None and len(log) else -1,
            "smplx_source": str(metrics["smplx_source"].iloc[0])
            if "smplx_source" in metrics and len(metrics) else ""}


def _drop_missing_lpips(df: pd.DataFrame) -> pd.DataFrame:
    return df.drop(columns=["lpips"]) if df["lpips"].isna().all() else df


def ablation_table(results: Path, scene: str, variants: dict[str, str | dict]) -> pd.DataFrame:
    """``variants``: row label (e.g. 'w/o regularisation') -> the avatar variant name, or a dict
    with ``variant`` and the switch columns (regularize, densify, accumulate, pose_dependent).
    One row per label, in the given order."""
    bench = read_benchmarks(Path(results) / "_benchmarks")
    rows = []
    for label, spec in variants.items():
        spec = {"variant": spec} if isinstance(spec, str) else dict(spec)
        r = variant_row(results, scene, spec["variant"], bench)
        switches = {k: spec.get(k) for k in ("regularize", "densify", "accumulate",
                                             "pose_dependent")}
        rows.append({**r, **switches, "variant": label, "avatar_variant": spec["variant"]})
    cols = ["variant", "avatar_variant", "regularize", "densify", "accumulate",
            "pose_dependent", "smplx_source", "psnr", "ssim", "lpips", "hand_psnr",
            "train_seconds", "eval_seconds", "points"]
    return _drop_missing_lpips(pd.DataFrame(rows, columns=cols))


def ssim_finding(df: pd.DataFrame, full: str = "full") -> str:
    """One sentence: is the full model best on SSIM (the paper's finding), and if not, which
    variants beat it and by how much."""
    if df is None or full not in set(df["variant"]) or df["ssim"].isna().all():
        return "no full-model row with SSIM: the paper's finding cannot be checked"
    d = df.set_index("variant")
    best = float(d.loc[full, "ssim"])
    better = d[(d["ssim"] > best) & (d.index != full)]["ssim"].sort_values(ascending=False)
    if not len(better):
        return f"the full model is best on SSIM ({best:.4f}), as in the paper"
    names = ", ".join(f"{k} {v:.4f} (+{v - best:.4f})" for k, v in better.items())
    return f"the full model ({best:.4f}) is NOT best on SSIM: beaten by {names}"


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
