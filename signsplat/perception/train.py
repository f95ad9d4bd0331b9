"""Training of the shipped default detectors on simulated scenes, and their ONNX export.

Reproducible: scene specs, sample order and augmentation come from fixed seeds; the budget
is a number of steps (not wall time). Long runs use one torch thread per model so that the
segmenter and the keypoint model train side by side on two cores.

- :func:`training_scene_specs`: varied synthetic scenes (shape, appearance, cameras, motion,
  effects), seeds disjoint from the evaluation scenes.
- :func:`train_segmenter` / :func:`train_keypoints`: train a :mod:`~signsplat.perception.nets`
  model on a :class:`~signsplat.perception.data.FrameSet` and export it to ONNX.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from signsplat.perception import data as D
from signsplat.perception.contracts import RTM_MEAN, RTM_STD
from signsplat.perception.nets import TinySegmenter, TinySimCC, count_parameters, export_onnx

SEG_MEAN = (127.5, 127.5, 127.5)
SEG_STD = (127.5, 127.5, 127.5)


@dataclass(frozen=True)
class TrainConfig:
    """Training knobs of the default detectors (the config's ``perception.train`` section)."""

    scenes: int = 20                 # training scenes to simulate
    seed: int = 0
    frame_stride: int = 1            # use every n-th frame of each view
    val_scenes: int = 1              # last scenes held out for the training report
    seg_steps: int = 600
    seg_batch: int = 12
    seg_crop: int = 128              # square training crop (the net is fully convolutional)
    seg_size: tuple[int, int] = (256, 256)   # export/inference size (H, W)
    kp_steps: int = 800
    kp_batch: int = 24
    kp_input: tuple[int, int] = (128, 96)    # crop (H, W)
    kp_sigma: float = 1.25           # Gaussian sigma in heatmap cells (stride 4)
    lr: float = 3e-3
    weight_decay: float = 1e-4
    threads: int = 1                 # torch threads per model
    max_minutes: float | None = None  # wall-clock cap per model (None: run all steps; with a
    # cap, the learning-rate schedule follows max(step, time) progress and training stops at
    # the cap, so results then depend on the machine's speed; the card records the steps run)

    @classmethod
    def from_dict(cls, d: dict | None) -> "TrainConfig":
        d = dict(d or {})
        for key in ("seg_size", "kp_input"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


def training_scene_specs(count: int, seed: int, glosses: list[str]) -> list[dict]:
    """``count`` scene specs (scene schema) drawn from a seeded generator.

    Seeds, signer shapes and appearance seeds start at 1000 (the evaluation scenes use small
    seeds), cameras vary in number, arc, distance, height and field of view; effects are drawn
    from the simulator's registry.
    """
    rng = np.random.default_rng(10_000 + seed)
    specs = []
    for i in range(count):
        n_gloss = int(rng.integers(3, 6))
        chosen = [str(g) for g in rng.choice(glosses, size=min(n_gloss, len(glosses)),
                                             replace=False)]
        ring = rng.random() < 0.15
        effects: list = ["lighting"]
        if rng.random() < 0.5:
            effects.append({"background": {"kind": "solid",
                                           "color": [round(float(c), 3)
                                                     for c in rng.uniform(0.05, 0.95, 3)]}})
        else:
            effects.append({"background": {"kind": "textured", "seed": int(1000 + i)}})
        if rng.random() < 0.6:
            effects.append({"sensor_noise": {"sigma": round(float(rng.uniform(0.003, 0.03)), 4)}})
        for name, p in (("motion_blur", 0.3), ("occluder", 0.3), ("camera_jitter", 0.3)):
            if rng.random() < p:
                effects.append(name)
        specs.append({
            "name": f"train{i:03d}",
            "seed": int(1000 + i),
            "fps": 25,
            "max_frames": 40,
            "cameras": {
                "count": int(rng.integers(2, 4)),
                "layout": "ring" if ring else "arc",
                "arc_degrees": round(float(rng.uniform(40, 180)), 1),
                "distance": round(float(rng.uniform(1.7, 2.6)), 3),
                "height": round(float(rng.uniform(1.2, 1.55)), 3),
                "target": [round(float(rng.uniform(-0.08, 0.08)), 3),
                           round(float(rng.uniform(1.12, 1.45)), 3), 0.0],
                "width": 256,
                "height_px": 256,
                "fov_degrees": round(float(rng.uniform(24, 42)), 1),
            },
            "signer": {
                "betas": [round(float(b), 3) for b in rng.normal(0, 0.8, 10)],
                "appearance_seed": int(1000 + i),
                "expression_scale": round(float(rng.uniform(0.5, 1.5)), 2),
            },
            "motion": {"glosses": chosen, "hold_frames": int(rng.integers(0, 4))},
            "effects": effects,
        })
    return specs


def _progress(step: int, total: int, t0: float, max_minutes: float | None) -> float:
    """Training progress in [0, 1]: steps done, or elapsed time when a cap is set and later."""
    p = step / max(1, total)
    if max_minutes:
        p = max(p, (time.perf_counter() - t0) / (60.0 * max_minutes))
    return min(1.0, p)


def _lr(progress: float, base: float, warm: float = 0.03) -> float:
    """Linear warm-up then cosine decay to 0, as a function of progress in [0, 1]."""
    if progress < warm:
        return base * max(progress, 1e-3) / warm
    return base * 0.5 * (1 + math.cos(math.pi * (progress - warm) / (1 - warm)))


def _to_tensor(imgs: np.ndarray, mean, std) -> torch.Tensor:
    x = (imgs.astype(np.float32) - np.asarray(mean, np.float32)) / np.asarray(std, np.float32)
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))


def _log(msg: str, log) -> None:
    print(msg, file=log or sys.stderr, flush=True)


