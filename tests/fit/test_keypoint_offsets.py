"""A detector's keypoints against the body model's (signsplat.fit.keypoint_offsets): the
estimate, the keypoint model that applies it, the table and the workflow's choice of table."""

from __future__ import annotations

import cv2
import numpy as np
import pandas as pd
import pytest
import torch

from signsplat.config import validate
from signsplat.fit import keypoint_offsets as ko
from signsplat.io.tables import write_table

K_ANCH = len(ko.ANCHORED)


def _rig(V=3):
    """V cameras on a 120-degree arc 2.5 m from the origin, looking at it."""
    K = np.tile(np.array([[300.0, 0, 128], [0, 300.0, 128], [0, 0, 1]]), (V, 1, 1))
    R, t = [], []
    for a in np.radians(np.linspace(-60, 60, V)):
        Rv = cv2.Rodrigues(np.array([0.0, np.pi + a, 0.0]))[0]
        centre = np.array([2.5 * np.sin(a), 0.0, 2.5 * np.cos(a)])
        R.append(Rv)
        t.append(-Rv @ centre)
    return K, np.array(R), np.array(t)


def _project(K, R, t, X):
    Xc = np.einsum("vij,tkj->vtki", R, X) + t[:, None, None]
    return np.stack([K[:, 0, 0, None, None] * Xc[..., 0] / Xc[..., 2] + K[:, 0, 2, None, None],
                     K[:, 1, 1, None, None] * Xc[..., 1] / Xc[..., 2] + K[:, 1, 2, None, None]],
                    -1)


def _sample(truth, T=40, noise_px=0.5, outliers=0.05, seed=0):
    """A scene whose detector puts every anchored keypoint at ``truth`` (K,3) on its segment;
    the segments turn from frame to frame, some detections are gross errors."""
    rng = np.random.default_rng(seed)
    K, R, t = _rig()
    kp = np.zeros((T, 133, 3))
    kp[..., :2] = rng.uniform(-0.5, 0.5, (T, 133, 2))
    rot = np.stack([cv2.Rodrigues(rng.normal(0, 0.6, 3))[0]
                    for _ in range(T * K_ANCH)]).reshape(T, K_ANCH, 3, 3)
    seen = kp.copy()
    seen[:, ko.ANCHORED] += np.einsum("tkij,kj->tki", rot, truth)
    obs = np.zeros((len(R), T, 133, 3))
    obs[..., :2] = _project(K, R, t, seen) + rng.normal(0, noise_px, (len(R), T, 133, 2))
    obs[..., 2] = 0.9
    gross = rng.random(obs.shape[:3]) < outliers
    obs[..., :2] += np.where(gross[..., None], 30.0, 0.0)
    return ko.SceneSample(kp=kp, rot=rot, K=K, R=R, t=t, obs=obs)


def test_the_estimate_finds_offsets_that_turn_with_their_segments():
    rng = np.random.default_rng(1)  # every offset 2-5 cm along each axis, either way
    truth = rng.uniform(0.02, 0.05, (K_ANCH, 3)) * rng.choice([-1.0, 1.0], (K_ANCH, 3))
    samples = [_sample(truth, seed=s) for s in range(3)]
    est, before, after = ko.estimate_offsets(samples, min_score=0.3, ridge=1.0,
                                             min_observations=10)
    assert np.abs(est - truth).max() < 0.002  # metres
    assert (after.sse / after.n).max() < (before.sse / before.n).min()
    table = ko.offsets_table(est, before, after, min_observations=10)
    assert len(table) == K_ANCH and (table["rms_after_px"] < 1.0).all()
    assert (table["rms_before_px"] > 2 * table["rms_after_px"]).all()
    # the same detections read as offsets that do not turn: the estimate is far off
    still = [ko.SceneSample(s.kp, np.tile(np.eye(3), s.rot.shape[:2] + (1, 1)), s.K, s.R, s.t,
                            s.obs) for s in samples]
    wrong, _, _ = ko.estimate_offsets(still, 0.3, 1.0, 10)
    assert np.abs(wrong - truth).max() > 0.01


def test_no_detection_gives_zero_offsets_and_no_nan():
    s = _sample(np.zeros((K_ANCH, 3)))
    s.obs[..., 2] = 0.0  # every score below min_score
    s.kp[:3, ko.ANCHORED, 2] = -3.0  # and some keypoints behind every camera
    est, before, after = ko.estimate_offsets([s], 0.3, 1000.0, 10)
    assert np.array_equal(est, np.zeros_like(est)) and after.n.sum() == 0
    assert ko.offsets_table(est, before, after, 10).empty
    with pytest.raises(ValueError, match="no scene"):
        ko.estimate_offsets([], 0.3, 1000.0, 10)


