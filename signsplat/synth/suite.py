"""A generalisation suite of synthetic scenes, generated from a small grid (issue 29).

Real studios differ in camera count, arc, spacing, distance, height, tilt, focal length, image
size, clip length, signer and image effects. :func:`generate_suite` turns a grid (a YAML file,
``config/scenes/suite/grid.yaml``) into one scene spec per design row:

- ``rigs``: camera count, arc (degrees) and spacing (``even``, or ``uneven``: azimuths, and
  each camera's distance and height, jittered by the grid's ``uneven`` amounts);
- ``distance`` (m), ``framing`` (the vertical extent in metres the image covers at the signer,
  which with the distance sets the focal length), ``height`` (camera height, look height: the
  tilt), ``image`` ([width, height] px), ``clip`` (frames), ``betas`` (bodies) and ``effects``
  (lists of effect entries; a scene declares only those it uses).

Every axis value is used about equally often: axis ``a`` takes its values in the order of
seeded random permutations, one after the other (a Latin-hypercube-like design), so ``scenes``
rows cover each axis and mix the combinations. ``cases`` adds named rows with fixed values (the
hard cases: a camera behind the signer, two cameras at a small baseline, a view with the
signer half out of frame). Each scene is validated against ``scene.schema.yaml``.
"""

from __future__ import annotations

import argparse
import copy
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from signsplat.config import validate
from signsplat.io.atomic import write_bytes_atomic
from signsplat.synth.scene import check_scene, even_azimuths, framing_fov

#: the design's axes, in the order their permutations are drawn
AXES = ("rig", "distance", "framing", "height", "image", "clip", "betas", "effects",
        "glosses")


def _permuted(values: list, n: int, rng: np.random.Generator) -> list:
    """``n`` values, each of ``values`` about n / len(values) times, in random order."""
    out: list = []
    while len(out) < n:
        out += [values[i] for i in rng.permutation(len(values))]
    return out[:n]


def _azimuths(count: int, arc: float, spacing: str, uneven: float,
              rng: np.random.Generator) -> list[float]:
    """Camera azimuths (degrees): evenly over ``arc`` (a full ring when arc >= 360), or with
    each inner camera moved by up to ``uneven`` of the even gap (ends stay)."""
    az, gap = even_azimuths(count, arc)
    inner = np.arange(1, count) if arc >= 360 else np.arange(1, count - 1)
    az = az.astype(float)
    if spacing == "uneven" and len(inner):
        az[inner] += rng.uniform(-uneven, uneven, len(inner)) * gap
    return [round(float(a), 2) for a in az]


def scene_from_row(row: dict[str, Any], grid: dict[str, Any], seed: int) -> dict[str, Any]:
    """One scene spec (before validation) from a design row (one value per axis)."""
    rng = np.random.default_rng(seed)
    rig = row["rig"]
    count, arc, spacing = int(rig["count"]), float(rig["arc"]), rig.get("spacing", "even")
    dist = float(row["distance"])
    cam_h, look_h = (float(x) for x in row["height"])
    width, height = (int(x) for x in row["image"])
    framing = float(row["framing"])
    fov = framing_fov(framing, dist)
    un = grid.get("uneven", {})
    views = []
    for i, az in enumerate(_azimuths(count, arc, spacing, float(un.get("azimuth", 0.3)), rng)):
        v: dict[str, Any] = {"azimuth_degrees": az}
        if spacing == "uneven":
            v["distance"] = round(dist * (1 + rng.uniform(-1, 1) * float(un.get("distance", 0.1))),
                                  3)
            v["height"] = round(cam_h + rng.uniform(-1, 1) * float(un.get("height", 0.1)), 3)
        views.append(v)
    for i, over in (rig.get("views") or {}).items():  # per-camera overrides of a hard case
        views[int(i)].update(over)
    look = [0.0, look_h, 0.0]
    scene = {
        "seed": int(seed % 100000),
        "fps": 25,
        "max_frames": int(row["clip"]),
        "cameras": {"count": count, "distance": dist, "height": cam_h, "target": look,
                    "width": width, "height_px": height, "fov_degrees": round(fov, 3),
                    "views": views},
        "signer": {"betas": [float(b) for b in row["betas"]],
                   "appearance_seed": int(rng.integers(0, 1000))},
        "motion": {"glosses": list(row["glosses"]), "hold_frames": 2},
        "effects": copy.deepcopy(row["effects"]),
    }
    return scene


