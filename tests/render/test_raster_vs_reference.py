"""The CPU kernel against the plain-PyTorch reference: forward (1e-5 max abs, float32) and the
gradients of every input (1e-4 relative to each gradient's scale), over render modes, SH degrees
0-3, several cameras, antialiasing and backgrounds."""

from __future__ import annotations

import pytest
import torch
from raster_scenes import leafs, scene

from signsplat.render import rasterization

FWD_TOL = 1e-5
GRAD_TOL = 1e-4


def _render(backend, s, *, mode="RGB", aa=False, bg=None, absgrad=False):
    return rasterization(**s, backgrounds=bg, render_mode=mode,
                         rasterize_mode="antialiased" if aa else "classic", absgrad=absgrad,
                         backend=backend)


def _bg(s, seed=3):
    C = s["viewmats"].shape[0]
    g = torch.Generator().manual_seed(seed)
    return torch.rand(C, 3, generator=g).to(s["means"].dtype)


def _compare_forward(rc, ra, mc, rr, rar, mr, mode):
    assert rc.shape == rr.shape and ra.shape == rar.shape
    assert torch.equal(mc["radii"], mr["radii"])
    vis = (mr["radii"] > 0).any(-1)
    assert torch.equal(mc["means2d"][vis], mr["means2d"][vis])  # same op order: bitwise
    torch.testing.assert_close(mc["depths"][vis], mr["depths"][vis], rtol=1e-6, atol=1e-6)
    torch.testing.assert_close(mc["conics"][vis], mr["conics"][vis], rtol=1e-5, atol=1e-6)
    assert (ra - rar).abs().max().item() <= FWD_TOL
    if mode in ("ED", "RGB+ED"):
        # expected depth = D / alpha: compare D (the division amplifies float32 rounding of
        # 1 - T by 1 / alpha at nearly transparent pixels)
        if rc.shape[-1] > 1:
            assert (rc[..., :-1] - rr[..., :-1]).abs().max().item() <= FWD_TOL
        assert (rc[..., -1:] * ra - rr[..., -1:] * rar).abs().max().item() <= FWD_TOL
    else:
        assert (rc - rr).abs().max().item() <= FWD_TOL


CASES = [
    dict(mode="RGB", sh=None, C=1),
    dict(mode="RGB", sh=0, C=2),
    dict(mode="RGB", sh=1, C=2),
    dict(mode="RGB", sh=2, C=1),
    dict(mode="RGB", sh=3, C=3),
    dict(mode="D", sh=None, C=2),
    dict(mode="ED", sh=None, C=2),
    dict(mode="RGB+D", sh=3, C=2),
    dict(mode="RGB+ED", sh=None, C=3),
    dict(mode="RGB", sh=None, C=2, aa=True),
    dict(mode="RGB+D", sh=2, C=2, aa=True),
    dict(mode="RGB", sh=None, C=2, D=5),        # more than four channels
    dict(mode="RGB", sh=None, C=2, per_camera=True),
    dict(mode="RGB", sh=3, C=2, per_camera=True),
]


def _case_id(c):
    return "-".join(f"{k}={v}" for k, v in c.items())


@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_forward_matches_reference(case):
    s = scene(N=300, W=48, H=40, C=case["C"], seed=11, sh_degree=case["sh"],
              D=case.get("D", 3), per_camera=case.get("per_camera", False))
    D = case.get("D", 3)
    bg = None if case["mode"] in ("D", "ED") or D != 3 else _bg(s)
    out_c = _render("cpu", s, mode=case["mode"], aa=case.get("aa", False), bg=bg)
    out_r = _render("reference", s, mode=case["mode"], aa=case.get("aa", False), bg=bg)
    assert out_c[2]["backend"] == "cpu" and out_r[2]["backend"] == "reference"
    _compare_forward(*out_c, *out_r, case["mode"])
    assert out_c[1].mean() > 0.2  # the scenes do cover the images


