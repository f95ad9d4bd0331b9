"""Whether the signer's masks in the example clip hold the signer and leave out the other
people, at points judged by eye (benchmarks/data/demovideo_people.yaml).

Usage: python benchmarks/bench_footage_masks.py [--results results] [--sequence clip]
       [--out benchmarks/results/footage_masks.parquet]

Needs a finished segment stage of `make footage` (``<results>/<sequence>/perception/
masks.parquet`` and its mask images). A point is in the mask where the mask's alpha there is
at least one half. One row per annotated frame, and a row ``all``:

- ``signer_points`` / ``signer_in``: points on the signer, and how many the mask holds;
- ``others_points`` / ``others_in``: points on the other people, and how many it takes in;
- ``area``: the mask's pixels (alpha at least one half).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from footage_table import publish

from signsplat.io.images import read_mask
from signsplat.io.tables import read_table
from signsplat.perception import tables as _tables  # noqa: F401  (registers "masks")

ANNOTATION = Path(__file__).parent / "data" / "demovideo_people.yaml"


def inside(alpha: np.ndarray, points: list[list[float]]) -> int:
    """How many of the (x, y) pixel ``points`` lie where ``alpha`` (H, W, 0-1) is >= 0.5."""
    h, w = alpha.shape
    return sum(int(alpha[min(max(int(round(y)), 0), h - 1),
                         min(max(int(round(x)), 0), w - 1)] >= 0.5) for x, y in points)


def judge(masks: dict[int, np.ndarray], points: dict[int, dict]) -> pd.DataFrame:
    """Rows per annotated frame and ``all`` from each frame's alpha (frame -> (H, W) 0-1;
    a frame without a mask counts as an empty one)."""
    rows = []
    for frame, people in sorted(points.items()):
        alpha = masks.get(int(frame))
        if alpha is None:
            alpha = np.zeros((1, 1), np.float32)
        rows.append(dict(frame=str(frame),
                         signer_points=len(people["signer"]),
                         signer_in=inside(alpha, people["signer"]),
                         others_points=len(people["others"]),
                         others_in=inside(alpha, people["others"]),
                         area=int((alpha >= 0.5).sum())))
    df = pd.DataFrame(rows)
    total = df.drop(columns="frame").sum()
    return pd.concat([df, pd.DataFrame([dict(frame="all", **total)])], ignore_index=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", default="results")
    p.add_argument("--sequence", default="clip")
    p.add_argument("--out", default="benchmarks/results/footage_masks.parquet")
    a = p.parse_args()
    note = yaml.safe_load(ANNOTATION.read_text())
    perception = Path(a.results) / a.sequence / "perception"
    table = read_table(perception / "masks.parquet", "masks")
    if table["view"].nunique() != 1 or table["frame"].max() >= note["frames"]:
        raise SystemExit(f"{perception / 'masks.parquet'}: {table['view'].nunique()} view(s), "
                         f"frames up to {table['frame'].max()}; {ANNOTATION} annotates one "
                         f"view of {note['frames']} frames")
    wanted = table[table["frame"].isin(list(note["points"]))]
    masks = {int(r.frame): read_mask(perception / r.mask) for r in wanted.itertuples()}
    publish(judge(masks, note["points"]), a.sequence, a.out)


if __name__ == "__main__":
    main()
