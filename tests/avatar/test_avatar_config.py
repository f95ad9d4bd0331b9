"""The avatar config: the schema is the one copy of the defaults, profiles override them."""

import pytest

from signsplat.avatar.config import PROFILES, avatar_config, resolve, to_dict
from signsplat.config import ConfigError


@pytest.mark.parametrize("profile", sorted(PROFILES))
def test_dataclasses_hold_exactly_the_schema_keys(profile):
    # a schema key without a dataclass field would be dropped silently, and a field without a
    # schema default would have no value: both directions are checked by the round trip
    resolved = resolve({"profile": profile})
    assert to_dict(avatar_config({"profile": profile})) == resolved


def test_profile_sits_under_the_users_values():
    cfg = avatar_config({"profile": "quality", "train": {"iterations": 10}})
    assert cfg.train.iterations == 10  # the user's value
    assert cfg.strategy.max_points == PROFILES["quality"]["strategy"]["max_points"]
    assert cfg.strategy.refine_stop == PROFILES["quality"]["strategy"]["refine_stop"]
    assert avatar_config({"profile": "quality"}).train.iterations == \
        PROFILES["quality"]["train"]["iterations"]
    demo = avatar_config({})
    assert demo.strategy.max_points != cfg.strategy.max_points
    assert demo.train.iterations != PROFILES["quality"]["train"]["iterations"]


def test_lists_become_tuples_and_parts_dataclasses():
    cfg = avatar_config({"train": {"background": [0, 0, 0]}})
    assert cfg.train.background == (0, 0, 0)
    assert isinstance(cfg.model.init_color, tuple)
    assert cfg.model.scale_max.hands < cfg.model.scale_max.body


def test_a_bad_key_is_named():
    with pytest.raises(ConfigError, match="regularise"):
        avatar_config({"regularise": {"enabled": False}})