def _grads(backend, s, *, mode, aa, with_bg, absgrad=True):
    leaves = leafs(s)
    bg = _bg(s).requires_grad_(True) if with_bg else None
    rc, ra, meta = _render(backend, leaves, mode=mode, aa=aa, bg=bg, absgrad=absgrad)
    meta["means2d"].retain_grad()
    g = torch.Generator().manual_seed(7)
    w_c = torch.randn(rc.shape, generator=g).to(rc.dtype)
    w_a = torch.randn(ra.shape, generator=g).to(rc.dtype)
    if mode in ("ED", "RGB+ED"):
        # the expected depth of nearly transparent pixels is ill-conditioned (1 / alpha):
        # weight it where the pixel is reasonably opaque, as a masked depth loss would
        w_c[..., -1:] = w_c[..., -1:] * (ra.detach() > 0.3)
    loss = (rc * w_c).sum() + (ra * w_a).sum()
    loss.backward()
    out = {k: leaves[k].grad for k in ("means", "quats", "scales", "opacities", "colors",
                                       "viewmats")}
    if with_bg:
        out["backgrounds"] = bg.grad
    out["means2d"] = meta["means2d"].grad
    if absgrad:
        out["means2d.absgrad"] = meta["means2d"].absgrad
    return out


@pytest.mark.parametrize("case", CASES, ids=_case_id)
def test_gradients_match_reference(case):
    s = scene(N=300, W=48, H=40, C=case["C"], seed=12, sh_degree=case["sh"],
              D=case.get("D", 3), per_camera=case.get("per_camera", False))
    with_bg = case["mode"] not in ("D", "ED") and case.get("D", 3) == 3
    kw = dict(mode=case["mode"], aa=case.get("aa", False), with_bg=with_bg)
    gc = _grads("cpu", s, **kw)
    gr = _grads("reference", s, **kw)
    for name, ref in gr.items():
        got = gc[name]
        if case["mode"] in ("D", "ED") and name == "colors":
            assert got is None and ref is None
            continue
        assert got is not None and ref is not None, name
        assert got.shape == ref.shape, name
        assert torch.isfinite(got).all(), name
        scale = ref.abs().max().item()
        assert scale > 0, name
        err = (got - ref).abs().max().item() / scale
        assert err <= GRAD_TOL, f"{name}: relative error {err:.2e}"


def test_float64_forward_matches_reference():
    s = scene(N=200, W=40, H=32, C=2, seed=4, dtype=torch.float64, sh_degree=2)
    rc, ra, _ = _render("cpu", s, mode="RGB+D", bg=_bg(s))
    rr, rar, _ = _render("reference", s, mode="RGB+D", bg=_bg(s))
    assert rc.dtype == torch.float64
    assert (rc - rr).abs().max().item() < 1e-10
    assert (ra - rar).abs().max().item() < 1e-10


def test_reference_block_culling_changes_nothing():
    from signsplat.render import _reference

    s = scene(N=250, W=40, H=36, C=2, seed=5)
    s = leafs(s)
    args = {k: s[k] for k in ("means", "quats", "scales", "opacities", "colors", "viewmats",
                              "Ks")}
    common = dict(width=40, height=36, near_plane=0.01, far_plane=1e10, eps2d=0.3,
                  sh_degree=None, backgrounds=None, render_mode="RGB",
                  rasterize_mode="classic", tile_size=16, absgrad=True)
    dense = _reference.rasterize(**args, **common)
    culled = _reference.rasterize(**args, **common, cull_blocks=True)
    torch.testing.assert_close(dense[0], culled[0], rtol=0, atol=1e-6)
    torch.testing.assert_close(dense[1], culled[1], rtol=0, atol=1e-6)
    g1 = torch.autograd.grad(dense[0].sum(), s["means"], retain_graph=True)[0]
    g2 = torch.autograd.grad(culled[0].sum(), s["means"])[0]
    torch.testing.assert_close(g1, g2, rtol=1e-5, atol=1e-6)
