"""One home per default: every dataclass that mirrors a config section has the schema's
defaults (or none of its own). A field whose code default differs fails with both values."""

from __future__ import annotations

import dataclasses

import pytest

from signsplat.config import default_mismatches, schema_defaults

# (dataclass "module:Class", schema file, keys of its section in the schema, field -> config key)
MIRRORS = [
    ("signsplat.perception.contracts:SegmenterSpec", "stages/perception.schema.yaml",
     ("segmenter",), {"path": "model"}),
    ("signsplat.perception.contracts:KeypointSpec", "stages/perception.schema.yaml",
     ("keypoints",), {"path": "model"}),
    ("signsplat.avatar.strategy:MeshDensifyStrategy", "stages/avatar.schema.yaml",
     ("strategy",), {}),
    ("signsplat.motion.stitching:StitchConfig", "stages/stitch.schema.yaml", (), {}),
    ("signsplat.colmap.run:ColmapOptions", "stages/colmap.schema.yaml", (), {}),
]


def _load(path: str):
    import importlib

    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


@pytest.mark.parametrize("path, schema, keys, rename", MIRRORS, ids=[m[0] for m in MIRRORS])
def test_code_defaults_equal_the_schema(path, schema, keys, rename):
    cls = _load(path)
    defaults = schema_defaults(schema, *keys)
    compared = [f.name for f in dataclasses.fields(cls) if rename.get(f.name, f.name) in defaults]
    assert compared, f"{path} shares no field with the schema section {keys}"
    assert default_mismatches(cls, defaults, rename) == []


@pytest.mark.parametrize("path", ["signsplat.perception.train:TrainConfig",
                                  "signsplat.colmap.compare:CompareConfig",
                                  "signsplat.avatar.config:TrainConfig"])
def test_config_only_dataclasses_carry_no_defaults(path):
    """These are built from their validated section only (from_dict / avatar_config)."""
    cls = _load(path)
    assert [f.name for f in dataclasses.fields(cls) if f.default is not dataclasses.MISSING
            or f.default_factory is not dataclasses.MISSING] == []


def test_a_drifted_default_is_reported_with_both_values():
    @dataclasses.dataclass
    class Knobs:
        model: str = "a.onnx"
        steps: int = 5
        size: tuple = (2, 3)
        only_in_code: int = 1
        required: float = dataclasses.field(default=0.0)

    defaults = {"model": "a.onnx", "steps": 6, "size": [2, 3], "required": 0.0}
    assert default_mismatches(Knobs, defaults) == ["Knobs.steps: code 5, schema 6"]
