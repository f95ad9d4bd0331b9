"""Building blocks of the fit without a body model: filters, kernels, cameras, metrics."""

import numpy as np
import pytest
import torch

from signsplat.fit import cameras
from signsplat.fit import evaluate as fit_eval
from signsplat.fit import filters
from signsplat.fit import robust


# --- filters ---------------------------------------------------------------------------------

def _track(T=50, K=4, seed=0, noise=2.0):
    rng = np.random.default_rng(seed)
    t = np.arange(T) / 25.0
    clean = np.stack([100 + 40 * np.sin(2 * np.pi * 0.5 * t)[:, None] + np.arange(K)[None] * 5,
                      120 + 30 * np.cos(2 * np.pi * 0.4 * t)[:, None] + np.zeros(K)[None]], -1)
    noisy = clean + rng.normal(0, noise, clean.shape)
    kp = np.concatenate([noisy, np.ones((T, K, 1))], -1)
    return t, clean, kp


def test_sanitize_counts_nan_and_zero_scores():
    _, _, kp = _track()
    kp[3, 0, :2] = np.nan
    kp[4, 1, 2] = 0.0
    kp[5, 2, 2] = np.nan
    out, st = filters.sanitize(kp, min_score=0.1)
    assert st.nan == 1 and st.low_score == 2
    assert np.isfinite(out).all()
    assert out[3, 0, 2] == 0 and out[4, 1, 2] == 0 and out[5, 2, 2] == 0
    assert st.used == kp.shape[0] * kp.shape[1] - 3


def test_outlier_rejection_finds_a_jump():
    _, _, kp = _track()
    kp[20, 1, :2] += 80.0
    out, n = filters.reject_outliers(kp, radius=3, threshold_px=25.0)
    assert out[20, 1, 2] == 0.0
    assert n == 1


def test_one_euro_reduces_noise_and_skips_gaps():
    t, clean, kp = _track(noise=3.0)
    kp[10:14, 0, 2] = 0  # a gap: untouched and not advancing the filter
    kp[10:14, 0, :2] = 0
    out = filters.one_euro(kp, t, min_cutoff=3.0, beta=0.05)
    m = kp[..., 2] > 0
    err_in = np.abs(kp[..., :2] - clean)[m].mean()
    err_out = np.abs(out[..., :2] - clean)[m].mean()
    jit_in = np.abs(np.diff(kp[20:, 1:, :2], 2, axis=0)).mean()  # frames after the gap
    jit_out = np.abs(np.diff(out[20:, 1:, :2], 2, axis=0)).mean()
    assert jit_out < 0.7 * jit_in  # jitter (acceleration) reduced
    assert err_out < err_in  # and the position error too (lag < noise here)
    assert (out[10:14, 0, :2] == 0).all()
    assert np.isfinite(out).all()


# --- robust kernels ----------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["geman_mcclure", "huber", "l2"])
def test_kernels_quadratic_near_zero_and_finite_gradient(name):
    r2 = torch.tensor([0.0, 1e-4, 100.0, 1e6], requires_grad=True)
    out = robust.kernel(name)(r2, 5.0)
    out.sum().backward()
    assert torch.isfinite(r2.grad).all()
    assert out[1].item() == pytest.approx(1e-4, rel=1e-2)
    if name == "geman_mcclure":
        assert out[3].item() < 25.0 + 1e-3  # saturates at sigma^2
    if name == "huber":
        assert out[3].item() == pytest.approx(2 * 5 * 1000 - 25)


def test_unknown_kernel_named():
    with pytest.raises(ValueError, match="geman_mcclure"):
        robust.kernel("cauchy")


# --- cameras ---------------------------------------------------------------------------------

def _ring(count=4, arc=150, dist=2.0):
    K = cameras.intrinsics_from_fov(256, 256, 36.0)
    rig = cameras.rig_prior(np.tile(K, (count, 1, 1)), [256] * count, [256] * count, count, arc, dist,
                      np.array([0.0, 1.2, 0.0]))
    return rig