def generate_suite(grid: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Scene specs of the grid, ``{name: spec}`` (see the module docstring): each spec holds
    only what the grid sets (the schema fills the rest when it is loaded) and has been
    validated."""
    seed = int(grid.get("seed", 0))
    n = int(grid["scenes"])
    axes = grid["axes"]
    missing = [a for a in AXES if a not in axes]
    if missing:
        raise ValueError(f"grid: axes {missing} missing; the grid needs {list(AXES)}")
    rng = np.random.default_rng(seed)
    columns = {a: _permuted(list(axes[a]), n, rng) for a in AXES}
    rows = [(f"g{i:02d}", {a: columns[a][i] for a in AXES}) for i in range(n)]
    for case in grid.get("cases", []):
        row = {a: case.get(a, axes[a][0]) for a in AXES}
        rows.append((str(case["name"]), row))
    out = {}
    for i, (name, row) in enumerate(rows):
        spec = scene_from_row(row, grid, seed * 1000 + i)
        check = validate(copy.deepcopy(spec), "scene.schema.yaml", f"suite scene {name}")
        check_scene(check, f"suite scene {name}")
        out[name] = {"name": name, **spec}
    return out


def describe(spec: dict[str, Any]) -> str:
    """A one-line summary of a suite scene (for the YAML header and the tables)."""
    c = spec["cameras"]
    az = [v["azimuth_degrees"] for v in c["views"]]
    eff = [e if isinstance(e, str) else next(iter(e)) for e in spec["effects"]]
    return (f"{c['count']} cameras at azimuths {az} deg, {c['distance']} m, height "
            f"{c['height']} m looking at {c['target'][1]} m, fov {c['fov_degrees']:.1f} deg, "
            f"{c['width']}x{c['height_px']} px, {spec['max_frames']} frames, effects "
            f"{', '.join(eff) or 'none'}")


def write_suite(scenes: dict[str, dict[str, Any]], out_dir: str | os.PathLike,
                source: str) -> list[Path]:
    """Write ``<name>.yaml`` per scene and ``sequences.tsv`` (a sequence sheet for the
    workflow) into ``out_dir``; scenes of an earlier run no longer in the grid are removed."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("*.yaml"):
        if old.stem not in scenes and old.name != Path(source).name:
            old.unlink()
    paths = []
    lines = ["sequence\tsource\tspec\tcameras\tcalibration\tfps\tstart\tend\tresize"]
    for name, spec in scenes.items():
        body = {k: v for k, v in spec.items() if k != "name"}
        text = (f"# Generated by `signsplat suite-scenes` from {source}; do not edit.\n"
                f"# {describe(spec)}\n"
                + yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=100))
        path = out / f"{name}.yaml"
        write_bytes_atomic(path, text.encode())
        paths.append(path)
        lines.append(f"{name}\tsynthetic\t{path.as_posix()}\t\t\t\t\t\t")
    write_bytes_atomic(out / "sequences.tsv", ("\n".join(lines) + "\n").encode())
    return paths


def suite_scenes(argv: list[str]) -> int:
    """``signsplat suite-scenes``: write the suite's scene YAMLs from a grid file."""
    p = argparse.ArgumentParser(prog="signsplat suite-scenes",
                                description="write the generalisation suite's scenes")
    p.add_argument("--grid", default="config/scenes/suite/grid.yaml")
    p.add_argument("--out", default="config/scenes/suite")
    p.add_argument("--only", nargs="*", help="write only these scene names")
    args = p.parse_args(argv)
    from signsplat.errors import InputError

    try:
        grid = yaml.safe_load(Path(args.grid).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"{args.grid}: cannot read the grid ({exc})") from None
    scenes = generate_suite(grid)
    if args.only:
        unknown = sorted(set(args.only) - set(scenes))
        if unknown:
            raise InputError(f"--only: no scene(s) {unknown} in {args.grid}; known "
                             f"{sorted(scenes)}")
        scenes = {k: v for k, v in scenes.items() if k in args.only}
    paths = write_suite(scenes, args.out, args.grid)
    for name, spec in scenes.items():
        print(f"{name}: {describe(spec)}")
    print(f"{len(paths)} scenes in {args.out}")
    return 0
