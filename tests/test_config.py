"""Config loading: defaults filled in, invalid values fail with key, value and what is allowed."""

import pytest
import yaml

from signsplat.config import REPO_ROOT, ConfigError, load_config, load_scene, validate


def test_default_config_is_valid_and_complete():
    from signsplat.config import load_sequences

    cfg = load_config(REPO_ROOT / "config" / "config.yaml")
    assert cfg["body_model"]["num_betas"] == 10
    seqs = load_sequences(cfg, REPO_ROOT)
    # the embedded default: a 6-view studio scene and a single-view scene
    assert sorted(row["num_views"] for row in seqs.values()) == [1, 6]
    for name, row in seqs.items():
        assert row["scene"]["name"] == name


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


def _sheet(tmp_path, text):
    path = tmp_path / "seq.tsv"
    path.write_text(text.replace("|", "\t"))
    return {"sequences": str(path), "scenes": []}


def test_sequence_sheet_rows(tmp_path):
    from signsplat.config import load_sequences

    cfg = _sheet(tmp_path, "sequence|source|spec|cameras|fps\n"
                 f"s6|synthetic|{REPO_ROOT}/config/scenes/studio6.yaml||\n"
                 "clip|video||a.mp4;b.mp4;c.mp4|30\n")
    seqs = load_sequences(cfg)
    assert seqs["s6"]["num_views"] == 6 and seqs["s6"]["scene"]["name"] == "s6"
    assert seqs["clip"]["num_views"] == 3 and seqs["clip"]["fps"] == 30.0


@pytest.mark.parametrize("body, fragment", [
    ("x|video||", "key 'cameras': value None is not allowed; must be type string"),
    ("x|webcam||a.mp4", "'synthetic', 'video'"),
    ("x|video|||abc", "key 'fps': value 'abc' is not a float"),
])
def test_sequence_sheet_errors_name_the_line(tmp_path, body, fragment):
    from signsplat.config import load_sequences

    cfg = _sheet(tmp_path, "sequence|source|spec|cameras|fps\n" + body + "\n")
    with pytest.raises(ConfigError) as err:
        load_sequences(cfg)
    assert "seq.tsv: line 2" in str(err.value) and fragment in str(err.value)


def test_sequence_listed_twice(tmp_path):
    from signsplat.config import load_sequences

    cfg = _sheet(tmp_path, "sequence|source|cameras\nx|video|a.mp4\nx|video|b.mp4\n")
    with pytest.raises(ConfigError, match="line 3: sequence 'x' is listed twice"):
        load_sequences(cfg)
