import pytest

from signsplat.synth.glosses import build_gloss_library, clips_from_table


@pytest.fixture(scope="session")
def gloss_library():
    """The synthetic library (built once per test session)."""
    return clips_from_table(build_gloss_library(seed=0, fps=25.0))
