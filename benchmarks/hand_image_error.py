"""Where a fitted hand's image error comes from: its place in the image or its own shape.

For each fit given, the hand's vertices are projected by the fitted cameras and the true
hand's by the true cameras (as the fit's ``image_error``). Per view and frame the mean 2D
difference is the hand's shift (wrist, arm, body and camera together); what is left after
removing it is the hand's own shape and turn in the image (its finger pose and orientation).

    python benchmarks/hand_image_error.py --body results/_assets/body_model.npz \
        --sim results/studio6/sim --fits results/studio6/fit other/fit --out table.parquet

Prints one row per fit and hand; ``--out`` saves them (Parquet).
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd

from signsplat.body.joints import PART_LEFT_HAND, PART_RIGHT_HAND
from signsplat.fit.bodyfit import load_keypoint_model
from signsplat.fit.data import read_rig, read_smplx
from signsplat.fit.evaluate import in_images, keypoints_of


def hand_errors(uv_fit: np.ndarray, uv_true: np.ndarray, seen: np.ndarray) -> dict[str, float]:
    """Mean image error, the hand's 2D shift and what is left after it, over the view-frames
    where every vertex of the hand is seen. uv_* (V,T,N,2) px; seen (V,T,N)."""
    whole = seen.all(-1)
    d = uv_fit - uv_true
    shift = d.mean(2, keepdims=True)
    return {"view_frames": int(whole.sum()),
            "image_error_px": float(np.linalg.norm(d, axis=-1)[whole].mean()),
            "shift_px": float(np.linalg.norm(shift[..., 0, :], axis=-1)[whole].mean()),
            "shape_px": float(np.linalg.norm(d - shift, axis=-1)[whole].mean())}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--body", required=True)
    p.add_argument("--sim", required=True, help="the scene's sim/ folder (truth)")
    p.add_argument("--fits", nargs="+", required=True, help="fit folders of that scene")
    p.add_argument("--out")
    args = p.parse_args()
    kpm = load_keypoint_model(args.body, 10, 10)
    labels = kpm.model.part_labels.cpu().numpy()
    gp, gf = read_smplx(f"{args.sim}/smplx_gt.parquet")
    rig_g, _ = read_rig(f"{args.sim}/cameras.parquet")
    pos = {int(f): i for i, f in enumerate(gf)}
    rows = []
    for fit in args.fits:
        fp, ff = read_smplx(f"{fit}/smplx_fit.parquet")
        rig_f, _ = read_rig(f"{fit}/cameras_fit.parquet")
        idx = [i for i, f in enumerate(ff) if int(f) in pos]
        _, _, gv = keypoints_of(kpm, {k: v[[pos[int(ff[i])] for i in idx]]
                                      for k, v in gp.items()})
        _, _, fv = keypoints_of(kpm, {k: v[idx] for k, v in fp.items()})
        for hand, label in (("left_hand", PART_LEFT_HAND), ("right_hand", PART_RIGHT_HAND)):
            part = labels == label
            uf, _ = in_images(fv[:, part], rig_f)
            ug, seen = in_images(gv[:, part], rig_g)
            rows.append({"fit": fit, "part": hand, **hand_errors(uf, ug, seen)})
    df = pd.DataFrame(rows)
    print(df.round(3).to_string(index=False))
    if args.out:
        df.to_parquet(args.out, index=False)


if __name__ == "__main__":
    main()
