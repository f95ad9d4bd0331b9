"""Fit accuracy against ground truth (numpy): alignment, MPJPE, PA-MPJPE, cameras, jitter.

Point sets are ``(T, N, 3)`` float64 in metres; results are in millimetres (``*_mm``),
degrees or pixels as named. The fitted world frame is a free gauge (fixed by a reference camera
during the solve), so before 3D errors are taken the fit is brought into the ground-truth frame
with one transform for the whole sequence, estimated from the cameras (see
:func:`gauge_alignment`). Per-part errors then remove the part's root (pelvis, wrist, face
centroid) per frame; PA- errors use a per-frame similarity (Procrustes) instead.
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd
import torch

from signsplat.errors import InputError
from signsplat.fit.bodyfit import KeypointModel, keypoints_of
from signsplat.fit.cameras import Rig, project
from signsplat.fit.data import read_rig, read_smplx
from signsplat.fit.rig_init import placed_views
from signsplat.fit.sequence import FitResult
from signsplat.geometry.align import Similarity, rotation_angle_deg, umeyama  # noqa: F401


def procrustes_batch(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Per-frame similarity alignment of ``pred (T,N,3)`` onto ``gt (T,N,3)``; returns aligned."""
    out = np.empty_like(pred, dtype=float)
    for i in range(len(pred)):
        out[i] = umeyama(pred[i], gt[i], with_scale=True).apply(pred[i])
    return out


def _camera_axes_points(rig: Rig, length: float) -> np.ndarray:
    """Centre plus points along each camera's z and y axes, (3V, 3)."""
    C = rig.centres()
    z = rig.R[:, 2, :]
    y = rig.R[:, 1, :]
    return np.concatenate([C, C + length * z, C + length * y])


def gauge_alignment(fit: Rig, gt: Rig, min_spread: float = 0.05) -> tuple[Similarity, str]:
    """Transform taking the fitted world frame onto the ground-truth world frame.

    With >= 3 cameras whose centres span more than ``min_spread`` metres in two directions, a
    similarity (Umeyama) on the centres; otherwise (one camera, two, or nearly coincident or
    collinear centres) a rigid transform from the centres plus points 1 m along each camera's
    optical and vertical axes, which also uses the camera orientations. Returns (transform,
    method name).
    """
    C_fit, C_gt = fit.centres(), gt.centres()
    if len(C_gt) >= 3:
        sv = np.linalg.svd(C_gt - C_gt.mean(0), compute_uv=False)
        if sv[1] > min_spread:
            return umeyama(C_fit, C_gt, with_scale=True), "similarity_centres"
    return umeyama(_camera_axes_points(fit, 1.0), _camera_axes_points(gt, 1.0),
                   with_scale=False), "rigid_axes"


def align_rig(fit: Rig, sim: Similarity) -> Rig:
    """Express a rig in the destination frame of ``sim`` (``x_dst = s R x_src + t``)."""
    R_new = fit.R @ sim.R.T
    C_new = sim.apply(fit.centres())
    t_new = -np.einsum("vij,vj->vi", R_new, C_new)
    return Rig(K=fit.K, R=R_new, t=t_new, width=fit.width, height=fit.height)


def camera_errors(fit: Rig, gt: Rig) -> dict[str, float]:
    """Rotation (deg) and centre (m) errors per the gauge alignment; means and maxima."""
    sim, method = gauge_alignment(fit, gt)
    al = align_rig(fit, sim)
    rot = rotation_angle_deg(al.R, gt.R)
    cen = np.linalg.norm(al.centres() - gt.centres(), axis=-1)
    f_err = np.abs(fit.K[:, 0, 0] - gt.K[:, 0, 0]) / gt.K[:, 0, 0]
    return {"rotation_deg_mean": float(rot.mean()), "rotation_deg_max": float(rot.max()),
            "centre_m_mean": float(cen.mean()), "centre_m_max": float(cen.max()),
            "focal_rel_err_mean": float(f_err.mean()), "scale": float(sim.s),
            "alignment": method}


def placed_camera_errors(fit: Rig, gt: Rig, status: list[str]
                         ) -> tuple[dict[str, float], Similarity]:
    """:func:`camera_errors` and the gauge alignment over the cameras the fit placed
    (``status`` per view; all views when none was placed): cameras without detections or that
    could not be placed are not measured (fit_eval counts them in ``cameras_unplaced``)."""
    ok = placed_views(status) or list(range(fit.num_views))
    sim, _ = gauge_alignment(fit.select(ok), gt.select(ok))
    return camera_errors(fit.select(ok), gt.select(ok)), sim


