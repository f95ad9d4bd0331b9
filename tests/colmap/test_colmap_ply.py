"""PLY export of COLMAP points (signsplat.colmap.ply)."""

import numpy as np
import trimesh

from signsplat.colmap.ply import write_points_ply


def test_ply_readable_by_trimesh_with_count_positions_and_colours(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(0, 1, (257, 3))
    cols = rng.integers(0, 256, (257, 3), dtype=np.uint8)
    pts[10] = np.nan  # dropped
    path = write_points_ply(tmp_path / "p.ply", pts, cols, comment="test")
    cloud = trimesh.load(path)
    assert isinstance(cloud, trimesh.PointCloud)
    assert len(cloud.vertices) == 256
    keep = np.ones(257, bool)
    keep[10] = False
    np.testing.assert_allclose(cloud.vertices, pts[keep], atol=1e-6)
    np.testing.assert_array_equal(cloud.colors[:, :3], cols[keep])
    header = path.read_bytes().split(b"end_header")[0].decode()
    for prop in ("float x", "float y", "float z", "uchar red", "uchar green", "uchar blue"):
        assert f"property {prop}" in header


def test_empty_cloud_is_a_valid_file(tmp_path):
    path = write_points_ply(tmp_path / "e.ply", np.zeros((0, 3)))
    data = path.read_bytes()
    assert b"element vertex 0\n" in data
    assert data.endswith(b"end_header\n")
