"""The learned irradiance (model.shading): exact colour scaling, gain 1 at start, the switch."""

import math

import torch
from avatar_scenes import random_smplx

from signsplat.avatar.checkpoint import build_model
from signsplat.avatar.config import avatar_config
from signsplat.avatar.attributes import point_attributes_torch
from signsplat.avatar.model import irradiance_basis
from signsplat.render.sh import spherical_harmonics

CFG = {"upsample": {"edge_length": 0.08, "face_area": 3e-3}}


def _model(body, **over):
    return build_model(body, torch.zeros(1, 10), avatar_config({**CFG, **over}))


def _pose(model, body, params):
    out = body(**params)
    return model(out.v_shaped, out.vertices, out.transforms, params.get("transl"), 1)


def _decode(sh, dirs):
    """RGB (before the rasterizer's clamp) that SH (B, P, K, 3) decode to in directions dirs."""
    return spherical_harmonics(1, dirs, sh) + 0.5


def test_the_gain_scales_the_decoded_colour_exactly():
    g = torch.Generator().manual_seed(0)
    sh = torch.randn(50, 4, 3, generator=g)
    gain = torch.rand(2, 50, 3, generator=g) * 2
    dirs = torch.nn.functional.normalize(torch.randn(2, 50, 3, generator=g), dim=-1)
    args = (torch.zeros(50, 3), torch.randn(50, 4, generator=g), torch.zeros(50))
    rest = (torch.randn(2, 50, 4, generator=g), torch.ones(50), 0.0)
    shaded = point_attributes_torch(*args, sh[:, 0], sh[:, 1:], None, gain, *rest)[3]
    plain = point_attributes_torch(*args, sh[:, 0], sh[:, 1:], None, None, *rest)[3]
    torch.testing.assert_close(_decode(shaded, dirs), gain * _decode(plain, dirs))


def test_irradiance_basis_is_orthonormal_on_the_sphere():
    # Monte-Carlo check of the real SH constants: E[Y_i Y_j] over the sphere = delta_ij / 4pi
    g = torch.Generator().manual_seed(1)
    n = torch.nn.functional.normalize(torch.randn(400_000, 3, generator=g, dtype=torch.float64),
                                      dim=-1)
    y = irradiance_basis(n)
    gram = 4 * math.pi * (y.T @ y) / len(n)
    torch.testing.assert_close(gram, torch.eye(9, dtype=torch.float64), atol=2e-2, rtol=0)


def test_gain_starts_at_one_and_follows_the_normal_once_learned(tiny_body):
    on = _model(tiny_body)
    off = _model(tiny_body, model={"shading": False})
    assert off.irradiance is None and not any("irradiance" in n for n, _ in off.named_parameters())
    with torch.no_grad():
        off.load_state_dict(on.state_dict(), strict=False)
    p = random_smplx(2, seed=3, scale=0.5)
    frame = [{k: v[i:i + 1] for k, v in p.items()} for i in range(2)]
    a_on, a_off = _pose(on, tiny_body, frame[0]), _pose(off, tiny_body, frame[0])
    torch.testing.assert_close(a_on.colors, a_off.colors, atol=1e-5, rtol=0)  # gain 1
    with torch.no_grad():  # a light from +z: points facing it get brighter than others
        on.irradiance[2] = 1.5
    a, b = _pose(on, tiny_body, frame[0]), _pose(on, tiny_body, frame[1])
    assert torch.isfinite(a.colors).all()
    assert not torch.allclose(a.colors, b.colors)  # the colour now depends on the pose
    a2, b2 = _pose(off, tiny_body, frame[0]), _pose(off, tiny_body, frame[1])
    torch.testing.assert_close(a2.colors, b2.colors)  # switched off: it does not
