"""Multi-view fit: SMPL-X over a sequence and the extrinsics of every camera, jointly.

1. Cameras are initialised without ground truth and without assuming the rig (config
   ``camera_init``, default ``auto``): hypotheses from 2D-2D keypoint correspondences across
   views, from PnP of the rest body and from the configured arc prior, scored on held-out
   keypoints (:mod:`signsplat.fit.rig_init`). This defines the world frame: the rest body's
   frame at the first frames (y up, the signer facing +z). A view no hypothesis places is
   reported ``unplaced``: its keypoints are left out and its camera is held fixed. A view
   that may face the signer from the other side (``doubtful``) is decided by its person masks
   once the stages without mask terms have fitted the body (:mod:`signsplat.fit.side_check`,
   config ``init.mask_side_margin``); when it is turned around, the stages start again.
2. Gauge: the reference camera (the placed, not doubtful view with the most observations) is
   held fixed, which removes the 6-DoF world-frame freedom. Scale: with free extrinsics a
   uniform body scale is unobservable (the proxy's beta 0 is one), so the shape prior sets it;
   the evaluation's similarity alignment absorbs it.
   With ``camera_init: calibrated`` (a calibrated studio) the calibration table's extrinsics
   are used and held fixed instead (the calibration's world frame; no camera is solved), and
   the body starts where the head/torso keypoints triangulate (:func:`initial_root`).
3. Stages (config ``fit.multiview.stages``) run with Adam: first per chunk of frames, each chunk
   warm-started from the previous chunk's last frame (cameras fixed), then jointly over the
   whole sequence with betas and the free cameras; the final joint stage is Levenberg-Marquardt
   over everything (:mod:`signsplat.fit.levenberg_marquardt`), which the torso chain's
   conditioning needs.

The fit models static cameras; with per-frame camera motion (the simulator's camera_jitter)
it finds one camera per view, evaluated against the mean camera
(:func:`signsplat.fit.data.read_rig`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace

import cv2
import numpy as np
import torch

from signsplat.fit import sequence as seq
from signsplat.fit.bodyfit import FitParams, KeypointModel, keypoints_of
from signsplat.fit.cameras import (CameraParams, Rig, projection_matrices, rig_up_direction,
                                   triangulate)
from signsplat.fit.flow import flow_targets
from signsplat.fit.rig_init import (PNP_KEYPOINTS, exchange_sides, inlier_threshold_px,
                                    place_cameras, placed_views, side_swaps)
from signsplat.fit.side_check import SideCheck, check_side
from signsplat.fit.solver import (Stage, make_problem, rest_body_pose, run_stage,
                                  run_warm_started)
from signsplat.geometry.align import umeyama

log = logging.getLogger(__name__)


def neutral_keypoints(kpm: KeypointModel, dtype=torch.float32, device="cpu") -> np.ndarray:
    """(133,3) keypoints of the rest-pose, mean-shape body at the origin (float64, metres)."""
    with torch.no_grad():
        _, kp, _ = kpm(transl=torch.zeros(1, 3, dtype=dtype, device=device))
    return kp[0].double().cpu().numpy()


def initial_root(kpm: KeypointModel, rig: Rig, obs: np.ndarray, T: int, dtype=torch.float32,
                 device: torch.device | str = "cpu", frames: int = 10) -> dict[str, np.ndarray]:
    """``global_orient`` and ``transl`` (T,3) placing the neutral body on the head/torso
    keypoints triangulated by a calibrated rig (median over the first ``frames`` frames that
    see them): the rigid (Kabsch) fit of the neutral body's keypoints to those points. Fewer
    than 3 triangulated points leave the body at the origin, unrotated."""
    with torch.no_grad():
        j, kp, _ = kpm(transl=torch.zeros(1, 3, dtype=dtype, device=device))
    pelvis = j[0, 0].double().cpu().numpy()
    kp0 = kp[0].double().cpu().numpy()
    idx = np.asarray(PNP_KEYPOINTS)
    seen = np.nonzero((obs[:, :, idx, 2] > 0).sum((0, 2)) > 0)[0][:frames]
    zero = {"global_orient": np.zeros((T, 3)), "transl": np.zeros((T, 3))}
    if not len(seen):
        return zero
    o = obs[:, seen][:, :, idx]  # (V,F,K,3): every frame's points triangulated in one call
    V, F, Kn = o.shape[:3]
    X, ok = triangulate(projection_matrices(rig.K, rig.R, rig.t), o[..., :2].reshape(V, -1, 2),
                        o[..., 2].reshape(V, -1))
    with np.errstate(all="ignore"):
        X = np.nanmedian(np.where(ok[:, None], X, np.nan).reshape(F, Kn, 3), axis=0)
    ok = np.isfinite(X).all(1)
    if ok.sum() < 3:
        return zero
    rigid = umeyama(kp0[idx][ok], X[ok], with_scale=False)
    # SMPL-X rotates about the pelvis: posed = R (x - pelvis) + pelvis + transl
    transl = rigid.t + rigid.R @ pelvis - pelvis
    rotvec = cv2.Rodrigues(rigid.R)[0].reshape(3)
    return {"global_orient": np.tile(rotvec, (T, 1)), "transl": np.tile(transl, (T, 1))}


def _exchange_back(obs: np.ndarray, rig: Rig, views: list[int], mv: dict, height,
                   extra_log: dict) -> np.ndarray:
    """``obs`` with left and right exchanged back in the view-frames whose detections match
    the other views' points only that way round (config ``repair_sides``; counted in
    ``extra_log['side_swaps']``)."""
    if not mv["repair_sides"]:
        return obs
    swaps = side_swaps(rig.K, rig.R, rig.t, obs, inlier_threshold_px(mv["init"], height),
                       views=views)
    if swaps.any():
        obs = exchange_sides(obs, swaps)
        log.info("left and right exchanged back in %d view-frames (views %s)",
                 int(swaps.sum()), sorted(set(np.nonzero(swaps)[0].tolist())))
    extra_log["side_swaps"] = int(swaps.sum())
    return obs


def _run_stages(problem, params: FitParams, cams: CameraParams, stages: list[Stage],
                chunk: int, fitted: np.ndarray, solved: set[str], log_out: dict) -> None:
    """Run ``stages`` in order (Adam warm-started per chunk, or jointly); ``solved`` gathers
    the parameter groups solved so far (warm starts copy only the others); ``log_out`` gets
    the views whose cameras each stage held (``cameras_held``)."""
    for stage in stages:
        ts = time.perf_counter()
        held = problem.held_views(stage)
        if stage.holds_cameras:
            log_out.setdefault("cameras_held", {})[stage.name] = held
            log.info("stage %s: cameras of views %s held (keypoints within %.2f px of the "
                     "other views' at the camera initialisation), the others move", stage.name,
                     held, stage.hold_cameras_within_px)
        if stage.warm_start:
            losses = run_warm_started(problem, params, cams, stage, chunk, fitted, solved)
        else:
            losses = run_stage(problem, params, cams, stage)[-1:]
        solved |= set(stage.groups)
        log.info("stage %s: %.1f s, final loss %s", stage.name, time.perf_counter() - ts,
                 np.round(losses, 3).tolist())


def _mask_sides(kpm: KeypointModel, params: FitParams, rig: Rig, obs: np.ndarray,
                masks: np.ndarray, fitted: np.ndarray, views: list[int], threshold_px: float,
                max_frames: int = 24) -> dict[int, SideCheck]:
    """:func:`signsplat.fit.side_check.check_side` of each of ``views`` on the body fitted so
    far, over at most ``max_frames`` evenly spaced fitted frames."""
    idx = np.nonzero(fitted)[0]
    idx = idx[np.unique(np.linspace(0, len(idx) - 1, min(max_frames, len(idx))).astype(int))]
    _, kp, verts = keypoints_of(kpm, {k: v[idx] for k, v in params.export().items()})
    faces = kpm.model.faces.cpu().numpy()
    centre = kp[:, [5, 6]].mean((0, 1))  # the chest: between the shoulders
    return {v: check_side(rig.K[v], rig.R[v], rig.t[v], verts, faces, kp, masks[v, idx],
                          obs[v, idx], centre, threshold_px) for v in views}


def fit_multiview(kpm: KeypointModel, obs: np.ndarray, frames: np.ndarray, K: np.ndarray,
                  width, height, cfg: dict, device: torch.device | str = "cpu",
                  dtype=torch.float32, masks: np.ndarray | None = None,
                  extrinsics: tuple[np.ndarray, np.ndarray] | None = None,
                  images: np.ndarray | None = None) -> seq.FitResult:
    """Fit SMPL-X + cameras to cleaned observations.

    kpm: keypoint model; obs (V,T,133,3) pixels + confidence (0 = ignore, no NaN);
    frames (T,) frame numbers; K (V,3,3) intrinsics (calibrated or approximate); width/height
    (V,) pixels; cfg: the validated ``fit`` config section (``cfg['multiview']`` for this mode);
    masks (V,T,H,W) bool person masks for the stages with silhouette weights (a stage with
    such weights and no masks raises ValueError); extrinsics (R (V,3,3), t (V,3)) of a calibrated
    rig, used (and held fixed) with ``camera_init: calibrated``; images (V,T,H,W) uint8 grey
    frames for the stages with a flow weight (their flow is computed once here, with the
    settings ``cfg['multiview']['flow']``; a stage with a flow weight and no images or masks
    raises ValueError).
    """
    t0 = time.perf_counter()
    mv = cfg["multiview"]
    V, T = obs.shape[:2]
    fitted, count = seq.fitted_mask(obs, cfg["min_keypoints"])
    if not fitted.any():
        raise ValueError("no frame has enough keypoints to fit")
    views_obs = (obs[..., 2] > 0).sum(axis=(1, 2))
    init = {"body_pose": rest_body_pose(cfg, T)}
    if mv["camera_init"] == "calibrated":
        if extrinsics is None:
            raise ValueError("camera_init calibrated needs the calibrated extrinsics")
        rig0 = Rig(K=np.asarray(K, float), R=np.asarray(extrinsics[0], float),
                   t=np.asarray(extrinsics[1], float), width=np.asarray(width),
                   height=np.asarray(height))
        status = ["calibrated"] * V
        solved = list(range(V))
        rms = np.full(V, np.nan)
        ref = -1  # no reference camera: the calibration fixes the world frame
        extra_log = {"camera_init": "calibrated"}
        cam_args = {"fixed": list(range(V)), "refine_focal": False}
        doubtful = []
        init.update(initial_root(kpm, rig0, obs, T, dtype, device))
        log.info("cameras: calibrated extrinsics, held fixed; body placed at %s m",
                 np.round(init["transl"][0], 3).tolist())
    else:
        kp0 = neutral_keypoints(kpm, dtype, device)
        hyp = place_cameras(kp0, obs, K, width, height, mv)
        status = hyp.status
        rig0 = Rig(K=np.asarray(K, float), R=hyp.R, t=hyp.t, width=np.asarray(width),
                   height=np.asarray(height))
        solved = placed_views(status)
        if not solved:
            raise ValueError("no camera could be placed: too few keypoints seen by the views "
                             "(see the camera init lines of the log)")
        unplaced = [v for v in range(V) if status[v] == "unplaced"]
        if unplaced:  # their keypoints would pull the body towards a wrong camera
            obs = obs.copy()
            obs[unplaced] = 0.0
            fitted, count = seq.fitted_mask(obs, cfg["min_keypoints"])
            if not fitted.any():
                raise ValueError("no frame has enough keypoints in the placed views")
        # the reference holds the world frame: not a view that may face the other side
        sure = [v for v in solved if v not in hyp.doubtful] or solved
        ref = max(sure, key=lambda v: views_obs[v])
        cam_args = {"fixed": [v for v in range(V) if v == ref or v not in solved],
                    "refine_focal": mv["refine_focal"]}
        doubtful = sorted(hyp.doubtful)
        rms = hyp.view_px
        extra_log = {"camera_init": hyp.winner, "camera_init_turned": len(hyp.turned),
                     "camera_init_doubtful": len(hyp.doubtful),
                     "camera_init_turned_views": sorted(hyp.turned),
                     "camera_init_doubtful_views": sorted(hyp.doubtful),
                     **{f"camera_init_{k}_px": float(x) for k, x in hyp.scores.items()}}
        log.info("cameras initialised: %s (winner %s, reference view %d, held-out px %s)",
                 status, hyp.winner, ref, np.round(rms, 2).tolist())
    fit_obs = _exchange_back(obs, rig0, solved, mv, height, extra_log)
    t_init = time.perf_counter()

    weights = {"upright": mv["upright_weight"], "camera_anchor": mv["camera_anchor_weight"]}
    stages = [Stage.from_config(s) for s in mv["stages"]]
    flow_args = {}
    if any(stage.uses_flow for stage in stages):
        if images is None or masks is None:
            raise ValueError("a stage weights the flow term: it needs the images and the "
                             "person masks")
        fc = mv["flow"]  # validated: the schema holds the defaults
        tf = time.perf_counter()
        flow = flow_targets(images, masks, frames, fc["gaps"], fc["consistency_px"],
                            fc["preset"], dtype=dtype, device=device)
        log.info("optical flow: %d frame pairs (gaps %s), %.1f s", flow.num_pairs,
                 fc["gaps"], time.perf_counter() - tf)
        flow_args = {"flow": flow}
    # the stages before the first with mask terms fit the body on the keypoints alone
    first_mask = next((i for i, st in enumerate(stages) if st.uses_silhouette), len(stages))
    image_sizes = np.column_stack([width, height])  # (V,2): the hold's bounds
    margin = mv["init"]["mask_side_margin"]
    check = doubtful if masks is not None and margin is not None else []
    view_px = np.asarray(rms, float).copy()  # the stages' hold_cameras_within_px reads it
    view_px[cam_args["fixed"]] = np.nan  # fixed cameras never move: none to hold
    while True:
        params = FitParams(T, kpm.model.num_betas, kpm.model.num_expression, dtype=dtype,
                           device=device, init=init)
        cams = CameraParams(rig0, **cam_args, dtype=dtype, device=device)
        up = rig_up_direction(rig0.R[solved]) if mv["level_cameras"] else None
        log.info("world vertical for the upright prior: %s",
                 "body frame +y" if up is None else np.round(up, 4).tolist())
        problem = make_problem(kpm, fit_obs, cfg, frames, weights=weights,
                               dtype=dtype, device=device, up=up, level_cameras=up is not None,
                               masks=masks, image_sizes=image_sizes, view_px=view_px,
                               **flow_args)
        extra_log["legs_held"] = problem.legs_held
        if problem.legs_held:
            log.info("legs no view sees (%s): held at the rest pose (fit.hold_unseen_legs)",
                     ", ".join(problem.legs_held))
        groups_solved: set[str] = set()
        _run_stages(problem, params, cams, stages[:first_mask], mv["chunk"], fitted,
                    groups_solved, extra_log)
        if check:
            sides = _mask_sides(kpm, params, cams.to_rig(), fit_obs, masks, fitted, check,
                                inlier_threshold_px(mv["init"], height))
            check = []  # once: a second placement is not doubted again
            extra_log["camera_mask_sides"] = {
                str(v): {"iou_here": round(c.iou_here, 4), "iou_there": round(c.iou_there, 4),
                         "turned": c.turn(margin)} for v, c in sides.items()}
            turn = {v: c for v, c in sides.items() if c.turn(margin)}
            for v, c in sides.items():
                log.log(logging.WARNING if v in turn else logging.INFO,
                        "camera side by the masks: view %d's fitted outline overlaps its masks "
                        "%.3f (mean IoU) where it is placed and %.3f turned around: %s", v,
                        c.iou_here, c.iou_there,
                        "turned around, fitting again" if v in turn else "it stays")
            if turn:
                R, t = rig0.R.copy(), rig0.t.copy()
                for v, c in turn.items():
                    R[v], t[v] = c.R, c.t
                    view_px[v] = np.nan  # measured on the other side: no evidence here
                rig0 = replace(rig0, R=R, t=t)
                fit_obs = _exchange_back(obs, rig0, solved, mv, height, extra_log)
                continue
        _run_stages(problem, params, cams, stages[first_mask:], mv["chunk"], fitted,
                    groups_solved, extra_log)
        break
    raw = params.export()
    filled, prov = seq.fill_gaps(raw, fitted)
    t1 = time.perf_counter()
    rig = cams.to_rig()
    for v in range(V):
        if status[v] == "no_detections":
            log.warning("view %d has no detections: its camera is the arc prior, unconstrained", v)
    return seq.FitResult(params=filled, rig=rig, frames=np.asarray(frames), provenance=prov,
                         num_keypoints=count.astype(np.int64), camera_status=status,
                         seconds={"camera_init": t_init - t0, "solve": t1 - t_init,
                                  "total": t1 - t0},
                         log={"reference_view": ref, **extra_log,
                              **{f"camera_init_px_view{v}": float(r) for v, r in enumerate(rms)}})
