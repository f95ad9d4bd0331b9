"""Synthetic sequence sheets: N signers x M sentences as scene specs plus a ``sequences.tsv``
(the workflow's sequence sheet) that lists them, for dataset-sized batch runs.

A signer is a body shape (betas drawn from N(0, betas_sigma^2)), an appearance seed and an
expression scale; a sentence is a gloss sequence drawn from the gloss library's signs, the
same for every signer (as in a corpus where each signer signs the same sentences). Every
sequence has its own seed and a camera count between ``cameras[0]`` and ``cameras[1]``: the
counts are dealt in turn and shuffled, so every count occurs once there are as many sequences
as counts. Specs are a base scene with these fields replaced, each validated against
``workflow/schemas/scene.schema.yaml`` and its effects checked before anything is written.
"""

from __future__ import annotations

import copy
import os
from pathlib import Path

import numpy as np
import yaml

from signsplat.config import validate
from signsplat.errors import InputError
from signsplat.io.atomic import atomic_path
from signsplat.synth.glosses import all_signs
from signsplat.synth.scene import check_scene


def sign_glosses() -> list[str]:
    """Gloss names of the library's signs (its fingerspelled letters left out)."""
    return [s.gloss for s in all_signs() if s.kind == "sign"]


def synth_sequences(signers: int, sentences: int, base: dict, *, seed: int,
                    glosses: tuple[int, int], cameras: tuple[int, int],
                    betas_sigma: float, num_betas: int) -> dict[str, dict]:
    """``{name: scene spec}`` for ``signers`` x ``sentences`` sequences named
    ``sig<i>_sen<j>``: ``base`` with signer, motion glosses, camera count and seed replaced.
    ``glosses`` and ``cameras`` are inclusive (min, max) ranges."""
    if signers < 1 or sentences < 1:
        raise InputError(f"--signers {signers} / --sentences {sentences}: both must be >= 1")
    lo, hi = cameras
    if not 1 <= lo <= hi:
        raise InputError(f"--cameras {lo} {hi}: need 1 <= min <= max")
    g_lo, g_hi = glosses
    vocab = sign_glosses()
    if not 1 <= g_lo <= g_hi <= len(vocab):
        raise InputError(f"--glosses {g_lo} {g_hi}: need 1 <= min <= max <= {len(vocab)} "
                         f"(signs in the gloss library)")
    rng = np.random.default_rng(seed)
    people = [{"betas": [round(float(b), 4) for b in rng.normal(0.0, betas_sigma, num_betas)],
               "appearance_seed": int(rng.integers(0, 2**31)),
               "expression_scale": round(float(rng.uniform(0.6, 1.4)), 3)}
              for _ in range(signers)]
    lines = [[str(g) for g in rng.choice(vocab, size=int(rng.integers(g_lo, g_hi + 1)),
                                         replace=False)]
             for _ in range(sentences)]
    n = signers * sentences
    counts = lo + np.arange(n) % (hi - lo + 1)
    rng.shuffle(counts)
    wi, wj = len(str(signers - 1)), len(str(sentences - 1))
    base_seed = int(base.get("seed", 0))
    out = {}
    for k, (i, j) in enumerate((i, j) for i in range(signers) for j in range(sentences)):
        spec = copy.deepcopy(base)
        spec.pop("name", None)
        spec["seed"] = base_seed + k
        spec["signer"] = dict(people[i])
        spec["motion"] = {**spec.get("motion", {}), "glosses": lines[j]}
        spec["cameras"] = {**spec.get("cameras", {}), "count": int(counts[k])}
        out[f"sig{i:0{max(wi, 2)}d}_sen{j:0{max(wj, 2)}d}"] = spec
    for name, spec in out.items():
        check_scene(validate(copy.deepcopy(spec), "scene.schema.yaml", f"sequence {name}"), name)
    return out


def write_sheet(specs: dict[str, dict], out_dir: str | os.PathLike) -> Path:
    """Write ``out_dir/scenes/<name>.yaml`` for each spec and ``out_dir/sequences.tsv`` (spec
    paths absolute, so the sheet works from any working directory); returns the sheet."""
    out_dir = Path(out_dir).resolve()
    rows = ["sequence\tsource\tspec"]
    for name, spec in specs.items():
        path = out_dir / "scenes" / f"{name}.yaml"
        with atomic_path(path) as tmp:
            tmp.write_text(yaml.safe_dump(spec, sort_keys=False))
        rows.append(f"{name}\tsynthetic\t{path}")
    sheet = out_dir / "sequences.tsv"
    with atomic_path(sheet) as tmp:
        tmp.write_text("\n".join(rows) + "\n")
    return sheet
