"""Training of the avatar (paper 4.1): Adam over Gaussians, networks and (optionally) SMPL-X.

One optimiser step sums the losses of ``accumulate_poses`` poses (the paper's loss accumulation;
off = one pose per step), each rendered from ``views_per_pose`` training cameras (the posing
and the networks run once per pose; an extra camera costs one render). Each render's loss is L1 + D-SSIM (+ LPIPS when
available) against the ground truth with its background replaced by the training background,
plus an extra L1 on the hand crops, plus the regularisation terms. Density control is a
:class:`~signsplat.avatar.strategy.MeshDensifyStrategy` called around the backward pass.

Checkpoints hold everything needed to continue bit-for-bit on the CPU (model with its current
point count, optimiser moments, strategy statistics and random state, the frame sampler, the
SMPL-X parameters, elapsed time and the log) and are written atomically.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
import pandas as pd
import torch

from signsplat.avatar.cameras import CameraRefinement
from signsplat.avatar.checkpoint import SmplxParams, build_model
from signsplat.avatar.colour_init import (
    initialise_colours,
    observed_colours,
    sample_pairs,
)
from signsplat.avatar.config import AvatarConfig, to_dict
from signsplat.avatar.data import SceneData, split_frames, target
from signsplat.avatar.losses import image_loss, load_lpips, psnr
from signsplat.avatar.model import POINT_PARAMS, sh_degree_at
from signsplat.avatar.regions import part_box
from signsplat.avatar.regularize import Regularizer, displacement_terms
from signsplat.avatar.strategy import MeshDensifyStrategy
from signsplat.device import make_deterministic
from signsplat.io.atomic import atomic_path
from signsplat.io.tables import Table, register_table

#: the SMPL-X blocks with a learning rate of their own (``train.lr_hand_poses``)
HAND_POSES = ("left_hand_pose", "right_hand_pose")

log = logging.getLogger(__name__)

TRAIN_LOG = register_table(Table(
    "avatar_train_log",
    "Avatar training log: one row per logged optimiser step.",
    {
        "step": "int64 optimiser step (1-based)",
        "seconds": "float64 wall-clock training seconds so far (checkpoint I/O excluded)",
        "loss": "float64 total loss of the step (mean over its poses)",
        "psnr": "float64 PSNR (dB) of the step's renders against their masked targets",
        "num_points": "int64 Gaussians after the step",
        "sh_degree": "int64 SH degree in use",
    },
    # one column per loss term (l1, dssim, hand, reg_*), and with train.refine_cameras the
    # camera corrections so far: camera_rotation_deg_max/_mean, camera_shift_mm_max/_mean
    extra_columns=True,
))

RasterizeFn = Callable[..., tuple[torch.Tensor, torch.Tensor, dict]]


def default_rasterizer() -> RasterizeFn:
    from signsplat.render import rasterization

    return rasterization


def render_gaussians(rasterize: RasterizeFn, g, b: int, viewmats: torch.Tensor, Ks: torch.Tensor,
                     width: int, height: int, background: torch.Tensor,
                     backend: str, **raster) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """Render frame ``b`` of posed Gaussians ``g`` from C cameras -> (C,H,W,3), (C,H,W,1), meta.
    ``raster``: the rasterizer's filter options (``eps2d``, ``rasterize_mode``: the avatar's
    ``ModelConfig.raster_options()``; none given: the rasterizer's defaults)."""
    c = viewmats.shape[0]
    colors, alphas, meta = rasterize(
        means=g.means[b], quats=g.quats[b], scales=g.scales[b], opacities=g.opacities[b],
        colors=g.colors[b], viewmats=viewmats, Ks=Ks, width=width, height=height,
        sh_degree=g.sh_degree, backgrounds=background[None].expand(c, -1), backend=backend,
        **raster,
    )
    meta.setdefault("width", width)
    meta.setdefault("height", height)
    return colors, alphas, meta


def eval_eps2d(eps2d: float, train_resolution: int, width: int) -> float:
    """Dilation for rendering at ``width`` an avatar trained with dilation ``eps2d`` at
    ``train_resolution`` (0 = native). The dilation of training is part of what the avatar
    learned: trained at 128 px it covers four times the world-space area it covers at 256 px,
    and its Gaussians shrink to rely on it; rendered at 256 px with the same pixels^2 they
    leave holes. Keeping the dilation's world-space footprint keeps what was learned."""
    if train_resolution <= 0:
        return eps2d
    return eps2d * (width / train_resolution) ** 2


