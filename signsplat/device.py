"""Device selection, done once per stage and passed down (no `.cuda()` elsewhere)."""

from __future__ import annotations

import torch

from signsplat.errors import SignSplatError


def select_device(name: str = "auto") -> torch.device:
    """Return the torch device for ``name`` in {"auto", "cpu", "cuda", "cuda:N"}.

    ``auto`` picks CUDA when torch sees a GPU, else the CPU. Asking for CUDA on a machine
    without it is an error rather than a silent fall-back.
    """
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise SignSplatError(f"device {name!r} requested but torch sees no CUDA device; "
                             "allowed here: 'auto' or 'cpu'")
    if name != "cpu" and not name.startswith("cuda"):
        raise SignSplatError(f"unknown device {name!r}; allowed: 'auto', 'cpu', 'cuda[:N]'")
    return torch.device(name)
