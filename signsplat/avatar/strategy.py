"""Adaptive density control on the mesh (paper 3.4), as a strategy object apart from the trainer.

Like gsplat's ``DefaultStrategy``: the trainer calls :meth:`MeshDensifyStrategy.step_pre_backward`
on each render's ``meta`` (so ``meta["means2d"]`` keeps its gradient) and
:meth:`MeshDensifyStrategy.step_post_backward` after the backward pass; the strategy keeps its
statistics in a plain ``state`` dict and edits the model's per-point tensors and the optimiser
state together.

- Candidates: points whose view-space position gradient, averaged over the renders in which
  they were visible (in NDC units, i.e. pixels scaled by half the image size), exceeds
  ``grad_threshold`` (3DGS, Kerbl et al. 2023).
- Growth: for each candidate a new point on an adjacent mesh face, ``v = k1 x + k2 y + k3 z +
  l n_f`` with a learnable convex combination ``k = softmax(logits)`` and normal offset ``l``;
  it starts half-way between the candidate and a random point of the face and copies the
  candidate's Gaussian attributes. The total never exceeds ``max_points``.
- Pruning: points too large (canonical scale above ``prune_scale_fraction`` of their part's
  bound) or nearly transparent (opacity below ``prune_opacity``) are subsampled: each is removed
  with probability ``1 - prune_keep_fraction``. Original mesh vertices are never removed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import nn

from signsplat.avatar.model import POINT_BUFFERS, POINT_PARAMS, AvatarModel


@dataclass
class MeshDensifyStrategy:
    """Densification and pruning of mesh-anchored Gaussians; every knob a field, its default
    the avatar schema's (``strategy`` section; tests/test_config_defaults.py keeps them equal)."""

    grad_threshold: float = 0.0002
    refine_start: int = 100
    refine_stop: int = 600
    refine_every: int = 50
    reset_every: int = 0
    max_points: int = 60000
    max_new_per_refine: int = 3000
    prune_opacity: float = 0.02
    prune_scale_fraction: float = 0.98
    prune_keep_fraction: float = 0.5
    seed: int = 0

    @classmethod
    def from_config(cls, cfg) -> MeshDensifyStrategy:
        kw = {k: getattr(cfg, k) for k in cls.__dataclass_fields__}
        return cls(**kw)

    def initialize_state(self) -> dict[str, Any]:
        gen = torch.Generator().manual_seed(self.seed)
        return {"grad2d": None, "count": None, "rng": gen.get_state()}

    # ------------------------------------------------------------------ hooks
    def step_pre_backward(self, info: dict[str, Any]) -> None:
        """Keep the gradient of ``info["means2d"]`` (C, N, 2) for the statistics."""
        if info["means2d"].requires_grad:
            info["means2d"].retain_grad()

    def step_post_backward(self, model: AvatarModel, optimizer: torch.optim.Optimizer,
                           state: dict[str, Any], step: int,
                           infos: list[dict[str, Any]]) -> dict[str, int]:
        """Accumulate statistics of this step's renders; refine at the scheduled steps.

        Returns counts ``{"added": a, "pruned": p}`` (zero on steps without refinement).
        """
        for info in infos:
            self._accumulate(state, info, model.num_points)
        stats = {"added": 0, "pruned": 0}
        if (step > self.refine_start and step <= self.refine_stop
                and step % self.refine_every == 0 and state["count"] is not None):
            stats["pruned"] = self.prune(model, optimizer, state)
            stats["added"] = self.grow(model, optimizer, state)
            state["grad2d"] = state["count"] = None
        elif self.reset_every and step % self.reset_every == 0:
            state["grad2d"] = state["count"] = None
        return stats

    def _accumulate(self, state: dict[str, Any], info: dict[str, Any], n: int) -> None:
        grad = info["means2d"].grad
        if grad is None:
            return
        g = grad.detach().clone()  # (C, N, 2) pixels
        g[..., 0] *= info["width"] / 2.0
        g[..., 1] *= info["height"] / 2.0
        norm = g.norm(dim=-1)  # (C, N)
        radii = info.get("radii")
        if radii is not None:
            vis = (radii > 0).all(-1) if radii.dim() == 3 else radii > 0
        else:
            vis = norm > 0
        if state["grad2d"] is None or state["grad2d"].shape[0] != n:
            state["grad2d"] = torch.zeros(n)
            state["count"] = torch.zeros(n)
        state["grad2d"] += (norm * vis).sum(0).cpu()
        state["count"] += vis.sum(0).float().cpu()

    # ------------------------------------------------------------------ pruning
    def prune(self, model: AvatarModel, optimizer: torch.optim.Optimizer,
              state: dict[str, Any]) -> int:
        """Subsample too-large or near-transparent non-original points; returns how many went."""
        with torch.no_grad():
            opacity = torch.sigmoid(model.opacity_raw[:, 0])
            smax = model.scale_max_per_point()
            scale = model.cfg.scale_min + (smax[:, None] - model.cfg.scale_min) * torch.sigmoid(
                model.scale_raw)
            bad = (opacity < self.prune_opacity) | (
                scale.max(-1).values > self.prune_scale_fraction * smax)
            bad &= ~model.is_original
        if not bool(bad.any()):
            return 0
        gen = _generator(state)
        drop = bad.cpu() & (torch.rand(model.num_points, generator=gen)
                            >= self.prune_keep_fraction)
        state["rng"] = gen.get_state()
        keep = torch.nonzero(~drop)[:, 0].to(model.anchors.device)
        removed = model.num_points - len(keep)
        if removed:
            edit_points(model, optimizer, keep, None)
            for key in ("grad2d", "count"):
                if state[key] is not None:
                    state[key] = state[key][keep.cpu()]
        return removed

    # ------------------------------------------------------------------ growth
    def grow(self, model: AvatarModel, optimizer: torch.optim.Optimizer,
             state: dict[str, Any]) -> int:
        """Add points on faces adjacent to the gradient candidates; returns how many."""
        if state["grad2d"] is None:
            return 0
        avg = state["grad2d"] / state["count"].clamp_min(1)
        budget = min(self.max_new_per_refine, self.max_points - model.num_points)
        cand = torch.nonzero(avg > self.grad_threshold)[:, 0]
        if budget <= 0 or len(cand) == 0:
            return 0
        if len(cand) > budget:
            cand = cand[torch.argsort(avg[cand], descending=True, stable=True)[:budget]]
            cand = torch.sort(cand).values
        gen = _generator(state)
        dev = model.anchors.device
        cand_d = cand.to(dev)
        faces = model.faces
        face_ix = model.face[cand_d].clone()
        need = face_ix < 0  # original vertices: pick one of their incident faces at random
        if bool(need.any()):
            verts = model.anchors[cand_d[need], 0].cpu()
            face_ix[need] = _random_incident_face(faces.cpu(), verts, gen).to(dev)
        tri = faces[face_ix]  # (n, 3)
        # candidate position as weights over the chosen face's vertices
        bary = model.barycentric().detach()[cand_d]
        anchors = model.anchors[cand_d]
        w = (anchors[:, :, None] == tri[:, None, :]).float() * bary[:, :, None]
        w = w.sum(1)
        w = w / w.sum(-1, keepdim=True).clamp_min(1e-9)
        rnd = -torch.log(torch.rand(len(cand), 3, generator=gen).clamp_min(1e-9))  # Dirichlet(1)
        rnd = (rnd / rnd.sum(-1, keepdim=True)).to(dev)
        k = (0.5 * w + 0.5 * rnd).clamp_min(1e-4)
        k = k / k.sum(-1, keepdim=True)
        state["rng"] = gen.get_state()
        with torch.no_grad():
            new = {name: t[cand_d].clone() for name, t in model.point_tensors().items()}
        new.update(
            anchors=tri.clone(), bary_fixed=k, face=face_ix,
            is_original=torch.zeros(len(cand), dtype=torch.bool, device=dev),
            learnable=torch.ones(len(cand), dtype=torch.bool, device=dev),
            bary_logits=torch.log(k),
        )
        keep = torch.arange(model.num_points, device=dev)
        edit_points(model, optimizer, keep, new)
        return len(cand)


