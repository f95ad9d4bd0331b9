"""The gsplat-compatible API: shapes, meta, validation, backend choice, devices, caching."""

from __future__ import annotations

import os
import subprocess
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import torch
from raster_scenes import leafs, scene

import signsplat.render as R
from signsplat.render import rasterization, select_backend

ROOT = Path(__file__).resolve().parents[2]


def test_shapes_and_meta_like_gsplat():
    s = scene(N=120, W=33, H=21, C=3, seed=1)
    rc, ra, meta = rasterization(**s)
    assert rc.shape == (3, 21, 33, 3) and ra.shape == (3, 21, 33, 1)
    assert rc.dtype == ra.dtype == torch.float32
    for key, shape in (("radii", (3, 120, 2)), ("means2d", (3, 120, 2)), ("depths", (3, 120)),
                       ("conics", (3, 120, 3)), ("opacities", (3, 120))):
        assert tuple(meta[key].shape) == shape, key
    assert meta["radii"].dtype == torch.int32
    assert meta["width"] == 33 and meta["height"] == 21 and meta["n_cameras"] == 3
    assert meta["gaussian_ids"] is None and meta["camera_ids"] is None
    assert meta["backend"] == "cpu"
    assert meta["tile_width"] == 3 and meta["tile_height"] == 2
    assert meta["n_pairs"] > 0 and meta["n_isects"] > 0


@pytest.mark.parametrize("mode,channels", [("RGB", 3), ("D", 1), ("ED", 1), ("RGB+D", 4),
                                           ("RGB+ED", 4)])
def test_render_mode_channels(mode, channels):
    s = scene(N=80, W=20, H=16, C=2, seed=2)
    rc, ra, _ = rasterization(**s, render_mode=mode, backgrounds=torch.ones(2, 3))
    assert rc.shape == (2, 16, 20, channels)
    if mode in ("D", "ED"):  # backgrounds are ignored for depth-only modes (zero background)
        rc0, _, _ = rasterization(**s, render_mode=mode)
        assert torch.equal(rc, rc0)


def test_expected_depth_is_weighted_mean_depth():
    s = scene(N=80, W=20, H=16, C=1, seed=3)
    d, a, _ = rasterization(**s, render_mode="D")
    ed, _, meta = rasterization(**s, render_mode="ED")
    ok = a[..., 0] > 1e-3
    torch.testing.assert_close(ed[ok], (d / a.clamp_min(1e-10))[ok])
    vis = (meta["radii"] > 0).any(-1)
    dep = meta["depths"][vis]
    assert ed[ok].min() >= dep.min() - 1e-4 and ed[ok].max() <= dep.max() + 1e-4


def test_background_composited_with_transmittance():
    s = scene(N=60, W=20, H=16, C=1, seed=4)
    bg = torch.tensor([[0.2, 0.5, 0.9]])
    c0, a0, _ = rasterization(**s)
    c1, a1, _ = rasterization(**s, backgrounds=bg)
    torch.testing.assert_close(c1, c0 + (1 - a0) * bg[:, None, None, :])


def test_tile_size_does_not_change_the_image():
    s = scene(N=150, W=40, H=30, C=1, seed=5)
    outs = [rasterization(**s, tile_size=t)[0] for t in (8, 16, 32)]
    assert torch.equal(outs[0], outs[1]) and torch.equal(outs[1], outs[2])
    outs = [rasterization(**s, tile_size=t, backend="reference")[2]["tile_width"]
            for t in (8, 16)]
    assert outs == [5, 3]


def test_means2d_grad_and_absgrad_available():
    s = leafs(scene(N=50, W=24, H=20, C=2, seed=6))
    rc, ra, meta = rasterization(**s, absgrad=True)
    meta["means2d"].retain_grad()
    rc.sum().backward()
    assert meta["means2d"].grad.shape == (2, 50, 2)
    assert meta["means2d"].absgrad.shape == (2, 50, 2)
    culled = (meta["radii"] == 0).all(-1)
    assert (meta["means2d"].grad[culled] == 0).all()
    assert (meta["means2d"].absgrad[culled] == 0).all()


def test_no_absgrad_attribute_without_absgrad():
    s = leafs(scene(N=20, W=16, H=16, seed=7))
    rc, _, meta = rasterization(**s)
    rc.sum().backward()
    assert not hasattr(meta["means2d"], "absgrad")


def test_no_grad_mode_and_detached_inputs():
    s = scene(N=40, W=16, H=16, seed=8)
    with torch.no_grad():
        rc, ra, meta = rasterization(**s)
    assert not rc.requires_grad and rc.shape == (1, 16, 16, 3)


def test_dtype_of_other_inputs_follows_means():
    s = scene(N=40, W=16, H=16, seed=9)
    s2 = dict(s, quats=s["quats"].double(), Ks=s["Ks"].double())
    torch.testing.assert_close(rasterization(**s)[0], rasterization(**s2)[0])