def test_project_matches_opencv_convention():
    rig = _ring(1, 0)
    X = torch.tensor([[[0.0, 1.2, 0.0], [0.1, 1.3, 0.0]]], dtype=torch.float64)
    uv, z = cameras.project(X, *(torch.as_tensor(a) for a in (rig.K, rig.R, rig.t)))
    assert uv.shape == (1, 1, 2, 2)
    assert uv[0, 0, 0].numpy() == pytest.approx([127.5, 127.5], abs=1e-6)
    assert z[0, 0, 0].item() == pytest.approx(2.0)
    # +x world (signer's left) appears on the image's right for a camera in front (+z)
    assert uv[0, 0, 1, 0] > uv[0, 0, 0, 0]
    assert uv[0, 0, 1, 1] < uv[0, 0, 0, 1]  # up is image -y


def test_project_is_each_views_pinhole_with_skew():
    """Every view, frame and point against the pinhole written out point by point (three
    views, so a mixed-up layout of views and axes shows)."""
    rng = np.random.default_rng(3)
    rig = _ring(3)
    K = rig.K.copy()
    K[:, 0, 1] = [0.0, 0.7, -1.3]  # skew
    K[:, 1, 1] *= [1.0, 1.1, 0.9]
    X = rng.normal([0, 1.2, 0], 0.3, (2, 5, 3))
    uv, z = cameras.project(torch.as_tensor(X), *(torch.as_tensor(a) for a in (K, rig.R, rig.t)))
    assert uv.shape == (3, 2, 5, 2) and z.shape == (3, 2, 5)
    for v in range(3):
        for b in range(2):
            for n in range(5):
                c = rig.R[v] @ X[b, n] + rig.t[v]
                u = K[v, 0, 0] * c[0] / c[2] + K[v, 0, 1] * c[1] / c[2] + K[v, 0, 2]
                w = K[v, 1, 1] * c[1] / c[2] + K[v, 1, 2]
                assert uv[v, b, n].numpy() == pytest.approx([u, w], abs=1e-9)
                assert z[v, b, n].item() == pytest.approx(c[2], abs=1e-12)


def test_take_is_indexing_with_its_gradient():
    torch.manual_seed(0)
    uv = torch.randn(3, 4, 7, 2, dtype=torch.float64, requires_grad=True)
    view, batch, point = (torch.randint(0, s, (40,)) for s in (3, 4, 7))  # with repeats
    weights = torch.randn(40, 2, dtype=torch.float64)
    got = cameras.take(uv, view, batch, point)
    (g_take,) = torch.autograd.grad((got * weights).sum(), uv)
    want = uv[view, batch, point]
    (g_index,) = torch.autograd.grad((want * weights).sum(), uv)
    assert torch.equal(got, want)
    assert torch.allclose(g_take, g_index, atol=1e-12)


def test_pnp_recovers_pose_from_noisy_points():
    rng = np.random.default_rng(1)
    rig = _ring(3)
    pts = rng.normal([0, 1.2, 0], [0.2, 0.3, 0.1], (30, 3))
    for v in range(3):
        uv = cameras.project(torch.as_tensor(pts)[None], *(torch.as_tensor(a[v:v + 1]) for a in
                                                      (rig.K, rig.R, rig.t)))[0][0, 0].numpy()
        uv += rng.normal(0, 0.5, uv.shape)
        R, t, rms = cameras.pnp(pts, uv, rig.K[v])
        assert fit_eval.rotation_angle_deg(R, rig.R[v]) < 1.0
        assert np.linalg.norm(-R.T @ t - rig.centres()[v]) < 0.05
        assert rms < 2.0


def test_pnp_refuses_too_few_or_nan_points():
    rig = _ring(1, 0)
    assert cameras.pnp(np.zeros((3, 3)), np.zeros((3, 2)), rig.K[0]) is None
    pts = np.random.default_rng(0).normal(size=(6, 3)) + [0, 0, 3]
    uv = np.full((6, 2), np.nan)
    assert cameras.pnp(pts, uv, rig.K[0]) is None


