"""Density control on the mesh: growth on adjacent faces, the point cap, pruning by subsampling."""

import torch
from avatar_scenes import rig

from signsplat.avatar.checkpoint import build_model
from signsplat.avatar.config import avatar_config
from signsplat.avatar.model import POINT_PARAMS, face_normals
from signsplat.avatar.strategy import MeshDensifyStrategy
from signsplat.render import rasterization


def _setup(body, **strategy):
    cfg = avatar_config({"upsample": {"edge_length": 0.08, "face_area": 3e-3}})
    model = build_model(body, torch.zeros(1, 10), cfg)
    opt = torch.optim.Adam([{"params": [getattr(model, n)], "name": n, "lr": 1e-2}
                            for n in POINT_PARAMS])
    s = MeshDensifyStrategy(**{"refine_start": 0, "refine_every": 1, "refine_stop": 100,
                               "grad_threshold": 1e-9, **strategy})
    return model, opt, s, s.initialize_state()


def _render_backward(model, body, strategy):
    out = body(betas=torch.zeros(1, 10))
    g = model(out.v_shaped, out.vertices, out.transforms, None, 0)
    vm, K = rig(2, 24)
    img, _, meta = rasterization(g.means[0], g.quats[0], g.scales[0], g.opacities[0],
                                 g.colors[0], vm, K, 24, 24, sh_degree=0,
                                 backgrounds=torch.zeros(2, 3))
    meta.update(width=24, height=24)
    strategy.step_pre_backward(meta)
    ((img - 0.3) ** 2).sum().backward()
    return meta


def test_growth_stops_at_the_point_cap(tiny_body):
    model, opt, s, state = _setup(tiny_body, max_points=0, max_new_per_refine=10_000,
                                  prune_opacity=0.0, prune_scale_fraction=1.0)
    n0 = model.num_points
    s.max_points = n0 + 7
    meta = _render_backward(model, tiny_body, s)
    stats = s.step_post_backward(model, opt, state, 1, [meta])
    assert stats["added"] == 7 and model.num_points == n0 + 7
    opt.step()  # optimiser state and parameters still line up
    for n in POINT_PARAMS:
        assert getattr(model, n).shape[0] == n0 + 7
    # at the cap: nothing more, no error
    meta = _render_backward(model, tiny_body, s)
    stats = s.step_post_backward(model, opt, state, 2, [meta])
    assert stats["added"] == 0 and model.num_points == n0 + 7
    opt.step()


def test_new_points_lie_on_adjacent_faces_and_learn_their_place(tiny_body):
    model, opt, s, state = _setup(tiny_body, max_points=100_000, max_new_per_refine=50,
                                  prune_opacity=0.0, prune_scale_fraction=1.0)
    n0 = model.num_points
    meta = _render_backward(model, tiny_body, s)
    opt.step()
    with torch.no_grad():  # tag every point: a new point copies its parent's tensors
        model.sh_dc[:, 0, 0] = torch.arange(n0, dtype=torch.float32)
    anchors0, face0 = model.anchors.clone(), model.face.clone()
    s.step_post_backward(model, opt, state, 1, [meta])
    new = torch.arange(n0, model.num_points)
    assert len(new) == 50 and bool(model.learnable[new].all())
    assert not bool(model.is_original[new].any())
    tri = model.faces[model.face[new]]
    assert torch.equal(model.anchors[new], tri)
    # adjacency: a child of a mesh vertex lies on a face containing that vertex, a child of a
    # point on a face on that same face
    parent = model.sh_dc[new, 0, 0].detach().round().long()
    from_vertex = face0[parent] < 0
    assert bool(from_vertex.any()) and bool((~from_vertex).any())
    assert bool((tri[from_vertex] == anchors0[parent[from_vertex], :1]).any(1).all())
    assert torch.equal(model.face[new][~from_vertex], face0[parent[~from_vertex]])
    k = model.barycentric()[new]
    torch.testing.assert_close(k.sum(1), torch.ones(len(new)))
    assert bool((k > 0).all())
    # a new point starts on its face (l = 0); moving l moves it along the face normal
    out = tiny_body(betas=torch.zeros(1, 10))
    g0 = model(out.v_shaped, out.vertices, out.transforms, None, 0)
    with torch.no_grad():
        model.normal_offset[new] = 0.01
    g1 = model(out.v_shaped, out.vertices, out.transforms, None, 0)
    n = face_normals(out.vertices[0], tri)
    torch.testing.assert_close(g1.means[0, new] - g0.means[0, new], 0.01 * n, atol=1e-5, rtol=0)
    torch.testing.assert_close(g1.means[0, :n0], g0.means[0, :n0])
    # k1..k3 and l receive gradients
    (g1.means[0, new] ** 2).sum().backward()
    assert float(model.bary_logits.grad[new].abs().sum()) > 0
    assert float(model.normal_offset.grad[new].abs().sum()) > 0


def test_pruning_subsamples_and_never_removes_mesh_vertices(tiny_body):
    model, opt, s, state = _setup(tiny_body, max_points=100_000, max_new_per_refine=200,
                                  prune_opacity=0.0, prune_scale_fraction=1.0)
    meta = _render_backward(model, tiny_body, s)
    s.step_post_backward(model, opt, state, 1, [meta])
    n_before, n_orig = model.num_points, int(model.is_original.sum())
    n_cand = n_before - n_orig
    with torch.no_grad():
        model.opacity_raw.fill_(-20.0)  # everything transparent
    s.prune_opacity, s.prune_keep_fraction = 0.5, 0.5
    removed = s.prune(model, opt, state)
    assert int(model.is_original.sum()) == n_orig  # originals all kept
    assert 0.3 * n_cand < removed < 0.7 * n_cand  # about half of the candidates go
    assert model.num_points == n_before - removed
    assert bool(model.is_original[:n_orig].all())  # originals stay first, in order
    opt.step()
