"""Configuration: YAML files validated against JSON schemas, passed around as plain data.

There is no global configuration object. The workflow loads ``config/config.yaml`` once,
validates it (defaults filled in from the schema) and hands each stage the section it needs.
An invalid file fails at once with the key, the bad value and what is allowed.

Schemas live in ``workflow/schemas``; a schema may ``$ref`` a sibling file by relative path
(``stages/avatar.schema.yaml``), so each stage owns the schema of its own section.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import os
from pathlib import Path
from typing import Any

import yaml
from jsonschema import Draft202012Validator, validators
from referencing import Registry, Resource
from referencing.jsonschema import DRAFT202012 as _SPEC

from signsplat.errors import InputError, SignSplatError

REPO_ROOT = Path(__file__).resolve().parent.parent
SCHEMA_DIR = REPO_ROOT / "workflow" / "schemas"


class ConfigError(SignSplatError, ValueError):
    """A configuration file does not match its schema."""


# libyaml's loader when PyYAML has it: ~10x faster than the pure-Python one (a sheet of 1,000
# sequences loads 1,000 scene files while Snakemake parses the workflow)
_YAML_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _load_yaml(path: Path) -> Any:
    try:
        with open(path) as fh:
            return yaml.load(fh, Loader=_YAML_LOADER)  # noqa: S506 (a safe loader)
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from None


@functools.lru_cache(maxsize=1)
def _registry() -> Registry:
    """All schema files, read once per process (validation runs many times at parse time)."""
    resources = []
    for file in SCHEMA_DIR.rglob("*.schema.yaml"):
        uri = file.relative_to(SCHEMA_DIR).as_posix()
        contents = _load_yaml(file)
        # Without "$schema", jsonschema keeps our default-filling validator class when it
        # follows a $ref (with it, it would switch to the stock class of that dialect).
        contents.pop("$schema", None)
        resources.append((uri, Resource.from_contents(contents, default_specification=_SPEC)))
    return Registry().with_resources(resources)


def _with_defaults(validator_class):
    """A validator that also fills in ``default`` values of object properties."""
    validate_properties = validator_class.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, schema):
        if isinstance(instance, dict):
            for name, sub in properties.items():
                if isinstance(sub, dict) and "default" in sub and name not in instance:
                    instance[name] = copy.deepcopy(sub["default"])
        yield from validate_properties(validator, properties, instance, schema)

    return validators.extend(validator_class, {"properties": set_defaults})


_Validator = _with_defaults(Draft202012Validator)


def _describe(error) -> str:
    key = ".".join(str(p) for p in error.absolute_path) or "<top level>"
    v, val = error.validator, error.validator_value
    if v == "enum":
        allowed = "one of " + ", ".join(repr(x) for x in val)
    elif v == "type":
        allowed = f"type {val}"
    elif v in ("minimum", "exclusiveMinimum"):
        allowed = f"{'>=' if v == 'minimum' else '>'} {val}"
    elif v in ("maximum", "exclusiveMaximum"):
        allowed = f"{'<=' if v == 'maximum' else '<'} {val}"
    elif v == "additionalProperties":
        allowed = "known keys: " + ", ".join(sorted(error.schema.get("properties", {})))
        return f"key '{key}': {error.message}; {allowed}"
    elif v == "required":
        return f"key '{key}': {error.message}"
    else:
        allowed = f"{v} {val!r}"
    return f"key '{key}': value {error.instance!r} is not allowed; must be {allowed}"


def deep_merge(base: dict, over: dict) -> dict:
    """``over`` applied on a copy of ``base``; nested dicts are merged key by key."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def validate(data: Any, schema_name: str, source: str | os.PathLike = "<config>") -> Any:
    """Validate ``data`` against ``workflow/schemas/<schema_name>``; fill defaults in place.

    ``schema_name`` may name a part of a schema file with a JSON pointer, e.g.
    ``stages/fit.schema.yaml#/$defs/stage``. Raises :class:`ConfigError` naming the source,
    key, bad value and what is allowed.
    """
    registry = _registry()
    schema = {"$ref": schema_name} if "#" in schema_name else registry.contents(schema_name)
    validator = _Validator(schema, registry=registry)
    errors = sorted(validator.iter_errors(data), key=lambda e: list(e.absolute_path))
    if errors:
        # report the most specific error of each branch (anyOf/oneOf produce context errors)
        lines = []
        for err in errors:
            best = err
            while best.context:
                best = min(best.context, key=lambda e: -len(e.absolute_path))
            lines.append(_describe(best if best.absolute_path else err))
        raise ConfigError(f"{source}: " + "; ".join(dict.fromkeys(lines)))
    return data


def json_option(text: str | None, option: str = "--config-json") -> Any:
    """The value of a command-line JSON option (None or empty: ``{}``); an
    :class:`~signsplat.errors.InputError` naming the option when it is not JSON."""
    if not text:
        return {}
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{option}: not valid JSON ({exc})") from None


