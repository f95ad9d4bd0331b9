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


def test_heads_inside_counts_the_others_heads_by_score_band():
    import pandas as pd

    heads_inside = load_benchmark("bench_footage_masks").heads_inside
    alpha = np.zeros((10, 20), bool)
    alpha[:, :10] = True
    rows = [  # frame, score, head box centre x, chosen
        (0, 0.9, 5.0, True), (0, 0.8, 15.0, False), (0, 0.3, 8.0, False),
        (1, 0.7, 4.0, False), (1, np.nan, 16.0, False), (2, 0.9, 3.0, False)]
    persons = pd.DataFrame([dict(frame=f, score=s, head_x0=x - 1, head_x1=x + 1, head_y0=4.0,
                                 head_y1=6.0, chosen=c) for f, s, x, c in rows])
    got = heads_inside(persons, {0: alpha, 1: alpha}, 0.5)  # frame 2 has no mask
    assert got["people"].tolist() == ["score >= 0.5", "score < 0.5", "all"]
    assert got[["frames", "heads", "heads_in", "frames_in"]].values.tolist() == [
        [3, 3, 1, 1], [1, 1, 1, 1], [3, 5, 2, 2]]
