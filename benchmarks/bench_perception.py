"""Speed of the perception models at 256x256 on CPU, by thread count and batch size.

Usage: python benchmarks/bench_perception.py [--models LABEL=SEG.onnx,KP.onnx ...]
       [--frames 64] [--rounds 3] [--out benchmarks/results/perception.parquet]

Random frames with a centred person box; times model calls with pre/post-processing
(segment_batch + mask_stats + detect_batch), no PNG I/O. Several model pairs are timed side by
side, alternating in every round (a burst of load on a shared machine then hits all of them),
and the best round is kept. Prints frames/s per setting and saves the table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.io.atomic import atomic_path
from signsplat.perception.contracts import (KeypointSpec, SegmenterSpec, load_keypointer,
                                            load_segmenter)
from signsplat.perception.keypoints import detect_batch
from signsplat.perception.segment import mask_stats, segment_batch


def _time_pair(sm, km, seg, kp, images, box) -> tuple[float, float]:
    t_seg = t_kp = 0.0
    for start in range(0, len(images), seg.batch_size):
        chunk = images[start:start + seg.batch_size]
        t0 = time.perf_counter()
        for alpha in segment_batch(sm, seg, chunk):
            mask_stats(alpha, seg.threshold)
        t1 = time.perf_counter()
        detect_batch(km, kp, chunk, [box] * len(chunk))
        t_kp += time.perf_counter() - t1
        t_seg += t1 - t0
    return t_seg, t_kp


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", nargs="+", default=["shipped=models/segmenter.onnx,models/keypoints.onnx"],
                   help="LABEL=SEGMENTER.onnx,KEYPOINTS.onnx (several are timed side by side)")
    p.add_argument("--frames", type=int, default=64)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", default="benchmarks/results/perception.parquet")
    a = p.parse_args()
    pairs = {}
    for item in a.models:
        label, paths = item.split("=", 1)
        pairs[label] = tuple(paths.split(","))
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, (256, 256, 3), dtype=np.uint8) for _ in range(a.frames)]
    box = np.array([48.0, 8.0, 208.0, 256.0])
    rows = []
    print(f"{'models':>10} {'threads':>7} {'batch':>5} {'seg fps':>8} {'kp fps':>8} {'total fps':>9}")
    for threads in (1, 2):
        for batch in (1, 8):
            loaded = {}
            for label, (spath, kpath) in pairs.items():
                seg = SegmenterSpec(spath, batch_size=batch)
                kp = KeypointSpec(kpath, batch_size=batch)
                loaded[label] = (load_segmenter(seg, threads), load_keypointer(kp, threads), seg, kp)
                _time_pair(*loaded[label], images[:batch], box)  # warm-up
            best = {label: (np.inf, np.inf) for label in pairs}
            for _ in range(a.rounds):
                for label, args in loaded.items():
                    ts, tk = _time_pair(*args, images, box)
                    best[label] = (min(best[label][0], ts), min(best[label][1], tk))
            n = len(images)
            for label, (ts, tk) in best.items():
                print(f"{label:>10} {threads:>7} {batch:>5} {n / ts:>8.1f} {n / tk:>8.1f} "
                      f"{n / (ts + tk):>9.1f}")
                rows.append({"models": label, "threads": threads, "batch": batch,
                             "segment_fps": n / ts, "keypoints_fps": n / tk,
                             "total_fps": n / (ts + tk), "frames": n})
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(a.out) as tmp:
        pd.DataFrame(rows).to_parquet(tmp, index=False)
    print(f"saved {a.out}")


if __name__ == "__main__":
    main()