def mpjpe_mm(pred: np.ndarray, gt: np.ndarray, root: np.ndarray | int | None) -> float:
    """Mean per-joint position error in mm after removing a per-frame root.

    pred, gt (T,N,3) metres. ``root``: an index into N, an index array (their mean is the root),
    or None (no root removal).
    """
    if root is not None:
        idx = np.atleast_1d(root)
        pred = pred - pred[:, idx].mean(1, keepdims=True)
        gt = gt - gt[:, idx].mean(1, keepdims=True)
    return float(np.linalg.norm(pred - gt, axis=-1).mean() * 1000)


def seen_mpjpe_mm(pred: np.ndarray, gt: np.ndarray, seen: np.ndarray, root: int) -> float:
    """MPJPE in mm, root-relative as :func:`mpjpe_mm`, over the entries of ``seen (T,N)`` only
    (NaN when there is none). pred, gt (T,N,3) metres; the root joint counts whether or not
    it is seen."""
    if not seen.any():
        return float("nan")
    err = np.linalg.norm((pred - pred[:, root:root + 1]) - (gt - gt[:, root:root + 1]), axis=-1)
    return float(err[seen].mean() * 1000)


def pa_mpjpe_mm(pred: np.ndarray, gt: np.ndarray) -> float:
    """MPJPE in mm after a per-frame similarity (Procrustes) alignment."""
    return float(np.linalg.norm(procrustes_batch(pred, gt) - gt, axis=-1).mean() * 1000)


def acceleration_error_mm(pred: np.ndarray, gt: np.ndarray, root: int | None = None) -> float:
    """Jitter: mean norm of the difference of second differences (mm / frame^2). T >= 3."""
    if len(pred) < 3:
        return float("nan")
    if root is not None:
        pred = pred - pred[:, root:root + 1]
        gt = gt - gt[:, root:root + 1]
    acc_p = pred[2:] - 2 * pred[1:-1] + pred[:-2]
    acc_g = gt[2:] - 2 * gt[1:-1] + gt[:-2]
    return float(np.linalg.norm(acc_p - acc_g, axis=-1).mean() * 1000)


def reprojection_px(uv: np.ndarray, kp: np.ndarray) -> float:
    """Mean pixel distance between projections ``uv (...,2)`` and observations ``kp (...,3)``.

    Only observations with score > 0 count; NaN when none does.
    """
    m = kp[..., 2] > 0
    if not m.any():
        return float("nan")
    return float(np.linalg.norm(uv[m] - kp[..., :2][m], axis=-1).mean())


#: image-error parts: body-model part label -> fit_eval part name
IMAGE_PARTS = {0: "body", 1: "head", 2: "left_hand", 3: "right_hand"}


def in_images(X: np.ndarray, rig: Rig) -> tuple[np.ndarray, np.ndarray]:
    """Points ``X`` (T,N,3) metres in every camera of ``rig``: pixels (V,T,N,2) and whether
    the camera sees each point in its image (V,T,N): in front, inside the frame."""
    uv, z = project(*(torch.as_tensor(np.asarray(a, float)) for a in (X, rig.K, rig.R, rig.t)))
    uv, z = uv.numpy(), z.numpy()
    w = np.asarray(rig.width, float)[:, None, None]
    h = np.asarray(rig.height, float)[:, None, None]
    seen = (z > 1e-6) & (uv[..., 0] >= 0) & (uv[..., 0] < w) & (uv[..., 1] >= 0) & \
        (uv[..., 1] < h)
    return uv, seen


def image_errors(fit_verts: np.ndarray, fit_rig: Rig, gt_verts: np.ndarray, gt_rig: Rig,
                 part_labels: np.ndarray) -> list[tuple[str, str, float, str]]:
    """Where the fitted body lands in the images against the true one: mean pixel distance
    between the fitted vertices projected by the fitted cameras and the true vertices projected
    by the true cameras (no alignment: both are in pixels of the same images), over the
    vertices the true camera sees in its image (:func:`in_images`). This is what
    an avatar trained on the fit inherits. Vertices (T,N,3) metres; part_labels (N,) of
    :data:`signsplat.body.joints.PART_NAMES`. Rows ('image_error', part, px, 'px')."""
    uv_f, _ = in_images(fit_verts, fit_rig)
    uv_g, seen = in_images(gt_verts, gt_rig)
    err = np.linalg.norm(uv_f - uv_g, axis=-1)

    def mean(m):
        return float(err[m].mean()) if m.any() else float("nan")

    rows = [("image_error", "all", mean(seen), "px")]
    for label, part in IMAGE_PARTS.items():
        rows.append(("image_error", part, mean(seen & (part_labels == label)[None, None]), "px"))
    return rows


# --- the fit_eval table ---------------------------------------------------------------------

