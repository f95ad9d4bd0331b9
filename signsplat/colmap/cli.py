"""``signsplat colmap-compare``: COLMAP on a scene's images vs the SMPL-X camera solve.

Reads the simulator's (or ingest's) ``frames.parquet`` and ground-truth ``cameras.parquet``,
optionally the fitting stage's ``cameras_fit.parquet`` and ``fit_eval.parquet``, and writes
``colmap_compare.parquet``, one PLY per successful run and the baseline ``points.ply``
(the largest successful reconstruction, aligned into the world frame). pycolmap's log and
ours go to stderr (the workflow redirects it into the rule's log). The table is printed last.
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

import pandas as pd

from signsplat.colmap.compare import CompareConfig, compare_scene
from signsplat.colmap.ply import write_points_ply
from signsplat.config import json_option
from signsplat.device import add_runtime_args
from signsplat.io.tables import read_table, write_table


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="signsplat colmap-compare", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--frames", required=True, help="frames.parquet (image paths relative to it)")
    p.add_argument("--cameras", required=True, help="ground-truth cameras.parquet")
    p.add_argument("--fit-cameras", help="cameras_fit.parquet of the SMPL-X fit (optional)")
    p.add_argument("--fit-eval", help="fit_eval.parquet (optional; seconds of the fit)")
    p.add_argument("--config-json", default="{}", help="the 'colmap' config section as JSON")
    p.add_argument("--out", required=True, help="colmap_compare.parquet to write")
    p.add_argument("--ply", help="baseline point cloud PLY (default: beside --out, points.ply)")
    p.add_argument("--ply-dir", help="folder of per-run PLYs (default: beside --out, ply/)")
    p.add_argument("--work-dir", help="parent of the temporary COLMAP folders (default: tmp)")
    add_runtime_args(p, gpu=False)
    return p


def _config(text: str) -> CompareConfig:
    """The `colmap` config section, validated against its schema (defaults filled in)."""
    return CompareConfig.from_dict(json_option(text), "--config-json")


def colmap_compare(argv: list[str]) -> int:
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s: %(message)s")
    log = logging.getLogger("signsplat.colmap")
    cfg = _config(args.config_json)
    out = Path(args.out)
    frames = read_table(args.frames, "frames")
    cameras = read_table(args.cameras, "cameras")
    fit_cameras = read_table(args.fit_cameras, "cameras") if args.fit_cameras else None
    fit_eval = None
    if args.fit_eval:
        if Path(args.fit_eval).exists():
            fit_eval = pd.read_parquet(args.fit_eval)
        else:
            log.warning("%s not found: the SMPL-X row has no seconds", args.fit_eval)
    ply_dir = Path(args.ply_dir) if args.ply_dir else out.parent / "ply"
    ply_dir.mkdir(parents=True, exist_ok=True)  # a workflow output even when every run fails
    table, points, colors = compare_scene(
        frames, Path(args.frames).parent, cameras, cfg, threads=args.threads, ply_dir=ply_dir,
        table_dir=out.parent, fit_cameras=fit_cameras, fit_eval=fit_eval,
        work_root=args.work_dir, cameras_source=args.cameras,
    )
    write_table(table, out, "colmap_compare", metadata={
        "config": json.dumps(cfg.describe()),
        "pixel_convention": "opencv (pixel centres at integer coordinates)",
    })
    best = Path(args.ply) if args.ply else out.parent / "points.ply"
    write_points_ply(best, points, colors, comment="COLMAP baseline points, world frame")
    log.info("wrote %s (%d rows) and %s (%d points)", out, len(table), best, len(points))
    with pd.option_context("display.width", 200, "display.max_columns", 30,
                           "display.max_colwidth", 60):
        print(table.drop(columns=["ply"]).to_string(index=False, float_format="%.3f"))
    return 0
