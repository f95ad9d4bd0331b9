"""float64 ``torch.autograd.gradcheck`` of the CPU kernel on tiny scenes, every differentiable
input (means, quats, scales, opacities, colors / SH, viewmats, backgrounds)."""

from __future__ import annotations

import pytest
import torch
from raster_scenes import scene

from signsplat.render import rasterization


@pytest.mark.parametrize("mode,sh,aa,fast", [("RGB", None, False, False),
                                             ("RGB+D", 2, False, True),
                                             ("RGB+ED", 3, True, True),
                                             ("D", None, True, False)])
def test_gradcheck_cpu_float64(mode, sh, aa, fast):
    """Full Jacobians where cheap; gradcheck's fast mode (random projections u^T J v) for the
    SH cases, whose Jacobians have hundreds of columns."""
    s = scene(N=6, W=12, H=10, C=2, seed=21, dtype=torch.float64, sh_degree=sh,
              scale=(0.08, 0.2), opacity=(0.3, 0.9))
    C = 2
    bg = torch.rand(C, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(1))
    names = ["means", "quats", "scales", "opacities", "colors", "viewmats"]
    inputs = [s[k].clone().requires_grad_(True) for k in names]
    with_bg = mode not in ("D", "ED")
    if with_bg:
        inputs.append(bg.clone().requires_grad_(True))

    def f(*args):
        kw = dict(zip(names, args[:6]))
        out_c, out_a, _ = rasterization(
            **kw, Ks=s["Ks"], width=s["width"], height=s["height"], sh_degree=sh,
            backgrounds=args[6] if with_bg else None, render_mode=mode,
            rasterize_mode="antialiased" if aa else "classic", backend="cpu")
        return out_c, out_a

    out_c, out_a = f(*inputs)
    assert out_a.max() > 0.5  # the tiny scene is visible
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-3, fast_mode=fast)


def test_gradcheck_means2d_absgrad_consistent():
    """absgrad >= |grad| componentwise (it sums absolute per-pixel terms)."""
    s = scene(N=30, W=24, H=20, C=2, seed=22)
    leaves = {k: (v.clone().requires_grad_(True) if torch.is_tensor(v) and k == "means" else v)
              for k, v in s.items()}
    rc, ra, meta = rasterization(**leaves, absgrad=True, backend="cpu")
    meta["means2d"].retain_grad()
    (rc.sum() + 0.5 * ra.sum()).backward()
    g, a = meta["means2d"].grad, meta["means2d"].absgrad
    assert g.shape == a.shape == (2, 30, 2)
    assert (a + 1e-6 >= g.abs()).all()
    assert a.sum() > 0
