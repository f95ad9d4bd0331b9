"""Config loading: defaults filled in, invalid values fail with key, value and what is allowed."""

import pytest
import yaml

from signsplat.config import ConfigError, REPO_ROOT, load_config, load_scene, validate


def test_default_config_is_valid_and_complete():
    cfg = load_config(REPO_ROOT / "config" / "config.yaml")
    assert cfg["scenes"], "the embedded default must name scenes"
    assert cfg["body_model"]["num_betas"] == 10
    for name in cfg["scenes"]:
        scene = load_scene(REPO_ROOT / "config" / "scenes" / f"{name}.yaml")
        assert scene["name"] == name
        assert scene["cameras"]["count"] >= 1


def test_defaults_are_filled_in():
    cfg = validate({}, "config.schema.yaml")
    assert cfg["device"] == "auto"
    assert cfg["body_model"]["path"] is None  # nested defaults through $ref


@pytest.mark.parametrize(
    "bad, key, fragment",
    [
        ({"device": "tpu"}, "device", "'auto', 'cpu', 'cuda'"),
        ({"body_model": {"num_betas": 0}}, "body_model.num_betas", ">= 1"),
        ({"scenes": ["bad name!"]}, "scenes.0", "pattern"),
        ({"body_model": {"colour": 1}}, "body_model", "known keys"),
    ],
)
def test_invalid_config_names_key_value_and_allowed(tmp_path, bad, key, fragment):
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(bad))
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert str(path) in msg and f"'{key}'" in msg and fragment in msg


def test_unparsable_and_missing_files(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "broken.yaml"
    bad.write_text("scenes: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(bad)


def test_scene_needs_cameras_and_motion(tmp_path):
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump({"cameras": {"count": 2}}))
    with pytest.raises(ConfigError, match="'motion' is a required property"):
        load_scene(path)
