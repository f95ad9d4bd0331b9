"""Thread settings: torch and the Numba rasterizer get the thread count asked for."""

from __future__ import annotations

import subprocess
import sys


def _in_a_fresh_process(code: str) -> None:
    """Run ``code`` in a new interpreter (thread pools and torch's flags are process-wide)."""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600, check=False)
    assert res.returncode == 0, res.stdout + res.stderr[-2000:]


def test_set_threads_holds_for_torch_after_numba_starts_its_pool():
    """In a fresh process (the pools are process-wide): numba's pool launch must not undo the
    torch setting, and rendering with the Numba kernel must not either."""
    code = (
        "import torch, numba\n"
        "from signsplat.device import set_threads\n"
        "from signsplat.render import rasterization\n"
        "set_threads(1)\n"
        "assert (torch.get_num_threads(), numba.get_num_threads()) == (1, 1), "
        "(torch.get_num_threads(), numba.get_num_threads())\n"
        "n = 20\n"
        "g = torch.Generator().manual_seed(0)\n"
        "means = torch.randn(n, 3, generator=g) * 0.2 + torch.tensor([0, 0, 3.0])\n"
        "quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)\n"
        "K = torch.tensor([[[50.0, 0, 32], [0, 50.0, 32], [0, 0, 1]]])\n"
        "rasterization(means, quats, torch.full((n, 3), 0.05), torch.full((n,), 0.8),\n"
        "              torch.rand(n, 3, generator=g), torch.eye(4)[None], K, 64, 64)\n"
        "assert torch.get_num_threads() == 1, torch.get_num_threads()\n"
        "set_threads(2)\n"
        "assert torch.get_num_threads() == 2\n"
    )
    _in_a_fresh_process(code)


def test_make_deterministic_makes_the_avatars_vertex_gather_backward_reproducible():
    """The avatar gathers each point's anchor vertices with repeated indices; on several
    threads the backward of that gather accumulates with atomic adds and differs run to run.
    In a fresh process (the setting is global): first without :func:`make_deterministic`,
    repeated backwards must part (else this check could not see the fault it guards against),
    then with it 20 repeats must agree bit for bit. Four threads, more than the cores of a
    small machine, so the threads' interleaving varies even when other work keeps a core busy
    (with two threads on a loaded 2-core machine, 200 repeats could agree)."""
    code = (
        "import torch\n"
        "from signsplat.device import make_deterministic, set_threads\n"
        "set_threads(4)\n"
        "g = torch.Generator().manual_seed(0)\n"
        "v = torch.randn(3, 10475, 3, generator=g)\n"
        "anchors = torch.randint(0, 10475, (60000, 3), generator=g)\n"
        "w = torch.randn(3, 60000, 3, 3, generator=g)\n"
        "def grad():\n"
        "    x = v.clone().requires_grad_(True)\n"
        "    (x[:, anchors] * w).sum().backward()\n"
        "    return x.grad\n"
        "ref = grad()\n"
        "tries = next((i + 1 for i in range(200) if not torch.equal(ref, grad())), None)\n"
        "print('parted after', tries)\n"
        "assert tries is not None, 'without make_deterministic 200 repeats agreed'\n"
        "make_deterministic()\n"
        "assert torch.are_deterministic_algorithms_enabled()\n"
        "ref = grad()\n"
        "assert all(torch.equal(ref, grad()) for _ in range(20))\n"
    )
    _in_a_fresh_process(code)


def test_stages_without_torch_do_not_import_it_and_determinism_skips_the_compiler():
    """Every rule's process pays for what it imports (torch and its compiler take seconds):
    the segmentation, keypoint, COLMAP and report commands import no torch through the
    shared device options, and
    :func:`make_deterministic` sets torch's flag, warn-only, without loading torch's compiler."""
    code = (
        "import sys\n"
        "import signsplat.perception.cli, signsplat.colmap.cli, signsplat.report.cli\n"
        "assert 'torch' not in sys.modules, 'torch imported by a stage that does not use it'\n"
        "import torch\n"
        "from signsplat.device import make_deterministic\n"
        "make_deterministic()\n"
        "assert torch.are_deterministic_algorithms_enabled()\n"
        "assert torch.is_deterministic_algorithms_warn_only_enabled()\n"
        "assert 'torch._inductor' not in sys.modules, 'make_deterministic loaded the compiler'\n"
    )
    _in_a_fresh_process(code)