def test_integer_like_and_float64_inputs():
    s = scene(N=40, W=16, H=16, seed=10, dtype=torch.float64)
    rc, ra, meta = rasterization(**s)
    assert rc.dtype == torch.float64 and meta["means2d"].dtype == torch.float64


@pytest.mark.parametrize("bad", [
    dict(render_mode="RGBD"), dict(rasterize_mode="fancy"), dict(backend="opengl"),
    dict(width=0), dict(sh_degree=4), dict(sh_degree=3), dict(tile_size=0),
])
def test_validation_errors(bad):
    s = scene(N=10, W=8, H=8, seed=11)
    if bad.get("sh_degree") == 3:  # SH degree 3 needs 16 coefficients; colors are [N, 3]
        s["colors"] = torch.zeros(10, 4, 3)
    s.update(bad)
    with pytest.raises(ValueError):
        rasterization(**s)


@pytest.mark.parametrize("key,shape", [("means", (10, 2)), ("quats", (10, 3)),
                                       ("scales", (9, 3)), ("opacities", (10, 1)),
                                       ("colors", (9, 3)), ("viewmats", (1, 3, 4)),
                                       ("Ks", (2, 3, 3))])
def test_shape_errors(key, shape):
    s = scene(N=10, W=8, H=8, seed=12)
    s[key] = torch.zeros(shape)
    with pytest.raises(ValueError):
        rasterization(**s)


def test_background_shape_error_and_half_precision():
    s = scene(N=10, W=8, H=8, seed=13)
    with pytest.raises(ValueError):
        rasterization(**s, backgrounds=torch.zeros(1, 4))
    s16 = {k: (v.half() if torch.is_tensor(v) else v) for k, v in s.items()}
    with pytest.raises(TypeError):
        rasterization(**s16)


def test_select_backend_rules():
    assert select_backend("auto", "cpu", gsplat_available=True) == "cpu"
    assert select_backend("auto", "cuda", gsplat_available=True) == "gsplat"
    assert select_backend("auto", "cuda", gsplat_available=False) == "cpu"
    assert select_backend("reference", "cuda", gsplat_available=True) == "reference"
    assert select_backend("cpu", "cuda", gsplat_available=True) == "cpu"
    with pytest.raises(ImportError):
        select_backend("gsplat", "cuda", gsplat_available=False)
    with pytest.raises(ValueError):
        select_backend("gsplat", "cpu", gsplat_available=True)
    with pytest.raises(ValueError):
        select_backend("vulkan", "cpu")


def test_gsplat_backend_call_is_forwarded(monkeypatch):
    """The gsplat backend passes our arguments through (packed=False) and tags meta."""
    calls = {}

    def fake_rasterization(*args, **kwargs):
        calls["args"], calls["kwargs"] = args, kwargs
        C, H, W = args[5].shape[0], args[8], args[7]
        return torch.zeros(C, H, W, 3), torch.zeros(C, H, W, 1), {"radii": None}

    monkeypatch.setitem(sys.modules, "gsplat", types.SimpleNamespace(
        rasterization=fake_rasterization))
    from signsplat.render import _gsplat

    s = scene(N=5, W=8, H=6, C=2, seed=14)
    rc, ra, meta = _gsplat.rasterize(
        *(s[k] for k in ("means", "quats", "scales", "opacities", "colors", "viewmats", "Ks")),
        width=8, height=6, near_plane=0.01, far_plane=1e10, eps2d=0.3, sh_degree=None,
        backgrounds=None, render_mode="RGB+D", rasterize_mode="antialiased", tile_size=16,
        absgrad=True)
    assert calls["kwargs"]["packed"] is False and calls["kwargs"]["absgrad"] is True
    assert calls["kwargs"]["render_mode"] == "RGB+D"
    assert calls["kwargs"]["rasterize_mode"] == "antialiased"
    assert meta["backend"] == "gsplat" and meta["n_cameras"] == 2
    assert rc.shape == (2, 6, 8, 3)


def test_gsplat_backend_on_cpu_tensors_is_refused():
    s = scene(N=5, W=8, H=6, seed=15)
    with pytest.raises((ValueError, ImportError)):
        rasterization(**s, backend="gsplat")


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_tensors():  # pragma: no cover - no GPU in CI
    s = {k: (v.cuda() if torch.is_tensor(v) else v) for k, v in scene(N=50, W=16, H=16).items()}
    rc, ra, meta = rasterization(**s)
    assert rc.device.type == "cuda"
    ref, _, _ = rasterization(**s, backend="reference")
    torch.testing.assert_close(rc, ref, atol=1e-4, rtol=0)


def test_exp_kernel_accuracy():
    from signsplat.render import _kernels as K

    s = np.linspace(0, 79, 200001).astype(np.float32)
    out = np.empty_like(s)
    K.exp_neg_array(s, out)
    ref = np.exp(-s.astype(np.float64))
    assert (np.abs(out - ref) / ref).max() < 2.5 * 2.0 ** -24


def test_numba_cache_directory_is_writable():
    from signsplat import numba_cache
    from signsplat.render import _kernels

    assert _kernels.CACHE_DIR is not None and _kernels.CACHE_DIR.is_dir()
    assert numba_cache._FILES[Path(_kernels.__file__).resolve()] == _kernels.CACHE_DIR


