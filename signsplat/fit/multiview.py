"""Multi-view fit: SMPL-X over a sequence and the extrinsics of every camera, jointly.

1. Cameras are initialised without ground truth (config ``camera_init``, default ``auto``):
   per view the candidates PnP of the neutral body's head/torso keypoints (rest pose, mean
   shape, at the origin) against the median of its first frames' detections, PnP-RANSAC on
   every confident detection of those frames, and the coarse arc prior from the config; the
   rig is chosen by multi-view consistency (leave-one-out triangulation). This defines the
   world frame: the body-anchored frame of the first frames (y up, the signer facing +z).
2. Gauge: the reference camera (the initialised view with the most observations) is held fixed,
   which removes the 6-DoF world-frame freedom. Scale: with free extrinsics a uniform body
   scale is unobservable (the proxy's beta 0 is one), so the shape prior sets it; the
   evaluation's similarity alignment absorbs it.
   With ``camera_init: calibrated`` (a calibrated studio) the calibration table's extrinsics
   are used and held fixed instead (the calibration's world frame; no camera is solved), and
   the body starts where the head/torso keypoints triangulate (:func:`initial_root`).
3. Stages (config ``fit.multiview.stages``) run with Adam: first per chunk of frames, each chunk
   warm-started from the previous chunk's last frame (cameras fixed), then jointly over the
   whole sequence with betas and the free cameras; the final joint stage is Levenberg-Marquardt
   over everything (:mod:`signsplat.fit.levenberg_marquardt`), which the torso chain's conditioning needs.
"""

from __future__ import annotations

import logging
import time

import cv2
import numpy as np
import torch

from signsplat.body import joints as body_joints
from signsplat.fit import sequence as seq
from signsplat.fit.bodyfit import FitParams, KeypointModel
from signsplat.fit.cameras import (CameraParams, Rig, leave_one_out_px, pnp, pnp_ransac,
                                   projection_matrices, rig_prior, rig_up_direction,
                                   triangulate)
from signsplat.fit.flow import flow_targets
from signsplat.fit.solver import (Stage, make_problem, rest_body_pose, run_stage,
                                  run_warm_started)
from signsplat.geometry.align import umeyama

log = logging.getLogger(__name__)

#: Keypoints that move rigidly with the head and torso: nose, eyes, ears, shoulders, hips, face.
PNP_KEYPOINTS = tuple(range(0, 7)) + (11, 12) + body_joints.KP_FACE
#: Keypoints of the multi-view consistency test (camera_init auto): the COCO body points down
#: to the hips (the most reliable detections), over the first frames.
CONSISTENCY_KEYPOINTS = tuple(range(0, 13))


def neutral_keypoints(kpm: KeypointModel, dtype=torch.float32, device="cpu") -> np.ndarray:
    """(133,3) keypoints of the rest-pose, mean-shape body at the origin (float64, metres)."""
    with torch.no_grad():
        _, kp, _ = kpm(transl=torch.zeros(1, 3, dtype=dtype, device=device))
    return kp[0].double().cpu().numpy()


def median_observation(obs_v: np.ndarray, frames: int) -> np.ndarray:
    """Per-keypoint median over the first ``frames`` frames that observe it.

    obs_v (T,133,3) of one view -> (133,3): x, y and the fraction of those frames observing it.
    """
    out = np.zeros((obs_v.shape[1], 3))
    for k in range(obs_v.shape[1]):
        ok = np.nonzero(obs_v[:, k, 2] > 0)[0][:frames]
        if len(ok):
            out[k, :2] = np.median(obs_v[ok, k, :2], axis=0)
            out[k, 2] = len(ok) / frames
    return out


def _pooled_correspondences(kp_neutral: np.ndarray, obs_v: np.ndarray, frames: int,
                             min_score: float) -> tuple[np.ndarray, np.ndarray]:
    """Neutral-body points and their detections over the first ``frames`` observed frames of
    one view (head/torso keypoints with score >= ``min_score``): (N,3), (N,2)."""
    idx = np.asarray(PNP_KEYPOINTS)
    seen = np.nonzero((obs_v[:, idx, 2] > 0).any(1))[0][:frames]
    o = obs_v[seen][:, idx]  # (F,K,3)
    m = o[..., 2] >= min_score
    return np.broadcast_to(kp_neutral[idx], o[..., :3].shape)[m], o[..., :2][m]


#: Left/right counterpart of each consistency keypoint (nose stays).
_MIRROR = (0, 2, 1, 4, 3, 6, 5, 8, 7, 10, 9, 12, 11)


