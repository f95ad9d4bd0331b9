"""Hard cases stay finite, forward and every gradient (CPU kernel; the reference where cheap):
zero and huge scales, needle-thin covariances, behind the camera and straddling the near plane,
at and beyond the image border, opacity 0 and 1, thousands stacked on one pixel, zero
quaternions, an empty scene, a 1x1 image; plus hypothesis-generated mixtures of them."""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from raster_scenes import cameras

from signsplat.render import rasterization

KEYS = ("means", "quats", "scales", "opacities", "colors", "viewmats")


def _check_finite(s, backend="cpu", mode="RGB+D", aa=False, sh=None, W=24, H=20, C=1,
                  absgrad=True):
    leaves = {k: s[k].clone().requires_grad_(True) for k in KEYS if k != "viewmats"}
    vm, Ks = cameras(C, W, H)
    leaves["viewmats"] = vm.float().requires_grad_(True)
    bg = torch.full((C, 3), 0.25, requires_grad=True)
    rc, ra, meta = rasterization(**leaves, Ks=Ks.float(), width=W, height=H, sh_degree=sh,
                                 backgrounds=bg, render_mode=mode, absgrad=absgrad,
                                 rasterize_mode="antialiased" if aa else "classic",
                                 backend=backend)
    meta["means2d"].retain_grad()
    assert torch.isfinite(rc).all() and torch.isfinite(ra).all()
    assert (ra >= 0).all() and (ra <= 1).all()
    (rc.sum() + ra.sum()).backward()
    for k in KEYS:
        if k == "colors" and mode in ("D", "ED"):
            continue  # colours are not rendered in depth-only modes
        assert leaves[k].grad is not None, k
        assert torch.isfinite(leaves[k].grad).all(), k
    if mode not in ("D", "ED"):  # backgrounds are not used by depth-only modes
        assert torch.isfinite(bg.grad).all()
    if meta["means2d"].grad is not None:
        assert torch.isfinite(meta["means2d"].grad).all()
    if absgrad and hasattr(meta["means2d"], "absgrad"):
        assert torch.isfinite(meta["means2d"].absgrad).all()
    return rc, ra, meta


