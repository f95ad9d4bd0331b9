"""Fixtures: tiny fake simulated scenes and small ONNX models with known behaviour."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import torch
from torch import nn
from workflow_runs import shared_once

from signsplat.io.tables import write_table
from signsplat.perception.nets import TinySimCC, export_onnx

K = 133


def _figure(rng: np.random.Generator, size: int, present: bool = True):
    """A bright stick figure on a dark textured background: image, mask, keypoints (K, 2)."""
    img = (rng.random((size, size, 3)) * 40).astype(np.uint8)
    mask = np.zeros((size, size), np.uint8)
    kp = np.full((K, 2), np.nan, np.float32)
    if not present:
        return img, mask, kp, np.zeros(K, bool)
    cx = size / 2 + rng.uniform(-size / 10, size / 10)
    top = size * rng.uniform(0.12, 0.2)
    col = tuple(int(c) for c in rng.integers(170, 255, 3))
    head = (int(cx), int(top + size * 0.08))
    cv2.circle(mask, head, int(size * 0.07), 1, -1)
    cv2.rectangle(mask, (int(cx - size * 0.12), int(top + size * 0.15)),
                  (int(cx + size * 0.12), int(size * 0.8)), 1, -1)
    # keypoints scattered over the figure's box (their layout does not matter to the tests)
    kp[:, 0] = rng.uniform(cx - size * 0.12, cx + size * 0.12, K)
    kp[:, 1] = rng.uniform(top + size * 0.16, size * 0.79, K)
    hands = [(cx - size * 0.3, size * 0.45), (cx + size * 0.3, size * 0.45)]
    for (hx, hy), sl in zip(hands, (slice(91, 112), slice(112, 133))):
        cv2.line(mask, (int(cx), int(size * 0.3)), (int(hx), int(hy)), 1, max(2, size // 32))
        cv2.circle(mask, (int(hx), int(hy)), max(2, size // 24), 1, -1)
        kp[sl] = np.array([hx, hy]) + rng.normal(0, 1, (21, 2))
    img[mask > 0] = col
    return img, mask * 255, kp, np.ones(K, bool)


def make_fake_scene(root: Path, name: str = "fake", views: int = 2, frames: int = 3,
                    size: int = 64, seed: int = 0, empty: tuple = ()) -> Path:
    """A folder in the simulator's layout (frames/keypoints_gt tables, images/, masks/)."""
    rng = np.random.default_rng(seed)
    sim = Path(root) / name / "sim"
    frows, krows = [], []
    for v in range(views):
        for f in range(frames):
            img, mask, kp, vis = _figure(rng, size, present=(v, f) not in empty)
            ip, mp = f"images/{v:02d}/{f:04d}.png", f"masks/{v:02d}/{f:04d}.png"
            for rel, arr in ((ip, cv2.cvtColor(img, cv2.COLOR_RGB2BGR)), (mp, mask)):
                (sim / rel).parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(sim / rel), arr)
            frows.append((name, v, f, f / 25.0, ip, mp))
            for k in range(K):
                krows.append((name, v, f, k, kp[k, 0], kp[k, 1], float(vis[k]), bool(vis[k]),
                              2.0))
    fr = pd.DataFrame(frows, columns=["scene", "view", "frame", "time", "image", "mask"])
    fr = fr.astype({"view": "int32", "frame": "int32"})
    kt = pd.DataFrame(krows, columns=["scene", "view", "frame", "kp", "x", "y", "score",
                                      "visible", "depth"])
    kt = kt.astype({"view": "int32", "frame": "int32", "kp": "int16", "x": "float32",
                    "y": "float32", "score": "float32", "depth": "float32"})
    write_table(fr, sim / "frames.parquet", "frames")
    write_table(kt, sim / "keypoints_gt.parquet", "keypoints")
    return sim


class BrightnessSegmenter(nn.Module):
    """alpha = sigmoid(40 * (mean channel value - 0)) on inputs in [-1, 1]: bright = person."""

    def forward(self, x):
        return torch.sigmoid(40.0 * x.mean(dim=1, keepdim=True))


class RTMWShaped(nn.Module):
    """Random model with RTMW's exact I/O: (1,3,384,288) -> (1,133,576), (1,133,768)."""

    def __init__(self, k: int = K):
        super().__init__()
        self.conv = nn.Conv2d(3, k, 1)

    def forward(self, x):
        h = self.conv(x)
        sx = torch.nn.functional.interpolate(h.mean(2), scale_factor=2.0, mode="linear")
        sy = torch.nn.functional.interpolate(h.mean(3), scale_factor=2.0, mode="linear")
        return sx, sy


def export_static(model: nn.Module, path: Path, shape: tuple, names: list[str]) -> Path:
    torch.manual_seed(0)
    with torch.no_grad():
        torch.onnx.export(model.eval(), (torch.zeros(shape),), str(path), input_names=["input"],
                          output_names=names, opset_version=17, dynamo=False)
    return path


def _export_models(d: Path) -> dict[str, str]:
    d.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    out = {
        "bright_seg": d / "bright_seg.onnx",
        "rtmw": export_static(RTMWShaped(), d / "rtmw.onnx", (1, 3, 384, 288),
                              ["simcc_x", "simcc_y"]),
        "rtm17": export_static(RTMWShaped(17), d / "rtm17.onnx", (1, 3, 384, 288),
                               ["simcc_x", "simcc_y"]),
        "tiny_kp": d / "tiny_kp.onnx",
    }
    export_onnx(BrightnessSegmenter(), out["bright_seg"], (64, 64), ["alpha"])
    export_onnx(TinySimCC(), out["tiny_kp"], (64, 48), ["simcc_x", "simcc_y"])
    return {k: str(v) for k, v in out.items()}


@pytest.fixture(scope="session")
def models(tmp_path_factory) -> dict[str, Path]:
    """The small models, exported once for all of make test's workers (two of them through
    torch.export, seconds each)."""
    paths = shared_once(tmp_path_factory, "perception_models", _export_models)
    return {k: Path(v) for k, v in paths.items()}


@pytest.fixture
def fake_scene(tmp_path) -> Path:
    return make_fake_scene(tmp_path, empty=((1, 2),))


@pytest.fixture
def scene_factory():
    """make_fake_scene, for tests that need other sizes."""
    return make_fake_scene
