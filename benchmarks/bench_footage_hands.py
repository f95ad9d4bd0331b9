"""How often the real keypointer finds the signer's hands in the example clip where they can be
seen, judged by eye (benchmarks/data/demovideo_hands.yaml), beside the workflow's own
pose-based guess of visibility (the footage_quality table).

Usage: python benchmarks/bench_footage_hands.py [--results results] [--sequence clip]
       [--out benchmarks/results/footage_hands.parquet]

Needs a finished `make footage` (``<results>/<sequence>/perception/keypoints.parquet``).
Rows per hand:

- ``visible_by_eye``: frames in which the annotation says the hand can be seen;
- ``found_where_visible``: the share of those in which the hand is found (at least half of
  its 21 points score ``min_score``, as in the footage_quality table);
- ``found_where_hidden``: frames in which a hand is reported although by eye it cannot be
  seen (it is something else: a neighbour's hand, a sleeve);
- ``pose_visible`` / ``found_where_pose_visible``: the footage_quality table's guess of
  visibility (wrist scored, expected hand centre in the frame) and its detection rate.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from footage_table import publish

from signsplat.io.images import read_rgb
from signsplat.io.tables import read_table
from signsplat.perception.quality import hand_found, hand_visible, keypoint_arrays

ANNOTATION = Path(__file__).parent / "data" / "demovideo_hands.yaml"


def visible_mask(ranges: list[list[int]], frames: int) -> np.ndarray:
    """(frames,) bool from inclusive [first, last] frame ranges."""
    mask = np.zeros(frames, bool)
    for first, last in ranges:
        if not 0 <= first <= last < frames:
            raise ValueError(f"{ANNOTATION}: range [{first}, {last}] is outside frames "
                             f"0..{frames - 1}")
        mask[first:last + 1] = True
    return mask


def hand_rows(xy: np.ndarray, sc: np.ndarray, size_wh: tuple[int, int], visible: dict,
              min_score: float) -> list[dict]:
    rows = []
    for side, ranges in visible.items():
        seen = visible_mask(ranges, len(sc))
        found = hand_found(sc, side, min_score)
        pose = hand_visible(xy, sc, side, size_wh, min_score)
        rows.append(dict(
            hand=side, frames=len(sc), visible_by_eye=int(seen.sum()),
            found_where_visible=float(found[seen].mean()) if seen.any() else np.nan,
            found_where_hidden=int((found & ~seen).sum()),
            pose_visible=int(pose.sum()),
            found_where_pose_visible=float(found[pose].mean()) if pose.any() else np.nan))
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", default="results")
    p.add_argument("--sequence", default="clip")
    p.add_argument("--min-score", type=float, default=0.5)
    p.add_argument("--out", default="benchmarks/results/footage_hands.parquet")
    a = p.parse_args()
    note = yaml.safe_load(ANNOTATION.read_text())
    seq = Path(a.results) / a.sequence
    frames = read_table(seq / "frames" / "frames.parquet", "frames")
    if len(frames) != note["frames"] or frames["view"].nunique() != 1:
        raise SystemExit(f"{seq / 'frames' / 'frames.parquet'}: {len(frames)} frames in "
                         f"{frames['view'].nunique()} view(s); {ANNOTATION} annotates one view "
                         f"of {note['frames']} frames")
    kp = read_table(seq / "perception" / "keypoints.parquet", "keypoints")
    h, w = read_rgb(seq / "frames" / frames["image"].iloc[0]).shape[:2]
    xy, sc = keypoint_arrays(kp, frames)
    df = pd.DataFrame(hand_rows(xy, sc, (w, h), note["visible"], a.min_score))
    publish(df, a.sequence, a.out)


if __name__ == "__main__":
    main()