def test_camera_params_gauge_view_stays_fixed():
    rig = _ring(3)
    cams = cameras.CameraParams(rig, fixed=[0], dtype=torch.float64)
    with torch.no_grad():
        cams.rotvec += 0.1
        cams.dt += 0.2
    K, R, t = cams()
    assert torch.allclose(R[0], torch.as_tensor(rig.R[0]))
    assert torch.allclose(t[0], torch.as_tensor(rig.t[0]))
    assert not torch.allclose(R[1], torch.as_tensor(rig.R[1]))


# --- metrics ---------------------------------------------------------------------------------

def _random_similarity(seed):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    import roma
    R = roma.unitquat_to_rotmat(torch.as_tensor(q)).numpy()
    return fit_eval.Similarity(1.3, R, rng.normal(size=3))


def test_umeyama_recovers_similarity():
    sim = _random_similarity(0)
    src = np.random.default_rng(2).normal(size=(20, 3))
    est = fit_eval.umeyama(src, sim.apply(src))
    assert est.s == pytest.approx(1.3)
    assert np.allclose(est.R, sim.R, atol=1e-8)
    assert np.allclose(est.apply(src), sim.apply(src), atol=1e-8)


def test_camera_errors_zero_after_gauge_change_and_detect_a_rotation():
    gt = _ring(6)
    sim = _random_similarity(3)
    inv_R = sim.R.T
    # express gt in another frame: x_fit = R^T (x_gt - t) / s
    inv = fit_eval.Similarity(1 / sim.s, inv_R, -inv_R @ sim.t / sim.s)
    fit = fit_eval.align_rig(gt, inv)
    err = fit_eval.camera_errors(fit, gt)
    assert err["rotation_deg_max"] < 1e-6 and err["centre_m_max"] < 1e-6
    # perturb one camera by 2 degrees
    import roma
    d = roma.rotvec_to_rotmat(torch.tensor([0.0, np.radians(2.0), 0.0], dtype=torch.float64)).numpy()
    fit.R[2] = d @ fit.R[2]
    err = fit_eval.camera_errors(fit, gt)
    assert 0.2 < err["rotation_deg_max"] < 2.5


@pytest.mark.parametrize("views,spread", [(1, 0.0), (2, 150.0), (3, 0.001)])
def test_gauge_alignment_degenerate_rigs_stay_finite(views, spread):
    gt = _ring(views, spread, dist=2.0)
    err = fit_eval.camera_errors(gt, gt)
    assert err["rotation_deg_max"] < 1e-5 and err["centre_m_max"] < 1e-5


def test_mpjpe_pa_and_jitter():
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(10, 22, 3))
    sim = _random_similarity(1)
    assert fit_eval.pa_mpjpe_mm(sim.apply(gt), gt) < 1e-6
    shifted = gt + np.array([0.01, 0, 0])
    assert fit_eval.mpjpe_mm(shifted, gt, root=None) == pytest.approx(10.0)
    assert fit_eval.mpjpe_mm(shifted, gt, root=0) < 1e-9
    assert fit_eval.acceleration_error_mm(shifted, gt) < 1e-9
    jitter = gt.copy()
    jitter[5] += 0.01
    assert fit_eval.acceleration_error_mm(jitter, gt) > 1.0


