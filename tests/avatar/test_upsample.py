"""Mesh upsampling: points along long edges and at centres of large faces, anchored on the mesh."""

import numpy as np
import torch
import trimesh

from signsplat.avatar.upsample import upsample_mesh


def _mesh():
    m = trimesh.creation.icosphere(subdivisions=1, radius=0.3)
    return torch.tensor(m.vertices, dtype=torch.float32), torch.tensor(m.faces)


def test_no_threshold_crossed_keeps_only_vertices():
    v, f = _mesh()
    pts = upsample_mesh(v, f, torch.zeros(len(v), dtype=torch.long), 10.0, 10.0)
    assert len(pts) == len(v) and bool(pts.is_original.all())
    torch.testing.assert_close(pts.positions(v), v)


def test_edge_and_face_points_counts_and_positions():
    v, f = _mesh()
    vn, fn = v.numpy(), f.numpy()
    e = np.concatenate([fn[:, [0, 1]], fn[:, [1, 2]], fn[:, [2, 0]]])
    edges = np.unique(np.sort(e, 1), axis=0)
    lengths = np.linalg.norm(vn[edges[:, 0]] - vn[edges[:, 1]], axis=1)
    thr = float(np.median(lengths)) * 0.45  # every edge gets 1-2 points
    tri = vn[fn]
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    area_thr = float(np.median(areas))
    pts = upsample_mesh(v, f, torch.zeros(len(v), dtype=torch.long), thr, area_thr)
    expected_edge = int((np.ceil(lengths / thr) - 1).sum())
    expected_face = int((areas > area_thr).sum())
    assert len(pts) == len(v) + expected_edge + expected_face
    assert int(pts.is_original.sum()) == len(v) and bool(pts.is_original[: len(v)].all())
    torch.testing.assert_close(pts.bary.sum(1), torch.ones(len(pts)))
    pos = pts.positions(v)
    new = ~pts.is_original
    # every new point lies in the triangle of its face (distance to the plane ~ 0)
    tri_t = v[f[pts.face[new]]]
    n = torch.cross(tri_t[:, 1] - tri_t[:, 0], tri_t[:, 2] - tri_t[:, 0], dim=-1)
    n = n / n.norm(dim=-1, keepdim=True)
    dist = ((pos[new] - tri_t[:, 0]) * n).sum(-1).abs()
    assert float(dist.max()) < 1e-5
    # edge points are strictly between their two end vertices, no duplicates
    assert len(torch.unique(pos.round(decimals=6), dim=0)) == len(pts)


def test_weights_and_parts_are_interpolated():
    v, f = _mesh()
    parts = (v[:, 0] > 0).long() * 2  # two labels
    pts = upsample_mesh(v, f, parts, 0.05, 1e-3)
    w = torch.softmax(torch.randn(len(v), 5), -1)
    pw = pts.weights(w)
    torch.testing.assert_close(pw.sum(1), torch.ones(len(pts)))
    torch.testing.assert_close(pw[: len(v)], w)
    heavy = pts.anchors[torch.arange(len(pts)), pts.bary.argmax(1)]
    assert torch.equal(pts.part, parts[heavy])


def test_grid_interior_fills_large_faces_at_the_edge_spacing():
    # one right triangle with legs of 10 cm: at 2.5 cm the longest edge (14.1 cm) gives n = 6,
    # so (n-1)(n-2)/2 = 10 interior grid points; "centre" gives the centroid alone
    v = torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    f = torch.tensor([[0, 1, 2]])
    parts = torch.zeros(3, dtype=torch.long)
    centre = upsample_mesh(v, f, parts, 0.025, 1e-4, "centre")
    grid = upsample_mesh(v, f, parts, 0.025, 1e-4, "grid")
    n_edge = len(centre) - 3 - 1
    assert len(grid) == 3 + n_edge + 10
    inner = grid.positions(v)[3 + n_edge:]
    b = grid.bary[3 + n_edge:]
    assert bool((b > 0).all()) and torch.allclose(b.sum(1), torch.ones(len(b)))
    assert bool((grid.face[3 + n_edge:] == 0).all())
    # interior points are distinct and no closer to each other than the grid step (14.1/6 cm
    # along the hypotenuse direction, 10/6 cm along the legs)
    d = torch.cdist(inner, inner) + torch.eye(len(inner))
    assert float(d.min()) > 0.1 / 6 - 1e-6
    try:
        upsample_mesh(v, f, parts, 0.025, 1e-4, "spiral")
    except ValueError as err:
        assert "spiral" in str(err) and "grid" in str(err)
    else:
        raise AssertionError("an unknown interior mode must fail")
