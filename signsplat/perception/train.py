"""Training of the shipped default detectors on simulated scenes, and their ONNX export.

Reproducible: scene specs, sample order and augmentation come from fixed seeds; the budget
is a number of steps (not wall time). Long runs use one torch thread per model so that the
segmenter and the keypoint model train side by side on two cores.

- The training scenes are simulated by :mod:`signsplat.synth.training_set` and passed in as
  folders (``signsplat simulate-training-set``).
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
from signsplat.perception.nets import (
    HAND_SLICES,
    CascadeSimCC,
    TinySegmenter,
    count_parameters,
    export_onnx,
)

SEG_MEAN = (127.5, 127.5, 127.5)
SEG_STD = (127.5, 127.5, 127.5)


@dataclass(frozen=True)
class TrainConfig:
    """Training knobs of the default detectors: the config's ``perception.train`` section,
    whose schema holds every default (build with :meth:`from_dict`)."""

    scenes: int  # training scenes to simulate
    seed: int
    frame_stride: int  # use every n-th frame of each view
    val_scenes: int  # last scenes held out for the training report
    seg_steps: int
    seg_batch: int
    seg_crop: int  # square training crop (the net is fully convolutional)
    seg_size: tuple[int, int]  # export/inference size (H, W)
    seg_full_steps: int  # phase 2: whole frames at lr / 3
    seg_full_batch: int
    seg_background_rate: float  # phase 2: share of frames on a replaced backdrop
    kp_steps: int
    kp_batch: int
    kp_input: tuple[int, int]  # crop (H, W); the coarse stage sees it pooled 2x
    kp_sigma: float  # Gaussian sigma in coarse heatmap cells
    kp_coarse_widths: tuple[int, ...]  # coarse encoder channels
    kp_coarse_head: int  # coarse decoder channels
    kp_coarse_stride: int  # coarse heatmap stride of the pooled crop (2 or 4)
    kp_hand_passes: int  # hand network passes (later ones re-centred), inference
    kp_wrist_min_prob: float | None  # body wrists from the hand roots above this
    hand_size: int  # hand crop resampled to hand_size x hand_size pixels
    hand_frac: float  # hand crop side as a fraction of the crop height
    hand_jitter: float  # hand-centre jitter in training (pixels at 256 rows)
    hand_sigma: float  # Gaussian sigma in hand heatmap cells (stride 4)
    kp_finetune_steps: int  # phase 2 at lr / 3
    kp_finetune_pred_centers: float  # phase 2: share of hand crops at the coarse centres
    kp_hand_steps: int  # phase 3: the hand network alone (coarse stage frozen)
    kp_hand_lr: float  # phase 3 learning rate (warm-up + cosine)
    kp_hand_right_weight: float  # phase 3: right-hand loss weight (left hand 1)
    kp_adapt_steps: int  # adapting an exported model to new scenes (adapt_keypoints)
    kp_adapt_lr: float
    checkpoint_every: int  # save a PyTorch checkpoint (out_path + '.pt') this often
    lr: float
    weight_decay: float
    threads: int  # torch threads per model
    max_minutes: float | None  # wall-clock cap per model (None: run all steps; with a
    # cap, the learning-rate schedule follows max(step, time) progress and training stops at
    # the cap, so results then depend on the machine's speed; the card records the steps run)
    seg_max_minutes: float | None  # per-model caps overriding max_minutes when set
    kp_max_minutes: float | None

    @classmethod
    def from_dict(cls, d: dict | None) -> "TrainConfig":
        """From a ``perception.train`` section; missing keys get the schema's defaults."""
        from signsplat.config import validate

        d = validate({"train": dict(d or {})}, "stages/perception.schema.yaml",
                     "perception.train")["train"]
        for key in ("seg_size", "kp_input", "kp_coarse_widths"):
            if key in d:
                d[key] = tuple(d[key])
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


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


