"""SMPL-X parameters: the ``smplx_params`` table (list columns, one row per frame) <-> tensors.

Blocks and their sizes are those of :data:`signsplat.body.joints.PARAM_BLOCKS` except
``betas`` and ``expression``, whose length is taken from the data (the default is 10).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd
import torch
from torch import Tensor

from signsplat.body.joints import PARAM_BLOCKS
from signsplat.errors import InputError

BLOCK_SIZES = dict(PARAM_BLOCKS)
VARIABLE_SIZE = ("betas", "expression")


def params_from_table(df: pd.DataFrame, dtype: torch.dtype = torch.float32,
                      device: torch.device | str | None = None) -> dict[str, Tensor]:
    """Rows of a ``smplx_params`` table (one scene) -> {block: (T, k) tensor}, by frame order.

    Rows are sorted by ``frame``; every block column must hold lists of one length (the
    fixed blocks: the sizes of ``PARAM_BLOCKS``). The ``frame`` numbers are returned under
    the key ``'frame'`` as a (T,) long tensor. Raises :class:`InputError` naming the column.
    """
    if "frame" in df.columns:
        df = df.sort_values("frame", kind="stable")
    out: dict[str, Tensor] = {}
    for name, size in PARAM_BLOCKS:
        if name not in df.columns:
            raise InputError(f"smplx_params table lacks column '{name}'")
        try:
            arr = np.stack([np.asarray(v, dtype=np.float32) for v in df[name]]) if len(df) else \
                np.zeros((0, size), np.float32)
        except ValueError as exc:
            raise InputError(f"smplx_params column '{name}' holds lists of different "
                             f"lengths ({exc})") from exc
        if arr.ndim != 2 or (name not in VARIABLE_SIZE and arr.shape[1] != size):
            raise InputError(f"smplx_params column '{name}' has shape {arr.shape}, "
                             f"expected (T, {size})")
        out[name] = torch.as_tensor(arr, dtype=dtype, device=device)
    if "frame" in df.columns:
        out["frame"] = torch.as_tensor(df["frame"].to_numpy(np.int64), device=device)
    return out


def params_to_table(params: dict[str, Tensor | np.ndarray], scene: str,
                    frames: Sequence[int] | np.ndarray | Tensor | None = None) -> pd.DataFrame:
    """{block: (T, k)} -> ``smplx_params`` rows (columns scene, frame, blocks as float32 lists).

    Missing blocks are written as zeros; ``betas`` of shape (1, S) or (S,) are repeated for
    every frame. ``frames`` defaults to 0..T-1. Extra keys (e.g. 'frame') are ignored.
    """
    def as_np(v) -> np.ndarray:
        if isinstance(v, Tensor):
            v = v.detach().cpu().numpy()
        return np.asarray(v, dtype=np.float32)

    arrays = {k: as_np(v) for k, v in params.items() if k in BLOCK_SIZES}
    T = None
    for k, v in arrays.items():
        if v.ndim == 2 and not (k == "betas" and v.shape[0] == 1):
            T = v.shape[0] if T is None else T
            if v.shape[0] != T:
                raise ValueError(f"block '{k}' has {v.shape[0]} frames, others have {T}")
    if T is None:
        T = len(frames) if frames is not None else 1
    if frames is None:
        frames = np.arange(T)
    if isinstance(frames, Tensor):
        frames = frames.detach().cpu().numpy()
    frames = np.asarray(frames, dtype=np.int64)
    if len(frames) != T:
        raise ValueError(f"{len(frames)} frame numbers for {T} frames")
    data: dict[str, list] = {"scene": [scene] * T, "frame": np.asarray(frames, np.int32)}
    for name, size in PARAM_BLOCKS:
        v = arrays.get(name)
        if v is None:
            v = np.zeros((T, size), np.float32)
        v = v.reshape(-1, v.shape[-1]) if v.ndim else v.reshape(1, 1)
        if v.shape[0] == 1 and T != 1:
            v = np.repeat(v, T, axis=0)
        if name not in VARIABLE_SIZE and v.shape[1] != size:
            raise ValueError(f"block '{name}' has {v.shape[1]} values per frame, expected {size}")
        data[name] = [row for row in v]
    return pd.DataFrame(data)
