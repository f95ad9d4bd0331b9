"""Regularisation (paper 3.5): neighbourhood variance of Gaussian parameters, displacement limits.

Neighbourhoods follow mesh connectivity: two points are neighbours when an anchor vertex of one
is an anchor vertex of the other or joined to one by a mesh edge, and they lie within
``radius`` of each other in the canonical pose. Face (head) points are never neighbours of
body or hand points, so the detailed face is not smoothed into the body. The variance of each
parameter over a neighbourhood (the point itself included) is minimised:
``sum_i (p_i - mean_N p)^2`` averaged over points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from signsplat.avatar.config import RegularizeConfig
from signsplat.avatar.model import AvatarModel, PosedGaussians
from signsplat.body.joints import PART_HEAD


@dataclass
class Neighbourhoods:
    """idx: (P, K) int64 neighbour indices (column 0 = the point itself); mask: (P, K) bool."""

    idx: torch.Tensor
    mask: torch.Tensor


def _edge_keys(faces: np.ndarray, n_v: int) -> np.ndarray:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1], np.stack([np.arange(n_v)] * 2, 1)])
    return np.unique(e[:, 0] * n_v + e[:, 1])


def build_neighbourhoods(points: torch.Tensor, anchors: torch.Tensor, part: torch.Tensor,
                         faces: torch.Tensor, n_vertices: int, radius: float,
                         max_neighbours: int) -> Neighbourhoods:
    """Mesh-connected neighbourhoods within ``radius`` (m).

    points: (P, 3) canonical positions; anchors: (P, 3) vertex indices; part: (P,) labels;
    faces: (F, 3). Returns at most ``max_neighbours`` nearest neighbours per point besides itself.
    """
    pts = points.detach().cpu().numpy()
    anc = anchors.cpu().numpy()
    head = (part.cpu().numpy() == PART_HEAD)
    k = min(max_neighbours * 3 + 1, len(pts))
    dist, idx = cKDTree(pts).query(pts, k=k, distance_upper_bound=radius)
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, 0)
    keys = _edge_keys(faces.cpu().numpy(), n_vertices)
    # connected if any anchor pair (a of p, b of q) is an edge or the same vertex
    a = anc[:, None, :, None]  # (P,1,3,1)
    b = anc[idx][:, :, None, :]  # (P,k,1,3)
    pair = (a * n_vertices + b).reshape(len(pts), k, 9)
    pos = np.searchsorted(keys, pair).clip(max=len(keys) - 1)
    connected = (keys[pos] == pair).any(-1)
    same_group = head[:, None] == head[idx]
    ok = valid & connected & same_group
    ok[:, 0] = True  # query returns the point itself first (distance 0)
    idx[:, 0] = np.arange(len(pts))
    # keep the first max_neighbours + 1 valid entries (they are sorted by distance)
    order = np.argsort(~ok, axis=1, kind="stable")[:, : max_neighbours + 1]
    idx = np.take_along_axis(idx, order, 1)
    ok = np.take_along_axis(ok, order, 1)
    return Neighbourhoods(torch.as_tensor(idx, dtype=torch.long), torch.as_tensor(ok))


def neighbourhood_variance(values: torch.Tensor, nb: Neighbourhoods) -> torch.Tensor:
    """Mean over points of the summed per-channel variance over their neighbourhood.

    values: (P, D) float; returns a scalar tensor.
    """
    idx, mask = nb.idx.to(values.device), nb.mask.to(values.device)
    m = mask[..., None].to(values.dtype)
    g = values[idx]  # (P, K, D)
    cnt = m.sum(1).clamp_min(1)
    mean = (g * m).sum(1) / cnt
    var = (((g - mean[:, None]) ** 2) * m).sum(1) / cnt
    return var.sum(-1).mean()


class Regularizer:
    """Regularisation terms of :class:`RegularizeConfig`; neighbourhoods rebuilt when the
    model's points change (densification, pruning)."""

    def __init__(self, cfg: RegularizeConfig):
        self.cfg = cfg
        self._nb: Neighbourhoods | None = None
        self._key: tuple | None = None

    def neighbourhoods(self, model: AvatarModel) -> Neighbourhoods:
        key = (model.num_points, int(model.learnable.sum()), int(model.anchors.sum()))
        if self._nb is None or key != self._key:
            # positions that depend only on the point structure (the centre of a densified
            # point's face, not its learned place on it), so that a run resumed from a
            # checkpoint rebuilds exactly the neighbourhoods the uninterrupted run cached
            with torch.no_grad():
                centre = model.template[model.anchors].mean(1)
                pts = torch.where(model.learnable[:, None], centre, model.canonical_points())
            self._nb = build_neighbourhoods(pts, model.anchors, model.part,
                                            model.faces, model.num_vertices, self.cfg.radius,
                                            self.cfg.max_neighbours)
            self._key = key
        return self._nb

    def __call__(self, model: AvatarModel, g: PosedGaussians) -> dict[str, torch.Tensor]:
        """Named, weighted terms for frame 0 of ``g`` (an empty dict when switched off)."""
        if not self.cfg.enabled:
            return {}
        c = self.cfg
        nb = self.neighbourhoods(model)
        q = g.quats[0]
        q = q * torch.where(q[:, :1] < 0, -1.0, 1.0)  # q and -q are the same rotation
        terms = {
            "reg_scale": c.w_scale * neighbourhood_variance(torch.log(g.scales[0]), nb),
            "reg_rotation": c.w_rotation * neighbourhood_variance(q, nb),
            "reg_opacity": c.w_opacity * neighbourhood_variance(g.opacities[0][:, None], nb),
            "reg_color": c.w_color * neighbourhood_variance(g.colors[0, :, 0], nb),
        }
        if g.colors.shape[2] > 1 and c.w_sh_rest > 0:
            terms["reg_sh_rest"] = c.w_sh_rest * neighbourhood_variance(
                g.colors[0, :, 1:].reshape(g.colors.shape[1], -1), nb)
        return terms


def displacement_terms(model: AvatarModel, g: PosedGaussians,
                       cfg: RegularizeConfig) -> dict[str, torch.Tensor]:
    """Soft limits: squared displacement |d| / part bound and normal offset l / scale bound.

    The hard limit on |d| is in the model (tanh bound, always on); these soft terms belong to
    the regularisation switch (empty dict when it is off), weighted by ``w_displacement`` and
    ``w_normal_offset``.
    """
    terms = {}
    if not cfg.enabled:
        return terms
    if g.displacement is not None and cfg.w_displacement > 0:
        groups = model.part_group()[: model.num_vertices]
        bound = model.disp_bounds[groups]
        terms["reg_displacement"] = cfg.w_displacement * (
            (g.displacement.norm(dim=-1) / bound) ** 2).mean()
    if bool(model.learnable.any()) and cfg.w_normal_offset > 0:
        sel = model.learnable
        terms["reg_normal_offset"] = cfg.w_normal_offset * (
            (g.normal_offset[sel] / model.scale_max_per_point()[sel]) ** 2).mean()
    return terms
