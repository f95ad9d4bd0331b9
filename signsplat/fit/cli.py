"""``signsplat fit``: SMPL-X fitting of one scene (multi-view with cameras, or single view).

Inputs: a ``keypoints`` table (detected or ground truth), a ``cameras`` table used ONLY for
image sizes and, when the config says ``intrinsics: calibrated``, for fx, fy, cx, cy (its R and t
are never read by the fit), the body model, and optionally the ``frames`` table (timestamps and
images for the overlays). With ``--gt-smplx`` / ``--gt-cameras`` the fit is also evaluated.

Outputs in ``--out-dir``: ``smplx_fit.parquet`` (table ``smplx_params`` + ``provenance`` and
``num_keypoints``; metadata ``hand_mean: flat``), ``cameras_fit.parquet`` (table ``cameras`` +
``fit_status``), ``fit_eval.parquet`` (table ``fit_eval``), ``fit_log.json`` (counters and
seconds) and ``overlays/view{v:02d}_frame{f:04d}.png``.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from signsplat.config import validate
from signsplat.device import make_deterministic
from signsplat.errors import InputError, SignSplatError
from signsplat.fit import data as D
from signsplat.fit import evaluate as E
from signsplat.fit import filters as F
from signsplat.fit.bodyfit import HAND_MEAN, KeypointModel
from signsplat.fit.cameras import Rig, intrinsics_from_fov, project
from signsplat.fit.sequence import FitResult
from signsplat.fit.solver import Stage
from signsplat.geometry.align import camera_centres
from signsplat.io.atomic import write_bytes_atomic
from signsplat.io.tables import write_table

log = logging.getLogger("signsplat.fit")


class FitError(SignSplatError, RuntimeError):
    """The fit could not run on these inputs (the message names the file)."""


def load_keypoint_model(body_path: str | os.PathLike, num_betas: int, num_expression: int,
                        device: torch.device | str = "cpu") -> KeypointModel:
    """Body model + whole-body regressor as a :class:`KeypointModel` on ``device``."""
    from signsplat.body.keypoints import WholeBodyRegressor
    from signsplat.body.model import BodyModel

    model = BodyModel.from_file(body_path, num_betas=num_betas,
                                num_expression=num_expression).to(device)
    regressor = WholeBodyRegressor(model)
    if isinstance(regressor, torch.nn.Module):
        regressor = regressor.to(device)
    return KeypointModel(model, regressor)


def clean_all(obs: np.ndarray, times: np.ndarray, heights: np.ndarray, cfg: dict
              ) -> tuple[np.ndarray, F.CleanStats]:
    """Clean every view (NaN/low score, outliers, One-Euro), then raise the confidences to
    ``confidence_power``. obs (V,T,133,3) -> same."""
    fc = cfg["filter"]
    out = np.empty_like(obs)
    stats = F.CleanStats()
    for v in range(obs.shape[0]):
        out[v], st = F.clean_keypoints(
            obs[v], times, min_score=cfg["min_score"], outlier_radius=fc["outlier_radius"],
            outlier_px=fc["outlier_fraction"] * float(heights[v]),
            one_euro_min_cutoff=fc["min_cutoff_hz"], one_euro_beta=fc["beta"],
            one_euro_d_cutoff=fc["d_cutoff_hz"], use_filter=fc["enabled"])
        stats = stats + st
    power = float(cfg["confidence_power"])
    if power != 1.0:  # ignored keypoints keep their 0
        out[..., 2] = out[..., 2] ** power
    return out, stats


def choose_mode(cfg: dict, num_views: int) -> str:
    mode = cfg["mode"]
    if mode == "auto":
        return "multiview" if num_views > 1 else "singleview"
    if mode == "multiview" and num_views < 2:
        raise FitError(f"mode multiview needs at least 2 cameras, the rig has {num_views}")
    return mode


def stages_using(stages: list[dict], *terms: str) -> list[str]:
    """Names of the stage configs whose :class:`Stage` has any of the properties ``terms``
    (``uses_silhouette``, ``uses_flow``)."""
    return [s["name"] for s in stages
            if any(getattr(Stage.from_config(s), term) for term in terms)]


def calibrated_extrinsics(calibration: str | os.PathLike | None, view: int | None = None
                          ) -> tuple[np.ndarray, np.ndarray]:
    """(R (V,3,3), t (V,3)) of a calibrated rig's cameras table, for ``camera_init:
    calibrated``; an InputError names the file when it has no usable extrinsics."""
    if not calibration:
        raise InputError("fit.multiview.camera_init: calibrated needs the calibrated cameras: "
                         "pass --calibration (a cameras table with R and t), or choose "
                         "camera_init auto, pnp or rig_prior")
    rig, _ = D.read_rig(calibration, with_extrinsics=True)
    ortho = np.abs(np.einsum("vij,vkj->vik", rig.R, rig.R) - np.eye(3)).max(axis=(1, 2))
    bad = np.nonzero((ortho > 1e-4) | (np.linalg.det(rig.R) < 0))[0]
    if len(bad):
        raise InputError(f"{calibration}: camera(s) {bad.tolist()} have an R that is not a "
                         "rotation (world-to-camera, det +1); fit.multiview.camera_init "
                         "calibrated uses R and t as they are")
    if rig.num_views > 1 and np.ptp(camera_centres(rig.R, rig.t), axis=0).max() < 1e-6:
        raise InputError(f"{calibration}: every camera sits at the same place - the table has "
                         "no calibrated extrinsics; choose fit.multiview.camera_init auto, pnp "
                         "or rig_prior")
    if view is not None:
        return rig.R[view:view + 1], rig.t[view:view + 1]
    return rig.R, rig.t


def run_fit(cfg: dict, keypoints: str | os.PathLike, calibration: str | os.PathLike | None,
            body: str | os.PathLike, *, frames: str | os.PathLike | None = None,
            scene: str | None = None, num_betas: int = 10, num_expression: int = 10,
            device: str = "cpu", fps: float = 25.0, view: int | None = None,
            max_frames: int | None = None, masks: str | os.PathLike | None = None
            ) -> tuple[FitResult, np.ndarray, str, KeypointModel]:
    """Load, clean and fit. Returns (result, cleaned obs (V,T,133,3), mode, keypoint model).

    ``view`` restricts a multi-camera scene to one camera (single-view fit of that view).
    ``masks``: a masks (or frames) table whose person masks feed the multi-view stages with
    silhouette weights (read only when such a stage exists).
    """
    from signsplat.fit.multiview import fit_multiview
    from signsplat.fit.singleview import fit_singleview

    # like the avatar's trainer, so every caller gets it: on more than one thread the backward
    # of a gather with repeated indices otherwise adds with atomics, and two fits could differ
    make_deterministic()
    frames_df = D.read_frames(frames) if frames else None
    if calibration:
        rig_cal, scene_cam = D.read_rig(calibration, with_extrinsics=False)
    elif frames_df is not None:  # real footage without calibration: approximate intrinsics
        rig_cal, scene_cam = D.rig_from_frames(frames_df, frames), str(frames_df["scene"].iloc[0])
        for m in ("multiview", "singleview"):
            cfg[m]["intrinsics"] = "approximate"
    else:
        raise InputError("the fit needs a cameras table (--calibration) or a frames table "
                         "(--frames) for the image sizes")
    frame_ids = None if frames_df is None else np.unique(frames_df["frame"].to_numpy())
    obs, seq_frames = D.read_keypoints(keypoints, rig_cal.num_views, frame_ids)
    if max_frames is not None:
        obs, seq_frames = obs[:, :max_frames], seq_frames[:max_frames]
    if view is not None:
        if not 0 <= view < rig_cal.num_views:
            raise InputError(f"{calibration}: no view {view}")
        obs = obs[view:view + 1]
        rig_cal = Rig(K=rig_cal.K[view:view + 1], R=rig_cal.R[view:view + 1],
                      t=rig_cal.t[view:view + 1], width=rig_cal.width[view:view + 1],
                      height=rig_cal.height[view:view + 1])
    if frames_df is not None:
        tmap = frames_df.groupby("frame")["time"].first()
        times = np.array([tmap.get(f, f / fps) for f in seq_frames], dtype=np.float64)
    else:
        times = seq_frames / float(fps)
    obs, stats = clean_all(obs, times, rig_cal.height, cfg)
    log.info("keypoints %s: %d observations, %d NaN ignored, %d low-score ignored, "
             "%d outliers rejected, %d used", keypoints, stats.total, stats.nan,
             stats.low_score, stats.outliers, stats.used)
    if stats.used == 0:
        raise InputError(f"{keypoints}: no usable keypoint (all scores below "
                         f"{cfg['min_score']} or NaN)")
    mode = choose_mode(cfg, obs.shape[0])
    sec = cfg[mode]
    if mode == "singleview":
        sv_stages = sec.get("init_stages", []) + sec.get("refine_stages", [])
        multi_only = stages_using(sv_stages, "uses_silhouette", "uses_flow")
        if multi_only:
            raise InputError(f"fit.singleview: stage(s) {multi_only} weight the silhouette or "
                             "flow terms, which only the multi-view fit has; set those "
                             "weights to 0")
    if sec["intrinsics"] == "calibrated":
        K = rig_cal.K
    else:
        K = np.stack([intrinsics_from_fov(w, h, sec["approx_fov_degrees"])
                      for w, h in zip(rig_cal.width, rig_cal.height)])
    kpm = load_keypoint_model(body, num_betas, num_expression, device)
    mask_arr = images = None
    sil = stages_using(sec.get("stages", []), "uses_silhouette")
    flow = stages_using(sec.get("stages", []), "uses_flow")
    if mode == "multiview" and (sil or flow) and not masks:
        raise InputError(f"fit.multiview.stages: stage(s) {sil + flow} weight the silhouette or "
                         "flow terms and need the person masks: pass --masks (the perception "
                         "stage's masks.parquet) or set those stages' weights to 0")
    if mode == "multiview" and flow and frames_df is None:
        raise InputError(f"fit.multiview.stages: stage(s) {flow} weight the flow term and need "
                         "the images: pass --frames (the frames table) or set their flow to 0")
    if mode == "multiview" and (sil or flow):
        mask_arr = D.read_masks(masks, seq_frames, rig_cal.width, rig_cal.height)
        if view is not None:
            mask_arr = mask_arr[view:view + 1]
    if mode == "multiview" and flow:
        images = D.read_grey_images(frames_df, seq_frames, rig_cal.width, rig_cal.height, frames)
        if view is not None:
            images = images[view:view + 1]
    extrinsics = None
    if mode == "multiview" and sec.get("camera_init") == "calibrated":
        extrinsics = calibrated_extrinsics(calibration, view)
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


def keypoints_of(kpm: KeypointModel, params: dict[str, np.ndarray], batch: int = 64
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joints (T,55,3), keypoints (T,133,3), vertices (T,V,3) float64 of parameter blocks."""
    ref = kpm.model.v_template
    names = ("betas", "expression", "global_orient", "body_pose", "jaw_pose", "leye_pose",
             "reye_pose", "left_hand_pose", "right_hand_pose", "transl")
    T = params["transl"].shape[0]
    js, ks, vs = [], [], []
    with torch.no_grad():
        for s in range(0, T, batch):
            inp = {n: torch.as_tensor(np.asarray(params[n][s:s + batch]), dtype=ref.dtype,
                                      device=ref.device) for n in names if n in params}
            j, k, out = kpm(full=True, **inp)
            js.append(j.double().cpu().numpy())
            ks.append(k.double().cpu().numpy())
            vs.append(out.vertices.double().cpu().numpy())
    return np.concatenate(js), np.concatenate(ks), np.concatenate(vs)