def _segmenter_phase(net, opt, train: D.FrameSet, cfg: TrainConfig, crop: int, batch: int,
                     steps: int, lr: float, rng: np.random.Generator, cap: float | None,
                     tag: str, log=None, background_rate: float = 0.0
                     ) -> tuple[int, list[float]]:
    """One phase of segmenter training (warm-up + cosine to 0 over ``steps``); BCE + soft Dice
    on ``batch`` random ``crop`` x ``crop`` windows of augmented frames (``background_rate``:
    share of frames whose background is replaced, see :func:`data.segmentation_sample`)."""
    t0, losses = time.perf_counter(), []
    step = 0
    while step < steps:
        progress = _progress(step, steps, t0, cap)
        if progress >= 1.0:
            break
        imgs, masks = [], []
        for i in rng.integers(0, len(train), batch):
            im, mk = D.segmentation_sample(train, int(i), cfg.seg_size, rng,
                                           background_rate=background_rate)
            y = int(rng.integers(0, cfg.seg_size[0] - crop + 1))
            x = int(rng.integers(0, cfg.seg_size[1] - crop + 1))
            imgs.append(im[y:y + crop, x:x + crop])
            masks.append(mk[y:y + crop, x:x + crop])
        x = _to_tensor(np.stack(imgs), SEG_MEAN, SEG_STD)
        target = torch.from_numpy(np.stack(masks))[:, None]
        for g in opt.param_groups:
            g["lr"] = _lr(progress, lr)
        logits = net.forward_logits(x)
        prob = torch.sigmoid(logits)
        inter = (prob * target).sum((1, 2, 3))
        dice = 1 - (2 * inter + 1) / (prob.sum((1, 2, 3)) + target.sum((1, 2, 3)) + 1)
        loss = F.binary_cross_entropy_with_logits(logits, target) + 0.5 * dice.mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if step % 50 == 0 or step == steps - 1:
            _log(f"segmenter {tag} step {step}/{steps} loss {np.mean(losses[-50:]):.4f} "
                 f"{time.perf_counter() - t0:.0f}s", log)
        step += 1
    return step, losses


def train_segmenter(train: D.FrameSet, cfg: TrainConfig, out_path: str | os.PathLike,
                    log=None, resume: str | os.PathLike | None = None,
                    export: bool = True) -> dict:
    """Train :class:`TinySegmenter` and export it to ONNX (``export=False``: only the state
    dicts beside ``out_path``).

    Phase 1: ``seg_steps`` steps on ``seg_crop`` windows (many samples per second). Phase 2:
    ``seg_full_steps`` steps on whole frames (``seg_size``, batch ``seg_full_batch``) at a
    third of the learning rate, with a fresh optimizer and its own random stream, so that the
    model sees the whole figure against its background, and with a share
    ``seg_background_rate`` of the frames on replaced backdrops (flat greys and colours,
    gradients, blotches: phase 1 alone over-extends masks into plain light-grey backgrounds
    next to the body). ``resume``: a phase-1 state dict (``out_path + '.1.pt'``
    of an earlier run) to start phase 2 from; the result equals an uninterrupted run's.
    Returns a summary dict (parameters, steps, seconds, losses).
    """
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    net = TinySegmenter()
    t0 = time.perf_counter()
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    cap = cfg.seg_max_minutes or cfg.max_minutes
    if resume is None:
        opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        steps1, losses1 = _segmenter_phase(
            net, opt, train, cfg, cfg.seg_crop, cfg.seg_batch, cfg.seg_steps, cfg.lr,
            np.random.default_rng(cfg.seed + 1), cap, "crops", log)
        torch.save(net.state_dict(), str(out_path) + ".1.pt")
    else:
        net.load_state_dict(torch.load(str(resume)))
        steps1, losses1 = cfg.seg_steps, [float("nan")] * 10
    t1 = time.perf_counter()
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr / 3, weight_decay=cfg.weight_decay)
    steps2, losses2 = _segmenter_phase(
        net, opt, train, cfg, min(cfg.seg_size), cfg.seg_full_batch, cfg.seg_full_steps,
        cfg.lr / 3, np.random.default_rng(cfg.seed + 11), cap, "frames", log,
        cfg.seg_background_rate)
    seconds = time.perf_counter() - t0
    torch.save(net.state_dict(), str(out_path) + ".pt")
    if export:
        export_onnx(net, out_path, cfg.seg_size, ["alpha"])
    losses = losses1 + losses2
    step = steps1 + steps2
    return {"model": "segmenter", "parameters": count_parameters(net), "steps": step,
            "batch": cfg.seg_batch, "train_seconds": round(seconds, 1),
            "phase_steps": [steps1, steps2], "phase2_seconds": round(time.perf_counter() - t1, 1),
            "first_loss": float(np.mean(losses[:10])), "final_loss": float(np.mean(losses[-50:])),
            "input_size": list(cfg.seg_size),
            "mean": list(SEG_MEAN), "std": list(SEG_STD), "frames": len(train)}