def test_body_seen_mpjpe_counts_only_joints_the_cameras_see():
    """A joint out of every image (a leg below the frame) does not count; a joint one of four
    cameras sees does not either; in a one-camera rig that camera is enough."""
    rng = np.random.default_rng(0)
    gt = np.zeros((3, 55, 3))
    gt[:, :22] = rng.uniform(-0.2, 0.2, (3, 22, 3)) + np.array([0.0, 1.2, 0.0])
    gt[:, 7] = [0.0, -5.0, 0.0]  # far below every camera's frame
    fit = gt.copy()
    fit[:, 7] += 0.5  # 500 mm off, but out of frame
    rig = _ring(4, 120)
    assert fit_eval.body_seen_mpjpe(fit, gt, rig) < 1e-9
    assert fit_eval.mpjpe_mm(fit[:, :22], gt[:, :22], 0) > 20.0  # the plain figure counts it
    fit = gt.copy()
    fit[:, 3] += [0.01, 0.0, 0.0]  # 10 mm off, seen: 10 mm over the 21 seen joints
    assert fit_eval.body_seen_mpjpe(fit, gt, rig) == pytest.approx(10.0 / 21, rel=1e-6)
    # one camera that sees joint 3 and not joint 5: one camera is enough there
    one = _ring(1, 0)
    gt[:, 5] = [0.8, 1.2, 0.0]  # beside the front camera's frame; two of the ring see it
    fit = gt.copy()
    fit[:, 3] += [0.01, 0.0, 0.0]
    fit[:, 5] += [0.5, 0.0, 0.0]
    _, seen_one = fit_eval.in_images(gt[:, :22], one)
    _, seen_ring = fit_eval.in_images(gt[:, :22], rig)
    assert not seen_one[0, :, 5].any() and (seen_ring[:, :, 5].sum(0) >= 2).all()
    assert fit_eval.body_seen_mpjpe(fit, gt, one) == pytest.approx(10.0 / 20, rel=1e-6)
    assert fit_eval.body_seen_mpjpe(fit, gt, rig) > 20.0
    # in a rig of four, a joint that one camera sees does not count
    gt[:, 6] = [1.0, 1.2, 0.0]
    fit = gt.copy()
    fit[:, 6] += [0.5, 0.0, 0.0]
    _, seen_ring = fit_eval.in_images(gt[:, :22], rig)
    assert (seen_ring[:, :, 6].sum(0) == 1).all()
    assert fit_eval.body_seen_mpjpe(fit, gt, rig) < 1e-9
    assert np.isnan(fit_eval.body_seen_mpjpe(fit, np.full_like(gt, 50.0), rig))  # none seen


def test_rig_up_direction_of_level_cameras():
    import roma
    rig = _ring(4, 120)
    up = cameras.rig_up_direction(rig.R)
    assert np.allclose(up, [0, 1, 0], atol=1e-6)
    # the same rig in a tilted world frame: the vertical turns with it
    Rw = roma.rotvec_to_rotmat(torch.tensor([0.1, 0.2, -0.05], dtype=torch.float64)).numpy()
    up2 = cameras.rig_up_direction(rig.R @ Rw.T)
    assert np.allclose(up2, Rw @ np.array([0, 1, 0]), atol=1e-6)
    assert cameras.rig_up_direction(rig.R[:1]) is None  # one camera: undefined


def test_image_errors_are_gauge_free_and_see_only_visible_vertices():
    """The same body and rig expressed in another world frame lands on the same pixels (0 px);
    a 1 cm shift of the hand vertices shows up in the hand row only; vertices no camera sees
    do not count."""
    gt = _ring(4)
    rng = np.random.default_rng(0)
    verts = rng.uniform(-0.3, 0.3, (2, 40, 3)) + np.array([0.0, 1.2, 0.0])  # the rig looks here
    labels = np.repeat(np.arange(4), 10)
    sim = _random_similarity(5)
    inv = fit_eval.Similarity(1 / sim.s, sim.R.T, -sim.R.T @ sim.t / sim.s)
    fit_rig = fit_eval.align_rig(gt, inv)
    fit_verts = inv.apply(verts)
    rows = {p: v for _, p, v, _ in fit_eval.image_errors(fit_verts, fit_rig, verts, gt, labels)}
    assert set(rows) == {"all", "body", "head", "left_hand", "right_hand"}
    assert max(rows.values()) < 1e-6
    moved = verts.copy()
    moved[:, labels == 2] += np.array([0.01, 0.0, 0.0])
    rows = {p: v for _, p, v, _ in fit_eval.image_errors(moved, gt, verts, gt, labels)}
    assert rows["left_hand"] > 0.5 and rows["body"] < 1e-9 and rows["right_hand"] < 1e-9
    far = verts.copy()
    far[:, labels == 3] += 100.0  # out of every image: not counted, so NaN for that part
    rows = {p: v for _, p, v, _ in fit_eval.image_errors(verts, gt, far, gt, labels)}
    assert np.isnan(rows["right_hand"]) and rows["all"] < 1e-9
