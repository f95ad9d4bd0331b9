"""Is it the detector's noise or its bias that loses the cameras? The multi-view fit's camera
initialisation (`signsplat.fit.rig_init.place_cameras`, default config) on finished suite scenes,
fed with different keypoints of the same frames:

- ``detected``: the perception stage's keypoints (what the fit uses);
- ``truth``: the simulator's keypoints where the detector reported the point (same support);
- ``truth+N px``: the same with independent Gaussian noise of N px per coordinate (noise
  without bias);
- ``detected-offset``: the detections minus each view's mean offset of each keypoint from the
  truth over the clip (an oracle removing the detector's constant, view-dependent bias; what
  is left is its noise).

Usage: python benchmarks/fit_init_bias.py --results results/suite [--scenes g16 issue29 ...]
       [--noise 1 2 3] [--out benchmarks/results/fit_init_bias.parquet]

Needs `<results>/<scene>/sim/` and `<results>/<scene>/perception/keypoints.parquet` (run
`benchmarks/fit_suite.py` or the workflow first) and `<results>/_assets/body_model.npz`.
Prints and writes one row per scene and keypoint source: the winning hypothesis and the
camera errors against the simulator's cameras (as in `fit_eval`), and the seconds.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from signsplat.config import validate  # noqa: E402
from signsplat.fit import data  # noqa: E402
from signsplat.fit.bodyfit import load_keypoint_model  # noqa: E402
from signsplat.fit.cameras import Rig  # noqa: E402
from signsplat.fit.evaluate import placed_camera_errors  # noqa: E402
from signsplat.fit.filters import clean_observations  # noqa: E402
from signsplat.fit.multiview import neutral_keypoints  # noqa: E402
from signsplat.fit.rig_init import place_cameras, placed_views  # noqa: E402
from signsplat.io.atomic import atomic_path  # noqa: E402


def keypoint_sources(det: np.ndarray, truth: np.ndarray, min_score: float, noise: list[float],
                     seed: int = 0) -> dict[str, np.ndarray]:
    """obs (V,T,133,3) variants of the same frames (see the module docstring)."""
    support = det[..., 2] >= min_score
    out = {"detected": det}
    clean = truth.copy()
    clean[..., 2] = np.where(support, 0.9, 0.0)
    out["truth"] = clean
    for s in noise:  # the same draw scaled: a level's noise does not depend on the others
        o = clean.copy()
        o[..., :2] += np.random.default_rng(seed).normal(0.0, s, o[..., :2].shape)
        out[f"truth+{s:g} px"] = o
    w = support[..., None]
    offset = ((det[..., :2] - truth[..., :2]) * w).sum(1, keepdims=True) / \
        np.maximum(w.sum(1, keepdims=True), 1)
    o = det.copy()
    o[..., :2] -= np.where(w, offset, 0.0)
    out["detected-offset"] = o
    return out


def scene_rows(results: Path, scene: str, cfg: dict, noise: list[float]) -> list[dict]:
    d = results / scene
    rig_cal, _ = data.read_rig(d / "sim" / "cameras.parquet", with_extrinsics=False)
    truth_rig, _ = data.read_rig(d / "sim" / "cameras.parquet")
    det, frames = data.read_keypoints(d / "perception" / "keypoints.parquet", rig_cal.num_views)
    gt, gt_frames = data.read_keypoints(d / "sim" / "keypoints_gt.parquet", rig_cal.num_views)
    if not np.array_equal(frames, gt_frames):  # align the truth on the detections' frames
        idx = np.searchsorted(gt_frames, frames)
        gt = gt[:, np.clip(idx, 0, len(gt_frames) - 1)]
    kp0 = neutral_keypoints(load_keypoint_model(results / "_assets" / "body_model.npz", 10, 10))
    rows = []
    for name, obs in keypoint_sources(det, gt, cfg["min_score"], noise).items():
        t0 = time.perf_counter()
        clean, _ = clean_observations(obs, frames / 25.0, rig_cal.height, cfg)
        hyp = place_cameras(kp0, clean, rig_cal.K, rig_cal.width, rig_cal.height,
                            cfg["multiview"])
        err, _ = placed_camera_errors(Rig(rig_cal.K, hyp.R, hyp.t, rig_cal.width,
                                          rig_cal.height), truth_rig, hyp.status)
        rows.append(dict(scene=scene, keypoints=name, cameras=rig_cal.num_views,
                         winner=hyp.winner, unplaced=rig_cal.num_views - len(placed_views(hyp.status)),
                         camera_rotation_deg=err["rotation_deg_mean"],
                         camera_rotation_deg_max=err["rotation_deg_max"],
                         camera_centre_m=err["centre_m_mean"],
                         seconds=time.perf_counter() - t0))
        print(f"{scene:20s} {name:16s} {hyp.winner:10s} rotation {err['rotation_deg_mean']:6.2f}"
              f" deg (max {err['rotation_deg_max']:6.2f}), centre {100 * err['centre_m_mean']:5.1f}"
              f" cm", flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", default="results/suite")
    p.add_argument("--scenes", nargs="*", help="default: every scene with detections")
    p.add_argument("--noise", nargs="*", type=float, default=[1.0, 2.0, 3.0])
    p.add_argument("--out", default="benchmarks/results/fit_init_bias.parquet")
    a = p.parse_args()
    results = Path(a.results)
    scenes = a.scenes or sorted(q.parent.parent.name for q in
                                results.glob("*/perception/keypoints.parquet"))
    cfg = validate({}, "stages/fit.schema.yaml")
    rows = [r for s in scenes for r in scene_rows(results, s, cfg, a.noise)]
    df = pd.DataFrame(rows)
    df["date"] = dt.date.today().isoformat()
    with atomic_path(a.out) as tmp:
        df.to_parquet(tmp, index=False)
    wide = df.pivot_table(index="scene", columns="keypoints", values="camera_rotation_deg")
    with pd.option_context("display.width", 200):
        print(wide.round(2).to_string())
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
