"""One scene's fit from files to files: read and clean the inputs, fit, evaluate, write.

Inputs: a ``keypoints`` table (detected or ground truth), a ``cameras`` table used ONLY for
image sizes and, when the config says ``intrinsics: calibrated``, for fx, fy, cx, cy (its R and t
are read only with ``camera_init: calibrated``), the body model, and optionally the ``frames``
table (timestamps and images for the overlays and the flow term) and the person ``masks``.
With the ground-truth tables the fit is also evaluated.

Outputs (:func:`fit_scene`, in ``out_dir``): ``smplx_fit.parquet`` (table ``smplx_params`` +
``provenance`` and ``num_keypoints``; metadata ``hand_mean: flat`` and ``legs_held``, the
legs no view saw, kept at the rest pose), ``cameras_fit.parquet``
(table ``cameras`` + ``fit_status``), ``fit_eval.parquet`` (table ``fit_eval``),
``fit_log.json`` (counters and seconds) and ``overlays/view{v:02d}_frame{f:04d}.png``.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from signsplat.device import make_deterministic
from signsplat.errors import InputError, SignSplatError
from signsplat.fit import data
from signsplat.fit.bodyfit import HAND_MEAN, KeypointModel, load_keypoint_model
from signsplat.fit.cameras import Rig, intrinsics_from_fov
from signsplat.fit.evaluate import fit_eval_table
from signsplat.fit.filters import clean_observations
from signsplat.fit.mode import fit_mode
from signsplat.fit.overlay import write_overlays
from signsplat.fit.sequence import FitResult
from signsplat.fit.solver import stages_using
from signsplat.io.atomic import write_bytes_atomic
from signsplat.fit.keypoint_offsets import load_offsets, offsets_label
from signsplat.io.tables import TableError, write_table

log = logging.getLogger("signsplat.fit")


class FitError(SignSplatError, RuntimeError):
    """The fit could not run on these inputs (the message names the file)."""


def run_fit(cfg: dict, keypoints: str | os.PathLike, calibration: str | os.PathLike | None,
            body: str | os.PathLike, *, frames: str | os.PathLike | None = None,
            scene: str | None = None, num_betas: int = 10, num_expression: int = 10,
            device: str = "cpu", fps: float = 25.0, view: int | None = None,
            max_frames: int | None = None, masks: str | os.PathLike | None = None,
            keypoint_offsets: str | os.PathLike | None = None,
            offsets_fingers: tuple[str, ...] = ()
            ) -> tuple[FitResult, np.ndarray, str, KeypointModel]:
    """Load, clean and fit. Returns (result, cleaned obs (V,T,133,3), mode, keypoint model).

    ``cfg``: the validated ``fit`` section. ``view`` restricts a multi-camera scene to one
    camera (single-view fit of that view). ``masks``: a masks (or frames) table whose person
    masks feed the multi-view stages with silhouette weights (read only when such a stage
    exists). ``fps``: frame rate when no frames table gives the timestamps.
    ``keypoint_offsets``: the detector's ``keypoint_offsets`` table; the fitted (and
    evaluated) keypoints are then the detector's, not the body model's. ``offsets_fingers``:
    hand sides whose finger rows alone are applied (another detector's fingers merged into
    the keypoints); empty = every row.
    """
    from signsplat.fit.multiview import fit_multiview
    from signsplat.fit.singleview import fit_singleview

    # like the avatar's trainer, so every caller gets it: on more than one thread the backward
    # of a gather with repeated indices otherwise adds with atomics, and two fits could differ
    make_deterministic()
    frames_df = data.read_frames(frames) if frames else None
    if calibration:
        rig_cal, scene_cam = data.read_rig(calibration, with_extrinsics=False)
    elif frames_df is not None:  # real footage without calibration: approximate intrinsics
        rig_cal = data.rig_from_frames(frames_df, frames)
        scene_cam = str(frames_df["scene"].iloc[0])
        for m in ("multiview", "singleview"):
            cfg[m]["intrinsics"] = "approximate"
    else:
        raise InputError("the fit needs a cameras table (--calibration) or a frames table "
                         "(--frames) for the image sizes")
    frame_ids = None if frames_df is None else np.unique(frames_df["frame"].to_numpy())
    obs, seq_frames = data.read_keypoints(keypoints, rig_cal.num_views, frame_ids)
    if max_frames is not None:
        obs, seq_frames = obs[:, :max_frames], seq_frames[:max_frames]
    if view is not None:
        if not 0 <= view < rig_cal.num_views:
            raise InputError(f"{calibration}: no view {view}")
        obs = obs[view:view + 1]
        rig_cal = rig_cal.select(slice(view, view + 1))
    if frames_df is not None:
        tmap = frames_df.groupby("frame")["time"].first()
        times = np.array([tmap.get(f, f / fps) for f in seq_frames], dtype=np.float64)
    else:
        times = seq_frames / float(fps)
    obs, stats = clean_observations(obs, times, rig_cal.height, cfg)
    log.info("keypoints %s: %d observations, %d NaN ignored, %d low-score ignored, "
             "%d outliers rejected, %d used", keypoints, stats.total, stats.nan,
             stats.low_score, stats.outliers, stats.used)
    if stats.used == 0:
        raise InputError(f"{keypoints}: no usable keypoint (all scores below "
                         f"{cfg['min_score']} or NaN)")
    mode = fit_mode(cfg, obs.shape[0])
    sec = cfg[mode]
    if mode == "singleview":
        multi_only = stages_using(sec["init_stages"] + sec["refine_stages"],
                                  "uses_silhouette", "uses_flow")
        if multi_only:
            raise InputError(f"fit.singleview: stage(s) {multi_only} weight the silhouette or "
                             "flow terms, which only the multi-view fit has; set those "
                             "weights to 0")
    if sec["intrinsics"] == "calibrated":
        K = rig_cal.K
    else:
        K = np.stack([intrinsics_from_fov(w, h, sec["approx_fov_degrees"])
                      for w, h in zip(rig_cal.width, rig_cal.height)])
    offsets = None
    if keypoint_offsets:
        try:
            offsets = load_offsets(keypoint_offsets, offsets_fingers)
        except (TableError, ValueError) as exc:
            raise InputError(str(exc)) from None
        log.info("keypoints: the detector's, moved by %s (%d keypoints)",
                 offsets_label(keypoint_offsets, offsets_fingers),
                 int((np.abs(offsets).sum(1) > 0).sum()))
    kpm = load_keypoint_model(body, num_betas, num_expression, device, offsets=offsets)
    mask_arr = images = extrinsics = None
    if mode == "multiview":
        sil = stages_using(sec["stages"], "uses_silhouette")
        flow = stages_using(sec["stages"], "uses_flow")
        if (sil or flow) and not masks:
            raise InputError(f"fit.multiview.stages: stage(s) {sil + flow} weight the "
                             "silhouette or flow terms and need the person masks: pass --masks "
                             "(the perception stage's masks.parquet) or set those stages' "
                             "weights to 0")
        if flow and frames_df is None:
            raise InputError(f"fit.multiview.stages: stage(s) {flow} weight the flow term and "
                             "need the images: pass --frames (the frames table) or set their "
                             "flow to 0")
        if sil or flow:
            mask_arr = data.read_masks(masks, seq_frames, rig_cal.width, rig_cal.height)
            if view is not None:
                mask_arr = mask_arr[view:view + 1]
        if flow:
            images = data.read_grey_images(frames_df, seq_frames, rig_cal.width,
                                           rig_cal.height, frames)
            if view is not None:
                images = images[view:view + 1]
        if sec["camera_init"] == "calibrated":
            extrinsics = data.read_calibrated_extrinsics(calibration, view)
    try:
        if mode == "multiview":
            result = fit_multiview(kpm, obs, seq_frames, K, rig_cal.width, rig_cal.height, cfg,
                                   device=device, masks=mask_arr, extrinsics=extrinsics,
                                   images=images)
        else:
            result = fit_singleview(kpm, obs[0], seq_frames, K[0], int(rig_cal.width[0]),
                                    int(rig_cal.height[0]), cfg, device=device)
    except ValueError as exc:
        raise FitError(f"{keypoints}: {exc}") from None
    result.log.update({"observations": stats.total, "ignored_nan": stats.nan,
                       "ignored_low_score": stats.low_score, "outliers": stats.outliers,
                       "used": stats.used})
    result.log["scene"] = scene or scene_cam
    return result, obs, mode, kpm


def world_frame(mode: str, reference_view: int | None) -> str:
    """What the fitted world frame is (written into the output tables' metadata)."""
    if mode == "singleview":
        return "camera frame"
    if reference_view == -1:
        return "calibration (cameras held fixed)"
    return f"reference camera {reference_view} held at its initial pose (body-anchored)"


def fit_scene(cfg: dict, out_dir: str | os.PathLike, keypoints: str | os.PathLike,
              calibration: str | os.PathLike | None, body: str | os.PathLike, *,
              frames: str | os.PathLike | None = None, masks: str | os.PathLike | None = None,
              gt_smplx: str | os.PathLike | None = None,
              gt_cameras: str | os.PathLike | None = None, scene: str | None = None,
              num_betas: int = 10, num_expression: int = 10, device: str = "cpu",
              fps: float = 25.0, view: int | None = None, max_frames: int | None = None,
              keypoint_offsets: str | os.PathLike | None = None,
              offsets_fingers: tuple[str, ...] = ()) -> dict:
    """:func:`run_fit`, then write every output into ``out_dir`` (see the module docstring).

    ``cfg['keypoints']`` names the keypoints' source in the tables. Returns the summary that
    is also written to ``fit_log.json``.
    """
    t0 = time.perf_counter()
    c0 = time.process_time()
    result, obs, mode, kpm = run_fit(cfg, keypoints, calibration, body, frames=frames,
                                     scene=scene, num_betas=num_betas,
                                     num_expression=num_expression, device=device, fps=fps,
                                     view=view, max_frames=max_frames, masks=masks,
                                     keypoint_offsets=keypoint_offsets,
                                     offsets_fingers=offsets_fingers)
    result.seconds["cpu"] = time.process_time() - c0
    out_dir = Path(out_dir)
    name = str(result.log["scene"])
    meta = {"hand_mean": HAND_MEAN, "body_model": str(body), "mode": mode,
            "keypoints": cfg["keypoints"],
            "keypoint_offsets": offsets_label(keypoint_offsets, offsets_fingers),
            "world_frame": world_frame(mode, result.log.get("reference_view")),
            "legs_held": ", ".join(result.log.get("legs_held", [])) or "none"}
    data.write_outputs(out_dir, data.smplx_table(result.params, name, result.frames,
                                                 result.provenance, result.num_keypoints),
                       data.cameras_table(result.rig, name, result.camera_status), meta)
    ev = fit_eval_table(kpm, result, obs, mode, cfg["keypoints"], gt_smplx, gt_cameras, view)
    write_table(ev, out_dir / "fit_eval.parquet", "fit_eval", metadata=meta)
    (out_dir / "overlays").mkdir(parents=True, exist_ok=True)
    overlays = write_overlays(kpm, result, obs, frames, out_dir, cfg, view,
                              masks_path=masks) if frames else []
    summary = {"scene": name, "mode": mode, "seconds": result.seconds,
               "seconds_with_io": time.perf_counter() - t0, "log": result.log,
               "provenance": {k: int(v) for k, v in
                              zip(*np.unique(result.provenance, return_counts=True))},
               "camera_status": result.camera_status, "overlays": len(overlays),
               "eval": {f"{m}/{p}": round(float(v), 3) for m, p, v in
                        ev[["metric", "part", "value"]].itertuples(index=False)}}
    write_bytes_atomic(out_dir / "fit_log.json", json.dumps(summary, indent=1,
                                                           default=str).encode())
    log.info("fit summary: %s", json.dumps(summary, default=str))
    return summary
