"""Thread settings: torch and the Numba rasterizer get the thread count asked for."""

from __future__ import annotations

import subprocess
import sys


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
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
