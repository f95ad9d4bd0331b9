"""Training code on a tiny fake scene: losses fall, exported files pass the contracts."""

from __future__ import annotations

import numpy as np

from signsplat.perception import data as D
from signsplat.perception.contracts import (
    KeypointSpec,
    SegmenterSpec,
    load_keypointer,
    load_segmenter,
)
from signsplat.perception.train import (
    TrainConfig,
    adapt_keypoints,
    keypoint_net_from_onnx,
    train_keypoints,
    train_segmenter,
)

# Small networks, 64 px images and a few steps: each training below takes seconds. Phase 3
# (the hand network alone) runs only where a test asks for it.
TINY = {"seg_size": [64, 64], "seg_batch": 2, "seg_crop": 32, "seg_full_batch": 2,
        "kp_input": [64, 48], "kp_batch": 2, "hand_size": 32,
        "kp_coarse_widths": [16, 24, 48, 96, 128], "kp_coarse_stride": 4, "kp_hand_passes": 1,
        "kp_wrist_min_prob": None, "kp_sigma": 1.25, "kp_hand_steps": 0, "checkpoint_every": 0}


def test_keypoint_samples_and_targets(tmp_path, scene_factory):
    fs = D.load_scene(scene_factory(tmp_path, frames=2, size=96))
    rng = np.random.default_rng(0)
    crop, pts, vis = D.keypoint_sample(fs, 0, (64, 48), rng, augment=False)
    assert crop.shape == (64, 48, 3) and pts.shape == (133, 2)
    t = D.heatmap_targets(pts, vis, (64, 48), 4, 1.0)
    assert t.shape == (133, 16, 12)
    k = int(np.flatnonzero(vis)[0])
    j, i = np.unravel_index(np.argmax(t[k]), t[k].shape)
    assert abs(4 * i + 1.5 - pts[k, 0]) <= 2.5 and abs(4 * j + 1.5 - pts[k, 1]) <= 2.5
    assert np.all(t[~vis] == 0) and t.max() <= 1


def test_scenes_of_other_image_sizes_train_together_and_give_the_same_crops(tmp_path,
                                                                            scene_factory):
    small = D.load_scene(scene_factory(tmp_path / "a", frames=2, size=64))
    large = D.load_scene(scene_factory(tmp_path / "b", frames=2, size=96, seed=1))
    both = D.concat([small, large])
    assert both.images.shape[1:3] == (96, 96) and len(both) == len(small) + len(large)
    for i in range(len(small)):
        a = D.keypoint_sample(small, i, (64, 48), np.random.default_rng(i))
        b = D.keypoint_sample(both, i, (64, 48), np.random.default_rng(i))
        assert np.array_equal(a[0], b[0]) and np.allclose(a[1], b[1])


def test_tiny_training_lowers_both_losses(tmp_path, scene_factory):
    """Both trainings learn (the exported files are checked by the command test below: an
    export costs seconds of torch.export tracing, so the suite does it once per network)."""
    fs = D.load_scene(scene_factory(tmp_path, views=2, frames=4, size=64))
    cfg = TrainConfig.from_dict({**TINY, "seg_steps": 30, "seg_batch": 4, "seg_crop": 48,
                                 "seg_full_steps": 10, "kp_steps": 30, "kp_batch": 4,
                                 "kp_finetune_steps": 6})
    s = train_segmenter(fs, cfg, tmp_path / "seg.onnx", export=False)
    assert s["final_loss"] < s["first_loss"]
    k = train_keypoints(fs, cfg, tmp_path / "kp.onnx", export=False)
    assert k["final_loss"] < k["first_loss"]