def test_the_keypoint_model_moves_only_the_anchored_keypoints_with_their_segment(
        proxy_body_path):
    from signsplat.fit.bodyfit import load_keypoint_model

    plain = load_keypoint_model(proxy_body_path, 10, 10)
    offsets = np.zeros((K_ANCH, 3))
    hip, nose = list(ko.ANCHORED).index(11), list(ko.ANCHORED).index(0)
    offsets[hip] = [0.0, 0.05, 0.0]
    offsets[nose] = [0.0, 0.0, 0.02]
    moved = load_keypoint_model(proxy_body_path, 10, 10, offsets=offsets)
    turn = torch.tensor([[0.0, np.pi / 2, 0.0]])  # the pelvis turned a quarter about y
    for full in (False, True):
        _, a, _ = plain(full=full, global_orient=turn)
        _, b, _ = moved(full=full, global_orient=turn)
        d = (b - a)[0].numpy()
        assert np.allclose(d[11], [0.0, 0.05, 0.0], atol=1e-6)  # up stays up
        assert np.allclose(d[0], [0.02, 0.0, 0.0], atol=1e-6)  # the front turned to +x
        others = np.delete(d, [0, 11], axis=0)
        assert np.abs(others).max() < 1e-7


def test_the_table_reads_back_and_names_a_keypoint_without_anchor(tmp_path):
    est = np.zeros((K_ANCH, 3))
    est[0] = [0.001, 0.002, 0.003]
    s = ko.SceneSystem(np.zeros((K_ANCH, 3, 3)), np.zeros((K_ANCH, 3)),
                       np.full(K_ANCH, 500), np.ones(K_ANCH))
    df = ko.offsets_table(est, s, s, 10)
    write_table(df, tmp_path / "ok.parquet", "keypoint_offsets")
    back = ko.offsets_array(ko.read_offsets(tmp_path / "ok.parquet"))
    assert np.allclose(back, est)
    bad = pd.concat([df, df.iloc[:1].assign(keypoint=30, name="tail")])
    write_table(bad, tmp_path / "bad.parquet", "keypoint_offsets")
    with pytest.raises(ValueError, match=r"\['tail'\] have no anchor.*'nose'"):
        ko.read_offsets(tmp_path / "bad.parquet")


def test_the_table_follows_the_detectors_and_only_for_detected_keypoints():
    cfg = validate({"keypoint_offsets": {"pretrained": "p.parquet"}}, "stages/fit.schema.yaml")
    kp = validate({}, "stages/perception.schema.yaml")["keypoints"]
    assert ko.fit_offsets(cfg, "pretrained", kp) == ("p.parquet", ())
    assert ko.fit_offsets(cfg, "shipped", kp) == (None, ())
    # MediaPipe's fingers in the shipped keypoints: the pretrained table's finger rows
    mp = {**kp, "hands": "mediapipe", "hand_sides": ["right"]}
    assert ko.fit_offsets(cfg, "shipped", mp) == ("p.parquet", ("right",))
    assert ko.fit_offsets(cfg, "wide", mp) == ("p.parquet", ("right",))
    assert ko.fit_offsets(cfg, "pretrained", mp) == ("p.parquet", ())
    own = validate({"keypoint_offsets": {"shipped": "s.parquet"}}, "stages/fit.schema.yaml")
    assert ko.fit_offsets(own, "shipped", mp) == ("s.parquet", ())
    cfg["keypoints"] = "ground_truth"
    assert ko.fit_offsets(cfg, "pretrained", kp) == (None, ())
    assert ko.fit_offsets(cfg, "shipped", mp) == (None, ())


def test_finger_rows_keep_only_the_fingers_of_the_named_hands(tmp_path):
    est = np.full((K_ANCH, 3), 0.01)
    s = ko.SceneSystem(np.zeros((K_ANCH, 3, 3)), np.zeros((K_ANCH, 3)),
                       np.full(K_ANCH, 500), np.ones(K_ANCH))
    df = ko.offsets_table(est, s, s, 10)
    right = ko.finger_rows(df, ["right"])
    assert len(right) == 20 and right["name"].str.match(r"right_hand_[a-z]+[1-4]$").all()
    write_table(df, tmp_path / "all.parquet", "keypoint_offsets")
    assert (np.abs(ko.load_offsets(tmp_path / "all.parquet")).sum(1) > 0).all()
    moved = np.abs(ko.load_offsets(tmp_path / "all.parquet", ("right",))).sum(1) > 0
    names = [ko._NAMES[k] for k in ko.ANCHORED[moved]]
    assert len(names) == 20 and "right_hand_wrist" not in names
    assert set(names) == set(right["name"])
    assert len(ko.finger_rows(df, ("left", "right"))) == 40
    with pytest.raises(ValueError, match=r"\['up'\]; allowed: left, right"):
        ko.finger_rows(df, ["up"])
    assert ko.offsets_label(None) == "none"
    assert ko.offsets_label("t.parquet", ("right",)) == "t.parquet (fingers: right)"