def evaluate(kpm: KeypointModel, result: FitResult, obs: np.ndarray, mode: str, source: str,
             gt_smplx: str | os.PathLike | None, gt_cameras: str | os.PathLike | None,
             view: int | None = None) -> pd.DataFrame:
    """Rows of the ``fit_eval`` table (see :data:`signsplat.fit.evaluate.FIT_EVAL`)."""
    rows: list[tuple[str, str, float, str]] = []
    T = len(result.frames)
    _, fit_kp, _ = keypoints_of(kpm, result.params)
    rig = result.rig
    uv, _ = project(torch.as_tensor(fit_kp), torch.as_tensor(rig.K), torch.as_tensor(rig.R),
                    torch.as_tensor(rig.t))
    rows += E.reprojection_rows(uv.numpy(), obs)
    if gt_cameras:
        gt_rig, _ = D.read_rig(gt_cameras)
        if view is not None:
            gt_rig = Rig(K=gt_rig.K[view:view + 1], R=gt_rig.R[view:view + 1],
                         t=gt_rig.t[view:view + 1], width=gt_rig.width[view:view + 1],
                         height=gt_rig.height[view:view + 1])
        if gt_rig.num_views != rig.num_views:
            raise InputError(f"{gt_cameras}: {gt_rig.num_views} cameras, the fit has "
                             f"{rig.num_views}")
        ok = [v for v, s in enumerate(result.camera_status) if s != "no_detections"]
        sub = lambda r: Rig(K=r.K[ok], R=r.R[ok], t=r.t[ok], width=r.width[ok],  # noqa: E731
                            height=r.height[ok])
        cam = E.camera_errors(sub(rig), sub(gt_rig))
        sim, _ = E.gauge_alignment(sub(rig), sub(gt_rig))
        if mode == "multiview":
            rows += [("camera_rotation", "cameras", cam["rotation_deg_mean"], "deg"),
                     ("camera_rotation_max", "cameras", cam["rotation_deg_max"], "deg"),
                     ("camera_centre", "cameras", cam["centre_m_mean"], "m"),
                     ("camera_centre_max", "cameras", cam["centre_m_max"], "m"),
                     ("camera_focal_rel", "cameras", cam["focal_rel_err_mean"], "1"),
                     ("gauge_scale", "cameras", cam["scale"], "1")]
    else:
        sim = None
    if gt_smplx:
        gt_params, gt_frames = D.read_smplx(gt_smplx)
        pos = {int(f): i for i, f in enumerate(gt_frames)}
        idx = [i for i, f in enumerate(result.frames) if int(f) in pos]
        if not idx:
            raise InputError(f"{gt_smplx}: no frame in common with the fit")
        gsel = [pos[int(result.frames[i])] for i in idx]
        gj, gk, gv = keypoints_of(kpm, {k: v[gsel] for k, v in gt_params.items()})
        fj, fk, fv = keypoints_of(kpm, {k: v[idx] for k, v in result.params.items()})
        if gt_cameras:
            rows += E.image_errors(fv, rig, gv, gt_rig, kpm.model.part_labels.cpu().numpy())
        if sim is None:  # no GT cameras: align the whole sequence's body joints
            sim = E.umeyama(fj.reshape(-1, 3), gj.reshape(-1, 3))
        fj, fk = sim.apply(fj), sim.apply(fk)
        fitted = np.asarray(result.provenance)[idx] == "fitted"
        pose_rows = E.pose_errors(fj[fitted], fk[fitted], gj[fitted], gk[fitted])
        jit = {(m, p): v for m, p, v, _ in E.pose_errors(fj, fk, gj, gk) if m == "jitter"}
        rows += [(m, p, jit[(m, p)] if m == "jitter" else v, u) for m, p, v, u in pose_rows]
    total = float(result.seconds.get("total", float("nan")))
    rows.append(("seconds", "all", total, "s"))
    if "cpu" in result.seconds:  # CPU time of this process (wall time suffers on shared CPUs)
        rows.append(("cpu_seconds", "all", float(result.seconds["cpu"]), "s"))
    rows.append(("frames_fitted", "all", float((result.provenance == "fitted").sum()), "1"))
    df = pd.DataFrame(rows, columns=["metric", "part", "value", "unit"])
    df.insert(0, "keypoints", source)
    df.insert(0, "mode", mode)
    df.insert(0, "scene", str(result.log.get("scene", "")))
    df["seconds_total"] = total
    df["seconds_per_frame"] = total / max(T, 1)
    return df


