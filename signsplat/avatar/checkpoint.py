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
    """Per-frame SMPL-X blocks (F, k); ``betas`` shared over the sequence (first frame's).

    With ``frames`` and ``knot_spacing`` > 1 (and ``learnable``) every per-frame block is its
    given values plus a learned correction that is piecewise linear in the frame number, with
    a knot every ``knot_spacing`` frames (parameters ``<block>_knots``, (K, k), zero at the
    start): a training frame's image loss then also corrects its neighbours, and a held-out
    frame between them. Otherwise each frame's block is learned on its own."""

    def __init__(self, params: dict[str, torch.Tensor], learnable: bool,
                 frames=None, knot_spacing: int = 1):
        super().__init__()
        self.learnable = learnable
        self.names = [n for n in SMPLX_BLOCKS if n in params]
        knotted = learnable and knot_spacing > 1 and frames is not None and len(frames) > 1
        self.knotted: list[str] = []
        if knotted:
            self.register_buffer("knot_weights", knot_weights(frames, knot_spacing))
        for name in self.names:
            value = params[name].float().clone()
            if name == "betas":
                value = value[:1]
            if knotted and name != "betas":
                self.register_buffer(name, value)
                k = torch.zeros(self.knot_weights.shape[1], value.shape[1])
                setattr(self, f"{name}_knots", nn.Parameter(k))
                self.knotted.append(name)
            elif learnable:
                setattr(self, name, nn.Parameter(value))
            else:
                self.register_buffer(name, value)

    def block(self, name: str, idx: torch.Tensor | None = None) -> torch.Tensor:
        """Block ``name`` of frames ``idx`` (all frames when None), corrections included."""
        t = getattr(self, name)
        if name in self.knotted:
            w = self.knot_weights if idx is None else self.knot_weights[idx]
            return (t if idx is None else t[idx]) + w @ getattr(self, f"{name}_knots")
        return t if idx is None else t[idx]

    def get(self, idx: torch.Tensor) -> dict[str, torch.Tensor]:
        out = {}
        for name in self.names:
            out[name] = (getattr(self, name).expand(len(idx), -1) if name == "betas"
                         else self.block(name, idx))
        return out

    def frame_values(self) -> dict[str, torch.Tensor]:
        """Every block for every frame as plain tensors (the checkpoint's ``smplx``)."""
        return {name: self.block(name).detach().clone() for name in self.names}

    def block_parameters(self) -> list[tuple[str, nn.Parameter]]:
        """The learnable tensors, each named by the block it moves (a block's knots too)."""
        return [(n.removesuffix("_knots"), p) for n, p in self.named_parameters()]

    def knots(self) -> dict[str, torch.Tensor]:
        """The learned knot values of each knotted block (the checkpoint's ``smplx_knots``)."""
        return {name: getattr(self, f"{name}_knots").detach().clone() for name in self.knotted}

    def load_saved(self, values: dict[str, torch.Tensor], knots: dict[str, torch.Tensor]
                   ) -> None:
        """Restore what :meth:`frame_values` and :meth:`knots` saved: a knotted module keeps
        its given values and takes the knots and the shape; otherwise every block's values."""
        if not self.knotted:
            self.load_state_dict(values)
            return
        with torch.no_grad():
            for name in self.knotted:
                getattr(self, f"{name}_knots").copy_(knots[name])
            self.betas.copy_(values["betas"][:1])


def knot_weights(frames, spacing: int) -> torch.Tensor:
    """(F, K) weights of a piecewise linear function of the frame number with knots every
    ``spacing`` frames from the first frame to past the last: row i interpolates frame i."""
    f = torch.as_tensor(frames, dtype=torch.float64)
    pos = (f - f.min()) / spacing
    k = int(torch.floor(pos.max()).item()) + 2
    lo = torch.floor(pos).long()
    t = pos - lo
    w = torch.zeros(len(f), k, dtype=torch.float64)
    w[torch.arange(len(f)), lo] = 1.0 - t
    w[torch.arange(len(f)), lo + 1] += t
    return w.float()


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
