# Config validation and helpers shared by every rule. No science here.
import copy
import json
import os
import sys
from pathlib import Path

from signsplat.config import ConfigError, validate
from signsplat.plan import STAGE_THREADS, plan

# The config as the user gave it (files and --config), before the schema fills its defaults
# in: a section with named profiles (avatar) puts the profile under the user's own values
# only, not under defaults that would hide it.
USER_CONFIG = copy.deepcopy(config)
# The config's files (config/config.yaml and any --configfile), named in config errors.
CONFIG_FILES = " + ".join(map(str, workflow.configfiles)) or "config/config.yaml"
validate(config, "config.schema.yaml", CONFIG_FILES)

PY = sys.executable
RESULTS = config["results"]
# Every stage with a GPU path gets `--device {DEVICE}`; every stage `--threads {threads}`, its
# rule's own threads (the one place a thread count is set; a profile's set-threads changes it).
DEVICE = config["device"]
# What this run does (signsplat.plan): sequences, the default scene, avatar variants.
PLAN = plan(config, USER_CONFIG, source=CONFIG_FILES)
# --cores of a local run; None where jobs get allocations of their own (a cluster executor).
LOCAL_CORES = getattr(workflow.global_resources.get("_cores"), "value", None)


def job_threads(wildcards):
    """`threads` of the simulation (which gains little from a second thread) and the stages
    after the fit (avatar, evaluation, stitching): in a run of the default target the
    sequences share the local cores, so their scenes render and their avatars train side by
    side; a study's target (quality, sweep, ...) keeps STAGE_THREADS. (Called per job, once
    the run's targets are known.)"""
    return PLAN.job_threads(_shared_cores())


def chain_threads(wildcards):
    """`threads` of a sequence's keypoints and fit: in a run of the default target a
    single-view sequence's share the cores (signsplat.plan.Plan.chain_threads)."""
    return PLAN.chain_threads(wildcards.scene, _shared_cores())


def _shared_cores():
    """The local cores the run's sequences share: in a run of the default target only."""
    default_run = set(getattr(workflow.dag_settings, "targets", ())) <= {"all"}
    return LOCAL_CORES if default_run else None


# Job priorities: the stages up to the fit first, then avatar training and the stitched video
# (the longest job after an avatar), then the rest (evaluations, COLMAP, the report). With the
# avatars on shared cores, none starts while a two-thread stage before a fit can run, so a
# multi-view fit never waits behind a one-thread avatar for a free core; a single-view
# sequence's keypoints and fit (one thread, chain_threads) run beside an avatar.
BEFORE_AVATAR, AVATAR = 2, 1
# Snakemake starts the ready jobs whose priorities add up to the most (any of them on a tie),
# so a fit on several cores outranks any two one-core jobs before the avatars: the multi-view
# fit does not wait behind a single-view sequence's keypoints, fit and perception scores.
MULTICORE_FIT = 2 * BEFORE_AVATAR + 1


def fit_priority(wildcards):
    return MULTICORE_FIT if chain_threads(wildcards) > 1 else BEFORE_AVATAR


SEQUENCES = PLAN.sequences  # name -> sheet row (synthetic rows carry their scene spec)
SCENES = PLAN.scenes  # synthetic sequences: name -> validated scene spec
VIDEOS = PLAN.videos  # footage: name -> sheet row


def final_outputs(report=True):
    """What `rule all` asks for: every stage's outputs over the run's sequences (and the
    report, which takes all the others as its inputs)."""
    seqs = list(SEQUENCES)
    out = expand(rules.simulate.output.frames, scene=list(SCENES))
    out += expand(rules.extract_frames.output.frames, scene=list(VIDEOS))
    out += expand(rules.detect_keypoints.output.keypoints, scene=seqs)
    out += expand(rules.perception_eval.output[0], scene=list(SCENES))
    out += expand(rules.perception_quality.output.table, scene=list(VIDEOS))
    out += expand(rules.fit_smplx.output.eval, scene=seqs)
    out += expand(rules.colmap_compare.output.table, scene=PLAN.multiview_scenes)
    out += expand(AVATAR_EVAL_FILES, scene=seqs, variant=DEFAULT_VARIANTS)
    out += stitch_outputs()
    return out + [rules.report.output.html] if report else out


def as_json(obj):
    """Parameters passed to a stage on its command line (quoted with `:q` in shell)."""
    return json.dumps(obj, sort_keys=True)


def scene_spec(wildcards):
    return as_json(SCENES[wildcards.scene])


def input_dir(scene):
    """Folder holding a sequence's frames.parquet and images (simulated or extracted)."""
    return f"{RESULTS}/{scene}/sim" if scene in SCENES else f"{RESULTS}/{scene}/frames"


def frames_table(wildcards):
    return f"{input_dir(wildcards.scene)}/frames.parquet"


wildcard_constraints:
    scene="[A-Za-z0-9_-]+",
