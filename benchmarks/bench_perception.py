"""Speed of the perception models at 256x256 on CPU, by thread count and batch size.

Usage: python benchmarks/bench_perception.py [--segmenter models/segmenter.onnx]
       [--keypoints models/keypoints.onnx] [--frames 64]

Random frames with a centred person box; times model calls with pre/post-processing
(segment_batch + mask_stats + detect_batch), no PNG I/O. Prints frames/s per setting.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from signsplat.perception.contracts import (KeypointSpec, SegmenterSpec, load_keypointer,
                                            load_segmenter)
from signsplat.perception.keypoints import detect_batch
from signsplat.perception.segment import mask_stats, segment_batch


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--segmenter", default="models/segmenter.onnx")
    p.add_argument("--keypoints", default="models/keypoints.onnx")
    p.add_argument("--frames", type=int, default=64)
    a = p.parse_args()
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 255, (256, 256, 3), dtype=np.uint8) for _ in range(a.frames)]
    box = np.array([48.0, 8.0, 208.0, 256.0])
    print(f"{'threads':>7} {'batch':>5} {'seg fps':>8} {'kp fps':>8} {'total fps':>9}")
    for threads in (1, 2):
        for batch in (1, 8):
            seg = SegmenterSpec(a.segmenter, batch_size=batch)
            kp = KeypointSpec(a.keypoints, batch_size=batch)
            sm, km = load_segmenter(seg, threads), load_keypointer(kp, threads)
            t_seg = t_kp = 0.0
            for start in range(0, len(images), batch):
                chunk = images[start:start + batch]
                t0 = time.perf_counter()
                for alpha in segment_batch(sm, seg, chunk):
                    mask_stats(alpha, seg.threshold)
                t1 = time.perf_counter()
                detect_batch(km, kp, chunk, [box] * len(chunk))
                t_kp += time.perf_counter() - t1
                t_seg += t1 - t0
            n = len(images)
            print(f"{threads:>7} {batch:>5} {n / t_seg:>8.1f} {n / t_kp:>8.1f} "
                  f"{n / (t_seg + t_kp):>9.1f}")


if __name__ == "__main__":
    main()
