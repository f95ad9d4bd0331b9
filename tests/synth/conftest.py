"""Shared assets of the synth tests: the proxy body model and the gloss library (written once)."""

import pytest


@pytest.fixture(scope="session")
def gloss_library_path(tmp_path_factory):
    from signsplat.synth.glosses import write_gloss_library

    path = tmp_path_factory.mktemp("gloss_assets") / "glosses.parquet"
    write_gloss_library(path, seed=0, fps=25.0)
    return path


@pytest.fixture(scope="session")
def proxy_body_path(tmp_path_factory):
    from signsplat.body.proxy import write_proxy_model

    path = tmp_path_factory.mktemp("body_assets") / "body.npz"
    write_proxy_model(path, seed=0)
    return path


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