def _base(N, seed=0, sh=None):
    """N Gaussians near the origin; ``cameras(1, ...)`` looks at them from (0, 0, -2.2)."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(N, 3, generator=g) * 2 - 1) * 0.3
    quats = torch.randn(N, 4, generator=g)
    scales = torch.full((N, 3), 0.05)
    opac = torch.full((N,), 0.7)
    colors = torch.rand(N, 3, generator=g) if sh is None else torch.randn(N, (sh + 1) ** 2, 3)
    return dict(means=means, quats=quats, scales=scales, opacities=opac, colors=colors,
                viewmats=None)


HARD = {}


def hard(fn):
    HARD[fn.__name__] = fn
    return fn


@hard
def zero_scales():
    s = _base(40)
    s["scales"][:20] = 0.0
    s["scales"][20:, 1:] = 0.0  # needles: one non-zero axis
    return s


@hard
def huge_scales():
    s = _base(40)
    s["scales"][:10] = 1e4
    s["scales"][10:20] = 1e8  # overflows float32 covariance: culled
    s["scales"][20:30, 0] = 1e4  # huge and thin
    return s


@hard
def needle_covariances():
    s = _base(60, seed=1)
    s["scales"][:, 0] = 0.5
    s["scales"][:, 1:] = 1e-7
    return s


@hard
def behind_and_near_plane():
    s = _base(60, seed=2)
    z = torch.linspace(-3.0, 0.2, 60)  # world z; the camera is at z = -2.2 looking at +z
    s["means"][:, 2] = z
    s["means"][:, :2] *= 0.05
    s["scales"][:] = 0.3  # large: many straddle the near plane
    return s


@hard
def exactly_at_camera_and_near_plane():
    s = _base(6, seed=3)
    s["means"][:] = torch.tensor([0.0, 0.0, -2.2])
    s["means"][1, 2] = -2.2 + 0.01  # exactly at near_plane = 0.01
    s["means"][2, 2] = -2.2 + 0.0100001
    s["means"][3, 2] = -2.2 + 1e-9
    return s


@hard
def at_and_beyond_border():
    s = _base(80, seed=4)
    t = torch.linspace(-1.0, 1.0, 80)
    s["means"][:, 0] = t * 1.2  # from far left to far right of the view
    s["means"][:, 1] = torch.flip(t, [0]) * 1.2
    s["means"][:, 2] = 0.0
    s["means"][:8, 0] = 1e6  # very far outside
    s["means"][8:16, 1] = -1e5
    return s


@hard
def opacity_zero_and_one():
    s = _base(50, seed=5)
    s["opacities"][:25] = 0.0
    s["opacities"][25:] = 1.0
    return s


@hard
def thousands_on_one_pixel():
    N = 3000
    s = _base(N, seed=6)
    s["means"][:] = 0.0
    s["means"][:, 2] = torch.linspace(-0.5, 0.5, N)
    s["scales"][:] = 0.002
    s["opacities"][:] = 0.2
    return s


@hard
def identical_depths():
    s = _base(200, seed=7)
    s["means"][:, 2] = 0.0  # many exact depth ties (with a frontal camera)
    return s


@hard
def zero_quaternions():
    s = _base(40, seed=8)
    s["quats"][:20] = 0.0
    s["quats"][20:30] = 1e-30
    return s


@hard
def empty_scene():
    return _base(0)


@pytest.mark.parametrize("name", sorted(HARD))
@pytest.mark.parametrize("aa", [False, True])
def test_hard_case_cpu(name, aa):
    _check_finite(HARD[name](), aa=aa)


@pytest.mark.parametrize("name", ["zero_scales", "needle_covariances", "behind_and_near_plane",
                                  "opacity_zero_and_one", "zero_quaternions", "empty_scene",
                                  "at_and_beyond_border", "identical_depths"])
def test_hard_case_reference(name):
    _check_finite(HARD[name](), backend="reference")


@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_one_by_one_image(backend):
    s = _base(30, seed=9, sh=2)
    rc, ra, _ = _check_finite(s, backend=backend, W=1, H=1, sh=2, mode="RGB+ED")
    assert rc.shape == (1, 1, 1, 4) and ra.shape == (1, 1, 1, 1)


def test_empty_scene_gives_background():
    s = _base(0)
    rc, ra, meta = _check_finite(s, mode="RGB")
    assert torch.allclose(rc, torch.full_like(rc, 0.25)) and (ra == 0).all()
    assert meta["radii"].shape == (1, 0, 2)


def test_zero_quaternion_is_identity_rotation():
    s = _base(2, seed=10)
    s["quats"][0] = 0.0
    s["quats"][1] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    s["scales"][:] = torch.tensor([0.1, 0.02, 0.05])
    s["means"][1] = s["means"][0]
    vm, Ks = cameras(1, 32, 32)
    out = rasterization(**{**s, "viewmats": vm.float()}, Ks=Ks.float(), width=32, height=32)
    conics = out[2]["conics"][0]
    torch.testing.assert_close(conics[0], conics[1])


def test_stacked_pixels_terminate():
    """Thousands of opaque Gaussians on one pixel: the pixel saturates (T < 1e-4 stop)."""
    s = thousands_on_one_pixel()
    s["opacities"][:] = 0.9
    rc, ra, _ = _check_finite(s, W=16, H=16, mode="RGB")
    assert ra.max() > 1 - 1e-3


# ----------------------------------------------------------------------------- hypothesis
_floats = st.floats(allow_nan=False, allow_infinity=False, width=32)


@st.composite
def hard_scenes(draw):
    N = draw(st.integers(0, 40))
    sh = draw(st.sampled_from([None, 0, 3]))
    kinds = st.sampled_from(["normal", "zero", "huge", "needle", "tiny"])
    means, quats, scales, opac = [], [], [], []
    for _ in range(N):
        means.append([draw(st.floats(-1.5, 1.5)), draw(st.floats(-1.5, 1.5)),
                      draw(st.one_of(st.floats(-3.0, 2.0), st.sampled_from([-2.19, -2.2])))])
        kind = draw(kinds)
        q = [draw(st.floats(-1, 1)) for _ in range(4)]
        if draw(st.booleans()) and draw(st.booleans()):
            q = [0.0, 0.0, 0.0, 0.0]
        quats.append(q)
        base = {"normal": 0.05, "zero": 0.0, "huge": 1e5, "needle": 1e-7, "tiny": 1e-4}[kind]
        sc = [base * draw(st.floats(0.5, 2.0)) for _ in range(3)]
        if kind == "needle":
            sc[0] = 0.3
        scales.append(sc)
        opac.append(draw(st.sampled_from([0.0, 1.0, 0.5, 1e-3, 0.999])))
    t = lambda x, shape: torch.tensor(x, dtype=torch.float32).reshape(shape)  # noqa: E731
    s = dict(means=t(means, (N, 3)), quats=t(quats, (N, 4)), scales=t(scales, (N, 3)),
             opacities=t(opac, (N,)))
    g = torch.Generator().manual_seed(draw(st.integers(0, 1000)))
    s["colors"] = (torch.rand(N, 3, generator=g) if sh is None
                   else torch.randn(N, (sh + 1) ** 2, 3, generator=g))
    s["viewmats"] = None
    W = draw(st.sampled_from([1, 7, 16, 23]))
    H = draw(st.sampled_from([1, 9, 16, 20]))
    C = draw(st.integers(1, 2))
    mode = draw(st.sampled_from(["RGB", "RGB+D", "RGB+ED", "ED"]))
    aa = draw(st.booleans())
    return s, sh, W, H, C, mode, aa


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(hard_scenes())
def test_hypothesis_hard_scenes_finite(args):
    s, sh, W, H, C, mode, aa = args
    _check_finite(s, sh=sh, W=W, H=H, C=C, mode=mode, aa=aa)


def test_radius_covers_alpha_threshold():
    """Every pixel with alpha >= 1/255 lies inside the Gaussian's bounding box (so tiling cannot
    change the image)."""
    from signsplat.render.projection import project
    from raster_scenes import scene

    s = scene(N=200, W=40, H=30, C=1, seed=3)
    p = project(s["means"], s["quats"], s["scales"], s["opacities"], s["viewmats"], s["Ks"],
                40, 30)
    ys, xs = torch.meshgrid(torch.arange(30) + 0.5, torch.arange(40) + 0.5, indexing="ij")
    vis = (p["radii"][0] > 0).any(-1)
    for i in torch.nonzero(vis)[:, 0].tolist():
        mx, my = p["means2d"][0, i]
        a, b, c = p["conics"][0, i]
        dx, dy = mx - xs, my - ys
        sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
        alpha = s["opacities"][i] * torch.exp(-sigma)
        inside = ((dx.abs() <= p["radii"][0, i, 0]) & (dy.abs() <= p["radii"][0, i, 1]))
        assert not ((alpha >= 1 / 255) & ~inside).any()
    assert math.isfinite(float(p["conics"].sum()))
