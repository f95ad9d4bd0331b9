"""Gather the tables a results folder holds, stage by stage, tolerating stages that did not run.

Everything here reads files and returns plain data (pandas tables, paths); nothing is drawn.
A stage whose files are missing yields a :class:`Section`-ready ``missing`` note instead of an
error, so a report can be written for a partial run.

Layout read (see README, "The workflow"): ``{results}/{scene}/sim/``, ``perception/eval.parquet``
and ``*_timings.parquet``, ``fit/fit_eval.parquet`` and ``fit/overlays/*.png``,
``colmap/colmap_compare.parquet``, ``avatar/{variant}/train_log.parquet``,
``eval/{variant}/metrics.parquet`` and ``eval/{variant}/images/*.png``,
``{scene}/ablations.parquet``, ``{scene}/sweep.parquet``, ``{scene}/fit_sweep.parquet``,
stitching outputs (``stitch_eval.parquet``, ``*.mp4``) anywhere below ``results``, and the
Snakemake benchmark files ``_benchmarks/**/*.tsv``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq

from signsplat.io.atomic import is_temporary
from signsplat.io.tables import table_metadata

# Columns of a Snakemake benchmark TSV that the report uses (seconds, CPU time, peak memory).
BENCH_COLUMNS = ("s", "cpu_time", "max_rss")


@dataclass
class SceneTables:
    """Everything found for one sequence; ``None`` / empty where a stage did not run."""

    name: str
    spec: dict | None = None
    frames: pd.DataFrame | None = None
    sim_images: list[Path] = field(default_factory=list)
    perception_eval: pd.DataFrame | None = None
    perception_timings: pd.DataFrame | None = None
    fit_eval: pd.DataFrame | None = None
    fit_overlays: list[Path] = field(default_factory=list)
    colmap: pd.DataFrame | None = None
    avatar_metrics: dict[str, pd.DataFrame] = field(default_factory=dict)
    avatar_views: dict[str, pd.DataFrame] = field(default_factory=dict)  # per camera
    avatar_images: dict[str, list[Path]] = field(default_factory=dict)
    train_logs: dict[str, pd.DataFrame] = field(default_factory=dict)
    keypoints_2d: Path | None = None  # ground-truth or detected keypoints (close-up crops)
    cameras: pd.DataFrame | None = None
    ablations: pd.DataFrame | None = None
    regularizer: pd.DataFrame | None = None
    sweep: pd.DataFrame | None = None
    fit_sweep: pd.DataFrame | None = None
    footage_quality: pd.DataFrame | None = None  # footage: detection rates, jitter
    footage_overlays: list[Path] = field(default_factory=list)  # mask + keypoints on frames
    persons: pd.DataFrame | None = None  # who the person detector saw, who was taken
    keypointer: dict = field(default_factory=dict)  # the detected keypoints' metadata


@dataclass
class Results:
    root: Path
    scenes: dict[str, SceneTables]
    benchmarks: pd.DataFrame  # rule, scene, job, seconds, cpu_seconds, max_rss_mb, file
    stitch_tables: list[tuple[Path, pd.DataFrame]]
    stitch_videos: list[Path]


def read_parquet(path: Path) -> pd.DataFrame | None:
    """A Parquet file as a DataFrame, or None when it is missing (unreadable files raise);
    the metadata of a table written by ``signsplat.io.tables.write_table`` in ``df.attrs``."""
    if not path.is_file():
        return None
    arrow = pq.read_table(path)
    df = arrow.to_pandas()
    df.attrs = table_metadata(arrow)
    return df


def _pngs(folder: Path, limit: int | None = None) -> list[Path]:
    files = sorted(p for p in folder.glob("*.png") if not is_temporary(p)) \
        if folder.is_dir() else []
    return files[:limit] if limit else files


def _scene_spec(scene_dir: Path, repo_scenes: Path | None) -> dict | None:
    spec = scene_dir / "sim" / "spec.json"
    if spec.is_file():
        return json.loads(spec.read_text())
    if repo_scenes is not None:
        yml = repo_scenes / f"{scene_dir.name}.yaml"
        if yml.is_file():
            import yaml

            return yaml.safe_load(yml.read_text())
    return None


def _concat(frames: list[pd.DataFrame]) -> pd.DataFrame | None:
    frames = [f for f in frames if f is not None and len(f)]
    return pd.concat(frames, ignore_index=True) if frames else None


def collect_scene(scene_dir: Path, repo_scenes: Path | None = None,
                  max_images: int = 6) -> SceneTables:
    """The tables and images of one sequence folder ``results/{scene}``."""
    t = SceneTables(scene_dir.name)
    sim = scene_dir / "sim"
    t.spec = _scene_spec(scene_dir, repo_scenes)
    t.frames = read_parquet(sim / "frames.parquet")
    t.cameras = read_parquet(sim / "cameras.parquet")
    if (sim / "images").is_dir():
        views = sorted(p for p in (sim / "images").iterdir() if p.is_dir())
        t.sim_images = [v_files[0] for v in views[:max_images] if (v_files := _pngs(v))]
    perc = scene_dir / "perception"
    t.perception_eval = read_parquet(perc / "eval.parquet")
    t.perception_timings = _concat([read_parquet(p) for p in sorted(perc.glob("*_timings.parquet"))])
    t.fit_eval = read_parquet(scene_dir / "fit" / "fit_eval.parquet")
    t.fit_overlays = _pngs(scene_dir / "fit" / "overlays", max_images)
    t.colmap = read_parquet(scene_dir / "colmap" / "colmap_compare.parquet")
    for metrics in sorted((scene_dir / "eval").glob("*/metrics.parquet")):
        variant = metrics.parent.name
        t.avatar_metrics[variant] = read_parquet(metrics)
        views = read_parquet(metrics.parent / "views.parquet")
        if views is not None:
            t.avatar_views[variant] = views
        t.avatar_images[variant] = _pngs(metrics.parent / "images", max_images)
    for log in sorted((scene_dir / "avatar").glob("*/train_log.parquet")):
        t.train_logs[log.parent.name] = read_parquet(log)
    for kp in (sim / "keypoints_gt.parquet", perc / "keypoints.parquet"):
        if kp.is_file():
            t.keypoints_2d = kp
            break
    if (perc / "keypoints.parquet").is_file():
        t.keypointer = table_metadata(pq.read_schema(perc / "keypoints.parquet"))
    t.footage_quality = read_parquet(perc / "quality.parquet")
    t.footage_overlays = _pngs(perc / "overlays", max_images)
    t.persons = read_parquet(perc / "persons.parquet")
    t.ablations = read_parquet(scene_dir / "ablations.parquet")
    t.regularizer = read_parquet(scene_dir / "regularizer.parquet")
    t.sweep = read_parquet(scene_dir / "sweep.parquet")
    t.fit_sweep = read_parquet(scene_dir / "fit_sweep.parquet")
    return t


def benchmark_files(bench_dir: str | Path):
    """Each readable Snakemake benchmark TSV below ``bench_dir`` (sorted) with the means over
    its repeats: yields ``(path, {"seconds", "cpu_seconds", "max_rss_mb"})`` (NaN for a column
    the file lacks); empty, unreadable or foreign TSV files are passed over."""
    bench_dir = Path(bench_dir)
    for f in sorted(bench_dir.rglob("*.tsv")) if bench_dir.is_dir() else []:
        try:
            df = pd.read_csv(f, sep="\t")
        except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError):
            continue
        if "s" not in df.columns or not len(df):
            continue
        yield f, {name: float(pd.to_numeric(df[col], errors="coerce").mean())
                  if col in df.columns else float("nan")
                  for name, col in (("seconds", "s"), ("cpu_seconds", "cpu_time"),
                                    ("max_rss_mb", "max_rss"))}


def read_benchmarks(bench_dir: Path) -> pd.DataFrame:
    """One row per Snakemake benchmark TSV (mean over its repeats): rule, scene, job, seconds.

    Files are ``_benchmarks/{rule}.tsv`` or ``_benchmarks/{scene}/{rule}[_{variant}].tsv``;
    ``job`` is the file stem (rule name plus wildcards), ``rule`` the stem up to a known
    variant suffix is not recoverable in general, so ``rule`` is the stem itself.
    """
    rows = []
    for f, means in benchmark_files(bench_dir):
        rel = f.relative_to(bench_dir)
        scene = rel.parts[0] if len(rel.parts) > 1 else ""
        rows.append({"job": f.stem, "scene": scene, **means, "file": str(f)})
    return pd.DataFrame(rows, columns=["job", "scene", "seconds", "cpu_seconds", "max_rss_mb",
                                       "file"])


def bench_seconds(bench: pd.DataFrame, job: str, scene: str = "") -> float | None:
    """Seconds of one benchmarked job (``train_avatar_demo`` in ``scene``), None if absent."""
    sel = bench[(bench["job"] == job) & (bench["scene"] == scene)]
    return float(sel["seconds"].iloc[0]) if len(sel) else None


def collect(results: str | Path, repo_scenes: str | Path | None = None,
            max_images: int = 6) -> Results:
    """Everything a results folder holds; sequence folders are those not starting with ``_``
    that hold at least one stage folder."""
    root = Path(results)
    stages = ("sim", "frames", "perception", "fit", "colmap", "avatar", "eval")
    scenes = {}
    for d in sorted(root.iterdir()) if root.is_dir() else []:
        if d.is_dir() and not d.name.startswith("_") and any((d / s).is_dir() for s in stages):
            scenes[d.name] = collect_scene(d, Path(repo_scenes) if repo_scenes else None,
                                           max_images)
    stitch_tables = [(p, df) for p in sorted(root.rglob("stitch_eval.parquet"))
                     if (df := read_parquet(p)) is not None]
    videos = sorted(p for p in root.rglob("*.mp4")
                    if "_train" not in p.parts and not is_temporary(p))
    return Results(root, scenes, read_benchmarks(root / "_benchmarks"), stitch_tables, videos)
