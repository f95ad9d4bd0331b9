"""Regularisation (paper 3.5): neighbourhood variance of Gaussian parameters, displacement limits.

Neighbourhoods follow mesh connectivity: two points are neighbours when an anchor vertex of one
is an anchor vertex of the other or joined to one by a mesh edge, and they lie within
``radius`` of each other in a space of position and attributes: the distance is
``sqrt(|x_p - x_q|^2 + (attribute_scale * |a_p - a_q|)^2)`` where ``a`` stacks the attributes
named in ``similarity`` (DC colour, log-scales, opacity), so that points of unlike appearance
(a dark sleeve beside a light hand) are not pulled together; ``attribute_scale = 0`` is proximity
only. With ``face_apart``, head points are never neighbours of body or hand points, so the
detailed face is not smoothed into the body. The variance of each parameter over a
neighbourhood (the point itself included) is minimised, ``sum_i (p_i - mean_N p)^2``, averaged
over points with the weight of each point's part (``part_weights``); which parameters it acts on
and how much is given by their weights ``w_*`` (0 = not regularised).

Neighbourhoods are built when the point set changes (densification, pruning) from the attributes
of that step, and kept in the trainer's checkpoint, so that a resumed run uses exactly the
neighbourhoods the uninterrupted run had.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from signsplat.avatar.config import PartWeights, RegularizeConfig
from signsplat.avatar.model import AvatarModel, PosedGaussians
from signsplat.body.joints import PART_BODY, PART_HEAD, PART_LEFT_HAND, PART_RIGHT_HAND

# config part_weights key of each part label (joints.PART_*)
_PART_KEYS = {PART_BODY: "body", PART_HEAD: "face", PART_LEFT_HAND: "hands",
              PART_RIGHT_HAND: "hands"}


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
                         max_neighbours: int, attributes: torch.Tensor | None = None,
                         attribute_scale: float = 0.0, face_apart: bool = True
                         ) -> Neighbourhoods:
    """Mesh-connected neighbourhoods within ``radius`` in position (m) and attributes.

    points: (P, 3) canonical positions; anchors: (P, 3) vertex indices; part: (P,) labels;
    faces: (F, 3); attributes: (P, A) values compared at ``attribute_scale`` metres per unit
    (None or a scale of 0: position only). Returns at most ``max_neighbours`` nearest
    neighbours per point besides itself.
    """
    pts = points.detach().cpu().double().numpy()
    if attributes is not None and attribute_scale > 0:
        attr = attributes.detach().cpu().double().numpy() * attribute_scale
        pts = np.concatenate([pts, np.nan_to_num(attr, nan=0.0, posinf=0.0, neginf=0.0)], 1)
    anc = anchors.cpu().numpy()
    head = (part.cpu().numpy() == PART_HEAD)
    k = min(max_neighbours * 3 + 1, len(pts))
    dist, idx = cKDTree(pts).query(pts, k=k, distance_upper_bound=radius)
    dist, idx = dist.reshape(len(pts), k), idx.reshape(len(pts), k)
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, 0)
    keys = _edge_keys(faces.cpu().numpy(), n_vertices)
    # connected if any anchor pair (a of p, b of q) is an edge or the same vertex
    a = anc[:, None, :, None]  # (P,1,3,1)
    b = anc[idx][:, :, None, :]  # (P,k,1,3)
    pair = (a * n_vertices + b).reshape(len(pts), k, 9)
    pos = np.searchsorted(keys, pair).clip(max=len(keys) - 1)
    connected = (keys[pos] == pair).any(-1)
    ok = valid & connected
    if face_apart:
        ok &= head[:, None] == head[idx]
    ok[:, 0] = True  # query returns the point itself first (distance 0)
    idx[:, 0] = np.arange(len(pts))
    # keep the first max_neighbours + 1 valid entries (they are sorted by distance)
    order = np.argsort(~ok, axis=1, kind="stable")[:, : max_neighbours + 1]
    idx = np.take_along_axis(idx, order, 1)
    ok = np.take_along_axis(ok, order, 1)
    return Neighbourhoods(torch.as_tensor(idx, dtype=torch.long), torch.as_tensor(ok))


def similarity_attributes(g: PosedGaussians, names: list[str]) -> torch.Tensor | None:
    """(P, A) attributes of frame 0 of ``g`` that count in neighbourhood distance: ``color``
    (DC colour, 3), ``scale`` (log-scales, 3), ``opacity`` (1); None for an empty list."""
    cols = {"color": lambda: g.colors[0, :, 0],
            "scale": lambda: torch.log(g.scales[0]),
            "opacity": lambda: g.opacities[0][:, None]}
    if not names:
        return None
    return torch.cat([cols[n]() for n in names], 1).detach()


def part_weights(part: torch.Tensor, weights: PartWeights) -> torch.Tensor:
    """(P,) weight of each point's part (``weights.body``, ``.face``, ``.hands``)."""
    table = torch.tensor([float(getattr(weights, _PART_KEYS[i])) for i in range(len(_PART_KEYS))])
    return table.to(part.device)[part]