def hand_training_centers(pts: np.ndarray, vis: np.ndarray, hw: tuple[int, int],
                          rng: np.random.Generator, jitter: float, negative_rate: float = 0.08
                          ) -> np.ndarray:
    """Hand-crop centres (2, 2) [left, right] in crop pixels for one training crop.

    The centre is the mean of the hand's 21 ground-truth points (visible or not) moved by a
    Gaussian jitter of ``jitter`` pixels (the coarse stage's error at inference), now and then
    five times larger; a few centres are random points of the crop (no hand to be seen).
    """
    h, w = hw
    out = np.zeros((2, 2), np.float32)
    for j, (a, b) in enumerate(HAND_SLICES):
        p = pts[a:b]
        ok = np.all(np.abs(p) < 1e3, axis=1)
        if rng.random() < negative_rate or not ok.any():
            out[j] = rng.uniform((0, 0), (w, h))
            continue
        scale = jitter * (5.0 if rng.random() < 0.1 else 1.0)
        out[j] = p[ok].mean(0) + rng.normal(0, scale, 2)
    return out


def hand_targets(pts: np.ndarray, vis: np.ndarray, centers: np.ndarray, side: float,
                 size: int, stride: int, sigma: float) -> np.ndarray:
    """Heatmap targets (2, 21, size/stride, size/stride) of both hands in their crops.

    Inverse of :func:`~signsplat.perception.nets.hand_grid`: crop pixel
    ``u = sgn * (x - cx) * size / side + size/2 - 0.5`` (sgn = -1 for the mirrored right hand).
    Points outside the hand crop or invisible get no peak.
    """
    k = size / side
    out = []
    for j, (a, b) in enumerate(HAND_SLICES):
        sgn = -1.0 if j == 1 else 1.0
        u = sgn * (pts[a:b, 0] - centers[j, 0]) * k + size / 2 - 0.5
        v = (pts[a:b, 1] - centers[j, 1]) * k + size / 2 - 0.5
        uv = np.stack([u, v], 1)
        inside = vis[a:b] & (u >= 0) & (u <= size - 1) & (v >= 0) & (v <= size - 1)
        out.append(D.heatmap_targets(uv, inside, (size, size), stride, sigma))
    return np.stack(out)


