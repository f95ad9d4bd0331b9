"""The detector training set: varied synthetic scenes, simulated into folders.

The shipped detectors (:mod:`signsplat.perception.train`) learn from these folders; they take
them as inputs and never call the simulator themselves.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from signsplat.config import validate
from signsplat.motion.clips import load_gloss_library
from signsplat.synth.scene import even_azimuths, framing_fov


CAMERA_SPACES = ("studio", "wide")


def _studio_cameras(rng: np.random.Generator, ring: bool) -> dict:
    """2-3 cameras around the simulator's framing (upper body, 30 degrees at 2 m), 256 px;
    ``ring``: evenly on a full ring instead of an arc."""
    return {"count": int(rng.integers(2, 4)),
            "layout": "ring" if ring else "arc",
            "arc_degrees": round(float(rng.uniform(30, 170)), 1),
            "distance": round(float(rng.uniform(1.75, 2.3)), 3),
            "height": round(float(rng.uniform(1.25, 1.45)), 3),
            "target": [round(float(rng.uniform(-0.05, 0.05)), 3),
                       round(float(rng.uniform(1.25, 1.4)), 3), 0.0],
            "width": 256,
            "height_px": 256,
            "fov_degrees": round(float(rng.uniform(26, 36)), 1)}


def _wide_cameras(rng: np.random.Generator) -> dict:
    """2-4 cameras anywhere a studio puts them: arcs of 30-240 degrees around any heading and
    30 % full rings (views from the side and behind), unevenly spaced; 1.5-4 m; camera
    heights 1.05-1.85 m looking at 1.2-1.4 m; the image height covering 0.9-1.8 m of the
    signer; images of 144-320 px on either side, square or not."""
    count = int(rng.integers(2, 5))
    base, gap = even_azimuths(count, 360.0 if rng.random() < 0.3 else float(rng.uniform(30, 240)))
    azimuths = base + rng.uniform(-40, 40) + rng.uniform(-0.3, 0.3, count) * gap
    distance = float(rng.uniform(1.5, 4.0))
    framing = float(rng.uniform(0.9, 1.8))
    sides = rng.choice([144, 160, 192, 208, 240, 256, 320], size=2)
    return {"count": count,
            "distance": round(distance, 3),
            "height": round(float(rng.uniform(1.05, 1.85)), 3),
            "target": [round(float(rng.uniform(-0.05, 0.05)), 3),
                       round(float(rng.uniform(1.2, 1.4)), 3), 0.0],
            "width": int(sides[0]),
            "height_px": int(sides[1]),
            "fov_degrees": round(framing_fov(framing, distance), 2),
            "views": [{"azimuth_degrees": round(float((a + 180) % 360 - 180), 2)}
                      for a in azimuths]}


def training_scene_specs(count: int, seed: int, glosses: list[str],
                         letters: list[str] | tuple = (), cameras: str = "studio") -> list[dict]:
    """``count`` scene specs (scene schema) drawn from a seeded generator.

    Seeds, signer shapes and appearance seeds start at 1000 (the evaluation scenes in
    config/scenes use small seeds and their own appearance seeds; the ``wide`` set starts at
    3000). ``cameras`` is the camera space: ``studio`` varies count, arc, distance, height,
    target and field of view around the simulator's framing; ``wide`` covers the rigs of the
    generalisation suite's kind (see :func:`_wide_cameras`). Signs are mixed with
    fingerspelled letters (about half the scenes spell 2-4 ``letters`` between signs, for the
    many hand shapes); lighting (direction, ambient, intensity, colour), background, sensor
    noise, motion blur, occluders and camera jitter are drawn from the simulator's effect
    registry.
    """
    if cameras not in CAMERA_SPACES:
        raise ValueError(f"camera space {cameras!r}: allowed values are {list(CAMERA_SPACES)}")
    wide = cameras == "wide"
    rng = np.random.default_rng(10_000 + seed + (77 if wide else 0))
    first = 3000 if wide else 1000
    specs = []
    for i in range(count):
        n_gloss = int(rng.integers(2, 5))
        chosen = [str(g) for g in rng.choice(glosses, size=min(n_gloss, len(glosses)),
                                             replace=False)]
        if letters and rng.random() < 0.5:
            spelled = [str(c) for c in rng.choice(list(letters), size=int(rng.integers(2, 5)))]
            at = int(rng.integers(0, len(chosen) + 1))
            chosen = chosen[:at] + spelled + chosen[at:]
        ring = not wide and rng.random() < 0.1  # drawn here: the studio specs stay as they were
        light = {"direction": [round(float(v), 3) for v in
                               (rng.uniform(-0.8, 0.8), rng.uniform(0.0, 1.0),
                                rng.uniform(0.4, 1.0))],
                 "ambient": round(float(rng.uniform(0.2, 0.5)), 3),
                 "intensity": round(float(rng.uniform(0.5, 1.0)), 3),
                 "color": [round(float(v), 3) for v in rng.uniform(0.85, 1.15, 3)]}
        effects: list = [{"lighting": light}]
        if rng.random() < 0.5:
            effects.append({"background": {"kind": "solid",
                                           "color": [round(float(c), 3)
                                                     for c in rng.uniform(0.05, 0.95, 3)]}})
        else:
            effects.append({"background": {"kind": "textured", "seed": int(first + i)}})
        if rng.random() < 0.6:
            effects.append({"sensor_noise": {"sigma": round(float(rng.uniform(0.003, 0.03)), 4)}})
        for name, p in (("motion_blur", 0.3), ("occluder", 0.25), ("camera_jitter", 0.3)):
            if rng.random() < p:
                effects.append(name)
        specs.append({
            "name": f"{'wide' if wide else 'train'}{i:03d}",
            "seed": int(first + i),
            "fps": 25,
            "max_frames": 50,
            "cameras": _wide_cameras(rng) if wide else _studio_cameras(rng, ring),
            "signer": {
                "betas": [round(float(b), 3) for b in rng.normal(0, 0.8, 10)],
                "appearance_seed": int(first + i),
                "expression_scale": round(float(rng.uniform(0.5, 1.5)), 2),
            },
            "motion": {"glosses": chosen, "hold_frames": int(rng.integers(0, 4))},
            "effects": effects,
        })
    return specs


def simulate_training_set(count: int, seed: int, body: str | os.PathLike,
                          glosses: str | os.PathLike, out_dir: str | os.PathLike,
                          threads: int = 1, progress: bool = True,
                          cameras: str = "studio") -> list[Path]:
    """Simulate (or reuse) the ``count`` training scenes of camera space ``cameras`` (see
    :func:`training_scene_specs`) into ``out_dir/<name>/sim``.

    A folder whose ``spec.json`` equals its spec and whose ground truth exists is kept, so a
    resumed run simulates only what is missing. Returns the ``sim`` folders in spec order.
    """
    from signsplat.synth.simulate import simulate_scene

    library = load_gloss_library(glosses)
    names = sorted(g for g, clip in library.items() if clip.kind != "letter")
    letters = sorted(g for g, clip in library.items() if clip.kind == "letter")
    out = []
    for spec in training_scene_specs(count, seed, names, letters, cameras):
        sim = Path(out_dir) / spec["name"] / "sim"
        spec_file = sim / "spec.json"
        text = json.dumps(spec, sort_keys=True)
        done = (sim / "keypoints_gt.parquet").exists() and spec_file.exists() \
            and spec_file.read_text() == text
        if not done:
            if sim.exists():
                shutil.rmtree(sim)
            validate(spec, "scene.schema.yaml", spec["name"])
            simulate_scene(spec, body, glosses, sim, threads, progress=progress)
            spec_file.write_text(text)
        out.append(sim)
    return out
