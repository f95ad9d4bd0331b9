"""How the segmenter's masks depend on its threshold: area bias and wrong pixels against the
simulator's masks, per group of simulated scenes and threshold.

    python -m signsplat simulate-training-set --count 4 --seed 101 --cameras studio \
        --body results/_assets/body_model.npz --glosses results/_assets/gloss_library.parquet \
        --out-dir /tmp/thr/studio            # and --cameras wide --out-dir /tmp/thr/wide
    python benchmarks/segmenter_threshold.py /tmp/thr/studio /tmp/thr/wide \
        --out benchmarks/results/segmenter_threshold.parquet

Each folder holds scene folders with a ``sim/`` (frames table with images and masks). Area
bias: (predicted pixels - true pixels) / true pixels (``perception_eval``'s
``mask_area_bias``); wrong pixels: pixels on one side only, over the true pixels. The
segmenter is the config's (``perception.segmenter``), read once per frame; only the threshold
varies.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.io.atomic import atomic_path
from signsplat.io.images import read_mask, read_rgb
from signsplat.io.tables import read_table
from signsplat.perception.cli import perception_config, specs
from signsplat.perception.contracts import load_segmenter
from signsplat.perception.evaluate import mask_area_bias
from signsplat.perception.segment import segment_batch

ROOT = Path(__file__).resolve().parents[1]


def group_rows(group: Path, model, spec, thresholds: list[float], every: int) -> list[dict]:
    """One row per threshold for the scene folders in ``group``."""
    pred = {t: [] for t in thresholds}
    wrong = {t: 0 for t in thresholds}
    true: list[int] = []
    frames_used = 0
    for scene in sorted(p for p in group.iterdir() if (p / "sim" / "frames.parquet").exists()):
        sim = scene / "sim"
        frames = read_table(sim / "frames.parquet", "frames")
        frames = frames[frames["frame"] % every == 0]
        for start in range(0, len(frames), spec.batch_size):
            rows = frames.iloc[start:start + spec.batch_size]
            alphas = segment_batch(model, spec, [read_rgb(sim / p) for p in rows["image"]])
            for alpha, mask_path in zip(alphas, rows["mask"]):
                gt = read_mask(sim / mask_path)
                true.append(int(gt.sum()))
                for t in thresholds:
                    m = alpha > t
                    pred[t].append(int(m.sum()))
                    wrong[t] += int((m != gt).sum())
        frames_used += len(frames)
    return [{"group": group.name, "threshold": t, "frames": frames_used,
             "area_bias": mask_area_bias(pred[t], true),
             "wrong_fraction": wrong[t] / max(sum(true), 1)} for t in thresholds]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("groups", nargs="+", type=Path, help="folders of simulated scene folders")
    p.add_argument("--thresholds", nargs="+", type=float,
                   default=[0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8])
    p.add_argument("--every", type=int, default=4, help="use every N-th frame")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path,
                   default=ROOT / "benchmarks/results/segmenter_threshold.parquet")
    args = p.parse_args()
    spec, _ = specs(perception_config(None))
    spec = dataclasses.replace(spec, path=str(ROOT / spec.path))
    model = load_segmenter(spec, args.threads)
    rows = [r for g in args.groups for r in group_rows(g, model, spec, args.thresholds,
                                                        args.every)]
    df = pd.DataFrame(rows)
    with atomic_path(args.out) as tmp:
        df.to_parquet(tmp, index=False)
    with pd.option_context("display.width", 120):
        print(df.assign(area_bias=df["area_bias"] * 100, wrong_fraction=df["wrong_fraction"] * 100)
              .to_string(index=False, float_format="%.2f"))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
