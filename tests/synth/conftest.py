"""Fixtures of the synth tests (the proxy body and the gloss library are in tests/conftest.py)."""

import pytest


@pytest.fixture
def spy_effects(monkeypatch):
    """Replace every registered effect by a subclass counting constructions and hook calls.

    Returns ``{name: {"init": n, "calls": n}}``, updated as the simulation runs.
    """
    from signsplat.synth import effects as fx

    counts = {}
    for name, cls in list(fx.REGISTRY.items()):
        counts[name] = {"init": 0, "calls": 0}

        def make(cls=cls, c=counts[name]):
            def __init__(self, *a, **k):
                c["init"] += 1
                cls.__init__(self, *a, **k)

            def hook(self, *a, **k):
                c["calls"] += 1
                return getattr(cls, cls.hook)(self, *a, **k)

            return type("Spy" + cls.__name__, (cls,), {"__init__": __init__, cls.hook: hook})

        monkeypatch.setitem(fx.REGISTRY, name, make())
    return counts
