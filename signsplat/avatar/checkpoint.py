"""An avatar as saved and loaded: the model built on a body, its SMPL-X parameters, and
:func:`load_avatar` for a ``checkpoint.pt`` of ``signsplat train-avatar`` (the package's public
way to get a trained avatar; the trainer writes the checkpoint)."""

from __future__ import annotations

import os

import torch
from torch import nn

from signsplat.avatar.config import AvatarConfig, avatar_config
from signsplat.avatar.data import SMPLX_BLOCKS
from signsplat.avatar.model import AvatarModel
from signsplat.avatar.upsample import upsample_mesh
from signsplat.render import DEFAULT_EPS2D


def canonical_template(body, betas: torch.Tensor) -> torch.Tensor:
    """(V, 3) rest-pose vertices of the body with ``betas`` (1, k)."""
    with torch.no_grad():
        return body(betas=betas).v_shaped[0]


def build_model(body, betas: torch.Tensor, cfg: AvatarConfig) -> AvatarModel:
    """Upsample the canonical mesh of ``body`` (shape ``betas``) and build the avatar."""
    template = canonical_template(body, betas)
    points = upsample_mesh(template, body.faces, body.part_labels, cfg.upsample.edge_length,
                           cfg.upsample.face_area, cfg.upsample.interior) if cfg.upsample.max_rounds else \
        upsample_mesh(template, body.faces, body.part_labels, float("inf"), float("inf"))
    return AvatarModel(points, body.faces, body.lbs_weights, template, cfg.model)


class SmplxParams(nn.Module):
    """Per-frame SMPL-X blocks (F, k); ``betas`` shared over the sequence (first frame's)."""

    def __init__(self, params: dict[str, torch.Tensor], learnable: bool):
        super().__init__()
        self.learnable = learnable
        for name in SMPLX_BLOCKS:
            if name not in params:
                continue
            value = params[name].float().clone()
            if name == "betas":
                value = value[:1]
            if learnable:
                setattr(self, name, nn.Parameter(value))
            else:
                self.register_buffer(name, value)
        self.names = [n for n in SMPLX_BLOCKS if n in params]

    def get(self, idx: torch.Tensor) -> dict[str, torch.Tensor]:
        out = {}
        for name in self.names:
            t = getattr(self, name)
            out[name] = t.expand(len(idx), -1) if name == "betas" else t[idx]
        return out


#: model settings added after avatars had been saved: a checkpoint without the key was trained
#: with these values (the paper's pose network on the points; 3DGS's filter)
SAVED_BEFORE = {
    "pose_net_on": {"pose_net_on": "points"},
    "eps2d": {"eps2d": DEFAULT_EPS2D, "rasterize_mode": "classic"},
}


def load_avatar(path: str | os.PathLike, body, device: torch.device | str = "cpu"):
    """A saved ``checkpoint.pt`` ready to render: (model, SMPL-X parameters module,
    checkpoint dict, :class:`~signsplat.avatar.config.AvatarConfig`)."""
    state = torch.load(path, map_location=device, weights_only=False)
    saved = state["config"]
    model_cfg = dict(saved.get("model", {}))
    for key, before in SAVED_BEFORE.items():
        if key not in model_cfg:
            model_cfg.update(before)
    cfg = avatar_config({**saved, "model": model_cfg})
    smplx_state = state["smplx"]
    learnable = cfg.train.finetune_smplx
    params = {k: v for k, v in smplx_state.items()}
    smplx = SmplxParams(params, learnable).to(device)
    smplx.load_state_dict(smplx_state)
    model = build_model(body.to(device), smplx.betas.detach(), cfg).to(device)
    model.resize_like(state["model"])
    model.load_state_dict(state["model"])
    return model, smplx, state, cfg
