"""Commands of the synthetic-data stages: ``signsplat simulate`` and ``signsplat gloss-library``."""

from __future__ import annotations

import argparse

from signsplat.config import config_option
from signsplat.device import add_runtime_args
from signsplat.errors import InputError


def _simulator_parser(prog: str, description: str, glosses_required: bool):
    """The options of the simulating commands: the body, the gloss library, threads."""
    parser = argparse.ArgumentParser(prog=f"signsplat {prog}", description=description)
    parser.add_argument("--body", required=True, help="body model .npz (SMPL-X layout)")
    parser.add_argument("--glosses", required=glosses_required, default=None,
                        help="gloss library Parquet")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bars")
    add_runtime_args(parser, gpu=False)
    return parser


def simulate(argv: list[str]) -> int:
    """``signsplat simulate --scene-json JSON --body NPZ --glosses PARQUET --out DIR``."""
    parser = _simulator_parser("simulate", "Render a synthetic signer scene.", False)
    parser.add_argument("--scene-json", required=True, help="scene spec (validated) as JSON")
    parser.add_argument("--out", required=True, help="output folder (results/<scene>/sim)")
    args = parser.parse_args(argv)

    from signsplat.synth.simulate import simulate_scene

    scene = config_option(args.scene_json, "scene.schema.yaml", "--scene-json")
    summary = simulate_scene(scene, args.body, args.glosses, args.out, threads=args.threads,
                             progress=not args.no_progress)
    print(f"simulated scene '{summary['scene']}': {summary['views']} view(s) x "
          f"{summary['frames']} frame(s) in {summary['seconds']:.1f} s "
          f"(posing {summary['pose_seconds']:.1f} s); "
          f"{1000 * summary['per_view_frame']:.1f} ms per frame per view "
          f"(render {1000 * summary['render_seconds'] / max(summary['images'], 1):.1f} ms)")
    return 0


def gloss_library(argv: list[str]) -> int:
    """``signsplat gloss-library --config-json JSON --out PARQUET``."""
    parser = argparse.ArgumentParser(prog="signsplat gloss-library",
                                     description="Write the synthetic gloss library.")
    parser.add_argument("--config-json", default="{}",
                        help="the gloss_library config section as JSON")
    parser.add_argument("--out", required=True, help="output Parquet path")
    args = parser.parse_args(argv)

    from signsplat.synth.glosses import write_gloss_library

    cfg = config_option(args.config_json, "stages/gloss_library.schema.yaml")
    write_gloss_library(args.out, seed=int(cfg["seed"]), fps=float(cfg["fps"]))
    print(f"wrote gloss library {args.out}")
    return 0


def sheet(argv: list[str]) -> int:
    """``signsplat sheet synth --signers N --sentences M --out DIR [...]``: a sequence sheet of
    N x M synthetic sequences (signsplat.synth.sheet)."""
    parser = argparse.ArgumentParser(
        prog="signsplat sheet synth",
        description="Write DIR/sequences.tsv and DIR/scenes/*.yaml: N signers (body shape, "
                    "appearance) x M sentences (gloss sequences), camera counts from --cameras; "
                    "run it with `snakemake --config sequences=DIR/sequences.tsv scenes=[]`.")
    parser.add_argument("kind", choices=["synth"], help="the kind of sheet (synthetic)")
    parser.add_argument("--signers", type=int, required=True)
    parser.add_argument("--sentences", type=int, required=True)
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--base", default="config/scenes/tiny.yaml",
                        help="scene YAML whose other settings every sequence takes")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--glosses", type=int, nargs=2, default=[1, 3], metavar=("MIN", "MAX"),
                        help="glosses per sentence")
    parser.add_argument("--cameras", type=int, nargs=2, default=[1, 6], metavar=("MIN", "MAX"),
                        help="cameras per sequence")
    parser.add_argument("--betas-sigma", type=float, default=1.0,
                        help="standard deviation of the body-shape coefficients")
    parser.add_argument("--num-betas", type=int, default=10)
    parser.add_argument("--frames", type=int, default=None,
                        help="max_frames of every sequence (default: the base scene's)")
    parser.add_argument("--size", type=int, default=None,
                        help="image width and height (default: the base scene's)")
    args = parser.parse_args(argv)

    import yaml

    from signsplat.synth.sheet import synth_sequences, write_sheet

    try:
        base = yaml.safe_load(open(args.base, encoding="utf-8")) or {}
    except OSError as exc:
        raise InputError(f"--base {args.base}: {exc.strerror}") from None
    if args.frames is not None:
        base["max_frames"] = args.frames
    if args.size is not None:
        base["cameras"] = {**base.get("cameras", {}), "width": args.size,
                           "height_px": args.size}
    specs = synth_sequences(args.signers, args.sentences, base, seed=args.seed,
                            glosses=tuple(args.glosses), cameras=tuple(args.cameras),
                            betas_sigma=args.betas_sigma, num_betas=args.num_betas)
    path = write_sheet(specs, args.out)
    counts = sorted({s["cameras"]["count"] for s in specs.values()})
    print(f"wrote {path}: {len(specs)} sequences ({args.signers} signers x {args.sentences} "
          f"sentences), camera counts {counts}")
    return 0


def simulate_training_set(argv: list[str]) -> int:
    """``signsplat simulate-training-set --count N --seed S --body NPZ --glosses PARQUET
    --out-dir DIR``: the detector training scenes, one ``DIR/<name>/sim`` folder each."""
    from signsplat.synth.training_set import CAMERA_SPACES, simulate_training_set as run

    parser = _simulator_parser("simulate-training-set", "Simulate the detector training scenes.",
                               True)
    parser.add_argument("--count", type=int, required=True, help="number of scenes")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene specs")
    parser.add_argument("--out-dir", required=True, help="folder for the scene folders")
    parser.add_argument("--cameras", choices=CAMERA_SPACES, default="studio",
                        help="camera space: studio (the simulator's framing, 256 px) or wide "
                             "(any rig: 1.5-4 m, rings, small and non-square images)")
    args = parser.parse_args(argv)
    if args.count < 2:
        parser.error(f"--count must be >= 2 (training and held-out scenes), got {args.count}")

    dirs = run(args.count, args.seed, args.body, args.glosses, args.out_dir, args.threads,
               progress=not args.no_progress, cameras=args.cameras)
    print(f"{len(dirs)} training scenes in {args.out_dir}")
    return 0