def test_numba_cache_fallback_when_nothing_preferred_is_writable(tmp_path, monkeypatch):
    from signsplat import numba_cache

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    monkeypatch.setattr(numba_cache, "_candidate_roots",
                        lambda: [ro / "cache", tmp_path / "fallback"])
    try:
        chosen = numba_cache._choose_dir("0123abcd")
    finally:
        ro.chmod(0o700)
    assert chosen is not None and str(chosen).startswith(str(tmp_path / "fallback")) \
        or chosen is not None and str(chosen).startswith(str(ro))  # root may write anyway


def test_registered_kernel_files_are_cached_by_content_outside_the_checkout(tmp_path):
    """A kernel module of another package that calls ``cache_kernels_of`` (as the avatar's and
    the mesh renderer's do) is cached under the per-user cache in a directory named by its
    content: a fresh clone of the same code finds it, an edited file gets a new one. In fresh
    processes with the cache home and the module in temporary folders."""
    mod = tmp_path / "pkg_kernels.py"
    body = ("from numba import njit\n"
            "from signsplat.numba_cache import cache_kernels_of, _FILES\n"
            "cache_kernels_of(__file__)\n"
            "@njit(cache=True)\n"
            "def twice(x):\n"
            "    return {} * x\n")
    run = ("import pkg_kernels, pathlib\n"
           "assert pkg_kernels.twice(3) == {}\n"
           "print(pkg_kernels._FILES[pathlib.Path(pkg_kernels.__file__).resolve()])\n")
    env = {**os.environ, "XDG_CACHE_HOME": str(tmp_path / "home"),
           "PYTHONPATH": os.pathsep.join([str(tmp_path), str(ROOT)])}
    env.pop("NUMBA_CACHE_DIR", None)
    dirs = []
    for factor in (2, 2, 3):
        mod.write_text(body.format(factor))
        res = subprocess.run([sys.executable, "-c", run.format(3 * factor)], env=env,
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr[-2000:]
        dirs.append(Path(res.stdout.strip()))
    assert dirs[0] == dirs[1] != dirs[2]
    assert all(d.parent == tmp_path / "home" / "signsplat" / "numba" for d in dirs)
    assert list(dirs[0].glob("pkg_kernels.twice-*.nbi")), list(dirs[0].iterdir())
    assert list(dirs[2].glob("pkg_kernels.twice-*.nbi"))
    assert not (tmp_path / "__pycache__").exists() or \
        not list((tmp_path / "__pycache__").glob("*.nbi"))  # not beside the source


def test_package_exports():
    assert callable(R.rasterization)
    assert R.BACKENDS == ("auto", "cpu", "reference", "gsplat")
    assert "EWA" in R.__doc__ and "1/255" in R.__doc__


def _cpu_grads(s: dict, threads: int) -> dict:
    import numba

    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        leaf = leafs(s, keys=("means", "quats", "scales", "opacities", "colors"))
        rc, ra, meta = rasterization(**leaf, backgrounds=torch.ones(s["viewmats"].shape[0], 3),
                                     backend="cpu", absgrad=True)
        w = torch.linspace(-1, 1, rc.numel()).reshape(rc.shape)
        ((rc * w).sum() + ra.sum()).backward()
    finally:
        numba.set_num_threads(before)
    out = {k: leaf[k].grad for k in ("means", "quats", "scales", "opacities", "colors")}
    out["absgrad"] = meta["means2d"].absgrad
    return out


def test_cpu_gradients_are_the_same_for_any_thread_count_and_run():
    # The backward's sums per Gaussian must not depend on which thread took which tile: large
    # Gaussians spanning many tiles, two cameras, repeated runs on two threads and one on one.
    import numba

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("Numba has one thread here (NUMBA_NUM_THREADS=1): nothing to compare")
    s = scene(N=600, W=96, H=80, C=2, seed=7, scale=(0.05, 0.2))
    one = _cpu_grads(s, 1)
    for _ in range(3):
        two = _cpu_grads(s, 2)
        for k in one:
            assert torch.equal(one[k], two[k]), k


@pytest.mark.parametrize("threads", [2, 3, 8])
def test_tile_schedule_gives_every_thread_an_equal_share_of_the_work(threads):
    # Numba's OpenMP layer hands each thread one contiguous block of the tile loop; the old
    # heaviest-first order gave the first thread all the heavy tiles (no speed-up on two).
    from signsplat.render._cpu import tile_schedule

    costs = np.random.default_rng(3).integers(0, 100, 257)
    order = tile_schedule(costs, threads)
    assert order.dtype == np.int64 and sorted(order.tolist()) == list(range(len(costs)))
    loads = [costs[block].sum() for block in np.array_split(order, threads)]
    assert max(loads) - min(loads) <= costs.max(), loads
    assert tile_schedule(costs, 1).tolist() == np.argsort(-costs, kind="stable").tolist()
