# Config validation and helpers shared by every rule. No science here.
import copy
import json
import os
import sys
from pathlib import Path

from signsplat.config import load_sequences, validate

# The config as the user gave it (files and --config), before the schema fills its defaults
# in: a section with named profiles (avatar) puts the profile under the user's own values
# only, not under defaults that would hide it.
USER_CONFIG = copy.deepcopy(config)
validate(config, "config.schema.yaml", "config/config.yaml")

PY = sys.executable
# GNU OpenMP's default spin-wait makes torch's and Numba's thread pools fight over the cores
# (2 threads ran 2-3x slower than 1 on a 2-core machine); short spins for every stage.
os.environ.setdefault("GOMP_SPINCOUNT", "10000")
RESULTS = config["results"]
# Every sequence of the run (sheet rows + config `scenes`): name -> row (see load_sequences).
SEQUENCES = load_sequences(config)
# Synthetic sequences: name -> validated scene spec.
SCENES = {name: row["scene"] for name, row in SEQUENCES.items() if row["source"] == "synthetic"}
VIDEOS = {name: row for name, row in SEQUENCES.items() if row["source"] == "video"}

# Stages append the files `rule all` asks for; the Snakefile's `rule all` reads them.
FINAL_OUTPUTS = []


def final_outputs():
    return FINAL_OUTPUTS


def as_json(obj):
    """Parameters passed to a stage on its command line (quoted with `:q` in shell)."""
    return json.dumps(obj, sort_keys=True)


def scene_spec(wildcards):
    return as_json(SCENES[wildcards.scene])


def num_views(scene):
    return SEQUENCES[scene]["num_views"]


def input_dir(scene):
    """Folder holding a sequence's frames.parquet and images (simulated or extracted)."""
    return f"{RESULTS}/{scene}/sim" if scene in SCENES else f"{RESULTS}/{scene}/frames"


def frames_table(wildcards):
    return f"{input_dir(wildcards.scene)}/frames.parquet"


wildcard_constraints:
    scene="[A-Za-z0-9_-]+",
