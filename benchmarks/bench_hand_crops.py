"""Where MediaPipe's hand landmarker looks for the dominant hand (``perception.keypoints.
hand_crop``): its cost and its fingers, side by side on a finished sequence.

Usage: python benchmarks/bench_hand_crops.py [--results results] [--sequence studio6]
       [--rounds 2] [--threads 1] [--reference results/studio6/perception/keypoints.parquet]
       [--out benchmarks/results/hand_crops.parquet]

Needs a finished `make demo` (the sequence's frames, masks and persons, and the simulator's
ground truth). The keypoint stage runs once per setting and round, alternating (a burst of
load on a shared machine then hits both), on the sequence's own perception section (its
sheet row's dominant hand); the fastest round is kept. Rows per ``hand_crop``:

- ``seconds``: the stage's model time (keypoint model and landmarker, no PNG reading);
- ``taken``: view-frames whose dominant fingers came from the landmarker, of ``frames``;
- ``pck``, ``err_px``: the dominant hand's PCK@0.05 and mean pixel error against the
  simulator's points (the perception evaluation's); ``other_hand_err_px`` the other hand's;
- ``same_as_reference``: whether the keypoints equal ``--reference`` to the last bit (the
  workflow's own table; a run of the code before the option has the `pose` behaviour).
"""

from __future__ import annotations

import argparse
import datetime as dt
import re
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.config import REPO_ROOT, load_config, load_sequences
from signsplat.io.atomic import atomic_path
from signsplat.io.tables import read_table
from signsplat.perception.detectors import detector_specs, detectors_for, perception_for
from signsplat.perception.evaluate import accuracy
from signsplat.perception.stages import detect_sequence

CROPS = ("pose", "model")


def run_once(perception: Path, out: Path, spec, threads: int) -> float:
    """The keypoint stage into ``out``: its model seconds."""
    report = detect_sequence(perception.parent / "sim" / "frames.parquet",
                             perception / "masks.parquet", out, spec, threads, progress=False,
                             persons_path=perception / "persons.parquet")
    return report.timings["model"]


def scores(sim: Path, perception: Path, keypoints: Path, side: str) -> dict[str, float]:
    """The dominant hand's PCK and error, the other hand's error (perception evaluation)."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        (tmp / "masks.parquet").symlink_to(perception / "masks.parquet")
        (tmp / "masks").symlink_to(perception / "masks")
        (tmp / "keypoints.parquet").symlink_to(keypoints)
        acc = accuracy(sim, tmp).set_index(["metric", "part"])["value"]
    other = "left" if side == "right" else "right"
    return {"pck": acc[("pck@0.05", f"{side}_hand")],
            "err_px": acc[("mean_px_error", f"{side}_hand")],
            "other_hand_err_px": acc[("mean_px_error", f"{other}_hand")]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default="results")
    ap.add_argument("--sequence", default="studio6")
    ap.add_argument("--config", default=str(REPO_ROOT / "config" / "config.yaml"))
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--reference", default=None,
                    help="a keypoints table to compare with (default: the workflow's own)")
    ap.add_argument("--out", default="benchmarks/results/hand_crops.parquet")
    a = ap.parse_args(argv)
    config = load_config(a.config)
    row = load_sequences(config, REPO_ROOT)[a.sequence]
    cfg = perception_for(row, config["perception"])
    if cfg["keypoints"]["hands"] != "mediapipe":
        sys.exit(f"{a.sequence}: its perception takes no MediaPipe fingers "
                 f"(keypoints.hands resolves to {cfg['keypoints']['hands']!r})")
    side = cfg["keypoints"]["hand_sides"][0]
    perception = Path(a.results) / a.sequence / "perception"
    sim = Path(a.results) / a.sequence / "sim"
    reference = Path(a.reference or perception / "keypoints.parquet")
    best: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(a.rounds):
            for crop in CROPS:
                one = {**cfg, "keypoints": {**cfg["keypoints"], "hand_crop": crop}}
                _, spec = detector_specs(one, detectors_for(row, config["perception"]), "cpu")
                seconds = run_once(perception, Path(tmp) / f"{crop}.parquet", spec, a.threads)
                print(f"round {r + 1}, {crop}: {seconds:.1f} s")
                best[crop] = min(seconds, best.get(crop, np.inf))
        ref = read_table(reference, "keypoints")
        rows = []
        for crop in CROPS:
            path = Path(tmp) / f"{crop}.parquet"
            kp = read_table(path, "keypoints")
            taken = re.search(r"taken in (\d+) of (\d+) frames", kp.attrs["note"])
            rows.append(dict(sequence=a.sequence, side=side, hand_crop=crop,
                             seconds=best[crop], threads=a.threads,
                             taken=int(taken[1]), frames=int(taken[2]),
                             **scores(sim, perception, path, side),
                             same_as_reference=bool(
                                 len(kp) == len(ref)
                                 and np.array_equal(kp[["x", "y", "score"]].to_numpy(),
                                                    ref[["x", "y", "score"]].to_numpy(),
                                                    equal_nan=True))))
    df = pd.DataFrame(rows)
    df["date"] = dt.date.today().isoformat()
    print(df.to_string(index=False))
    print(f"model crop: {df.seconds.iloc[0] / df.seconds.iloc[1]:.2f}x faster than pose crop")
    with atomic_path(a.out) as tmp:
        df.to_parquet(tmp, index=False)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
