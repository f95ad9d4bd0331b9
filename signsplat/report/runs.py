"""Summaries of the ablation and sweep runs: one row per avatar variant, from the files the
workflow wrote (``eval/{variant}/metrics.parquet``, ``avatar/{variant}/train_log.parquet``) and
the wall-clock seconds of the Snakemake ``benchmark:`` files (never a hand timer)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.io.atomic import atomic_path
from signsplat.report.collect import read_benchmarks, read_parquet


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
    metrics = read_parquet(results / scene / "eval" / variant / "metrics.parquet")
    if metrics is None:
        raise FileNotFoundError(f"{results / scene / 'eval' / variant / 'metrics.parquet'}")
    log = read_parquet(results / scene / "avatar" / variant / "train_log.parquet")

    def secs(job):
        sel = bench[(bench["job"] == job) & (bench["scene"] == scene)]
        return float(sel["seconds"].iloc[0]) if len(sel) else float("nan")

    row = {"scene": scene, "variant": variant, **image_scores(metrics),
           "train_seconds": secs(f"train_avatar_{variant}"),
           "eval_seconds": secs(f"evaluate_{variant}"),
           "points": int(log["num_points"].iloc[-1]) if log is not None and len(log) else -1,
           "smplx_source": str(metrics["smplx_source"].iloc[0])
           if "smplx_source" in metrics and len(metrics) else ""}
    row["seconds"] = row["train_seconds"] + (0.0 if np.isnan(row["eval_seconds"])
                                             else row["eval_seconds"])
    return row


def ablation_table(results: Path, scene: str, variants: dict[str, str]) -> pd.DataFrame:
    """``variants``: label (e.g. 'w/o regularisation') -> variant name. One row per label."""
    bench = read_benchmarks(Path(results) / "_benchmarks")
    rows = []
    for label, variant in variants.items():
        r = variant_row(results, scene, variant, bench)
        rows.append({**r, "variant": label, "avatar_variant": variant})
    cols = ["variant", "avatar_variant", "psnr", "ssim", "lpips", "hand_psnr", "train_seconds",
            "eval_seconds", "points", "smplx_source"]
    df = pd.DataFrame(rows)[cols]
    return df.dropna(axis=1, how="all") if df["lpips"].isna().all() else df


def sweep_table(results: Path, scene: str, settings: dict[str, dict]) -> pd.DataFrame:
    """``settings``: variant name -> the swept values (iterations, resolution, max_points ...).
    Seconds = training + evaluation (benchmarks); ``pareto_psnr`` / ``pareto_ssim`` mark the
    settings on the Pareto front."""
    from signsplat.report.plots import pareto_front

    bench = read_benchmarks(Path(results) / "_benchmarks")
    rows = [{"setting": v, **vals, **variant_row(results, scene, v, bench)}
            for v, vals in settings.items()]
    df = pd.DataFrame(rows).drop(columns=["variant"])
    df["pareto_psnr"] = pareto_front(df["seconds"], df["psnr"])
    df["pareto_ssim"] = pareto_front(df["seconds"], df["ssim"])
    return df


def write_parquet(df: pd.DataFrame, path: Path) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        df.to_parquet(tmp, index=False)
    return path
