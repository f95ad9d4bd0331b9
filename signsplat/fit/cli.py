"""``signsplat fit``: SMPL-X fitting of one scene (a thin wrapper over
:func:`signsplat.fit.run.fit_scene`, whose docstring lists the inputs and outputs)."""

from __future__ import annotations

import argparse
import functools
import logging
from pathlib import Path

from signsplat.config import config_option


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="signsplat fit", description=__doc__.split("\n")[0])
    p.add_argument("--config-json", default="{}",
                   help="the 'fit' config section as JSON (its 'keypoints' names the source)")
    p.add_argument("--keypoints", required=True, help="keypoints table (Parquet)")
    p.add_argument("--calibration",
                   help="cameras table: image sizes (+ intrinsics if calibrated; R, t only with "
                   "camera_init calibrated). Without it, sizes come from --frames and "
                   "intrinsics are approximate")
    p.add_argument("--body", required=True, help="body model .npz")
    p.add_argument("--frames", help="frames table (timestamps; images for overlays and flow)")
    p.add_argument("--masks", help="person masks (perception masks table, or a frames table "
                   "with masks) for the multi-view stages with silhouette weights")
    p.add_argument("--out-dir", required=True)
    p.add_argument("--scene")
    p.add_argument("--gt-smplx", help="ground-truth smplx_params table (evaluation)")
    p.add_argument("--gt-cameras", help="ground-truth cameras table (evaluation)")
    p.add_argument("--num-betas", type=int, default=10)
    p.add_argument("--num-expression", type=int, default=10)
    p.add_argument("--view", type=int, help="fit only this camera (single view)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--max-frames", type=int, help="fit only the first N frames")
    p.add_argument("--fps", type=float, default=25.0, help="when no frames table is given")
    p.add_argument("--keypoint-offsets",
                   help="keypoint_offsets table of the detector that found the keypoints "
                   "(signsplat.fit.keypoint_offsets); none = the body model's own keypoints")
    p.add_argument("--keypoint-offsets-fingers", nargs="+", choices=("left", "right"),
                   default=(), metavar="SIDE",
                   help="apply only the table's finger rows of these hands (left, right): "
                   "another detector's fingers merged into the keypoints "
                   "(perception.keypoints.hands: mediapipe)")
    return p


def fit(argv: list[str]) -> int:
    """Entry point of ``signsplat fit``."""
    import torch

    from signsplat.device import select_device
    from signsplat.fit.run import fit_scene

    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    cfg = config_option(args.config_json, "stages/fit.schema.yaml")
    torch.set_num_threads(max(1, args.threads))
    fit_scene(cfg, args.out_dir, args.keypoints, args.calibration, args.body,
              frames=args.frames, masks=args.masks, gt_smplx=args.gt_smplx,
              gt_cameras=args.gt_cameras, scene=args.scene, num_betas=args.num_betas,
              num_expression=args.num_expression, device=str(select_device(args.device)),
              fps=args.fps, view=args.view, max_frames=args.max_frames,
              keypoint_offsets=args.keypoint_offsets,
              offsets_fingers=tuple(args.keypoint_offsets_fingers))
    return 0


def keypoint_offsets(argv: list[str]) -> int:
    """Entry point of ``signsplat keypoint-offsets``: estimate a detector's keypoint offsets
    (:mod:`signsplat.fit.keypoint_offsets`) on finished simulated scenes and write the table."""
    import pandas as pd

    from signsplat.errors import InputError
    from signsplat.fit import keypoint_offsets as ko
    from signsplat.fit.bodyfit import load_keypoint_model
    from signsplat.io.tables import write_table

    p = argparse.ArgumentParser(
        prog="signsplat keypoint-offsets",
        description="Estimate where a detector puts each body, hand and face keypoint against the "
        "body model's own (constant 3D offsets on the body's segments), from finished "
        "simulated scenes with the detector's keypoints; write the keypoint_offsets table "
        "that config fit.keypoint_offsets names.")
    p.add_argument("--scenes", nargs="+", required=True,
                   help="scene folders with sim/ (smplx_gt, cameras) and the detector's "
                   "perception/keypoints.parquet")
    p.add_argument("--body", required=True, help="body model .npz the scenes were made with")
    p.add_argument("--detector", required=True,
                   help="what found the keypoints (written into the table's metadata)")
    p.add_argument("--out", required=True, help="keypoint_offsets table (Parquet)")
    p.add_argument("--min-score", type=float, default=0.3)
    p.add_argument("--ridge", type=float, default=1000.0,
                   help="px^2 per m^2 pulling each offset to zero")
    p.add_argument("--min-observations", type=int, default=200)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    # one keypoint model per count of shape and expression coefficients
    keypoint_model = functools.lru_cache(maxsize=None)(
        functools.partial(load_keypoint_model, args.body))
    samples = []
    for d in args.scenes:
        try:
            samples.append(ko.scene_sample(d, keypoint_model))
        except ValueError as exc:
            raise InputError(str(exc)) from None
    offsets, before, after = ko.estimate_offsets(samples, args.min_score, args.ridge,
                                                 args.min_observations)
    df = ko.offsets_table(offsets, before, after, args.min_observations)
    write_table(df, args.out, "keypoint_offsets",
                metadata={"detector": args.detector,
                          "scenes": " ".join(Path(s).name for s in args.scenes)})
    with pd.option_context("display.width", 160):
        print(df.round(4).to_string(index=False))
    return 0