def write_overlays(kpm: KeypointModel, result: FitResult, obs: np.ndarray, frames_path,
                   out_dir: Path, cfg: dict, view: int | None = None) -> list[Path]:
    """A few overlay PNGs per view (see :mod:`signsplat.fit.overlay`)."""
    from signsplat.fit import overlay as O
    from signsplat.io.images import read_rgb

    oc = cfg["overlay"]
    (out_dir / "overlays").mkdir(parents=True, exist_ok=True)
    df = D.read_frames(frames_path)
    pos = O.pick_frames(result.frames, result.provenance, oc["frames_per_view"])
    if not pos:
        return []
    sub = {k: v[pos] for k, v in result.params.items()}
    _, kp, verts = keypoints_of(kpm, sub)
    rig = result.rig
    step = max(1, verts.shape[1] // 3000)
    allpts = np.concatenate([kp, verts[:, ::step]], axis=1)
    uv, z = project(torch.as_tensor(allpts), torch.as_tensor(rig.K), torch.as_tensor(rig.R),
                    torch.as_tensor(rig.t))
    uv = uv.numpy()
    uv[z.numpy() <= 0.05] = np.nan
    paths = []
    for v in range(min(rig.num_views, oc["max_views"])):
        src_view = v if view is None else view
        for i, p in enumerate(pos):
            f = int(result.frames[p])
            row = df[(df["view"] == src_view) & (df["frame"] == f)]
            if row.empty:
                continue
            img = read_rgb(row["image_path"].iloc[0])
            drawn = O.draw_overlay(img, uv[v, i, :133], obs[v, p], uv[v, i, 133:])
            paths.append(O.write_overlay(out_dir / "overlays" / f"view{v:02d}_frame{f:04d}.png",
                                         drawn))
    return paths


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="signsplat fit", description=__doc__.split("\n")[0])
    p.add_argument("--config-json", default="{}", help="the 'fit' config section as JSON")
    p.add_argument("--keypoints", required=True, help="keypoints table (Parquet)")
    p.add_argument("--calibration",
                   help="cameras table: image sizes (+ intrinsics if calibrated); R, t unused. "
                   "Without it, sizes come from --frames and intrinsics are approximate")
    p.add_argument("--body", required=True, help="body model .npz")
    p.add_argument("--frames", help="frames table (timestamps; images for overlays)")
    p.add_argument("--masks", help="person masks (perception masks table, or a frames table "
                   "with masks) for the multi-view stages with silhouette weights")
    p.add_argument("--out-dir", required=True)
    p.add_argument("--scene")
    p.add_argument("--keypoints-source", default="detected",
                   choices=["detected", "ground_truth"])
    p.add_argument("--gt-smplx", help="ground-truth smplx_params table (evaluation)")
    p.add_argument("--gt-cameras", help="ground-truth cameras table (evaluation)")
    p.add_argument("--num-betas", type=int, default=10)
    p.add_argument("--num-expression", type=int, default=10)
    p.add_argument("--view", type=int, help="fit only this camera (single view)")
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--max-frames", type=int, help="fit only the first N frames")
    p.add_argument("--fps", type=float, default=25.0, help="when no frames table is given")
    return p