def config_option(text: str | None, schema_name: str, option: str = "--config-json") -> Any:
    """A config section given on the command line as JSON, validated against
    ``schema_name`` (defaults filled in); errors name ``option``."""
    return validate(json_option(text, option), schema_name, option)


def schema_defaults(schema_name: str, *keys: str) -> Any:
    """What a schema fills into an empty section: ``validate({}, schema_name)``, then the value
    at ``keys`` (e.g. ``schema_defaults("stages/perception.schema.yaml", "train")``)."""
    data = validate({}, schema_name, schema_name)
    for key in keys:
        data = data[key]
    return data


def default_mismatches(cls: type, defaults: dict, rename: dict[str, str] | None = None) -> list[str]:
    """Fields of dataclass ``cls`` whose own default differs from the schema's.

    ``defaults`` is the schema-filled section (:func:`schema_defaults`); ``rename`` maps a
    field name to its config key where they differ. A field without a default, or whose key
    the section lacks, carries no second copy and is not compared; lists equal tuples.
    Returns one line per difference, ``Class.field: code X, schema Y``.
    """
    rename = rename or {}

    def plain(v):
        return [plain(x) for x in v] if isinstance(v, (list, tuple)) else v

    out = []
    for f in dataclasses.fields(cls):
        key = rename.get(f.name, f.name)
        if key not in defaults:
            continue
        if f.default is not dataclasses.MISSING:
            code = f.default
        elif f.default_factory is not dataclasses.MISSING:
            code = f.default_factory()
        else:
            continue
        if plain(code) != plain(defaults[key]):
            out.append(f"{cls.__name__}.{f.name}: code {code!r}, schema {defaults[key]!r}")
    return out


def assert_defaults_match(cls: type, section: dict, rename: dict[str, str] | None = None) -> None:
    """Raise AssertionError listing :func:`default_mismatches` (for tests)."""
    bad = default_mismatches(cls, section, rename)
    assert not bad, "; ".join(bad)


def load_config(path: str | os.PathLike) -> dict:
    """Load and validate the main workflow config (``config/config.yaml``)."""
    path = Path(path)
    data = _load_yaml(path) or {}
    return validate(data, "config.schema.yaml", path)


def load_scene(path: str | os.PathLike) -> dict:
    """Load and validate a scene spec (``config/scenes/<name>.yaml``)."""
    path = Path(path)
    data = _load_yaml(path) or {}
    scene = validate(data, "scene.schema.yaml", path)
    scene.setdefault("name", path.stem)
    return scene


_SHEET_NUMBERS = {"fps": float, "start": int, "end": int}


def load_sequences(config: dict, root: str | os.PathLike = ".") -> dict[str, dict]:
    """The sequences a workflow run covers: the sheet's rows plus ``config['scenes']``.

    Returns ``{name: row}`` where ``row`` has the sheet's columns (empty cells as None) and,
    for synthetic sequences, ``scene`` (the validated scene spec); ``num_views`` is the number
    of cameras. Errors name the sheet, the row, the key and what is allowed.
    """
    import pandas as pd

    root = Path(root)
    rows: list[tuple[str, dict]] = []
    sheet = config.get("sequences")
    if sheet:
        path = root / sheet
        if not path.is_file():
            raise ConfigError(f"{path}: sequence sheet not found (config key 'sequences')")
        table = pd.read_csv(path, sep="\t", dtype=str, keep_default_na=False, comment="#")
        for i, rec in enumerate(table.to_dict("records"), start=2):  # line 1 is the header
            row = {k: (v.strip() or None) for k, v in rec.items()}
            for key, cast in _SHEET_NUMBERS.items():
                if row.get(key) is not None:
                    try:
                        row[key] = cast(row[key])
                    except ValueError:
                        raise ConfigError(f"{path}: line {i}: key '{key}': value {row[key]!r} "
                                          f"is not a {cast.__name__}") from None
            rows.append((f"{path}: line {i}", row))
    for name in config.get("scenes", []):
        rows.append(("config key 'scenes'", {"sequence": name, "source": "synthetic"}))

    sequences: dict[str, dict] = {}
    for where, row in rows:
        validate(row, "sequences.schema.yaml", where)
        name = row["sequence"]
        if name in sequences:
            raise ConfigError(f"{where}: sequence {name!r} is listed twice")
        if row["source"] == "synthetic":
            spec_path = root / (row["spec"] or f"config/scenes/{name}.yaml")
            row["scene"] = load_scene(spec_path)
            row["scene"]["name"] = name
            row["num_views"] = row["scene"]["cameras"]["count"]
        else:
            row["num_views"] = len([c for c in row["cameras"].split(";") if c.strip()])
        sequences[name] = row
    if not sequences:
        raise ConfigError("no sequences to run: the sheet is empty and config key 'scenes' "
                          "is []")
    return sequences
