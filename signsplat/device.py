"""Device selection, done once per stage and passed down (no `.cuda()` elsewhere)."""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING

from signsplat.errors import SignSplatError

if TYPE_CHECKING:
    import torch

# torch is imported inside the functions: the stages without it (segmentation, keypoints,
# COLMAP, the report) use this module for their options and need not pay torch's import time.


def select_device(name: str = "auto") -> torch.device:
    """Return the torch device for ``name`` in {"auto", "cpu", "cuda", "cuda:N"}.

    ``auto`` picks CUDA when torch sees a GPU, else the CPU. Asking for CUDA on a machine
    without it is an error rather than a silent fall-back.
    """
    import torch

    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise SignSplatError(f"device {name!r} requested but torch sees no CUDA device; "
                             "allowed here: 'auto' or 'cpu'")
    if name != "cpu" and not name.startswith("cuda"):
        raise SignSplatError(f"unknown device {name!r}; allowed: 'auto', 'cpu', 'cuda[:N]'")
    return torch.device(name)


def add_runtime_args(parser, gpu: bool = True) -> None:
    """The options every stage command shares: ``--threads`` (the workflow passes its rule's
    ``threads``, the one place a thread count is set) and, for a stage with a GPU path,
    ``--device`` (the config's ``device``)."""
    parser.add_argument("--threads", type=int, default=1,
                        help="CPU threads of torch, Numba and onnxruntime (default 1)")
    if gpu:
        parser.add_argument("--device", default="auto",
                            help="auto (CUDA when torch sees it), cpu, cuda or cuda:N")


def use_runtime(args) -> torch.device:
    """Apply ``--threads`` and return the device of ``--device`` (the CPU without one)."""
    set_threads(args.threads)
    return select_device(getattr(args, "device", "cpu"))


def set_threads(n: int) -> None:
    """Use ``n`` threads in torch and in the Numba rasterizer (two spinning pools on shared
    cores are much slower than one each).

    Numba first: with the OpenMP threading layer, Numba's ``set_num_threads`` launches its pool,
    which sets the process-wide OpenMP thread count to ``NUMBA_NUM_THREADS`` and so undid an
    earlier ``torch.set_num_threads`` (torch then ran every op on all cores while asked for one;
    on a core shared with another job each op waited for the descheduled thread).
    """
    import torch

    n = max(1, int(n))
    try:
        import numba

        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    except (ImportError, ValueError):
        pass
    torch.set_num_threads(n)


def make_deterministic() -> None:
    """Ask torch for its deterministic kernels (process-wide; only a warning where an op has
    none). On the CPU the one that matters to the avatar is the backward of gathering vertices
    with repeated indices (``v[:, anchors]``): by default it accumulates with atomic adds from
    several threads, so two runs of the same seed differed in the last bits of the SMPL-X
    gradients, and after 800 steps by 0.2 dB of training PSNR. With this (and the rasterizer's
    backward, deterministic by construction) two 2-thread trainings of the demo wrote identical
    checkpoints after 300 steps (docs/avatar.md, "Reproducibility", which also records one
    earlier probe that parted at step 12 and was not seen again)."""
    import torch

    # torch.use_deterministic_algorithms also imports torch._inductor (more than a second per
    # process) only to set the compiler's flag; nothing here compiles, so that flag is set
    # only where the compiler is already loaded.
    torch._C._set_deterministic_algorithms(True, warn_only=True)
    inductor = sys.modules.get("torch._inductor.config")
    if inductor is not None:
        inductor.deterministic = True
