"""Whether the signer's masks in the example clip hold the signer and leave out the other
people, at points judged by eye (benchmarks/data/demovideo_people.yaml).

Usage: python benchmarks/bench_footage_masks.py [--results results] [--sequence clip]
       [--out benchmarks/results/footage_masks.parquet]
       [--persons PERSONS] [--heads-out benchmarks/results/footage_mask_heads.parquet]

Needs a finished segment stage of `make footage` (``<results>/<sequence>/perception/
masks.parquet`` and its mask images). A point is in the mask where the mask's alpha there is
at least one half. One row per annotated frame, and a row ``all``:

- ``signer_points`` / ``signer_in``: points on the signer, and how many the mask holds;
- ``others_points`` / ``others_in``: points on the other people, and how many it takes in;
- ``area``: the mask's pixels (alpha at least one half).

A second table counts, over every frame, the other people the persons table lists (the
detector's head box of each person not chosen; ``--persons`` takes another run's table, to
score two runs' masks on the same people) whose head box centre lies in the mask: a row per
detector score band and ``all`` with ``frames`` (frames with such a person), ``heads`` and
``heads_in``, and ``frames_in`` (frames with at least one head inside).
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
from signsplat.perception import tables as _tables  # noqa: F401  (registers the tables)

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


def heads_inside(persons: pd.DataFrame, masks: dict[int, np.ndarray],
                 strong: float) -> pd.DataFrame:
    """Rows ``score >= strong``, ``score < strong`` and ``all``: the not-chosen people of a
    persons table whose head box centre lies in their frame's mask (frame -> alpha)."""
    people = persons[~persons["chosen"]].copy()
    people["cx"] = (people["head_x0"] + people["head_x1"]) / 2
    people["cy"] = (people["head_y0"] + people["head_y1"]) / 2
    people = people[np.isfinite(people[["cx", "cy"]]).all(axis=1)]
    people["inside"] = [inside(masks[int(r.frame)], [[r.cx, r.cy]]) if int(r.frame) in masks
                        else 0 for r in people.itertuples()]
    rows = []
    for band, sel in ((f"score >= {strong:g}", people["score"] >= strong),
                      (f"score < {strong:g}", people["score"] < strong),
                      ("all", np.ones(len(people), bool))):
        group = people[sel]
        rows.append(dict(people=band, frames=int(group["frame"].nunique()),
                         heads=len(group), heads_in=int(group["inside"].sum()),
                         frames_in=int(group.loc[group["inside"] > 0, "frame"].nunique())))
    return pd.DataFrame(rows)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", default="results")
    p.add_argument("--sequence", default="clip")
    p.add_argument("--out", default="benchmarks/results/footage_masks.parquet")
    p.add_argument("--persons", default=None,
                   help="persons.parquet whose people to count (default: the run's own)")
    p.add_argument("--heads-out", default="benchmarks/results/footage_mask_heads.parquet")
    p.add_argument("--strong", type=float, default=0.5,
                   help="the person detector's own threshold (pretrained.keypoints."
                        "min_detection_score), which splits the heads table")
    a = p.parse_args()
    note = yaml.safe_load(ANNOTATION.read_text())
    perception = Path(a.results) / a.sequence / "perception"
    table = read_table(perception / "masks.parquet", "masks")
    if table["view"].nunique() != 1 or table["frame"].max() >= note["frames"]:
        raise SystemExit(f"{perception / 'masks.parquet'}: {table['view'].nunique()} view(s), "
                         f"frames up to {table['frame'].max()}; {ANNOTATION} annotates one "
                         f"view of {note['frames']} frames")
    masks = {int(r.frame): read_mask(perception / r.mask) for r in table.itertuples()}
    publish(judge(masks, note["points"]), a.sequence, a.out)
    persons = read_table(a.persons or perception / "persons.parquet", "persons")
    publish(heads_inside(persons, masks, a.strong), a.sequence, a.heads_out)


if __name__ == "__main__":
    main()