def test_train_detectors_command_on_given_scenes_exports_files_that_pass_the_contracts(
        tmp_path, scene_factory):
    import json

    from signsplat.perception.cli import train_detectors

    dirs = [scene_factory(tmp_path, name=f"s{i}", views=1, frames=3, size=64, seed=i)
            for i in range(3)]
    cfg = {"train": {**TINY, "seg_steps": 3, "seg_full_steps": 2,
                                   "kp_steps": 3, "kp_finetune_steps": 2, "kp_hand_steps": 2,
                                   "val_scenes": 1},
           # a 5-step segmenter's alpha barely leaves 0.5: the shipped model's threshold
           # (0.7) would find no one in the validation scene
           "segmenter": {"input_size": [64, 64], "threshold": 0.5}}
    out = tmp_path / "models"
    assert train_detectors(["--work", str(tmp_path / "work"), "--out-dir", str(out),
                            "--sim-dirs", *map(str, dirs), "--config-json",
                            json.dumps(cfg)]) == 0
    card = json.loads((out / "training.json").read_text())
    assert card["train_scenes"] == 2 and card["validation_scenes"] == ["s2"]
    assert {m["model"] for m in card["models"]} == {"segmenter", "keypoints"}
    metrics = {(r["metric"], r["part"]) for r in card["validation"]}
    assert ("mask_iou", "all") in metrics and ("pck@0.05", "right_hand") in metrics
    assert (tmp_path / "work" / "logs" / "keypoints.log").read_text().count("step") >= 1
    seg = load_segmenter(SegmenterSpec(str(out / "segmenter.onnx"), input_size=(64, 64)))
    assert seg.dynamic_batch
    kp = load_keypointer(KeypointSpec(str(out / "keypoints.onnx")))
    assert kp.input_size == (64, 48) and kp.dynamic_batch
    sx, sy = kp.run(np.zeros((2, 3, 64, 48), np.float32))
    assert sx.min() >= 0 and sx.max() <= 1  # sigmoid inside the graph: scores are probabilities

    # The exported model read back into PyTorch (its coarse batch norms folded by the
    # exporter) computes what the graph computes, and adapting it to more scenes trains both
    # stages but leaves the folded batch norms as they are.
    import torch

    tcfg = TrainConfig.from_dict({**cfg["train"], "kp_adapt_steps": 3})
    net = keypoint_net_from_onnx(tcfg, out / "keypoints.onnx").eval()
    x = np.random.default_rng(0).uniform(-2, 2, (2, 3, 64, 48)).astype(np.float32)
    with torch.no_grad():
        mine = [t.numpy() for t in net(torch.from_numpy(x))]
    for a, b in zip(kp.run(x), mine):
        assert np.abs(a - b).max() < 1e-3  # the export checks its graph to 2e-3
    before = {k: v.clone() for k, v in net.state_dict().items()}
    fs = D.concat([D.load_scene(d) for d in dirs[:2]])
    summary = adapt_keypoints(fs, tcfg, tmp_path / "adapted.onnx", init=out / "keypoints.onnx",
                              export=False)
    assert summary["steps"] == 3 and np.isfinite(summary["final_loss"])
    after = torch.load(tmp_path / "adapted.onnx.pt")
    moved = {k for k in after if after[k].is_floating_point()
             and not torch.equal(after[k], before[k])}
    assert any(k.startswith("coarse.") for k in moved) and any(k.startswith("hand.")
                                                                for k in moved)
    assert not any(k.startswith("coarse.") and k.endswith(("running_mean", "running_var"))
                   for k in moved)


def test_segmenter_phase_two_resumes_exactly(tmp_path, scene_factory):
    import torch

    fs = D.load_scene(scene_factory(tmp_path, views=1, frames=3, size=64))
    cfg = TrainConfig.from_dict({**TINY, "seg_steps": 4, "seg_full_steps": 3,
                                 "checkpoint_every": 200})
    full = train_segmenter(fs, cfg, tmp_path / "a.onnx", export=False)
    resumed = train_segmenter(fs, cfg, tmp_path / "b.onnx", resume=tmp_path / "a.onnx.1.pt",
                              export=False)
    assert full["phase_steps"] == resumed["phase_steps"] == [4, 3]
    a, b = torch.load(tmp_path / "a.onnx.pt"), torch.load(tmp_path / "b.onnx.pt")
    phase1 = torch.load(tmp_path / "a.onnx.1.pt")
    assert all(torch.equal(a[k], b[k]) for k in a)
    assert any(not torch.equal(a[k], phase1[k]) for k in a if a[k].is_floating_point())


def test_keypoint_hand_phase_trains_only_the_hand_network_and_resumes_exactly(
        tmp_path, scene_factory):
    import torch

    fs = D.load_scene(scene_factory(tmp_path, views=1, frames=3, size=64))
    cfg = TrainConfig.from_dict({**TINY, "kp_steps": 2, "kp_finetune_steps": 4,
                                 "kp_hand_steps": 3, "kp_hand_right_weight": 3.0})
    full = train_keypoints(fs, cfg, tmp_path / "a.onnx", export=False)
    assert full["phase_steps"] == [2, 4, 3] and np.isfinite(full["final_loss"])
    after2, final = torch.load(tmp_path / "a.onnx.2.pt"), torch.load(tmp_path / "a.onnx.pt")
    changed = {k for k in final if final[k].is_floating_point()
               and not torch.equal(final[k], after2[k])}
    assert changed and all(k.startswith("hand.") for k in changed)
    resumed = train_keypoints(fs, cfg, tmp_path / "b.onnx", resume=tmp_path / "a.onnx.2.pt",
                              resume_phase=2, export=False)
    assert resumed["phase_steps"] == [2, 4, 3] and resumed["resumed_after_phase"] == 2
    b = torch.load(tmp_path / "b.onnx.pt")
    assert all(torch.equal(final[k], b[k]) for k in final)