def _heatmap_loss(logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Peak-weighted BCE on heatmap logits (the background dominates the cells)."""
    weight = 1.0 + 20.0 * target
    return (F.binary_cross_entropy_with_logits(logits, target, reduction="none")
            * weight).mean() * 10


def _keypoint_phase(net: CascadeSimCC, opt, train: D.FrameSet, cfg: TrainConfig, steps: int,
                    lr: float, rng: np.random.Generator, cap: float | None, pred_rate: float,
                    tag: str, out_path, log=None, hands_only: bool = False,
                    right_weight: float = 1.0) -> tuple[int, list[float]]:
    """One phase of keypoint training (warm-up + cosine to 0 over ``steps``).

    ``pred_rate``: fraction of the hand crops centred where the coarse stage (as it is at that
    step) puts the hand, as at inference, instead of at the jittered ground truth.
    ``hands_only``: the coarse stage only places the hand crops (no gradient, no loss); the
    loss is the hand network's. ``right_weight``: weight of the right hands' loss (left 1).
    """
    hw = cfg.kp_input
    cs, hs, side = net.coarse_stride, net.hand.stride, net.hand_side
    t0, losses, parts = time.perf_counter(), [], []
    step = 0
    while step < steps:
        progress = _progress(step, steps, t0, cap)
        if progress >= 1.0:
            break
        crops, samples, targets, centers = [], [], [], []
        for i in rng.integers(0, len(train), cfg.kp_batch):
            crop, pts, vis = D.keypoint_sample(train, int(i), hw, rng)
            crops.append(crop)
            samples.append((pts, vis))
            targets.append(D.heatmap_targets(pts, vis, hw, cs, cfg.kp_sigma))
            centers.append(hand_training_centers(pts, vis, hw, rng, cfg.hand_jitter * hw[0] / 256))
        x = _to_tensor(np.stack(crops), RTM_MEAN, RTM_STD)
        target = torch.from_numpy(np.stack(targets))
        for g in opt.param_groups:
            g["lr"] = _lr(progress, lr)
        with torch.set_grad_enabled(not hands_only):
            logits = net.coarse_logits(x)
        lc = _heatmap_loss(logits, target)
        centers = np.stack(centers)
        if pred_rate > 0:
            use = rng.random(centers.shape[:2]) < pred_rate
            pred = net.hand_centers(logits.detach()).numpy()
            centers = np.where(use[..., None], pred, centers).astype(np.float32)
        htarget = torch.from_numpy(np.concatenate([
            hand_targets(p, v, c, side, cfg.hand_size, hs, cfg.hand_sigma)
            for (p, v), c in zip(samples, centers)]))  # (2B, 21, h, w), left, right per sample
        with torch.no_grad():
            hx = net.hand_crops(x, torch.from_numpy(centers))
        hand_logits = net.hand(hx)
        if right_weight == 1.0:
            lh = _heatmap_loss(hand_logits, htarget)
        else:  # crops alternate left, right per sample; weighted mean of the two sides
            lh = (_heatmap_loss(hand_logits[0::2], htarget[0::2])
                  + right_weight * _heatmap_loss(hand_logits[1::2], htarget[1::2])) \
                * (2.0 / (1.0 + right_weight))
        loss = lh if hands_only else lc + lh
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        parts.append((lc.item(), lh.item()))
        if step % 50 == 0 or step == steps - 1:
            pc, ph = np.mean(parts[-50:], 0)
            _log(f"keypoints {tag} step {step}/{steps} loss {np.mean(losses[-50:]):.4f} "
                 f"(coarse {pc:.4f}, hands {ph:.4f}) {time.perf_counter() - t0:.0f}s", log)
        if cfg.checkpoint_every and step % cfg.checkpoint_every == 0 and step:
            torch.save(net.state_dict(), str(out_path) + ".pt")
        step += 1
    return step, losses


def keypoint_net(cfg: TrainConfig) -> CascadeSimCC:
    """The keypoint network that ``cfg`` describes (untrained)."""
    return CascadeSimCC(cfg.kp_input, hand_size=cfg.hand_size,
                        hand_side=cfg.hand_frac * cfg.kp_input[0],
                        coarse_widths=cfg.kp_coarse_widths, coarse_head=cfg.kp_coarse_head,
                        coarse_out_stride=cfg.kp_coarse_stride, hand_passes=cfg.kp_hand_passes,
                        wrist_min_prob=cfg.kp_wrist_min_prob)


def train_keypoints(train: D.FrameSet, cfg: TrainConfig, out_path: str | os.PathLike,
                    log=None, resume: str | os.PathLike | None = None,
                    resume_phase: int = 1, export: bool = True) -> dict:
    """Train :class:`CascadeSimCC` and export it to ONNX (``export=False``: only the state
    dicts beside ``out_path``).

    Each step draws ``kp_batch`` augmented person crops at ``kp_input``; the coarse stage
    learns all 133 heatmaps (stride 8 of the crop) and the hand stage learns its 21 heatmaps
    on both hands' crops, taken with the graph's own grid_sample (weighted BCE for both; the
    sum is minimised). Phase 1 (``kp_steps``, lr): hand crops around jittered ground-truth
    hand centres. Phase 2 (``kp_finetune_steps``, lr / 3, fresh optimizer, own random stream):
    a fraction ``kp_finetune_pred_centers`` of the hand crops is centred where the coarse stage
    puts the hand, as at inference. Phase 3 (``kp_hand_steps``, ``kp_hand_lr``, own optimizer
    and random stream): the hand network alone, the coarse stage frozen, crops placed as in
    phase 2, the right hand's loss weighted by ``kp_hand_right_weight`` (the signing hand has
    the varied handshapes). ``resume``: the state dict saved after phase ``resume_phase``
    (``out_path + '.1.pt'`` after phase 1, ``'.2.pt'`` after phase 2) to go on from; the
    result equals an uninterrupted run's.
    """
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    hw = cfg.kp_input
    side = cfg.hand_frac * hw[0]
    net = keypoint_net(cfg)
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    cap = cfg.kp_max_minutes or cfg.max_minutes
    t0 = time.perf_counter()
    if resume is not None:
        if resume_phase not in (1, 2):
            raise ValueError(f"resume_phase must be 1 or 2, got {resume_phase}")
        net.load_state_dict(torch.load(str(resume)))
    done = resume_phase if resume is not None else 0
    steps = [cfg.kp_steps, cfg.kp_finetune_steps, cfg.kp_hand_steps]
    losses = [[float("nan")] * 10, [], []]
    phase_seconds = [0.0, 0.0, 0.0]
    if done < 1:
        t = time.perf_counter()
        opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
        steps[0], losses[0] = _keypoint_phase(net, opt, train, cfg, cfg.kp_steps, cfg.lr,
                                              np.random.default_rng(cfg.seed + 2), cap, 0.0,
                                              "crops", out_path, log)
        torch.save(net.state_dict(), str(out_path) + ".1.pt")
        phase_seconds[0] = time.perf_counter() - t
    if done < 2:
        t = time.perf_counter()
        opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr / 3, weight_decay=cfg.weight_decay)
        steps[1], losses[1] = _keypoint_phase(
            net, opt, train, cfg, cfg.kp_finetune_steps, cfg.lr / 3,
            np.random.default_rng(cfg.seed + 12), cap, cfg.kp_finetune_pred_centers, "cascade",
            out_path, log)
        torch.save(net.state_dict(), str(out_path) + ".2.pt")
        phase_seconds[1] = time.perf_counter() - t
    if cfg.kp_hand_steps > 0:
        t = time.perf_counter()
        # The coarse stage runs without gradient in this phase and only the hand network is
        # optimised; eval mode keeps its batch-norm statistics as phase 2 left them.
        net.coarse.eval()
        opt = torch.optim.AdamW(net.hand.parameters(), lr=cfg.kp_hand_lr,
                                weight_decay=cfg.weight_decay)
        steps[2], losses[2] = _keypoint_phase(
            net, opt, train, cfg, cfg.kp_hand_steps, cfg.kp_hand_lr,
            np.random.default_rng(cfg.seed + 22), cap, cfg.kp_finetune_pred_centers, "hands",
            out_path, log, hands_only=True, right_weight=cfg.kp_hand_right_weight)
        phase_seconds[2] = time.perf_counter() - t
    seconds = time.perf_counter() - t0
    torch.save(net.state_dict(), str(out_path) + ".pt")
    if export:
        export_onnx(net, out_path, hw, ["simcc_x", "simcc_y"], atol=2e-3)
    all_losses = losses[0] + losses[1] + losses[2]
    return {"model": "keypoints", "parameters": count_parameters(net), "steps": sum(steps),
            "batch": cfg.kp_batch, "train_seconds": round(seconds, 1),
            "phase_steps": steps, "phase_seconds": [round(x, 1) for x in phase_seconds],
            "resumed_after_phase": done,
            "first_loss": float(np.mean(all_losses[:10])),
            "final_loss": float(np.mean(all_losses[-50:])),
            "input_size": list(hw), "hand_size": cfg.hand_size, "hand_side": side,
            "split_ratio": net.split_ratio, "mean": list(RTM_MEAN), "std": list(RTM_STD),
            "frames": len(train)}


def keypoint_net_from_onnx(cfg: TrainConfig, path: str | os.PathLike) -> CascadeSimCC:
    """The keypoint network with the weights of an exported ``keypoints.onnx`` of the same
    architecture (``cfg``).

    The exporter folds each coarse-stage batch norm into the convolution before it (the
    convolution's weight and a ``<name>.weight_bias``); such a batch norm becomes the identity
    plus that bias, so the network computes what the ONNX graph computes as long as the coarse
    stage stays in eval mode (its batch statistics are gone). The hand network's batch norms
    are exported whole. Raises ``ValueError`` naming the file when a weight is missing or of
    another shape.
    """
    import onnx
    from onnx import numpy_helper

    net = keypoint_net(cfg)
    weights = {i.name: numpy_helper.to_array(i)
               for i in onnx.load(str(path)).graph.initializer}
    state = {k: v.clone() for k, v in net.state_dict().items()}
    modules = list(net.named_modules())
    folded = set()  # the batch norms folded into the convolution before them
    for (name, mod), (after, bn) in zip(modules, modules[1:]):
        if isinstance(mod, torch.nn.Conv2d) and f"{name}.weight_bias" in weights \
                and isinstance(bn, torch.nn.BatchNorm2d):
            state[f"{after}.weight"].fill_(1.0)
            state[f"{after}.bias"] = torch.from_numpy(weights[f"{name}.weight_bias"].copy())
            state[f"{after}.running_mean"].zero_()
            state[f"{after}.running_var"].fill_(1.0 - bn.eps)
            folded.add(after)
    for key, value in state.items():
        if key in weights:
            if tuple(weights[key].shape) != tuple(value.shape):
                raise ValueError(f"{path}: weight {key} has shape {weights[key].shape}, the "
                                 f"configured network {tuple(value.shape)}")
            state[key] = torch.from_numpy(weights[key].copy())
        elif key.rsplit(".", 1)[0] not in folded and not key.endswith("num_batches_tracked"):
            raise ValueError(f"{path}: no weight {key}; is it a keypoint model of this "
                             "architecture (perception.train.kp_*)?")
    net.load_state_dict(state)
    return net


def adapt_keypoints(train: D.FrameSet, cfg: TrainConfig, out_path: str | os.PathLike,
                    log=None, *, init: str | os.PathLike, export: bool = True) -> dict:
    """Go on training an exported keypoint model (``init``, ONNX) on new scenes ``train``.

    ``kp_adapt_steps`` steps at ``kp_adapt_lr`` (warm-up + cosine), both stages learning, hand
    crops placed as in phase 2, the right hand weighted as in phase 3; the coarse stage keeps
    its batch norms frozen (see :func:`keypoint_net_from_onnx`). Use it to widen what a
    shipped model has seen (other rigs, image sizes) without training from scratch.
    """
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    net = keypoint_net_from_onnx(cfg, init)
    net.train()
    net.coarse.eval()
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.kp_adapt_lr, weight_decay=cfg.weight_decay)
    steps, losses = _keypoint_phase(
        net, opt, train, cfg, cfg.kp_adapt_steps, cfg.kp_adapt_lr,
        np.random.default_rng(cfg.seed + 32), cfg.kp_max_minutes or cfg.max_minutes,
        cfg.kp_finetune_pred_centers, "adapt", out_path, log,
        right_weight=cfg.kp_hand_right_weight)
    seconds = time.perf_counter() - t0
    torch.save(net.state_dict(), str(out_path) + ".pt")
    if export:
        export_onnx(net, out_path, cfg.kp_input, ["simcc_x", "simcc_y"], atol=2e-3)
    return {"model": "keypoints", "adapted_from": str(init), "steps": steps,
            "batch": cfg.kp_batch, "train_seconds": round(seconds, 1),
            "first_loss": float(np.mean(losses[:10])), "final_loss": float(np.mean(losses[-50:])),
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
        fn = {"segmenter": train_segmenter, "keypoints": train_keypoints,
              "adapt": adapt_keypoints}[job.which]
        summary = fn(fs, job.cfg, job.out_path, log, **job.extra)
        summary["scenes"] = [Path(d).parent.name for d in job.sim_dirs]
        summary["config"] = {k: (list(v) if isinstance(v, tuple) else v)
                             for k, v in asdict(job.cfg).items()}
        _log(json.dumps(summary), log)
    return summary
