# Config validation and helpers shared by every rule. No science here.
import json
import sys
from pathlib import Path

from signsplat.config import load_scene, validate

validate(config, "config.schema.yaml", "config/config.yaml")

PY = sys.executable
RESULTS = config["results"]
SCENES = {name: load_scene(f"config/scenes/{name}.yaml") for name in config["scenes"]}

# Stages append the files `rule all` asks for; the Snakefile's `rule all` reads them.
FINAL_OUTPUTS = []


def final_outputs():
    return FINAL_OUTPUTS


def as_json(obj):
    """Parameters passed to a stage on its command line (quoted with `:q` in shell)."""
    return json.dumps(obj, sort_keys=True)


def scene_spec(wildcards):
    return as_json(SCENES[wildcards.scene])


wildcard_constraints:
    scene="[A-Za-z0-9_-]+",
