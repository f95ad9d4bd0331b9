"""Procedural albedo: range, determinism, detail where the splats need it, speed."""

from __future__ import annotations

import time

import numpy as np
import pytest

from signsplat.body import joints as JN
from signsplat.body.appearance import albedo, palette

JI = JN.JOINT_INDEX


@pytest.fixture(scope="module")
def surface(proxy_arrays):
    """65,536 random points on the proxy surface with their part labels."""
    v, f, lab = proxy_arrays["v_template"], proxy_arrays["f"], proxy_arrays["part_labels"]
    rng = np.random.default_rng(0)
    fi = rng.integers(0, len(f), 65536)
    b = rng.dirichlet([1, 1, 1], 65536)
    return (v[f[fi]] * b[:, :, None]).sum(1), lab[f[fi, 0]]


def test_range_dtype_determinism(surface):
    pts, lab = surface
    a = albedo(pts, lab, seed=0)
    assert a.shape == (len(pts), 3) and a.dtype == np.float32
    assert a.min() >= 0.0 and a.max() <= 1.0
    np.testing.assert_array_equal(a, albedo(pts, lab, seed=0))
    others = [albedo(pts, lab, seed=s) for s in range(1, 5)]
    assert any(np.abs(o - a).max() > 0.1 for o in others)
    assert np.abs(albedo(pts[:100], lab[:100], seed=0) - a[:100]).max() == 0  # pointwise


def test_vertex_colors_are_the_albedo(proxy_arrays):
    a = albedo(proxy_arrays["v_template"], proxy_arrays["part_labels"], seed=0)
    np.testing.assert_allclose(proxy_arrays["vertex_colors"], a, atol=1e-6)


def _line(start, end, n=400):
    return np.linspace(start, end, n)


def test_shirt_pattern_has_moderate_frequency(proxy_arrays):
    J = proxy_arrays["J_regressor"] @ proxy_arrays["v_template"]
    chest = J[JI["spine3"]] + (0.0, 0.0, 0.2)
    pts = _line(chest - (0.1, 0, 0), chest + (0.1, 0, 0))  # 20 cm across the chest, 0.5 mm step
    col = albedo(pts, np.full(len(pts), JN.PART_BODY), seed=0)
    change = np.abs(np.diff(col, axis=0)).sum(1) > 0.05
    edges = np.nonzero(change)[0]
    assert len(edges) >= 8  # a pattern, not a flat colour
    runs = np.diff(edges) * (0.2 / (len(pts) - 1))
    assert np.median(runs) >= 0.008  # checks ~1.2 cm wide: resolvable at ~4 mm/pixel


def test_face_features(proxy_arrays):
    J = proxy_arrays["J_regressor"] @ proxy_arrays["v_template"]
    head = np.full(1, JN.PART_HEAD)
    skin = palette(0)["skin"]
    eye = J[JI["left_eye"]] + (0, 0, 0.0125)
    pupil = albedo(eye[None], head, 0)[0]
    assert pupil.max() < 0.1  # dark pupil
    sclera = albedo((eye + (0.009, 0, 0))[None], head, 0)[0]
    assert sclera.min() > 0.8
    cheek = albedo((eye + (0.01, -0.05, 0))[None], head, 0)[0]
    assert np.abs(cheek - skin).max() < 0.1
    mouth = np.array([[0.0, J[JI["jaw"], 1] + 0.004 + 0.006, 0.09]])
    lips = albedo(mouth, head, 0)[0]
    assert np.abs(lips - skin).max() > 0.03 and lips[0] > lips[2]  # reddish
    top = albedo(np.array([[0.0, v_top(proxy_arrays), 0.0]]), head, 0)[0]
    np.testing.assert_allclose(top, palette(0)["hair"], atol=1e-6)


def v_top(arrays):
    return arrays["v_template"][:, 1].max() - 0.005


def test_hand_details(proxy_arrays):
    J = proxy_arrays["J_regressor"] @ proxy_arrays["v_template"]
    lab = np.full(1, JN.PART_LEFT_HAND)
    skin = palette(0)["skin"]
    d = J[JI["left_middle3"]] - J[JI["left_middle2"]]
    d /= np.linalg.norm(d)
    nail = J[JI["left_middle3"]] + 0.015 * d + (0, 0.006, 0)
    assert np.abs(albedo(nail[None], lab, 0)[0] - skin).max() > 0.05
    crease = J[JI["left_middle2"]] + 0.0005 * d + (0, 0.007, 0)
    between = J[JI["left_middle2"]] + 0.012 * d + (0, 0.007, 0)
    c, b = albedo(np.stack([crease, between]), np.repeat(lab, 2), 0)
    assert c.sum() < b.sum() - 0.1  # the knuckle line is darker than the finger next to it
    # the palm (below, -y) differs from the back of the hand
    back = J[JI["left_wrist"]] + (0.05, 0.02, 0)
    palm = J[JI["left_wrist"]] + (0.05, -0.02, 0)
    a, p = albedo(np.stack([back, palm]), np.repeat(lab, 2), 0)
    assert np.abs(a - p).max() > 0.02


def test_speed(surface):
    pts, lab = surface
    albedo(pts, lab, 0)
    best = min(_timed(albedo, pts, lab) for _ in range(3))
    print(f"albedo of {len(pts)} points: {1000 * best:.1f} ms")
    assert best < 0.5  # ~10-50 ms measured on a shared 2-core machine


def _timed(fn, *args):
    t = time.perf_counter()
    fn(*args, 0)
    return time.perf_counter() - t