def _content_box(a: torch.Tensor, b: torch.Tensor, margin: int) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1) box around the True pixels of two (H, W) masks, plus ``margin``; at
    least 16 pixels on each side (the SSIM window); the whole image when both are empty."""
    h, w = a.shape
    m = a | b
    rows, cols = torch.nonzero(m.any(1)), torch.nonzero(m.any(0))
    if len(rows) == 0:
        return 0, h, 0, w
    y0, y1 = int(rows[0]) - margin, int(rows[-1]) + 1 + margin
    x0, x1 = int(cols[0]) - margin, int(cols[-1]) + 1 + margin
    if y1 - y0 < 16:
        y0, y1 = (y0 + y1) // 2 - 8, (y0 + y1) // 2 + 8
    if x1 - x0 < 16:
        x0, x1 = (x0 + x1) // 2 - 8, (x0 + x1) // 2 + 8
    return max(y0, 0), min(y1, h), max(x0, 0), min(x1, w)


def cameras_refined(cfg: AvatarConfig) -> bool:
    """Whether the training cameras are refined: ``train.refine_cameras`` on, or auto and
    the cameras come from the fit (ground-truth cameras are exact)."""
    mode = cfg.train.refine_cameras
    return mode is True or (mode == "auto" and cfg.train.smplx_source == "fitted")


def subject_centre(data: SceneData) -> torch.Tensor:
    """(3,) mean SMPL-X translation over the frames (the cameras' rotation centre)."""
    t = data.smplx.get("transl")
    if t is None or t.numel() == 0:
        return torch.zeros(3)
    return t.reshape(-1, 3).mean(0).float()


@dataclass
class Split:
    train_frames: np.ndarray  # indices into data.frames
    test_frames: np.ndarray
    train_views: np.ndarray  # indices into data.views
    test_views: np.ndarray


def make_split(data: SceneData, cfg: AvatarConfig) -> Split:
    tr, te = split_frames(data.frames, cfg.train.test_interval, cfg.train.test_offset)
    pos = {int(f): i for i, f in enumerate(data.frames)}
    held = set(cfg.train.test_views)
    tv = np.array([i for i, v in enumerate(data.views) if int(v) not in held], dtype=np.int64)
    hv = np.array([i for i, v in enumerate(data.views) if int(v) in held], dtype=np.int64)
    if len(tr) == 0 or len(tv) == 0:
        raise ValueError("no training frames or views left after the split")
    return Split(np.array([pos[int(f)] for f in tr]), np.array([pos[int(f)] for f in te]), tv, hv)


def lr_factor(step: int, iterations: int, final_fraction: float) -> float:
    """Learning-rate multiplier of optimiser step ``step`` (1-based): exponential decay from 1
    at the first step to ``final_fraction`` at step ``iterations`` (constant past it)."""
    if final_fraction >= 1.0 or iterations <= 1:
        return 1.0
    t = min(max(step - 1, 0) / (iterations - 1), 1.0)
    return float(final_fraction ** t)


class AvatarTrainer:
    """Trains one avatar on one scene. ``body`` is a ``signsplat.body.BodyModel``."""

    def __init__(self, body, data: SceneData, cfg: AvatarConfig,
                 device: torch.device | str = "cpu", rasterize: RasterizeFn | None = None):
        self.cfg = cfg
        self.device = torch.device(device)
        torch.manual_seed(cfg.train.seed)
        make_deterministic()
        self.body = body.to(self.device)
        self.data = data
        self.split = make_split(data, cfg)
        self.rasterize = rasterize or default_rasterizer()
        self.background = torch.tensor(cfg.train.background, dtype=torch.float32,
                                       device=self.device)
        self.smplx = SmplxParams(data.smplx, cfg.train.finetune_smplx, data.frames,
                                 cfg.train.pose_knot_spacing).to(self.device)
        self.model = build_model(self.body, self.smplx.betas.detach(), cfg).to(self.device)
        self.colour_init_seen = 0
        if cfg.train.color_init == "images" and cfg.train.color_init_images > 0:
            pairs = sample_pairs(self.split.train_frames, self.split.train_views,
                                 cfg.train.color_init_images, cfg.train.seed)
            rgb, count = observed_colours(self.model, self.body, self.smplx.get, data, pairs,
                                          self.rasterize, cfg.train.render_backend)
            self.colour_init_seen = initialise_colours(self.model, rgb, count)
        self.strategy = MeshDensifyStrategy.from_config(cfg.strategy)
        self.strategy_state = self.strategy.initialize_state()
        self.regularizer = Regularizer(cfg.regularize)
        self.lpips = load_lpips(cfg.loss.lpips_weights)
        self.sampler = torch.Generator().manual_seed(cfg.train.seed)
        self.step = 0
        self.seconds = 0.0
        self.log_rows: list[dict[str, Any]] = []
        self.cameras = CameraRefinement(
            data.viewmats, subject_centre(data), self.split.train_views,
            # one camera has no other to agree with: its correction is the gauge, so none
            cameras_refined(cfg) and len(self.split.train_views) > 1).to(self.device)
        self.optimizer = self._make_optimizer()
        self.Ks = data.Ks.to(self.device)

    # ------------------------------------------------------------------ setup
    def _make_optimizer(self) -> torch.optim.Adam:
        t = self.cfg.train
        lrs = {"scale_raw": t.lr_scale, "quat": t.lr_rotation, "opacity_raw": t.lr_opacity,
               "sh_dc": t.lr_color, "sh_rest": t.lr_sh_rest, "bary_logits": t.lr_means,
               "normal_offset": t.lr_means}
        groups = [{"params": [getattr(self.model, n)], "lr": lrs[n], "name": n}
                  for n in POINT_PARAMS]
        nets = [p for n, p in self.model.named_parameters()
                if n not in POINT_PARAMS and n != "irradiance"]
        if self.model.irradiance is not None:
            groups.append({"params": [self.model.irradiance], "lr": t.lr_shading,
                           "name": "shading"})
        if nets:
            groups.append({"params": nets, "lr": t.lr_network, "name": "networks"})
        if self.smplx.learnable:
            # blocks with a rate of their own (None: lr_smplx); the rest at lr_smplx
            own = (("hand_poses", HAND_POSES, t.lr_hand_poses), ("betas", ("betas",), t.lr_betas))
            # a block's knots (train.pose_knot_spacing) learn at the block's rate
            named = self.smplx.block_parameters()
            taken = {n for _, names, _ in own for n in names}
            groups.append({"params": [p for n, p in named if n not in taken],
                           "lr": t.lr_smplx, "name": "smplx"})
            for name, names, lr in own:
                params = [p for n, p in named if n in names]
                if params:
                    groups.append({"params": params, "name": name,
                                   "lr": t.lr_smplx if lr is None else lr})
        if self.cameras.enabled:
            groups.append({"params": [self.cameras.raw], "lr": t.lr_cameras, "name": "cameras"})
        for group in groups:
            group["base_lr"] = group["lr"]
        # fused: one pass over each tensor per step instead of a chain of elementwise operations
        # (the same update; docs/avatar_step.md)
        return torch.optim.Adam(groups, eps=1e-15, fused=self.device.type in ("cpu", "cuda"))

    @property
    def poses_per_step(self) -> int:
        return self.cfg.train.accumulate_poses if self.cfg.train.accumulate else 1

    # ------------------------------------------------------------------ forward
    def pose(self, frame_idx: torch.Tensor, sh_degree: int, smplx: dict | None = None):
        """Body output and posed Gaussians for frames ``frame_idx`` (indices into data.frames)."""
        params = smplx if smplx is not None else self.smplx.get(frame_idx.to(self.device))
        out = self.body(**params)
        g = self.model(out.v_shaped, out.vertices, out.transforms, params.get("transl"),
                       sh_degree)
        return out, g

    def _sample(self) -> list[tuple[int, tuple[int, ...]]]:
        """The step's poses: (frame index, camera indices) for ``poses_per_step`` distinct
        training frames, each with ``views_per_pose`` distinct training cameras (fewer when
        there are fewer cameras)."""
        tf, tv = self.split.train_frames, self.split.train_views
        n = self.poses_per_step
        fi = torch.randperm(len(tf), generator=self.sampler)[:n]
        if len(fi) < n:  # fewer training frames than poses per step
            fi = torch.randint(len(tf), (n,), generator=self.sampler)
        per = min(self.cfg.train.views_per_pose, len(tv))
        if per == 1:
            vi = torch.randint(len(tv), (n, 1), generator=self.sampler)
        else:
            vi = torch.stack([torch.randperm(len(tv), generator=self.sampler)[:per]
                              for _ in range(n)])
        return [(int(tf[f]), tuple(int(tv[v]) for v in vs)) for f, vs in zip(fi, vi)]

    @property
    def viewmats(self) -> torch.Tensor:
        """(V, 4, 4) world-to-camera matrices in use (refined when ``train.refine_cameras``)."""
        return self.cameras.viewmats()

    def image_terms(self, g, b: int, joints: torch.Tensor, frame_i: int, view_i: int,
                    viewmats: torch.Tensor) -> tuple[dict[str, torch.Tensor], float, dict]:
        """Loss terms of frame ``b`` of ``g`` seen from camera ``view_i`` of ``viewmats`` (the
        step's cameras, :attr:`viewmats`): (terms, psnr, meta)."""
        vm = viewmats[view_i:view_i + 1]
        colors, alphas, meta = render_gaussians(self.rasterize, g, b, vm,
                                                self.Ks[view_i:view_i + 1], self.data.width,
                                                self.data.height, self.background,
                                                self.cfg.train.render_backend,
                                                **self.cfg.model.raster_options())
        if self.cfg.strategy.enabled:
            self.strategy.step_pre_backward(meta)
        render = colors[0].permute(2, 0, 1)[None].clamp(0, 1)
        gt, mask = target(self.data, view_i, frame_i, self.background.cpu())
        gt = gt.to(self.device)[None]
        # outside the box of (ground-truth mask or rendered alpha) both images are exactly the
        # background: the image terms are computed on that box only (same minimum, less work)
        y0, y1, x0, x1 = _content_box(mask[0].to(self.device) > 0.5,
                                      alphas[0, ..., 0].detach() > 1.0 / 255.0, margin=6)
        c = self.cfg.loss
        terms = image_loss(render[..., y0:y1, x0:x1], gt[..., y0:y1, x0:x1], c.w_l1, c.w_dssim,
                           c.ssim_window, self.lpips, c.w_lpips)
        if c.w_hand > 0:
            hand = []
            for part in ("left_hand", "right_hand"):
                box = part_box(joints, part, viewmats[view_i].detach(), self.Ks[view_i],
                               self.data.width, self.data.height, self.cfg.eval.crop_size.hands)
                if box is not None:
                    x0, y0, x1, y1 = box
                    hand.append((render[..., y0:y1, x0:x1] - gt[..., y0:y1, x0:x1]).abs().mean())
            if hand:
                terms["hand"] = c.w_hand * torch.stack(hand).mean()
        with torch.no_grad():
            p = float(psnr(render, gt)[0])
        return terms, p, meta

    # ------------------------------------------------------------------ step
    def train_step(self) -> dict[str, float]:
        """One optimiser step: the ``poses_per_step`` sampled frames are posed together (one
        batched forward), each rendered from its sampled cameras; the mean of the renders'
        losses plus the regularisation (on the first frame) is back-propagated once."""
        t0 = time.perf_counter()
        self.step += 1
        sh = sh_degree_at(self.step, self.cfg.train.iterations, self.cfg.model.sh_degree,
                          self.cfg.sh_schedule.rise_at)
        self.optimizer.zero_grad(set_to_none=True)
        if self.cameras.enabled:  # decided from the step, so a resumed run does the same
            stop = self.cfg.train.refine_cameras_stop
            self.cameras.raw.requires_grad_(stop == 0 or self.step <= stop)
        pairs = self._sample()
        out, g = self.pose(torch.tensor([f for f, _ in pairs]), sh)
        metas, psnrs, losses, terms_sum = [], [], [], {}
        n = sum(len(views) for _, views in pairs)
        viewmats = self.viewmats
        for b, (fi, views) in enumerate(pairs):
            for vi in views:
                terms, p, meta = self.image_terms(g, b, out.joints[b], fi, vi, viewmats)
                losses.append(sum(terms.values()))
                metas.append(meta)
                psnrs.append(p)
                for name, v in terms.items():
                    terms_sum[name] = terms_sum.get(name, 0.0) + float(v.detach()) / n
        reg = {**self.regularizer(self.model, g),
               **displacement_terms(self.model, g, self.cfg.regularize)}
        for name, v in reg.items():
            terms_sum[name] = float(v.detach())
        loss = torch.stack(losses).mean() + sum(reg.values())
        loss.backward()
        total = float(loss.detach())
        factor = lr_factor(self.step, self.cfg.train.iterations, self.cfg.train.lr_final_fraction)
        for group in self.optimizer.param_groups:
            group["lr"] = group["base_lr"] * factor
        self.optimizer.step()
        stats = {"added": 0, "pruned": 0}
        if self.cfg.strategy.enabled:
            stats = self.strategy.step_post_backward(self.model, self.optimizer,
                                                     self.strategy_state, self.step, metas)
        self.seconds += time.perf_counter() - t0
        row = {"step": self.step, "seconds": self.seconds, "loss": total,
               "psnr": float(np.mean(psnrs)), "num_points": self.model.num_points,
               "sh_degree": sh, **terms_sum, **stats}
        if self.cameras.enabled:
            row.update(self.cameras.summary())
        if self.step % self.cfg.train.log_every == 0 or self.step == 1:
            self.log_rows.append(row)
        return row

    # ------------------------------------------------------------------ checkpoints
    def state_dict(self) -> dict[str, Any]:
        return {
            "format": "signsplat-avatar-1",
            "step": self.step,
            "seconds": self.seconds,
            "config": to_dict(self.cfg),
            "model": self.model.state_dict(),
            "smplx": self.smplx.frame_values(),
            # the learned corrections of knotted blocks, for resuming (train.pose_knot_spacing)
            "smplx_knots": self.smplx.knots(),
            "cameras": self.cameras.state_dict(),
            # refined cameras, which evaluation uses in place of the input ones (None: as given)
            "viewmats": self.viewmats.detach().cpu() if self.cameras.enabled else None,
            "optimizer": self.optimizer.state_dict(),
            "strategy": self.strategy_state,
            "regularizer": self.regularizer.state_dict(),
            "sampler": self.sampler.get_state(),
            "torch_rng": torch.get_rng_state(),
            "log": list(self.log_rows),
            "scene": self.data.scene,
            "frames": self.data.frames.tolist(),
            "split": {k: getattr(self.split, k).tolist() for k in self.split.__dataclass_fields__},
        }

    def save_checkpoint(self, path: str | os.PathLike) -> Path:
        path = Path(path)
        with atomic_path(path) as tmp:
            torch.save(self.state_dict(), tmp)
        return path

    def load_checkpoint(self, path: str | os.PathLike) -> None:
        state = torch.load(path, map_location=self.device, weights_only=False)
        saved = state["config"]["train"].get("pose_knot_spacing", 1)
        if saved != self.cfg.train.pose_knot_spacing:
            raise ValueError(f"{path}: saved with train.pose_knot_spacing {saved}, asked to "
                             f"resume with {self.cfg.train.pose_knot_spacing}; resume with "
                             f"{saved} or train from the start")
        self.model.resize_like(state["model"])
        self.model.load_state_dict(state["model"])
        self.smplx.load_saved(state["smplx"], state.get("smplx_knots", {}))
        if "cameras" in state:
            self.cameras.load_state_dict(state["cameras"])
        self.optimizer = self._make_optimizer()
        self.optimizer.load_state_dict(state["optimizer"])
        for group in self.optimizer.param_groups:  # checkpoints from before the lr schedule
            group.setdefault("base_lr", group["lr"])
        self.strategy_state = state["strategy"]
        self.regularizer.load_state_dict(state.get("regularizer", {}))
        self.sampler.set_state(state["sampler"])
        torch.set_rng_state(state["torch_rng"])
        self.step = int(state["step"])
        self.seconds = float(state["seconds"])
        self.log_rows = list(state["log"])

    # ------------------------------------------------------------------ run
    def run(self, iterations: int | None = None, checkpoint: str | os.PathLike | None = None,
            progress: bool = True) -> pd.DataFrame:
        """Train up to ``iterations`` steps in total (resuming from ``self.step``); write a
        checkpoint every ``checkpoint_every`` steps and at the end. Returns the log."""
        from tqdm import tqdm

        total = self.cfg.train.iterations if iterations is None else iterations
        bar = tqdm(total=total, initial=self.step, disable=not progress, desc="avatar",
                   mininterval=2.0)
        while self.step < total:
            row = self.train_step()
            bar.update(1)
            bar.set_postfix(loss=f"{row['loss']:.4f}", psnr=f"{row['psnr']:.2f}",
                            n=row["num_points"], refresh=False)
            if not progress and self.step % (10 * self.cfg.train.log_every) == 0:
                log.info("step %d/%d  %.0f s  loss %.4f  PSNR %.2f dB  %d points", self.step,
                         total, self.seconds, row["loss"], row["psnr"], row["num_points"])
            if checkpoint and self.step % self.cfg.train.checkpoint_every == 0:
                self.save_checkpoint(checkpoint)
        bar.close()
        if checkpoint:
            self.save_checkpoint(checkpoint)
        return pd.DataFrame(self.log_rows)