def neighbourhood_variance(values: torch.Tensor, nb: Neighbourhoods,
                           weights: torch.Tensor | None = None) -> torch.Tensor:
    """Mean over points of the summed per-channel variance over their neighbourhood, each
    point's term times its weight (``weights``: (P,), None = 1).

    values: (P, D) float; returns a scalar tensor.
    """
    idx, mask = nb.idx.to(values.device), nb.mask.to(values.device)
    m = mask[..., None].to(values.dtype)
    g = values[idx]  # (P, K, D)
    cnt = m.sum(1).clamp_min(1)
    mean = (g * m).sum(1) / cnt
    var = ((((g - mean[:, None]) ** 2) * m).sum(1) / cnt).sum(-1)
    if weights is not None:
        var = var * weights.to(var)
    return var.mean()


class Regularizer:
    """Regularisation terms of :class:`RegularizeConfig`; neighbourhoods rebuilt when the
    model's points change (densification, pruning)."""

    def __init__(self, cfg: RegularizeConfig):
        self.cfg = cfg
        self._nb: Neighbourhoods | None = None
        self._key: tuple | None = None

    @staticmethod
    def _structure(model: AvatarModel) -> tuple:
        return (model.num_points, int(model.learnable.sum()), int(model.anchors.sum()))

    def neighbourhoods(self, model: AvatarModel, g: PosedGaussians | None = None
                       ) -> Neighbourhoods:
        """The cached neighbourhoods, rebuilt from ``g``'s attributes (frame 0) when the point
        set has changed."""
        key = self._structure(model)
        if self._nb is None or key != self._key:
            # positions that depend only on the point structure (the centre of a densified
            # point's face, not its learned place on it)
            with torch.no_grad():
                centre = model.template[model.anchors].mean(1)
                pts = torch.where(model.learnable[:, None], centre, model.canonical_points())
            attrs = None
            if g is not None and self.cfg.attribute_scale > 0:
                attrs = similarity_attributes(g, list(self.cfg.similarity))
            self._nb = build_neighbourhoods(pts, model.anchors, model.part,
                                            model.faces, model.num_vertices, self.cfg.radius,
                                            self.cfg.max_neighbours, attrs,
                                            self.cfg.attribute_scale, self.cfg.face_apart)
            self._key = key
        return self._nb

    def state_dict(self) -> dict:
        """The cached neighbourhoods (empty when none were built)."""
        if self._nb is None:
            return {}
        return {"idx": self._nb.idx, "mask": self._nb.mask, "key": list(self._key)}

    def load_state_dict(self, state: dict) -> None:
        if state:
            self._nb = Neighbourhoods(state["idx"].cpu(), state["mask"].cpu())
            self._key = tuple(state["key"])
        else:
            self._nb, self._key = None, None

    def __call__(self, model: AvatarModel, g: PosedGaussians) -> dict[str, torch.Tensor]:
        """Named, weighted terms for frame 0 of ``g`` (an empty dict when switched off;
        parameters whose weight is 0 have no term)."""
        if not self.cfg.enabled:
            return {}
        c = self.cfg
        nb = self.neighbourhoods(model, g)
        w = part_weights(model.part, c.part_weights)
        q = g.quats[0]
        q = q * torch.where(q[:, :1] < 0, -1.0, 1.0)  # q and -q are the same rotation
        values = {
            "scale": (c.w_scale, lambda: torch.log(g.scales[0])),
            "rotation": (c.w_rotation, lambda: q),
            "opacity": (c.w_opacity, lambda: g.opacities[0][:, None]),
            "color": (c.w_color, lambda: g.colors[0, :, 0]),
        }
        if g.colors.shape[2] > 1:
            values["sh_rest"] = (c.w_sh_rest, lambda: g.colors[0, :, 1:].reshape(
                g.colors.shape[1], -1))
        return {f"reg_{name}": weight * neighbourhood_variance(get(), nb, w)
                for name, (weight, get) in values.items() if weight > 0}


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
