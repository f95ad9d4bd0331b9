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