def _consistency_points(obs: np.ndarray, frames: int
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Observations (V,N,2), weights (V,N) and left/right counterparts (N,) of the
    consistency keypoints over the ``2 frames`` frames observed most (earliest first)."""
    idx = np.asarray(CONSISTENCY_KEYPOINTS)
    busy = (obs[:, :, idx, 2] > 0).sum((0, 2))
    sel = np.sort(np.argsort(-busy, kind="stable")[:max(frames, 1) * 2])
    o = obs[:, sel][:, :, idx]  # (V,F,K,3)
    V, F, Kn = o.shape[:3]
    mirror = (np.arange(F)[:, None] * Kn + np.asarray(_MIRROR)[None]).reshape(-1)
    return o[..., :2].reshape(V, -1, 2), o[..., 2].reshape(V, -1), mirror


def initial_rig(kp_neutral: np.ndarray, obs: np.ndarray, K: np.ndarray, width, height,
                cfg: dict) -> tuple[Rig, list[str], np.ndarray]:
    """Cameras without ground truth; returns (rig, status per view, rms px per view).

    obs (V,T,133,3) cleaned observations; K (V,3,3). ``cfg['camera_init']``:

    - ``pnp``: each view's PnP of the neutral body against the median of its first frames'
      detections; the arc prior where PnP fails or is implausible;
    - ``rig_prior``: the arc prior for every view with detections;
    - ``auto``: per view the candidates PnP (median), PnP-RANSAC (every confident detection of
      the first frames, outliers rejected) and the arc prior; the rig is chosen by multi-view
      consistency (:func:`signsplat.fit.cameras.leave_one_out_px`: body keypoints triangulated
      from the other views must reproject onto each view's detections): first the best of
      the three uniform rigs, then per view the candidate that lowers its leave-one-out error
      (two rounds). Noisy detections (a few-pixel face, swapped sides) make single-view PnP
      tens of degrees wrong; the consistency test catches it. PnP candidates whose distance
      to the body is off the prior's by more than ``pnp_distance_tolerance`` are dropped, and
      a PnP rig must beat the prior rig by the factor ``prior_margin``.

    Status per view: 'pnp', 'pnp_ransac', 'prior' or 'no_detections'.
    """
    V = obs.shape[0]
    idx = np.asarray(PNP_KEYPOINTS)
    chest = kp_neutral[[5, 6]].mean(0)
    prior = rig_prior(K, width, height, V, cfg["camera_prior"]["arc_degrees"],
                      cfg["camera_prior"]["distance"], chest)
    R, t = prior.R.copy(), prior.t.copy()
    mode = cfg["camera_init"]
    status, rms = [], np.full(V, np.nan)
    cands: list[dict[str, tuple[np.ndarray, np.ndarray]]] = []
    for v in range(V):
        med = median_observation(obs[v], cfg["init_frames"])
        m = med[idx, 2] > 0
        cands.append({})
        if not m.any():
            status.append("no_detections")
            continue
        cands[v]["prior"] = (prior.R[v], prior.t[v])
        if mode == "rig_prior":
            status.append("prior")
            continue
        sol = None
        if m.sum() >= cfg["pnp_min_points"]:
            sol = pnp(kp_neutral[idx][m], med[idx][m][:, :2], K[v])
        if sol is not None and sol[2] <= cfg["pnp_max_rms_px"] and \
                np.linalg.norm(sol[1]) <= cfg["pnp_max_distance_m"] and \
                (mode != "auto" or _plausible_distance(sol[0], sol[1], chest, cfg)):
            cands[v]["pnp"] = (sol[0], sol[1])
            rms[v] = sol[2]
        elif sol is not None:
            rms[v] = sol[2]
        if mode == "auto":
            X, x = _pooled_correspondences(kp_neutral, obs[v], cfg["init_frames"],
                                           cfg["ransac_min_score"])
            thr = cfg["ransac_threshold"] * float(np.asarray(height)[v])
            rs = pnp_ransac(X, x, K[v], thr)
            if rs is not None and rs[3] >= cfg["ransac_min_inliers"] and \
                    np.linalg.norm(rs[1]) <= cfg["pnp_max_distance_m"] and \
                    _plausible_distance(rs[0], rs[1], chest, cfg):
                cands[v]["pnp_ransac"] = (rs[0], rs[1])
        best = "pnp" if "pnp" in cands[v] else "prior"
        R[v], t[v] = cands[v][best]
        status.append(best)
    if mode == "auto":
        R, t, status = _choose_by_consistency(cands, obs, np.asarray(K, float), R, t, status,
                                              cfg["init_frames"], cfg["prior_margin"])
    return Rig(K=np.asarray(K, float), R=R, t=t, width=np.asarray(width),
               height=np.asarray(height)), status, rms


def _plausible_distance(R: np.ndarray, t: np.ndarray, chest: np.ndarray, cfg: dict) -> bool:
    """A PnP camera's distance to the chest is within ``pnp_distance_tolerance`` (a ratio) of
    the rig prior's distance. Multi-view consistency cannot catch a rig that is consistently
    too close: with biased detections PnP of the neutral body can put every camera at half the
    distance, and such a rig still triangulates the few body points consistently."""
    d = float(np.linalg.norm(R @ chest + t))
    ref = float(cfg["camera_prior"]["distance"])
    tol = float(cfg["pnp_distance_tolerance"])
    return ref / tol <= d <= ref * tol


def _choose_by_consistency(cands, obs, K, R, t, status, frames, prior_margin=1.0):
    """Candidate cameras per view chosen by leave-one-out multi-view consistency.

    A uniform PnP rig replaces the uniform prior rig only when its leave-one-out error is
    below ``prior_margin`` times the prior's (the configured rig is trusted unless clearly
    beaten: a few body points from a narrow-baseline rig leave ambiguous configurations)."""
    uv, w, mirror = _consistency_points(obs, frames)
    live = [v for v in range(len(cands)) if cands[v]]
    if len(live) < 3:
        return R, t, status

    def score(Rs, ts):
        e = leave_one_out_px(K[live], Rs[live], ts[live], uv[live], w[live], mirror)
        return float(np.nanmedian(e)) if np.isfinite(e).any() else np.inf, e

    best, best_s = None, np.inf
    for name in ("prior", "pnp", "pnp_ransac"):
        Rs, ts, st = R.copy(), t.copy(), list(status)
        for v in live:
            key = name if name in cands[v] else next(
                k for k in ("pnp_ransac", "pnp", "prior") if k in cands[v])
            Rs[v], ts[v] = cands[v][key]
            st[v] = key
        s, _ = score(Rs, ts)
        log.info("camera init: uniform rig %r -> leave-one-out median %.2f px", name, s)
        if name == "prior":
            s = s * prior_margin
        if s < best_s:
            best, best_s = (Rs, ts, st), s
    if best is None:
        return R, t, status
    R, t, status = best
    for _ in range(2):
        changed = False
        for i, v in enumerate(live):
            cur = score(R, t)[1][i]
            for key, (Rc, tc) in cands[v].items():
                if key == status[v]:
                    continue
                R2, t2 = R.copy(), t.copy()
                R2[v], t2[v] = Rc, tc
                e = score(R2, t2)[1][i]
                if np.isfinite(e) and (not np.isfinite(cur) or e < 0.8 * cur):
                    R, t, cur = R2, t2, e
                    status = list(status)
                    status[v] = key
                    changed = True
        if not changed:
            break
    log.info("camera init: chosen %s", status)
    return R, t, status


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
        cams = CameraParams(rig0, fixed=list(range(V)), refine_focal=False, dtype=dtype,
                            device=device)
        init.update(initial_root(kpm, rig0, obs, T, dtype, device))
        log.info("cameras: calibrated extrinsics, held fixed; body placed at %s m",
                 np.round(init["transl"][0], 3).tolist())
    else:
        kp0 = neutral_keypoints(kpm, dtype, device)
        rig0, status, rms = initial_rig(kp0, obs, K, width, height, mv)
        ok = ("pnp",) if mv["camera_init"] == "pnp" else ("pnp", "pnp_ransac", "prior")
        solved = [v for v in range(V) if status[v] in ok]
        if not solved:
            raise ValueError("no camera could be initialised: too few head/torso keypoints in "
                             "every view's first frames")
        ref = max(solved, key=lambda v: views_obs[v])
        no_det = [v for v in range(V) if status[v] == "no_detections"]
        cams = CameraParams(rig0, fixed=[ref] + no_det, refine_focal=mv["refine_focal"],
                            dtype=dtype, device=device)
        log.info("cameras initialised: %s (reference view %d, PnP rms px %s)", status, ref,
                 np.round(rms, 2).tolist())
    t_init = time.perf_counter()

    params = FitParams(T, kpm.model.num_betas, kpm.model.num_expression, dtype=dtype,
                       device=device, init=init)
    solved_R = rig0.R[solved]
    up = rig_up_direction(solved_R) if mv["level_cameras"] else None
    log.info("world vertical for the upright prior: %s",
             "body frame +y" if up is None else np.round(up, 4).tolist())
    weights = {"upright": mv["upright_weight"], "camera_anchor": mv["camera_anchor_weight"]}
    flow_args = {}
    if any(Stage.from_config(s).uses_flow for s in mv["stages"]):
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
    problem = make_problem(kpm, obs, cfg, frames, weights=weights,
                           dtype=dtype, device=device, up=up, level_cameras=up is not None,
                           masks=masks, **flow_args)
    history = {}
    for st_cfg in mv["stages"]:
        stage = Stage.from_config(st_cfg)
        ts = time.perf_counter()
        if stage.warm_start:
            history[stage.name] = run_warm_started(problem, params, cams, stage,
                                                   mv["chunk"], fitted)
        else:
            history[stage.name] = run_stage(problem, params, cams, stage)[-1:]
        log.info("stage %s: %.1f s, final loss %s", stage.name, time.perf_counter() - ts,
                 np.round(history[stage.name], 3).tolist())
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
                         log={"reference_view": ref, **{f"pnp_rms_px_view{v}": float(r)
                                                        for v, r in enumerate(rms)}})
