"""benchmarks/hand_image_error.py: a hand's image error split into its shift and its shape."""

import numpy as np
from benchmark_scripts import load_benchmark


def _bench():
    return load_benchmark("hand_image_error")


def test_a_moved_hand_is_all_shift_and_a_turned_hand_is_shape():
    rng = np.random.default_rng(0)
    V, T, N = 2, 5, 30
    true = rng.uniform(50, 150, (V, T, N, 2))
    seen = np.ones((V, T, N), bool)
    e = _bench().hand_errors(true + [3.0, 4.0], true, seen)
    assert np.isclose(e["image_error_px"], 5.0) and np.isclose(e["shift_px"], 5.0)
    assert e["shape_px"] < 1e-9 and e["view_frames"] == V * T
    # the same hand turned by 90 degrees about its own centre: no shift, all shape
    c = true.mean(2, keepdims=True)
    turned = c + (true - c) @ np.array([[0.0, 1.0], [-1.0, 0.0]])
    e = _bench().hand_errors(turned, true, seen)
    assert e["shift_px"] < 1e-9 and np.isclose(e["shape_px"], e["image_error_px"])
    assert e["shape_px"] > 10.0
    # a view-frame where part of the hand is out of the image does not count
    seen[0, 0, 0] = False
    assert _bench().hand_errors(true + [3.0, 4.0], true, seen)["view_frames"] == V * T - 1
