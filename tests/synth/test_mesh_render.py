"""The independent mesh renderer against analytic cases and against trimesh ray casting."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from signsplat.synth import mesh_render as mr

K64 = np.array([[80.0, 0.0, 31.5], [0.0, 80.0, 31.5], [0.0, 0.0, 1.0]])
I3 = np.eye(3)


def quad(x0, x1, y0, y1, z):
    """Axis-aligned square at depth z facing the camera: (4,3) vertices, (2,3) faces."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def test_square_coverage_and_depth_are_exact():
    v, f = quad(-0.5, 0.5, -0.25, 0.25, 2.0)
    r = mr.rasterize(v, f, K64, I3, np.zeros(3), 64, 64)
    # u = 80 * x / 2 + 31.5 -> x in [-0.5, 0.5] covers u in [11.5, 51.5] -> pixels 12..51
    ys, xs = np.nonzero(r.mask)
    assert (xs.min(), xs.max()) == (12, 51)
    # v = 80 * y / 2 + 31.5 -> y in [-0.25, 0.25] covers v in [21.5, 41.5] -> rows 22..41
    assert (ys.min(), ys.max()) == (22, 41)
    assert r.mask.sum() == 40 * 20  # no holes on the shared diagonal
    np.testing.assert_allclose(r.depth[r.mask], 2.0, rtol=1e-6)
    assert np.all(np.isinf(r.depth[~r.mask])) and np.all(r.face_id[~r.mask] == -1)
    np.testing.assert_allclose(r.bary[r.mask].sum(-1), 1.0, atol=1e-5)


def test_translation_moves_the_square():
    v, f = quad(-0.5, 0.5, -0.25, 0.25, 0.0)
    r = mr.rasterize(v, f, K64, I3, np.array([0.0, 0.0, 4.0]), 64, 64)
    np.testing.assert_allclose(r.depth[r.mask], 4.0, rtol=1e-6)
    assert r.mask.sum() == 20 * 10


def test_tilted_plane_depth_and_barycentrics_are_perspective_correct():
    # plane z = 2 + 0.8 x, seen obliquely
    v = np.array([[-0.6, -0.5, 2 - 0.48], [0.6, -0.5, 2 + 0.48], [0.0, 0.6, 2.0]])
    f = np.array([[0, 1, 2]])
    r = mr.rasterize(v, f, K64, I3, np.zeros(3), 64, 64)
    ys, xs = np.nonzero(r.mask)
    assert len(xs) > 300
    dx, dy = (xs - 31.5) / 80.0, (ys - 31.5) / 80.0
    z_true = 2.0 / (1.0 - 0.8 * dx)  # ray (dx, dy, 1) * z meets the plane
    np.testing.assert_allclose(r.depth[r.mask], z_true, rtol=1e-5)
    # interpolated world positions lie on the pixel rays
    p = mr.interpolate(r, f, v)
    np.testing.assert_allclose(p[:, 0], dx * z_true, atol=1e-5)
    np.testing.assert_allclose(p[:, 1], dy * z_true, atol=1e-5)


@pytest.mark.parametrize("near_first", [True, False])
def test_occlusion_order_does_not_depend_on_face_order(near_first):
    vn, fn = quad(-0.3, 0.3, -0.3, 0.3, 1.5)
    vf, ff = quad(-1.2, 1.2, -1.2, 1.2, 3.0)
    if near_first:
        v, f = np.concatenate([vn, vf]), np.concatenate([fn, ff + 4])
        near_faces = {0, 1}
    else:
        v, f = np.concatenate([vf, vn]), np.concatenate([ff, fn + 4])
        near_faces = {2, 3}
    r = mr.rasterize(v, f, K64, I3, np.zeros(3), 64, 64)
    assert set(np.unique(r.face_id[32, 28:36])) <= near_faces  # centre: the near square
    np.testing.assert_allclose(r.depth[32, 32], 1.5, rtol=1e-6)
    np.testing.assert_allclose(r.depth[32, 8], 3.0, rtol=1e-6)  # outside: the far square


def test_triangle_crossing_the_near_plane_is_clipped_not_dropped():
    # floor-like triangle from behind the camera to far in front, below the eye
    v = np.array([[-1.0, 0.5, -1.0], [1.0, 0.5, -1.0], [0.0, 0.5, 5.0]])
    f = np.array([[0, 1, 2]])
    near = 0.1
    r = mr.rasterize(v, f, K64, I3, np.zeros(3), 64, 64, near=near)
    assert r.mask.any()
    assert r.depth[r.mask].min() >= near
    ys, xs = np.nonzero(r.mask)
    assert ys.min() > 31.5  # below the horizon only
    # depth of the plane y = 0.5 along a pixel ray: z = 0.5 / dy
    dy = (ys - 31.5) / 80.0
    np.testing.assert_allclose(r.depth[r.mask], 0.5 / dy, rtol=1e-5)


