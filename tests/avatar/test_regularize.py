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
    model, _ = _model(tiny_body, radius=0.08, max_neighbours=6)
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


def _posed(model, body):
    out = body(betas=torch.zeros(1, 10))
    return model(out.v_shaped, out.vertices, out.transforms, None, 0)


def test_attribute_similarity_keeps_unlike_points_apart(tiny_body):
    model, _ = _model(tiny_body)
    pts = model.canonical_points()
    args = (model.anchors, model.part, model.faces, model.num_vertices, 0.08, 6)
    # two "colours" split by a plane through the body: 1 unit apart in attribute space
    colour = (pts[:, 0] > pts[:, 0].median()).float()[:, None]
    near = build_neighbourhoods(pts, *args, colour, attribute_scale=0.0)
    apart = build_neighbourhoods(pts, *args, colour, attribute_scale=1.0)
    differs = lambda nb: (colour[nb.idx, 0] != colour[:, None, 0])[nb.mask]
    assert bool(differs(near).any())  # proximity alone joins the two colours
    assert not bool(differs(apart).any())
    # the distance is sqrt(dx^2 + (s da)^2): at s = 0.05 a unit of colour costs 5 cm, more
    # than a 3 cm radius allows but less than 8 cm
    small = build_neighbourhoods(pts, model.anchors, model.part, model.faces,
                                 model.num_vertices, 0.03, 6, colour, attribute_scale=0.05)
    assert not bool(differs(small).any())
    wide = build_neighbourhoods(pts, *args, colour, attribute_scale=0.05)
    assert bool(differs(wide).any())


def test_face_apart_is_a_switch(tiny_body):
    model, _ = _model(tiny_body)
    pts = model.canonical_points()
    head = model.part == PART_HEAD
    mixed = lambda nb: (head[:, None] != head[nb.idx])[nb.mask]
    args = (pts, model.anchors, model.part, model.faces, model.num_vertices, 0.08, 6)
    assert not bool(mixed(build_neighbourhoods(*args, face_apart=True)).any())
    assert bool(mixed(build_neighbourhoods(*args, face_apart=False)).any())


def test_each_weight_acts_on_its_own_parameter(tiny_body):
    names = {"w_scale": "reg_scale", "w_rotation": "reg_rotation",
             "w_opacity": "reg_opacity", "w_color": "reg_color"}
    for off, term in names.items():
        model, cfg = _model(tiny_body, enabled=True, **{off: 0.0})
        with torch.no_grad():
            model.sh_dc.normal_()
        terms = Regularizer(cfg.regularize)(model, _posed(model, tiny_body))
        assert set(terms) == set(names.values()) - {term}, off
    # doubling a weight doubles its term only
    model, cfg = _model(tiny_body, enabled=True)
    with torch.no_grad():
        model.sh_dc.normal_()
    g = _posed(model, tiny_body)
    one = Regularizer(cfg.regularize)(model, g)
    _, cfg2 = _model(tiny_body, enabled=True, w_color=2 * cfg.regularize.w_color)
    two = Regularizer(cfg2.regularize)(model, g)
    torch.testing.assert_close(two["reg_color"], 2 * one["reg_color"])
    torch.testing.assert_close(two["reg_scale"], one["reg_scale"])


def test_part_weights_weigh_each_part_s_points(tiny_body):
    from signsplat.avatar.regularize import part_weights
    from signsplat.body.joints import PART_BODY, PART_LEFT_HAND, PART_RIGHT_HAND

    model, cfg = _model(tiny_body, enabled=True,
                        part_weights={"body": 0.0, "face": 1.0, "hands": 0.0})
    with torch.no_grad():
        model.sh_dc.normal_()
    g = _posed(model, tiny_body)
    reg = Regularizer(cfg.regularize)
    terms = reg(model, g)
    nb = reg.neighbourhoods(model)
    head = (model.part == PART_HEAD).float()
    expected = cfg.regularize.w_color * neighbourhood_variance(g.colors[0, :, 0], nb, head)
    torch.testing.assert_close(terms["reg_color"], expected)
    assert float(terms["reg_color"].detach()) > 0
    w = part_weights(model.part, cfg.regularize.part_weights)
    assert bool((w[model.part == PART_HEAD] == 1).all())
    for p in (PART_BODY, PART_LEFT_HAND, PART_RIGHT_HAND):
        assert bool((w[model.part == p] == 0).all())
    _, none = _model(tiny_body, enabled=True,
                     part_weights={"body": 0.0, "face": 0.0, "hands": 0.0})
    zero = Regularizer(none.regularize)(model, g)
    assert all(float(t.detach()) == 0.0 for t in zero.values())


def test_neighbourhoods_travel_in_the_state(tiny_body):
    """A resumed run keeps the neighbourhoods built from the attributes of the step they were
    built at, not those of the step it resumes at."""
    model, cfg = _model(tiny_body, enabled=True, attribute_scale=1.0, radius=0.2)
    with torch.no_grad():
        model.sh_dc.normal_()
    first = Regularizer(cfg.regularize)
    nb = first.neighbourhoods(model, _posed(model, tiny_body))
    with torch.no_grad():
        model.sh_dc.normal_()  # the attributes move on; the point set does not
    g = _posed(model, tiny_body)
    fresh = Regularizer(cfg.regularize).neighbourhoods(model, g)
    assert not torch.equal(fresh.idx, nb.idx)  # the attributes do change them
    resumed = Regularizer(cfg.regularize)
    resumed.load_state_dict(first.state_dict())
    kept = resumed.neighbourhoods(model, g)
    assert torch.equal(kept.idx, nb.idx) and torch.equal(kept.mask, nb.mask)
