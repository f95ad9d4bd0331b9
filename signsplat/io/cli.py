"""Commands for input handling: ``signsplat extract-frames``."""

from __future__ import annotations

import argparse
import json
import time

from signsplat.io.ingest import extract_sequence


def extract_frames(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="signsplat extract-frames",
                                     description="Extract frames of one video per camera.")
    parser.add_argument("--sequence-json", required=True,
                        help="the sequence's row of the sequence sheet, as JSON")
    parser.add_argument("--out", required=True, help="output folder")
    args = parser.parse_args(argv)
    seq = json.loads(args.sequence_json)
    size = tuple(int(v) for v in seq["resize"].split("x")) if seq.get("resize") else None
    t0 = time.perf_counter()
    frames = extract_sequence(
        seq["sequence"], [c for c in seq["cameras"].split(";") if c], args.out,
        fps=seq.get("fps") or None, start=int(seq.get("start") or 0),
        end=int(seq["end"]) if seq.get("end") not in (None, "") else None, size=size,
        calibration=seq.get("calibration") or None,
        crop=tuple(int(v) for v in seq["crop"].split(",")) if seq.get("crop") else None,
    )
    print(f"{seq['sequence']}: {frames['view'].nunique()} view(s) x {frames['frame'].nunique()} "
          f"frame(s) in {time.perf_counter() - t0:.1f} s")
    return 0