from signsplat.body import joints as body_joints  # noqa: E402
from signsplat.io.tables import Table, register_table  # noqa: E402

FIT_EVAL = register_table(Table(
    "fit_eval",
    "SMPL-X fit accuracy against ground truth, one row per metric, with the fit's seconds.",
    {
        "scene": "str sequence name",
        "mode": "str multiview or singleview",
        "keypoints": "str detected or ground_truth (which 2D keypoints were fitted)",
        "metric": "str mpjpe, pa_mpjpe, reprojection, camera_rotation, camera_centre, jitter, "
                  "image_error (px between the fitted and the true body in the images), "
                  "cameras_unplaced (views the initialisation could not place; not in the "
                  "camera errors), scale, seconds, ...",
        "part": "str body, upper_body, left_hand, right_hand, hands, face, head (image_error), "
                "all, cameras; body_seen (mpjpe only): the body joints inside the images of "
                "at least two true cameras (the one camera of a one-view fit) in that frame",
        "value": "float64 the figure (NaN when not measurable)",
        "unit": "str mm, px, deg, m, mm/frame^2, s, 1",
        "seconds_total": "float64 wall-clock seconds of the whole fit",
        "seconds_per_frame": "float64 seconds_total / frames",
    },
))

#: Point sets evaluated in 3D: name -> (source, indices, root). Source 'joints' = the 55
#: SMPL-X joints, 'kp' = the 133 whole-body keypoints. Root: index into the set's indices,
#: 'centroid', or None.
BODY_JOINTS = tuple(range(22))
UPPER_BODY_JOINTS = tuple(body_joints.JOINT_INDEX[n] for n in (
    "pelvis", "spine1", "spine2", "spine3", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist"))
PARTS_3D = {
    "body": ("joints", BODY_JOINTS, 0),
    "upper_body": ("joints", UPPER_BODY_JOINTS, 0),
    "left_hand": ("kp", body_joints.KP_LEFT_HAND, 0),
    "right_hand": ("kp", body_joints.KP_RIGHT_HAND, 0),
    "face": ("kp", body_joints.KP_FACE, "centroid"),
}


def _part_points(joints: np.ndarray, kp: np.ndarray, part: str) -> tuple[np.ndarray, object]:
    src, idx, root = PARTS_3D[part]
    pts = (joints if src == "joints" else kp)[:, list(idx)]
    return pts, root


def pose_errors(fit_joints: np.ndarray, fit_kp: np.ndarray, gt_joints: np.ndarray,
                gt_kp: np.ndarray) -> list[tuple[str, str, float, str]]:
    """MPJPE / PA-MPJPE / jitter per part. Inputs (T,55,3), (T,133,3) in the GT frame, metres.

    Returns rows (metric, part, value, unit). 'hands' averages both hands.
    """
    rows = []
    for part in PARTS_3D:
        p, root = _part_points(fit_joints, fit_kp, part)
        g, _ = _part_points(gt_joints, gt_kp, part)
        r = np.arange(p.shape[1]) if root == "centroid" else root
        rows.append(("mpjpe", part, mpjpe_mm(p, g, r), "mm"))
        rows.append(("pa_mpjpe", part, pa_mpjpe_mm(p, g), "mm"))
        rows.append(("jitter", part, acceleration_error_mm(p, g), "mm/frame^2"))
    by = {(m, p): v for m, p, v, _ in rows}
    for metric, unit in (("mpjpe", "mm"), ("pa_mpjpe", "mm"), ("jitter", "mm/frame^2")):
        rows.append((metric, "hands", (by[(metric, "left_hand")] + by[(metric, "right_hand")]) / 2,
                     unit))
    return rows


def body_seen_mpjpe(fit_joints: np.ndarray, gt_joints: np.ndarray, gt_rig: Rig) -> float:
    """Body MPJPE (mm, pelvis-rooted) over the body joints that the true cameras see: inside
    the images of at least two cameras (of the one camera in a one-view fit) in that frame.
    Joints (T,55,3) in the ground-truth frame, metres. What the images can tell the fit,
    where ``body`` also counts joints out of every frame (legs below a waist-up framing)."""
    body = list(BODY_JOINTS)
    _, seen = in_images(gt_joints[:, body], gt_rig)
    need = min(2, gt_rig.num_views)
    return seen_mpjpe_mm(fit_joints[:, body], gt_joints[:, body], seen.sum(0) >= need, 0)


def reprojection_rows(uv: np.ndarray, obs: np.ndarray) -> list[tuple[str, str, float, str]]:
    """2D reprojection error per part: uv (V,T,133,2) of the fit, obs (V,T,133,3) fitted input."""
    rows = [("reprojection", "all", reprojection_px(uv, obs), "px")]
    for part, idx in body_joints.KEYPOINT_PARTS.items():
        idx = list(idx)
        rows.append(("reprojection", part, reprojection_px(uv[:, :, idx], obs[:, :, idx]), "px"))
    return rows


def truth_rows(kpm: KeypointModel, result: FitResult, mode: str,
               gt_smplx: str | os.PathLike | None, gt_cameras: str | os.PathLike | None,
               view: int | None = None) -> list[tuple[str, str, float, str]]:
    """The ``fit_eval`` rows measured against the ground-truth tables (camera errors, pose
    errors, image errors), as (metric, part, value, unit); none without them. ``view``: the
    camera of a one-view fit of a multi-camera scene."""
    rows: list[tuple[str, str, float, str]] = []
    rig = result.rig
    if gt_cameras:
        gt_rig, _ = read_rig(gt_cameras)
        if view is not None:
            gt_rig = gt_rig.select(slice(view, view + 1))
        if gt_rig.num_views != rig.num_views:
            raise InputError(f"{gt_cameras}: {gt_rig.num_views} cameras, the fit has "
                             f"{rig.num_views}")
        cam, sim = placed_camera_errors(rig, gt_rig, result.camera_status)
        if mode == "multiview":
            rows += [("camera_rotation", "cameras", cam["rotation_deg_mean"], "deg"),
                     ("camera_rotation_max", "cameras", cam["rotation_deg_max"], "deg"),
                     ("camera_centre", "cameras", cam["centre_m_mean"], "m"),
                     ("camera_centre_max", "cameras", cam["centre_m_max"], "m"),
                     ("camera_focal_rel", "cameras", cam["focal_rel_err_mean"], "1"),
                     ("gauge_scale", "cameras", cam["scale"], "1"),
                     ("cameras_unplaced", "cameras",
                      float(sum(s == "unplaced" for s in result.camera_status)), "1")]
    else:
        sim = None
    if gt_smplx:
        gt_params, gt_frames = read_smplx(gt_smplx)
        pos = {int(f): i for i, f in enumerate(gt_frames)}
        idx = [i for i, f in enumerate(result.frames) if int(f) in pos]
        if not idx:
            raise InputError(f"{gt_smplx}: no frame in common with the fit")
        gsel = [pos[int(result.frames[i])] for i in idx]
        gj, gk, gv = keypoints_of(kpm, {k: v[gsel] for k, v in gt_params.items()})
        fj, fk, fv = keypoints_of(kpm, {k: v[idx] for k, v in result.params.items()})
        if gt_cameras:
            rows += image_errors(fv, rig, gv, gt_rig, kpm.model.part_labels.cpu().numpy())
        if sim is None:  # no GT cameras: align the whole sequence's body joints
            sim = umeyama(fj.reshape(-1, 3), gj.reshape(-1, 3))
        fj, fk = sim.apply(fj), sim.apply(fk)
        fitted = np.asarray(result.provenance)[idx] == "fitted"
        pose_rows = pose_errors(fj[fitted], fk[fitted], gj[fitted], gk[fitted])
        jit = {(m, p): v for m, p, v, _ in pose_errors(fj, fk, gj, gk) if m == "jitter"}
        rows += [(m, p, jit[(m, p)] if m == "jitter" else v, u) for m, p, v, u in pose_rows]
        if gt_cameras:
            rows.append(("mpjpe", "body_seen", body_seen_mpjpe(fj[fitted], gj[fitted], gt_rig),
                         "mm"))
    return rows


def fit_eval_table(kpm: KeypointModel, result: FitResult, obs: np.ndarray, mode: str,
                   source: str, gt_smplx: str | os.PathLike | None,
                   gt_cameras: str | os.PathLike | None, view: int | None = None
                   ) -> pd.DataFrame:
    """The ``fit_eval`` table (:data:`FIT_EVAL`) of a fit: reprojection of the cleaned
    observations ``obs (V,T,133,3)``; with the ground-truth tables, :func:`truth_rows`.
    ``source``: detected or ground_truth; ``view``: the camera of a one-view fit of a
    multi-camera scene."""
    rows: list[tuple[str, str, float, str]] = []
    T = len(result.frames)
    _, fit_kp, _ = keypoints_of(kpm, result.params)
    rig = result.rig
    uv, _ = project(torch.as_tensor(fit_kp), torch.as_tensor(rig.K), torch.as_tensor(rig.R),
                    torch.as_tensor(rig.t))
    rows += reprojection_rows(uv.numpy(), obs)
    rows += truth_rows(kpm, result, mode, gt_smplx, gt_cameras, view)
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