def _generator(state: dict[str, Any]) -> torch.Generator:
    gen = torch.Generator()
    gen.set_state(state["rng"])
    return gen


def _random_incident_face(faces: torch.Tensor, verts: torch.Tensor,
                          gen: torch.Generator) -> torch.Tensor:
    """For each vertex in (n,), a uniformly chosen face (index) that contains it."""
    flat_v = faces.reshape(-1)
    order = torch.argsort(flat_v, stable=True)
    sorted_v = flat_v[order]
    start = torch.searchsorted(sorted_v, verts)
    end = torch.searchsorted(sorted_v, verts, right=True)
    count = (end - start).clamp_min(1)
    pick = start + (torch.rand(len(verts), generator=gen) * count).long().clamp_max(count - 1)
    return order[pick] // 3


def edit_points(model: AvatarModel, optimizer: torch.optim.Optimizer | None,
                keep: torch.Tensor, new: dict[str, torch.Tensor] | None) -> None:
    """Keep the points ``keep`` (sorted (K,) int64) and append ``new`` ones, in the model and in
    the optimiser (Adam moments of kept points move with them; new points start at zero).
    Per-point parameters must each sit alone in a param group named after them.
    """
    groups = {}
    if optimizer is not None:
        groups = {g.get("name"): g for g in optimizer.param_groups}
    for name in POINT_PARAMS:
        old = getattr(model, name)
        data = old.data[keep]
        if new is not None:
            data = torch.cat([data, new[name].to(data.dtype)])
        param = nn.Parameter(data, requires_grad=old.requires_grad)
        group = groups.get(name)
        if group is not None:
            st = optimizer.state.pop(old, None)
            if st:
                for key, val in list(st.items()):
                    if torch.is_tensor(val) and val.dim() > 0 and val.shape[0] == old.shape[0]:
                        val = val[keep]
                        if new is not None:
                            val = torch.cat([val, torch.zeros((len(new[name]),) + val.shape[1:],
                                                              dtype=val.dtype,
                                                              device=val.device)])
                        st[key] = val
                optimizer.state[param] = st
            group["params"] = [param]
        setattr(model, name, param)
    for name in POINT_BUFFERS:
        data = getattr(model, name)[keep]
        if new is not None:
            data = torch.cat([data, new[name].to(data.dtype)])
        setattr(model, name, data)
    model.refresh_order()
