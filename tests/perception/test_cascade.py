"""The cascade keypoint graph: sub-cell peaks, SimCC emission, hand crops and their inverse."""

from __future__ import annotations

import numpy as np
import torch

from signsplat.perception.keypoints import decode_simcc
from signsplat.perception.nets import CascadeSimCC, peak_subcell, simcc_profile
from signsplat.perception.train import hand_targets


def _logit(p):
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


def test_peak_subcell_recovers_a_gaussian_peak_between_cells():
    h, w = 12, 10
    peaks = [(3.3, 7.8), (6.6, 2.05), (0.2, 0.4)]  # the last one at the border
    yy, xx = np.mgrid[0:h, 0:w]
    maps = [0.9 * np.exp(-0.5 * ((xx - x0) ** 2 + (yy - y0) ** 2) / 1.25 ** 2)
            for x0, y0 in peaks]
    logits = torch.tensor(_logit(np.stack(maps)))[None].float()
    x, y, p = peak_subcell(logits)
    for k, (x0, y0) in enumerate(peaks[:2]):
        assert abs(float(x[0, k]) - x0) < 0.05 and abs(float(y[0, k]) - y0) < 0.05
    assert abs(float(x[0, 2]) - 0.2) <= 0.5 and abs(float(y[0, 2]) - 0.4) <= 0.5
    assert float(p.max()) <= 0.9 + 1e-4 and float(p.min()) > 0.5


def test_simcc_profile_decodes_to_the_coordinate_and_score():
    coords = torch.tensor([[10.3, 0.0, 95.7, 47.25]])
    scores = torch.tensor([[0.8, 0.1, 1.0, 0.0]])
    sx = simcc_profile(coords, scores, 96 * 2, 2).numpy()
    locs, raw = decode_simcc(sx, sx, 2)
    ok = scores.numpy() > 0
    assert np.all(np.abs(locs[..., 0][ok] - coords.numpy()[ok]) <= 0.25 + 1e-6)
    assert np.allclose(raw, scores.numpy(), atol=1e-6)
    assert np.isnan(locs[0, 3]).all()  # score 0: no location


def test_hand_targets_and_hand_points_are_inverse_for_both_hands():
    net = CascadeSimCC((256, 192), hand_size=64, hand_side=72.0)
    rng = np.random.default_rng(3)
    pts = np.zeros((133, 2), np.float32)
    centers = np.array([[60.0, 120.0], [140.0, 110.0]], np.float32)
    pts[91:112] = centers[0] + rng.uniform(-25, 25, (21, 2))
    pts[112:133] = centers[1] + rng.uniform(-25, 25, (21, 2))
    vis = np.ones(133, bool)
    t = hand_targets(pts, vis, centers, 72.0, 64, net.hand.stride, 1.25)  # (2, 21, 16, 16)
    assert t.shape == (2, 21, 16, 16)
    logits = torch.tensor(_logit(t.reshape(42, 16, 16) * 0.95)).float().reshape(2, 21, 16, 16)
    hx, hy, hs = net.hand_points(logits, torch.tensor(centers)[None])
    got = np.stack([hx[0].numpy(), hy[0].numpy()], -1)
    assert np.abs(got - pts[91:133]).max() < 0.5
    assert np.all((hs.numpy() > 0.8) & (hs.numpy() <= 0.95 + 1e-5))  # the peak cell


def test_hand_crop_sampling_matches_the_target_mapping():
    net = CascadeSimCC((256, 192), hand_size=64, hand_side=72.0)
    img = torch.zeros(1, 3, 256, 192)
    dots = [(70, 100), (150, 90)]  # (x, y) near the left / right hand centres
    for x, y in dots:
        img[0, :, y, x] = 1.0
    centers = torch.tensor([[[60.0, 110.0], [140.0, 100.0]]])
    crops = net.hand_crops(img, centers)[:, 0]  # (2, 64, 64)
    for j, (x, y) in enumerate(dots):
        sgn = -1 if j else 1
        c = centers[0, j].numpy()
        u = sgn * (x - c[0]) * 64 / 72 + 31.5
        v = (y - c[1]) * 64 / 72 + 31.5
        vv, uu = np.unravel_index(int(crops[j].argmax()), (64, 64))
        assert abs(uu - u) <= 1.0 and abs(vv - v) <= 1.0