def test_empty_views_do_not_crash():
    box = trimesh.creation.box(extents=(1, 1, 1))
    v, f = np.asarray(box.vertices), np.asarray(box.faces)
    behind = mr.rasterize(v, f, K64, I3, np.array([0.0, 0.0, -3.0]), 64, 64)
    aside = mr.rasterize(v + [50.0, 0, 0], f, K64, I3, np.array([0.0, 0.0, 3.0]), 64, 64)
    nothing = mr.rasterize(np.zeros((0, 3)), np.zeros((0, 3), int), K64, I3, np.zeros(3), 64, 64)
    for r in (behind, aside, nothing):
        assert not r.mask.any() and np.all(np.isinf(r.depth))
    assert mr.interpolate(behind, f, v).shape == (0, 3)
    # camera inside the box: only the walls beyond the near plane are drawn
    inside = mr.rasterize(v, f, K64, I3, np.zeros(3), 64, 64, near=0.05)
    assert inside.mask.all()
    np.testing.assert_allclose(inside.depth[31:33, 31:33], 0.5, rtol=1e-6)


def test_matches_trimesh_ray_casting_on_a_sphere():
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    R = trimesh.transformations.rotation_matrix(0.3, [0, 1, 0])[:3, :3]
    t = np.array([0.05, -0.02, 2.0])
    r = mr.rasterize(ico.vertices, ico.faces, K64, R, t, 64, 64)
    # the same rays cast with trimesh, in the world frame
    ys, xs = np.mgrid[0:64, 0:64]
    d_cam = np.stack([(xs - 31.5) / 80.0, (ys - 31.5) / 80.0, np.ones_like(xs, float)], -1)
    d_cam = d_cam.reshape(-1, 3)
    origin = -R.T @ t
    d_world = d_cam @ R  # R^T d
    hit, ray_idx, _ = ico.ray.intersects_location(np.repeat(origin[None], len(d_world), 0),
                                                  d_world, multiple_hits=False)
    ref = np.full(64 * 64, np.inf)
    ref[ray_idx] = (hit - origin) @ R[2]  # camera z of the hit
    ref = ref.reshape(64, 64)
    both = np.isfinite(ref) & r.mask
    # masks agree except possibly on a few silhouette pixels
    assert (np.isfinite(ref) ^ r.mask).sum() <= 4
    np.testing.assert_allclose(r.depth[both], ref[both], rtol=1e-4)


def test_sphere_area_matches_the_projected_disc():
    radius, dist = 0.5, 3.0
    ico = trimesh.creation.icosphere(subdivisions=5, radius=radius)
    K = np.array([[400.0, 0, 255.5], [0, 400.0, 255.5], [0, 0, 1]])
    r = mr.rasterize(ico.vertices, ico.faces, K, I3, np.array([0, 0, dist]), 512, 512)
    # silhouette of a sphere: a disc of angular radius asin(r/d)
    rad_px = 400.0 * np.tan(np.arcsin(radius / dist))
    assert abs(r.mask.sum() / (np.pi * rad_px ** 2) - 1) < 0.01
    np.testing.assert_allclose(r.depth[255:257, 255:257], dist - radius, rtol=2e-3)


def test_supersampling_helpers_keep_pixel_centres():
    K2 = mr.scale_intrinsics(K64, 2)
    # pixel centre u maps to the centre of its 2x2 block: 2u + 0.5
    np.testing.assert_allclose(K2 @ [0.1, 0.2, 1.0], [2 * (K64 @ [0.1, 0.2, 1.0])[0] + 0.5,
                                                     2 * (K64 @ [0.1, 0.2, 1.0])[1] + 0.5, 1])
    a = np.arange(16, dtype=float).reshape(4, 4)
    np.testing.assert_allclose(mr.downsample(a, 2), [[2.5, 4.5], [10.5, 12.5]])


def test_vertex_normals_of_a_sphere_point_outwards():
    ico = trimesh.creation.icosphere(subdivisions=2)
    n = mr.vertex_normals(ico.vertices, ico.faces)
    np.testing.assert_allclose(np.einsum("vc,vc->v", n, ico.vertices), 1.0, atol=0.02)


def test_renderer_is_independent_of_the_splat_rasterizer():
    root = Path(mr.__file__).parent
    for path in root.glob("*.py"):
        assert "signsplat.render" not in path.read_text(), path
    code = ("import sys, numpy as np\n"
            "from signsplat.synth import mesh_render, simulate, effects, scene\n"
            "v = np.array([[0,0,2.],[1,0,2],[0,1,2]]); f = np.array([[0,1,2]])\n"
            "mesh_render.rasterize(v, f, np.eye(3), np.eye(3), np.zeros(3), 8, 8)\n"
            "bad = [m for m in sys.modules if m.startswith(('signsplat.render', 'gsplat'))]\n"
            "assert not bad, bad\n")
    subprocess.run([sys.executable, "-c", code], check=True)