def fit(argv: list[str]) -> int:
    """Entry point of ``signsplat fit`` (see the module docstring)."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    from signsplat.device import select_device

    try:
        cfg_in = json.loads(args.config_json)
    except json.JSONDecodeError as exc:
        raise InputError(f"--config-json: not valid JSON ({exc})") from None
    cfg = validate(cfg_in, "stages/fit.schema.yaml", "--config-json")
    torch.set_num_threads(max(1, args.threads))
    device = select_device(args.device)
    t0 = time.perf_counter()
    c0 = time.process_time()
    result, obs, mode, kpm = run_fit(cfg, args.keypoints, args.calibration, args.body,
                                     frames=args.frames, scene=args.scene,
                                     num_betas=args.num_betas,
                                     num_expression=args.num_expression, device=str(device),
                                     fps=args.fps, view=args.view,
                                     max_frames=args.max_frames, masks=args.masks)
    result.seconds["cpu"] = time.process_time() - c0
    out_dir = Path(args.out_dir)
    scene = str(result.log["scene"])
    meta = {"hand_mean": HAND_MEAN, "body_model": str(args.body), "mode": mode,
            "keypoints": args.keypoints_source, "world_frame":
            "camera frame" if mode == "singleview" else
            "calibration (cameras held fixed)" if result.log.get("reference_view") == -1 else
            f"reference camera {result.log.get('reference_view')} held at its PnP pose "
            "(body-anchored)"}
    D.write_outputs(out_dir, D.smplx_table(result.params, scene, result.frames,
                                           result.provenance, result.num_keypoints),
                    D.cameras_table(result.rig, scene, result.camera_status), meta)
    ev = evaluate(kpm, result, obs, mode, args.keypoints_source, args.gt_smplx, args.gt_cameras,
                  args.view)
    write_table(ev, out_dir / "fit_eval.parquet", "fit_eval", metadata=meta)
    overlays = []
    (out_dir / "overlays").mkdir(parents=True, exist_ok=True)
    if args.frames:
        overlays = write_overlays(kpm, result, obs, args.frames, out_dir, cfg, args.view)
    summary = {"scene": scene, "mode": mode, "seconds": result.seconds,
               "seconds_with_io": time.perf_counter() - t0, "log": result.log,
               "provenance": {k: int(v) for k, v in
                              zip(*np.unique(result.provenance, return_counts=True))},
               "camera_status": result.camera_status, "overlays": len(overlays),
               "eval": {f"{m}/{p}": round(float(v), 3) for m, p, v in
                        ev[["metric", "part", "value"]].itertuples(index=False)}}
    write_bytes_atomic(out_dir / "fit_log.json", json.dumps(summary, indent=1,
                                                           default=str).encode())
    log.info("fit summary: %s", json.dumps(summary, default=str))
    return 0
