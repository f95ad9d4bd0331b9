"""benchmarks/bench_footage_masks.py: masks judged at points on the signer and the others."""

import numpy as np
from benchmark_scripts import load_benchmark


def test_judge_counts_points_inside_each_mask():
    judge = load_benchmark("bench_footage_masks").judge
    alpha = np.zeros((10, 20), np.float32)
    alpha[2:8, 2:8] = 1.0  # the signer
    alpha[2:8, 12:14] = 0.6  # a piece of someone else taken in
    points = {0: {"signer": [[4, 4], [7, 7]], "others": [[12.6, 5], [17, 5]]},
              5: {"signer": [[4, 4]], "others": [[12, 5]]}}  # frame 5 has no mask
    got = judge({0: alpha}, points)
    assert got["frame"].tolist() == ["0", "5", "all"]
    assert got[["signer_points", "signer_in", "others_points", "others_in", "area"]
               ].values.tolist() == [[2, 2, 2, 1, 48], [1, 0, 1, 0, 0], [3, 2, 3, 1, 48]]
