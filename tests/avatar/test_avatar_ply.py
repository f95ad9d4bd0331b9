"""3DGS PLY export: standard field names and order, f_rest count matching the SH degree."""

import numpy as np
import pytest
import torch

from signsplat.avatar.ply import ply_fields, read_gaussian_ply, write_gaussian_ply


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_roundtrip_and_layout(tmp_path, degree):
    g = torch.Generator().manual_seed(degree)
    n, k = 17, (degree + 1) ** 2
    means = torch.randn(n, 3, generator=g)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)
    scales = torch.rand(n, 3, generator=g) * 0.01 + 1e-3
    opac = torch.rand(n, generator=g) * 0.9 + 0.05
    sh = torch.randn(n, 16, 3, generator=g)  # more bases than needed: extra dropped
    path = write_gaussian_ply(tmp_path / "a.ply", means, quats, scales, opac, sh, degree)
    head = path.read_bytes().split(b"end_header\n")[0].decode()
    assert "format binary_little_endian 1.0" in head and f"element vertex {n}" in head
    d = read_gaussian_ply(path)
    assert list(d) == ply_fields(degree)
    assert sum(name.startswith("f_rest_") for name in d) == 3 * (k - 1)
    np.testing.assert_allclose(np.stack([d["x"], d["y"], d["z"]], 1), means.numpy(), rtol=1e-6)
    np.testing.assert_allclose(d["opacity"], torch.logit(opac).numpy(), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(np.exp(np.stack([d[f"scale_{i}"] for i in range(3)], 1)),
                               scales.numpy(), rtol=1e-5)
    np.testing.assert_allclose(np.stack([d[f"rot_{i}"] for i in range(4)], 1), quats.numpy())
    np.testing.assert_allclose(np.stack([d[f"f_dc_{i}"] for i in range(3)], 1), sh[:, 0].numpy())
    if degree:
        # channel-major: f_rest_0..k-2 are red coefficients 1..k-1, then green, then blue
        np.testing.assert_allclose(d["f_rest_0"], sh[:, 1, 0].numpy())
        np.testing.assert_allclose(d[f"f_rest_{k - 1}"], sh[:, 1, 1].numpy())
        np.testing.assert_allclose(d[f"f_rest_{2 * (k - 1)}"], sh[:, 1, 2].numpy())
    assert not list(tmp_path.glob(".*tmp*"))  # atomic write left no temporary file


def test_too_few_sh_bases_is_an_error(tmp_path):
    with pytest.raises(ValueError, match="needs 4"):
        write_gaussian_ply(tmp_path / "b.ply", torch.zeros(2, 3), torch.zeros(2, 4),
                           torch.ones(2, 3), torch.full((2,), 0.5), torch.zeros(2, 1, 3), 1)