def test_coarse_stage_at_stride_2_has_four_times_the_cells_and_the_same_contract():
    from signsplat.perception.nets import TinySimCC

    x = torch.randn(2, 3, 128, 96)
    s4, s2 = TinySimCC(out_stride=4).eval(), TinySimCC(out_stride=2).eval()
    with torch.no_grad():
        assert s4.heatmap_logits(x).shape == (2, 133, 32, 24)
        assert s2.heatmap_logits(x).shape == (2, 133, 64, 48)
        for sx, sy in (s4(x), s2(x)):  # SimCC vectors: W*r and H*r bins either way
            assert sx.shape == (2, 133, 192) and sy.shape == (2, 133, 256)
    net = CascadeSimCC((256, 192), coarse_out_stride=2)
    assert net.coarse_stride == 4


def test_recenter_moves_with_confidence_and_stays_when_nothing_is_found():
    net = CascadeSimCC((256, 192), hand_passes=2)
    centers = torch.tensor([[[60.0, 120.0], [140.0, 110.0]]])
    hx = torch.cat([torch.full((1, 21), 70.0), torch.full((1, 21), 150.0)], 1)
    hy = torch.cat([torch.full((1, 21), 130.0), torch.full((1, 21), 100.0)], 1)
    sure = torch.cat([torch.full((1, 21), 0.8), torch.zeros(1, 21)], 1)
    new = net.recenter(centers, hx, hy, sure)
    assert torch.allclose(new[0, 0], torch.tensor([70.0, 130.0]))  # confident: all the way
    assert torch.allclose(new[0, 1], centers[0, 1])  # nothing found: the crop stays
    half = net.recenter(centers, hx, hy, torch.full((1, 42), 0.25))
    assert torch.allclose(half[0, 0], torch.tensor([65.0, 125.0]))  # mean prob 0.25: half way


def test_body_wrists_come_from_the_hand_roots_only_when_the_hand_network_is_sure():
    """The body wrists (COCO 9, 10) are the hand roots (91, 112): with ``wrist_min_prob`` set,
    the output has them equal wherever the hand network's root probability is above it."""
    from signsplat.perception.keypoints import decode_simcc

    torch.manual_seed(0)
    x = torch.randn(3, 3, 256, 192)
    for thr, expect_equal in ((0.0, True), (1.0, False)):
        net = CascadeSimCC((256, 192), hand_passes=2, wrist_min_prob=thr).eval()
        with torch.no_grad():
            sx, sy = net(x)
        locs, _ = decode_simcc(sx.numpy(), sy.numpy(), 2)
        same = np.abs(locs[:, [9, 10]] - locs[:, [91, 112]]).max() <= 0.5
        assert same == expect_equal
        assert np.isfinite(sx.numpy()).all() and np.isfinite(sy.numpy()).all()


def test_exported_peaks_stay_finite_where_a_heatmap_is_far_below_zero(tmp_path):
    """A part with no peak anywhere (logits of -100 and lower, as for the feet out of frame)
    gives a finite location and a zero score in the exported graph, as in PyTorch. Exported,
    a Log(Sigmoid) there is -inf and the sub-cell parabola NaN; the export's own check
    refuses a graph that returns NaN where PyTorch does not."""
    import onnxruntime as ort

    from signsplat.perception.nets import export_onnx

    class Peaks(torch.nn.Module):
        def forward(self, x):
            return peak_subcell(x * 40.0 - 200.0)  # randn * 40 - 200: far below zero

    path = tmp_path / "peaks.onnx"
    export_onnx(Peaks(), path, (8, 8), ["x", "y", "p"])
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    x = np.random.default_rng(1).normal(size=(4, 3, 8, 8)).astype(np.float32)
    got = sess.run(None, {"input": x})
    assert all(np.isfinite(a).all() for a in got)
    assert np.all((got[0] >= 0) & (got[0] <= 7)) and got[2].max() < 1e-6
