"""Similarity alignment and camera errors (signsplat.colmap.align)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from signsplat.colmap.align import (
    Similarity, align_cameras, camera_centres, centres_degenerate, rotation_angle_deg, umeyama,
)


def _random_similarity(seed: int) -> Similarity:
    rng = np.random.default_rng(seed)
    return Similarity(float(rng.uniform(0.2, 5.0)), Rotation.random(random_state=seed).as_matrix(),
                      rng.normal(0, 3, 3))


def _rig(n: int, seed: int = 0):
    """n cameras with random orientations and centres spread over a few metres."""
    rng = np.random.default_rng(seed)
    R = Rotation.random(n, random_state=seed + 100).as_matrix()
    c = rng.normal(0, 2, (n, 3))
    t = -np.einsum("nij,nj->ni", R, c)
    return R, t


def _express_in(sim: Similarity, R, t):
    """The same cameras in a frame where x_gt = sim(x_est): returns estimated R, t."""
    # x_cam = R x_gt + t = R (s A x_est + b) + t  ->  rotation R A, translation (R b + t) / s
    R_est = R @ sim.rotation
    t_est = (np.einsum("nij,j->ni", R, sim.translation) + t) / sim.scale
    return R_est, t_est


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_umeyama_recovers_known_similarity(seed):
    sim = _random_similarity(seed)
    src = np.random.default_rng(seed + 10).normal(0, 1, (12, 3))
    got = umeyama(src, sim.apply(src))
    assert got.scale == pytest.approx(sim.scale, rel=1e-10)
    np.testing.assert_allclose(got.rotation, sim.rotation, atol=1e-10)
    np.testing.assert_allclose(got.translation, sim.translation, atol=1e-9)


def test_umeyama_returns_a_rotation_for_a_mirrored_target():
    src = np.random.default_rng(0).normal(0, 1, (10, 3))
    dst = src * np.array([1.0, 1.0, -1.0])  # a reflection: no rotation maps src onto dst
    got = umeyama(src, dst)
    assert np.linalg.det(got.rotation) == pytest.approx(1.0)


def test_umeyama_rejects_too_few_points():
    with pytest.raises(ValueError):
        umeyama(np.zeros((2, 3)), np.zeros((2, 3)))


@pytest.mark.parametrize("seed", [0, 5])
def test_align_cameras_exact_for_cameras_in_another_frame(seed):
    R, t = _rig(6, seed)
    sim = _random_similarity(seed)
    R_est, t_est = _express_in(sim, R, t)
    al = align_cameras(R_est, t_est, R, t)
    assert al.method == "umeyama"
    assert al.similarity.scale == pytest.approx(sim.scale, rel=1e-9)
    assert al.rotation_deg.max() < 1e-6
    assert al.centre_m.max() < 1e-9


def test_align_cameras_measures_a_known_perturbation():
    R, t = _rig(8, 3)
    R_est, t_est = R.copy(), t.copy()
    delta = Rotation.from_rotvec([0.0, np.radians(2.0), 0.0]).as_matrix()
    R_est[0] = delta @ R[0]  # rotate camera 0 about its own axis, centre unchanged
    t_est[0] = delta @ t[0]
    al = align_cameras(R_est, t_est, R, t)
    np.testing.assert_allclose(camera_centres(R_est, t_est), camera_centres(R, t), atol=1e-12)
    assert al.rotation_deg[0] == pytest.approx(2.0, abs=0.3)  # alignment spreads a little
    assert al.centre_m.max() < 1e-9


def test_nearly_coincident_cameras_fall_back_to_orientations():
    rng = np.random.default_rng(1)
    R = Rotation.random(5, random_state=7).as_matrix()
    c = np.array([0.0, 1.3, 3.0]) + rng.normal(0, 1e-3, (5, 3))  # ~1 mm apart
    t = -np.einsum("nij,nj->ni", R, c)
    assert centres_degenerate(c, min_spread=0.01) and not centres_degenerate(c)
    sim = _random_similarity(4)
    R_est, t_est = _express_in(sim, R, t)
    al = align_cameras(R_est, t_est, R, t)
    assert al.method == "orientation"
    assert np.isfinite(al.centre_m).all() and np.isfinite(al.rotation_deg).all()
    assert al.rotation_deg.max() < 1e-6
    np.testing.assert_allclose(al.similarity.rotation, sim.rotation, atol=1e-9)
    assert al.centre_m.max() < 1e-5


def test_two_cameras_use_orientations_and_recover_scale():
    R, t = _rig(2, 9)
    sim = _random_similarity(9)
    R_est, t_est = _express_in(sim, R, t)
    al = align_cameras(R_est, t_est, R, t)
    assert al.method == "orientation"
    assert al.similarity.scale == pytest.approx(sim.scale, rel=1e-9)
    assert al.centre_m.max() < 1e-9


def test_rotation_angle_deg():
    a = Rotation.random(4, random_state=0).as_matrix()
    b = Rotation.from_rotvec(np.tile([0, 0, np.radians(30.0)], (4, 1))).as_matrix() @ a
    np.testing.assert_allclose(rotation_angle_deg(b, a), 30.0, atol=1e-9)


def _look_at_rig(centres: np.ndarray):
    """Cameras at ``centres`` (N,3) all looking at the origin."""
    Rs = []
    for c in centres:
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0.0, 1.0, 0.0])
        x /= np.linalg.norm(x)
        Rs.append(np.stack([x, np.cross(z, x), z]))
    R = np.stack(Rs)
    return R, -np.einsum("nij,nj->ni", R, centres)


def test_coplanar_arc_cameras_align_exactly_with_umeyama():
    """A studio arc: every centre at the same height (coplanar, not collinear)."""
    ang = np.radians(np.linspace(-75, 75, 6))
    centres = np.stack([2 * np.sin(ang), np.full(6, 0.1), 2 * np.cos(ang)], 1)
    R, t = _look_at_rig(centres)
    sim = _random_similarity(11)
    al = align_cameras(*_express_in(sim, R, t), R, t)
    assert al.method == "umeyama"
    assert al.rotation_deg.max() < 1e-6 and al.centre_m.max() < 1e-9


def test_collinear_cameras_fall_back_to_orientations():
    centres = np.stack([np.linspace(-1, 1, 5), np.full(5, 0.2), np.full(5, 2.0)], 1)
    R, t = _look_at_rig(centres)
    sim = _random_similarity(12)
    al = align_cameras(*_express_in(sim, R, t), R, t)
    assert al.method == "orientation"
    assert al.rotation_deg.max() < 1e-6 and al.centre_m.max() < 1e-9
