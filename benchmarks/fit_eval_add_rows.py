"""Add to finished multi-view fits the ``fit_eval`` rows the evaluation has gained since they
ran (for example ``mpjpe`` / ``body_seen``), without fitting again.

Usage: python benchmarks/fit_eval_add_rows.py --results results/suite [--scenes g01 g16 ...]

For every scene folder with ``fit/`` (``smplx_fit``, ``cameras_fit``, ``fit_log.json``,
``fit_eval``) and ``sim/`` (``smplx_gt``, ``cameras``), the fit is scored against the truth
again with :func:`signsplat.fit.evaluate.truth_rows`. Rows whose (metric, part) the table
lacks are appended; the rows it has stay as the fit wrote them (they may have used the
detector's keypoint offsets, which this script does not know). The table is rewritten in
place, atomically. Prints what it added per scene.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from signsplat.fit import data  # noqa: E402
from signsplat.fit.bodyfit import load_keypoint_model  # noqa: E402
from signsplat.fit.evaluate import truth_rows  # noqa: E402
from signsplat.fit.sequence import FitResult  # noqa: E402
from signsplat.io.tables import read_table, write_table  # noqa: E402


def finished_fit(fit_dir: Path) -> tuple[FitResult, str]:
    """A fit's result as the evaluation sees it, read back from its files, and its mode."""
    log = json.loads((fit_dir / "fit_log.json").read_text())
    params, frames = data.read_smplx(fit_dir / "smplx_fit.parquet")
    table = read_table(fit_dir / "smplx_fit.parquet", "smplx_params").sort_values("frame")
    rig, _ = data.read_rig(fit_dir / "cameras_fit.parquet")
    result = FitResult(params=params, rig=rig, frames=frames,
                       provenance=table["provenance"].to_numpy(str),
                       num_keypoints=table["num_keypoints"].to_numpy(),
                       camera_status=list(log["camera_status"]))
    return result, str(log["mode"])


def add_rows(fit_dir: Path, gt_smplx: Path, gt_cameras: Path, body: Path
             ) -> list[tuple[str, str, float]]:
    """Append to ``fit_dir/fit_eval.parquet`` the truth rows it lacks; returns them."""
    result, mode = finished_fit(fit_dir)
    if mode != "multiview":
        raise SystemExit(f"{fit_dir}: mode {mode!r}; only multi-view fits are handled")
    ev = read_table(fit_dir / "fit_eval.parquet", "fit_eval")
    have = set(zip(ev["metric"], ev["part"]))
    kpm = load_keypoint_model(body, result.params["betas"].shape[1],
                              result.params["expression"].shape[1])
    rows = [r for r in truth_rows(kpm, result, mode, gt_smplx, gt_cameras)
            if (r[0], r[1]) not in have]
    if not rows:
        return []
    first = ev.iloc[0]
    new = pd.DataFrame([{"scene": first["scene"], "mode": first["mode"],
                         "keypoints": first["keypoints"], "metric": m, "part": p,
                         "value": float(v), "unit": u, "seconds_total": first["seconds_total"],
                         "seconds_per_frame": first["seconds_per_frame"]}
                        for m, p, v, u in rows])
    write_table(pd.concat([ev, new], ignore_index=True), fit_dir / "fit_eval.parquet",
                "fit_eval", metadata=dict(ev.attrs))
    return [(m, p, float(v)) for m, p, v, _ in rows]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", required=True, help="folder of scene folders")
    p.add_argument("--scenes", nargs="*", help="default: every scene with fit/fit_eval.parquet")
    p.add_argument("--body", help="body model .npz (default <results>/_assets/body_model.npz)")
    a = p.parse_args()
    results = Path(a.results)
    body = Path(a.body) if a.body else results / "_assets" / "body_model.npz"
    scenes = a.scenes or sorted(q.parent.parent.name for q in
                                results.glob("*/fit/fit_eval.parquet"))
    for scene in scenes:
        sim = results / scene / "sim"
        added = add_rows(results / scene / "fit", sim / "smplx_gt.parquet",
                         sim / "cameras.parquet", body)
        shown = ", ".join(f"{m}/{p} {v:.3g}" for m, p, v in added) or "nothing"
        print(f"{scene}: added {shown}", flush=True)
    if not scenes:
        print(f"no finished fits under {results}")


if __name__ == "__main__":
    main()
