"""The keypoint sources of benchmarks/fit_init_bias.py: the oracle that removes a detector's
constant offsets, and noise levels that do not depend on each other."""

import numpy as np
from benchmark_scripts import load_benchmark


def _bench():
    return load_benchmark("fit_init_bias")


def test_offsets_removed_noise_levels_independent():
    rng = np.random.default_rng(3)
    V, T, K = 3, 10, 133
    truth = np.zeros((V, T, K, 3))
    truth[..., :2] = rng.uniform(0, 200, (V, T, K, 2))
    truth[..., 2] = 1.0
    offset = rng.normal(0, 3, (V, 1, K, 2))  # constant over the clip, per view and keypoint
    det = truth.copy()
    det[..., :2] += offset + rng.normal(0, 0.5, (V, T, K, 2))
    det[..., 2] = rng.uniform(0.0, 1.0, (V, T, K))
    src = _bench().keypoint_sources(det, truth, 0.3, [1.0, 2.0])
    support = det[..., 2] >= 0.3
    assert set(src) == {"detected", "truth", "truth+1 px", "truth+2 px", "detected-offset"}
    np.testing.assert_array_equal(src["truth"][..., 2] > 0, support)
    # the oracle leaves the noise: its error is the noise about its own mean, not the offset
    err = np.linalg.norm(src["detected-offset"][..., :2] - truth[..., :2], axis=-1)[support]
    raw = np.linalg.norm(det[..., :2] - truth[..., :2], axis=-1)[support]
    assert np.median(err) < 0.8 < 2.0 < np.median(raw)
    # a level's draw is the same whichever levels run with it
    alone = _bench().keypoint_sources(det, truth, 0.3, [2.0])["truth+2 px"]
    np.testing.assert_array_equal(alone, src["truth+2 px"])
    n2 = src["truth+2 px"][..., :2] - src["truth"][..., :2]
    assert abs(n2[support].std() - 2.0) < 0.1