def train_segmenter(train: D.FrameSet, cfg: TrainConfig, out_path: str | os.PathLike,
                    log=None) -> dict:
    """Train :class:`TinySegmenter` (BCE + soft Dice on random crops), export ONNX.

    Returns a summary dict (parameters, steps, seconds, final loss).
    """
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed + 1)
    net = TinySegmenter()
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    t0, losses = time.perf_counter(), []
    c = cfg.seg_crop
    step = 0
    while step < cfg.seg_steps:
        progress = _progress(step, cfg.seg_steps, t0, cfg.max_minutes)
        if progress >= 1.0:
            break
        imgs, masks = [], []
        for i in rng.integers(0, len(train), cfg.seg_batch):
            im, mk = D.segmentation_sample(train, int(i), cfg.seg_size, rng)
            y = int(rng.integers(0, cfg.seg_size[0] - c + 1))
            x = int(rng.integers(0, cfg.seg_size[1] - c + 1))
            imgs.append(im[y:y + c, x:x + c])
            masks.append(mk[y:y + c, x:x + c])
        x = _to_tensor(np.stack(imgs), SEG_MEAN, SEG_STD)
        target = torch.from_numpy(np.stack(masks))[:, None]
        for g in opt.param_groups:
            g["lr"] = _lr(progress, cfg.lr)
        logits = net.forward_logits(x)
        prob = torch.sigmoid(logits)
        inter = (prob * target).sum((1, 2, 3))
        dice = 1 - (2 * inter + 1) / (prob.sum((1, 2, 3)) + target.sum((1, 2, 3)) + 1)
        loss = F.binary_cross_entropy_with_logits(logits, target) + 0.5 * dice.mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if step % 50 == 0 or step == cfg.seg_steps - 1:
            _log(f"segmenter step {step}/{cfg.seg_steps} loss {np.mean(losses[-50:]):.4f} "
                 f"{time.perf_counter() - t0:.0f}s", log)
        step += 1
    seconds = time.perf_counter() - t0
    export_onnx(net, out_path, cfg.seg_size, ["alpha"])
    return {"model": "segmenter", "parameters": count_parameters(net), "steps": step,
            "batch": cfg.seg_batch, "train_seconds": round(seconds, 1),
            "first_loss": float(np.mean(losses[:10])), "final_loss": float(np.mean(losses[-50:])),
            "input_size": list(cfg.seg_size),
            "mean": list(SEG_MEAN), "std": list(SEG_STD), "frames": len(train)}


def train_keypoints(train: D.FrameSet, cfg: TrainConfig, out_path: str | os.PathLike,
                    log=None) -> dict:
    """Train :class:`TinySimCC` (weighted BCE on stride-4 heatmaps), export ONNX."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed + 2)
    net = TinySimCC()
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    t0, losses = time.perf_counter(), []
    hw = cfg.kp_input
    step = 0
    while step < cfg.kp_steps:
        progress = _progress(step, cfg.kp_steps, t0, cfg.max_minutes)
        if progress >= 1.0:
            break
        crops, targets = [], []
        for i in rng.integers(0, len(train), cfg.kp_batch):
            crop, pts, vis = D.keypoint_sample(train, int(i), hw, rng)
            crops.append(crop)
            targets.append(D.heatmap_targets(pts, vis, hw, net.stride, cfg.kp_sigma))
        x = _to_tensor(np.stack(crops), RTM_MEAN, RTM_STD)
        target = torch.from_numpy(np.stack(targets))
        for g in opt.param_groups:
            g["lr"] = _lr(progress, cfg.lr)
        logits = net.heatmap_logits(x)
        weight = 1.0 + 20.0 * target
        loss = (F.binary_cross_entropy_with_logits(logits, target, reduction="none")
                * weight).mean() * 10
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if step % 50 == 0 or step == cfg.kp_steps - 1:
            _log(f"keypoints step {step}/{cfg.kp_steps} loss {np.mean(losses[-50:]):.4f} "
                 f"{time.perf_counter() - t0:.0f}s", log)
        step += 1
    seconds = time.perf_counter() - t0
    export_onnx(net, out_path, hw, ["simcc_x", "simcc_y"])
    return {"model": "keypoints", "parameters": count_parameters(net), "steps": step,
            "batch": cfg.kp_batch, "train_seconds": round(seconds, 1),
            "first_loss": float(np.mean(losses[:10])), "final_loss": float(np.mean(losses[-50:])),
            "input_size": list(hw),
            "split_ratio": net.split_ratio, "mean": list(RTM_MEAN), "std": list(RTM_STD),
            "frames": len(train)}


@dataclass
class TrainJob:
    """One model to train in its own process (picklable)."""

    which: str
    sim_dirs: list[str]
    cfg: TrainConfig
    out_path: str
    log_path: str
    extra: dict = field(default_factory=dict)


def run_job(job: TrainJob) -> dict:
    """Load the scenes and train one model; the log goes to ``job.log_path``."""
    Path(job.log_path).parent.mkdir(parents=True, exist_ok=True)
    with open(job.log_path, "w") as log:
        t0 = time.perf_counter()
        fs = D.concat([D.load_scene(d, job.cfg.frame_stride) for d in job.sim_dirs])
        _log(f"{job.which}: {len(fs)} frames from {len(job.sim_dirs)} scenes loaded in "
             f"{time.perf_counter() - t0:.0f}s", log)
        fn = train_segmenter if job.which == "segmenter" else train_keypoints
        summary = fn(fs, job.cfg, job.out_path, log)
        summary["scenes"] = [Path(d).parent.name for d in job.sim_dirs]
        summary["config"] = {k: (list(v) if isinstance(v, tuple) else v)
                             for k, v in asdict(job.cfg).items()}
        _log(json.dumps(summary), log)
    return summary
