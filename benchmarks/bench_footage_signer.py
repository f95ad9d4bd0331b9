"""Whether the segment stage took the right person as the signer in the example clip, frame
by frame, against where the signer stands judged by eye (benchmarks/data/demovideo_signer.yaml).

Usage: python benchmarks/bench_footage_signer.py [--results results] [--sequence clip]
       [--out benchmarks/results/footage_signer.parquet]

Needs a finished segment stage of `make footage` (``<results>/<sequence>/perception/
persons.parquet``). One row per judged frame range, and a row ``all``:

- ``judged``: frames in the range (the annotation leaves out those where people overlap);
- ``signer``: frames whose chosen person's mid-hip point lies in the range's interval;
- ``other``: frames in which someone else was chosen (hip outside the interval);
- ``none``: frames with nobody chosen (the mask is empty there);
- ``appearance``: frames in which the colour check made the choice (chosen_by).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd
import yaml
from footage_table import publish

from signsplat.io.tables import read_table
from signsplat.perception import tables as _tables  # noqa: F401  (registers "persons")

ANNOTATION = Path(__file__).parent / "data" / "demovideo_signer.yaml"


def judge(persons: pd.DataFrame, ranges: list[list[float]]) -> pd.DataFrame:
    """Rows per judged range (first, last, lo, hi) and ``all`` from a persons table."""
    chosen = persons[persons["chosen"]].set_index("frame")
    rows = []
    for first, last, lo, hi in ranges:
        frames = range(int(first), int(last) + 1)
        picked = chosen.reindex(frames)
        inside = picked["hip_x"].between(lo, hi)
        rows.append(dict(frames=f"{int(first)}-{int(last)}", hip_x=f"{lo:g}-{hi:g}",
                         judged=len(frames), signer=int(inside.sum()),
                         other=int((picked["hip_x"].notna() & ~inside).sum()),
                         none=int(picked["hip_x"].isna().sum()),
                         appearance=int((picked["chosen_by"] == "appearance").sum())))
    df = pd.DataFrame(rows)
    total = df[["judged", "signer", "other", "none", "appearance"]].sum()
    return pd.concat([df, pd.DataFrame([dict(frames="all", hip_x="", **total)])],
                     ignore_index=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", default="results")
    p.add_argument("--sequence", default="clip")
    p.add_argument("--out", default="benchmarks/results/footage_signer.parquet")
    a = p.parse_args()
    note = yaml.safe_load(ANNOTATION.read_text())
    seq = Path(a.results) / a.sequence
    persons = read_table(seq / "perception" / "persons.parquet", "persons")
    if persons["view"].nunique() != 1 or persons["frame"].max() >= note["frames"]:
        raise SystemExit(f"{seq / 'perception' / 'persons.parquet'}: {persons['view'].nunique()}"
                         f" view(s), frames up to {persons['frame'].max()}; {ANNOTATION} "
                         f"annotates one view of {note['frames']} frames")
    publish(judge(persons, note["hip_x"]), a.sequence, a.out)


if __name__ == "__main__":
    main()
