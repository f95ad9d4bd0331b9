"""The fit's thread pool (signsplat.fit.pool)."""

import pytest
import torch

from signsplat.fit.pool import map_threads


def test_map_threads_keeps_the_order_the_grad_mode_and_the_errors(torch_threads):
    import threading

    torch_threads(2)

    seen = set()

    def work(i):
        seen.add(threading.get_ident())
        x = torch.ones(3, requires_grad=True)
        return i * 10, (x * 2).requires_grad

    out = map_threads(work, range(40))
    assert [o[0] for o in out] == [10 * i for i in range(40)]
    assert all(o[1] for o in out)
    with torch.no_grad():  # a worker computes as its caller does (grad mode is per thread)
        assert not any(o[1] for o in map_threads(work, range(8)))
    assert threading.get_ident() not in seen  # the pool's threads did the work

    def fails(i):
        if i == 3:
            raise ValueError("item 3")
        return i

    with pytest.raises(ValueError, match="item 3"):
        map_threads(fails, range(6))
    assert map_threads(fails, []) == []


def test_map_threads_runs_in_turn_on_one_thread(torch_threads):
    import threading

    torch_threads(1)
    assert map_threads(lambda i: threading.get_ident(), range(4)) == [threading.get_ident()] * 4
