"""``signsplat train-avatar`` and ``signsplat evaluate-avatar``: thin wrappers over the library.

train-avatar writes ``checkpoint.pt`` (resumable, atomic), ``avatar.ply`` (3DGS PLY) and
``train_log.parquet`` into ``--out``; evaluate writes ``metrics.parquet``, ``views.parquet``
(per camera) and ``images/`` (ground truth | render | error map) into ``--out``.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import torch

from signsplat.config import json_option
from signsplat.device import add_runtime_args, use_runtime

log = logging.getLogger("signsplat.avatar")


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--body", required=True, help="body model .npz")
    p.add_argument("--frames", required=True, help="frames.parquet")
    p.add_argument("--cameras", required=True, help="cameras.parquet")
    p.add_argument("--smplx", required=True, help="smplx_params table (fitted or ground truth)")
    p.add_argument("--config-json", default="{}", help="the avatar config section as JSON")
    p.add_argument("--variant", default="default")
    p.add_argument("--out", required=True, help="output folder")
    add_runtime_args(p)


def _setup(args):
    from signsplat.avatar.config import avatar_config
    from signsplat.avatar.data import load_scene
    from signsplat.body.model import BodyModel

    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    cfg = avatar_config(json_option(args.config_json), "--config-json")
    device = use_runtime(args)
    body = BodyModel.from_file(args.body).to(device)
    data = load_scene(args.frames, args.cameras, args.smplx, cfg.train.resolution)
    return cfg, device, body, data


def train_avatar(argv: list[str]) -> int:
    from signsplat.avatar.train import AvatarTrainer
    from signsplat.io.tables import write_table

    p = argparse.ArgumentParser(prog="signsplat train-avatar", description=__doc__)
    _common(p)
    p.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    cfg, device, body, data = _setup(args)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ckpt = out / "checkpoint.pt"
    trainer = AvatarTrainer(body, data, cfg, device)
    if args.resume and ckpt.exists():
        trainer.load_checkpoint(ckpt)
        log.info("resumed from %s at step %d", ckpt, trainer.step)
    log.info("scene %s: %d frames x %d views, %d train frames, %d points",
             data.scene, len(data.frames), len(data.views), len(trainer.split.train_frames),
             trainer.model.num_points)
    df = trainer.run(checkpoint=ckpt, progress=not args.no_progress)
    df.insert(0, "variant", args.variant)
    df.insert(0, "scene", data.scene)
    write_table(df, out / "train_log.parquet", "avatar_train_log",
                metadata={"smplx_source": cfg.train.smplx_source, "profile": cfg.profile})
    export_ply(trainer, out / "avatar.ply")
    log.info("trained %d steps in %.1f s; %d points", trainer.step, trainer.seconds,
             trainer.model.num_points)
    return 0


def export_ply(trainer, path: Path) -> Path:
    """The avatar in the rest pose (``ply_frame`` -1) or a frame's pose, as a 3DGS PLY."""
    from signsplat.avatar.ply import write_gaussian_ply

    cfg = trainer.cfg
    with torch.no_grad():
        if cfg.train.ply_frame < 0:
            params = {"betas": trainer.smplx.betas}
        else:
            idx = int(list(trainer.data.frames).index(cfg.train.ply_frame))
            params = trainer.smplx.get(torch.tensor([idx]))
        out = trainer.body(**params)
        g = trainer.model(out.v_shaped, out.vertices, out.transforms, params.get("transl"),
                          cfg.model.sh_degree)
    return write_gaussian_ply(path, g.means[0], g.quats[0], g.scales[0], g.opacities[0],
                              g.colors[0], cfg.model.sh_degree)


def evaluate_avatar(argv: list[str]) -> int:
    from signsplat.avatar.evaluate import evaluate_checkpoint
    from signsplat.io.tables import write_table

    p = argparse.ArgumentParser(prog="signsplat evaluate-avatar", description=__doc__)
    _common(p)
    p.add_argument("--checkpoint", required=True)
    args = p.parse_args(argv)
    cfg, device, body, data = _setup(args)
    out = Path(args.out)
    eval_over = json_option(args.config_json).get("eval")
    df, views = evaluate_checkpoint(args.checkpoint, body, data, args.variant, out / "images",
                                    device=str(device), overrides=eval_over)
    write_table(df, out / "metrics.parquet", "avatar_metrics")
    write_table(views, out / "views.parquet", "avatar_view_metrics")
    sel = df[(df.protocol == "bg_replaced") & (df.metric == "psnr") & (~df.refine)]
    for _, r in sel.iterrows():
        log.info("%-16s %-10s PSNR %.2f dB (n=%d)", r.split, r.part, r.value, r.n_images)
    return 0
