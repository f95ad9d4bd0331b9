"""The two commands end to end on files: train-avatar then evaluate (tiny body-model file)."""

import json

import numpy as np
import torch
from avatar_scenes import random_smplx, rig
from test_avatar_train import SIZE, _write_scene

from signsplat.avatar.checkpoint import build_model
from signsplat.avatar.cli import evaluate_avatar, train_avatar
from signsplat.avatar.config import avatar_config
from signsplat.avatar.data import SceneData
from signsplat.avatar.ply import read_gaussian_ply
from signsplat.avatar.train import render_gaussians
from signsplat.body.model import BodyModel
from signsplat.io.tables import read_table
from signsplat.render import rasterization

CFG = {
    "upsample": {"edge_length": 0.08, "face_area": 3e-3},
    "model": {"scale_max": {"body": 0.08, "head": 0.06, "hands": 0.05}, "hidden": 8,
              "sh_degree": 1},
    "train": {"iterations": 4, "test_interval": 3, "test_offset": 2, "log_every": 1,
              "checkpoint_every": 2, "smplx_source": "ground_truth"},
    "eval": {"refine_steps": 1, "save_images": 1,
             "crop_size": {"body": 0.0, "head": 0.4, "hands": 0.4}},
}


def test_train_then_evaluate_on_files(tmp_path, tiny_body_path):
    body = BodyModel.from_file(tiny_body_path)
    vm, K = rig(3, SIZE)
    smplx = random_smplx(6)
    teacher = build_model(body, torch.zeros(1, 10), avatar_config(CFG))
    with torch.no_grad():
        teacher.sh_dc.normal_(0, 1.0)
        imgs = torch.zeros(3, 6, SIZE, SIZE, 3)
        for f in range(6):
            p = {k: v[f:f + 1] for k, v in smplx.items()}
            o = body(**p)
            g = teacher(o.v_shaped, o.vertices, o.transforms, p["transl"], 0)
            for c in range(3):
                imgs[c, f] = render_gaussians(rasterization, g, 0, vm[c:c + 1], K[c:c + 1],
                                              SIZE, SIZE, torch.ones(3), "cpu")[0][0]
    data = SceneData("tiny", np.arange(6), np.arange(3), (imgs * 255).round().byte(),
                     torch.full((3, 6, SIZE, SIZE), 255, dtype=torch.uint8), vm, K, smplx)
    scene = tmp_path / "sim"
    _write_scene(scene, data, smplx)
    common = ["--body", str(tiny_body_path), "--frames", str(scene / "frames.parquet"),
              "--cameras", str(scene / "cameras.parquet"), "--smplx",
              str(scene / "smplx.parquet"), "--config-json", json.dumps(CFG), "--variant",
              "demo", "--device", "cpu"]
    out = tmp_path / "avatar"
    assert train_avatar(common + ["--out", str(out), "--no-progress"]) == 0
    log = read_table(out / "train_log.parquet", "avatar_train_log")
    assert list(log.step) == [1, 2, 3, 4] and (log.variant == "demo").all()
    ply = read_gaussian_ply(out / "avatar.ply")
    assert sum(k.startswith("f_rest_") for k in ply) == 9  # SH degree 1
    assert np.isfinite(np.stack(list(ply.values()))).all()
    # resuming a finished run changes nothing
    before = torch.load(out / "checkpoint.pt", weights_only=False)["step"]
    assert train_avatar(common + ["--out", str(out), "--no-progress", "--resume"]) == 0
    assert torch.load(out / "checkpoint.pt", weights_only=False)["step"] == before == 4
    ev = tmp_path / "eval"
    assert evaluate_avatar(common + ["--out", str(ev), "--checkpoint", str(out / "checkpoint.pt")]) == 0
    m = read_table(ev / "metrics.parquet", "avatar_metrics")
    assert set(m.scene) == {"tiny"} and set(m.variant) == {"demo"}
    assert (m.smplx_source == "ground_truth").all() and (m.train_seconds > 0).all()
    assert len(list((ev / "images").glob("*.png"))) == 1
