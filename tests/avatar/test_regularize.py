"""Neighbourhood variance regularisation and displacement limits."""

import torch

from signsplat.avatar.checkpoint import build_model
from signsplat.avatar.config import avatar_config
from signsplat.avatar.regularize import (
    Regularizer,
    build_neighbourhoods,
    displacement_terms,
    neighbourhood_variance,
)
from signsplat.body.joints import PART_HEAD


def _model(body, **reg):
    cfg = avatar_config({"upsample": {"edge_length": 0.08, "face_area": 3e-3},
                         "regularize": reg})
    return build_model(body, torch.zeros(1, 10), cfg), cfg


def test_neighbourhoods_are_local_connected_and_split_face_from_body(tiny_body):
    model, cfg = _model(tiny_body, radius=0.08, max_neighbours=6)
    pts = model.canonical_points()
    nb = build_neighbourhoods(pts, model.anchors, model.part, model.faces, model.num_vertices,
                              0.08, 6)
    assert nb.idx.shape == (model.num_points, 7)
    assert torch.equal(nb.idx[:, 0], torch.arange(model.num_points)) and bool(nb.mask[:, 0].all())
    d = (pts[nb.idx] - pts[:, None]).norm(dim=-1)
    assert float(d[nb.mask].max()) <= 0.08 + 1e-6
    head = model.part == PART_HEAD
    assert not bool((head[:, None] != head[nb.idx])[nb.mask].any())
    assert float(nb.mask[:, 1:].float().mean()) > 0.5  # most points do have neighbours
    # connectivity: far points on opposite sides of the sphere are never neighbours even with a
    # huge radius unless their anchors are joined by an edge
    big = build_neighbourhoods(pts, model.anchors, model.part, model.faces, model.num_vertices,
                               10.0, 6)
    assert float((pts[big.idx] - pts[:, None]).norm(dim=-1)[big.mask].max()) < 0.3


def test_variance_term_and_its_gradient():
    idx = torch.tensor([[0, 1, 2], [1, 0, 2], [2, 1, 0]])
    from signsplat.avatar.regularize import Neighbourhoods

    nb = Neighbourhoods(idx, torch.ones(3, 3, dtype=torch.bool))
    same = torch.ones(3, 2)
    assert float(neighbourhood_variance(same, nb)) == 0.0
    v = torch.tensor([[0.0], [1.0], [2.0]], requires_grad=True)
    loss = neighbourhood_variance(v, nb)
    torch.testing.assert_close(loss, torch.tensor(2.0 / 3.0))
    loss.backward()
    assert float(v.grad[0]) < 0 < float(v.grad[2])  # pulls towards the mean


def test_switch_off_gives_no_terms_and_builds_nothing(tiny_body):
    model, cfg = _model(tiny_body, enabled=False)
    out = tiny_body(betas=torch.zeros(1, 10))
    g = model(out.v_shaped, out.vertices, out.transforms, None, 0)
    reg = Regularizer(cfg.regularize)
    assert reg(model, g) == {} and reg._nb is None
    assert displacement_terms(model, g, cfg.regularize) == {}
    model_on, cfg_on = _model(tiny_body, enabled=True)
    with torch.no_grad():
        model_on.sh_dc.normal_()
        model_on.disp_net.head.bias.fill_(1.0)
    g = model_on(out.v_shaped, out.vertices, out.transforms, None, 0)
    terms = Regularizer(cfg_on.regularize)(model_on, g)
    assert {"reg_scale", "reg_rotation", "reg_opacity", "reg_color"} <= set(terms)
    assert float(terms["reg_color"].detach()) > 0
    disp = displacement_terms(model_on, g, cfg_on.regularize)["reg_displacement"]
    assert float(disp.detach()) > 0
