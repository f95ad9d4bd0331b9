"""The fit's independent pieces of work on torch's thread count.

Why: the silhouette stage's matchings (the contour of each image, the flow term's vertices of
each view) are loops of small operations that use one core whatever torch's thread count; run
side by side in threads they use the cores the fit was given (docs/fit.md, "The fit on its two
threads").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch

T = TypeVar("T")
R = TypeVar("R")


def map_threads(fn: Callable[[T], R], items: Iterable[T]) -> list[R]:
    """``[fn(item) for item in items]``, in order: on a pool of ``torch.get_num_threads()``
    threads when that is more than one (torch, NumPy and SciPy's k-d trees release the GIL in
    their work), else in turn. The workers take the caller's grad mode (it is per thread); a
    worker's exception is raised here."""
    items = list(items)
    workers = min(torch.get_num_threads(), len(items))
    if workers <= 1:
        return [fn(item) for item in items]
    grad = torch.is_grad_enabled()

    def run(item: T) -> R:
        with torch.set_grad_enabled(grad):
            return fn(item)

    with ThreadPoolExecutor(workers) as pool:
        return list(pool.map(run, items))
