"""Where another detector puts a keypoint on the body: constant 3D offsets per keypoint.

A detector trained on real photos (MediaPipe's models, the ``pretrained`` detectors) does
not mean by "left hip" the point the body model's regressor gives: its hips, ears, shoulders
and jaw contour sit centimetres away, the same way on every body and from every view. The fit
would bend the body and move the cameras to make up for it. This module measures that gap
on simulated scenes, where the body is known, and gives it to the fit's keypoint model as
one 3D offset per keypoint, fixed in the frame of a body segment so that it turns with the
segment (:data:`ANCHORS`).

Functional core: :func:`normal_equations` (one scene's Gauss-Newton system) and
:func:`solve_offsets` (the pooled, ridge-regularised solution). :func:`scene_sample` reads a
finished scene; :func:`read_offsets` the table (:data:`KEYPOINT_OFFSETS`) the fit loads;
:func:`fit_offsets` says which table, and which of its rows, a fit of given detectors uses.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import torch

from signsplat.body import joints as body_joints
from signsplat.io.tables import Table, read_table, register_table

_J = body_joints.JOINT_INDEX
#: COCO-WholeBody keypoint -> the SMPL-X joint whose segment carries its offset: the segment
#: the keypoint lies on or ends (an elbow on the upper arm, a wrist on the forearm, a hip on
#: the pelvis, a shoulder on the collar, a knuckle or fingertip on the bone before it, a face
#: point on the head). Every keypoint has one.
ANCHORS: dict[str, str] = {
    "nose": "head", "left_eye": "head", "right_eye": "head", "left_ear": "head",
    "right_ear": "head", "left_shoulder": "left_collar", "right_shoulder": "right_collar",
    "left_elbow": "left_shoulder", "right_elbow": "right_shoulder",
    "left_wrist": "left_elbow", "right_wrist": "right_elbow", "left_hip": "pelvis",
    "right_hip": "pelvis", "left_knee": "left_hip", "right_knee": "right_hip",
    "left_ankle": "left_knee", "right_ankle": "right_knee",
    "left_big_toe": "left_ankle", "left_small_toe": "left_ankle", "left_heel": "left_ankle",
    "right_big_toe": "right_ankle", "right_small_toe": "right_ankle",
    "right_heel": "right_ankle",
    **{f"{side}_hand_wrist": f"{side}_elbow" for side in ("left", "right")},
    **{f"{side}_hand_{finger}{k}": (f"{side}_wrist" if k == 1 else f"{side}_{finger}{k - 1}")
       for side in ("left", "right") for finger in body_joints.COCO_FINGERS for k in range(1, 5)},
    **{f"face_{i}": "head" for i in range(68)},
}
_NAMES = body_joints.COCO_WHOLEBODY_NAMES
#: (K,) keypoint indices with an anchor, and (K,) their SMPL-X joints
ANCHORED = np.array([_NAMES.index(k) for k in ANCHORS])
ANCHOR_JOINTS = np.array([_J[j] for j in ANCHORS.values()])

KEYPOINT_OFFSETS = register_table(Table(
    "keypoint_offsets",
    "A detector's keypoints against the body model's: one constant 3D offset per keypoint in "
    "the frame of its anchor segment, estimated on simulated scenes (signsplat.fit."
    "keypoint_offsets).",
    {
        "keypoint": "int64 COCO-WholeBody index (0-132)",
        "name": "str COCO-WholeBody name",
        "anchor": "str SMPL-X joint whose segment's rotation turns the offset",
        "dx": "float64 offset along the segment's rest-pose x (the body's left), metres",
        "dy": "float64 offset along rest-pose y (up), metres",
        "dz": "float64 offset along rest-pose z (the body's front), metres",
        "observations": "int64 detections the estimate used (after trimming)",
        "rms_before_px": "float64 RMS distance of those detections to the projected keypoint "
                         "without the offset, px",
        "rms_after_px": "float64 the same with it, px",
    },
    metadata={"detector": "the detectors the offsets belong to (pretrained: their versions)",
              "scenes": "the simulated scenes they were estimated on"},
))


@dataclass
class SceneSystem:
    """One scene's Gauss-Newton normal equations per anchored keypoint at given offsets:
    ``A (K,3,3)``, ``b (K,3)``, detections used ``n (K,)`` and residual sums of squares
    ``sse (K,)`` (px^2) at those offsets."""

    A: np.ndarray
    b: np.ndarray
    n: np.ndarray
    sse: np.ndarray

    def __add__(self, other: SceneSystem) -> SceneSystem:
        return SceneSystem(self.A + other.A, self.b + other.b, self.n + other.n,
                           self.sse + other.sse)


def normal_equations(kp: np.ndarray, rot: np.ndarray, K: np.ndarray, R: np.ndarray,
                     t: np.ndarray, obs: np.ndarray, offsets: np.ndarray, min_score: float,
                     trim_px: float) -> SceneSystem:
    """Linearised least squares of the detections ``obs (V,T,K,3)`` (pixels, score) against
    the keypoints ``kp (T,K,3)`` moved by ``rot (T,K,3,3) @ offsets (K,3)`` (metres) and
    projected by cameras ``K, R (V,3,3)``, ``t (V,3)``. Detections scoring below
    ``min_score``, behind a camera or over ``trim_px`` from the moved keypoint are left out."""
    X = kp + np.einsum("tkij,kj->tki", rot, offsets)
    Xc = np.einsum("vij,tkj->vtki", R, X) + t[:, None, None, :]
    z = Xc[..., 2]
    front = z > 1e-3
    zs = np.where(front, z, 1.0)
    fx, fy = K[:, 0, 0][:, None, None], K[:, 1, 1][:, None, None]
    uv = np.stack([fx * Xc[..., 0] / zs + K[:, 0, 2][:, None, None],
                   fy * Xc[..., 1] / zs + K[:, 1, 2][:, None, None]], -1)
    r = obs[..., :2] - uv
    w = (obs[..., 2] >= min_score) & front & np.isfinite(r).all(-1)
    r = np.where(w[..., None], r, 0.0)
    w &= np.linalg.norm(r, axis=-1) <= trim_px
    r = np.where(w[..., None], r, 0.0)
    # d uv / d Xc, then through the camera rotation and the segment rotation to the offset
    Jc = np.zeros(uv.shape + (3,))
    Jc[..., 0, 0] = fx / zs
    Jc[..., 0, 2] = -fx * Xc[..., 0] / zs ** 2
    Jc[..., 1, 1] = fy / zs
    Jc[..., 1, 2] = -fy * Xc[..., 1] / zs ** 2
    J = np.einsum("vtkab,vbc,tkcd->vtkad", Jc, R, rot) * w[..., None, None]
    return SceneSystem(A=np.einsum("vtkai,vtkaj->kij", J, J),
                       b=np.einsum("vtkai,vtka->ki", J, r),
                       n=w.sum((0, 1)), sse=(r ** 2).sum((0, 1, 3)))


def solve_offsets(system: SceneSystem, offsets: np.ndarray, ridge: float,
                  min_observations: int) -> np.ndarray:
    """One Gauss-Newton step from ``offsets (K,3)`` on the pooled ``system``, with a ridge of
    ``ridge`` px^2 per m^2 pulling each offset to zero; keypoints with fewer than
    ``min_observations`` detections get zero."""
    eye = np.eye(3) * ridge
    step = np.linalg.solve(system.A + eye, (system.b - ridge * offsets)[..., None])[..., 0]
    out = offsets + step
    out[system.n < min_observations] = 0.0
    return out


def segment_rotations(kpm, params: dict[str, np.ndarray], batch: int = 64
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Keypoints (T,133,3) and the rotations (T,K,3,3) of the anchored keypoints' segments of
    the SMPL-X parameters ``params`` (block -> (T,k)), posed by the fit's keypoint model
    without offsets."""
    ref = kpm.model.v_template
    T = params["transl"].shape[0]
    kps, rots = [], []
    with torch.no_grad():
        for s in range(0, T, batch):
            inp = {n: torch.as_tensor(np.asarray(v[s:s + batch]), dtype=ref.dtype,
                                      device=ref.device) for n, v in params.items()}
            out = kpm.model(**inp)
            kps.append(kpm.regressor(out).double().cpu().numpy())
            rots.append(out.transforms[:, ANCHOR_JOINTS, :3, :3].double().cpu().numpy())
    return np.concatenate(kps), np.concatenate(rots)


def fit_offsets(fit_cfg: dict, detectors: str, keypoints_cfg: dict
                ) -> tuple[str | None, tuple[str, ...]]:
    """The ``keypoint_offsets`` table a fit of keypoints found by ``detectors`` uses (config
    ``fit.keypoint_offsets``; None for the simulator's keypoints or when unset) and the hand
    sides whose finger rows alone it applies (empty: every row).

    With ``perception.keypoints.hands: mediapipe`` (``keypoints_cfg``) the shipped and wide
    keypointers' fingers on ``hand_sides`` are MediaPipe's: a set without a table of its own
    then takes the ``pretrained`` table's finger rows for those sides."""
    if fit_cfg["keypoints"] != "detected":
        return None, ()
    tables = fit_cfg["keypoint_offsets"]
    if (tables[detectors] is None and detectors != "pretrained"
            and keypoints_cfg["hands"] == "mediapipe" and tables["pretrained"] is not None):
        return tables["pretrained"], tuple(keypoints_cfg["hand_sides"])
    return tables[detectors], ()


def finger_rows(df: pd.DataFrame, sides: tuple[str, ...] | list[str]) -> pd.DataFrame:
    """The rows of a ``keypoint_offsets`` table for the finger points (knuckles to tips, not
    the wrist) of the hands on ``sides`` (``left``, ``right``)."""
    bad = sorted(set(sides) - {"left", "right"})
    if bad:
        raise ValueError(f"hand side(s) {bad}; allowed: left, right")
    names = {f"{s}_hand_{f}{k}" for s in sides for f in body_joints.COCO_FINGERS
             for k in range(1, 5)}
    return df[df["name"].isin(names)]


def offsets_label(path: str | os.PathLike | None, fingers: tuple[str, ...] = ()) -> str:
    """How a fit's outputs name the offsets it used: ``none``, the table, or the table and
    the sides whose finger rows alone it applied."""
    if not path:
        return "none"
    return f"{path} (fingers: {', '.join(fingers)})" if fingers else str(path)


def read_offsets(path: str | os.PathLike) -> pd.DataFrame:
    """The ``keypoint_offsets`` table at ``path`` (file, columns and anchors checked)."""
    df = read_table(path, "keypoint_offsets")
    bad = sorted(set(df["name"]) - set(ANCHORS))
    if bad:
        raise ValueError(f"{path}: keypoint(s) {bad} have no anchor segment; allowed "
                         f"{list(ANCHORS)}")
    return df


def offsets_array(df: pd.DataFrame) -> np.ndarray:
    """(K,3) offsets of :data:`ANCHORED` from a ``keypoint_offsets`` table (zero where the
    table has no row)."""
    out = np.zeros((len(ANCHORED), 3))
    pos = {int(k): i for i, k in enumerate(ANCHORED)}
    for row in df.itertuples(index=False):
        out[pos[int(row.keypoint)]] = (row.dx, row.dy, row.dz)
    return out


def load_offsets(path: str | os.PathLike, fingers: tuple[str, ...] = ()) -> np.ndarray:
    """(K,3) offsets of :data:`ANCHORED` from the table at ``path``; with ``fingers``, only
    the finger rows of those hands (:func:`finger_rows`)."""
    table = read_offsets(path)
    return offsets_array(finger_rows(table, fingers) if fingers else table)


@dataclass
class SceneSample:
    """What the estimate needs of one simulated scene: the true keypoints ``kp (T,133,3)`` and
    segment rotations ``rot (T,K,3,3)`` (:func:`segment_rotations`), the true cameras ``K, R
    (V,3,3)``, ``t (V,3)`` and the detector's keypoints ``obs (V,T,133,3)`` of the same
    frames."""

    kp: np.ndarray
    rot: np.ndarray
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    obs: np.ndarray

    def system(self, offsets: np.ndarray, min_score: float, trim_px: float) -> SceneSystem:
        return normal_equations(self.kp[:, ANCHORED], self.rot, self.K, self.R, self.t,
                                self.obs[:, :, ANCHORED], offsets, min_score, trim_px)


def estimate_offsets(samples: list[SceneSample], min_score: float, ridge: float,
                     min_observations: int, trims_px: tuple[float, ...] = (20.0, 10.0, 6.0,
                                                                           6.0)
                     ) -> tuple[np.ndarray, SceneSystem, SceneSystem]:
    """Offsets (K,3) of :data:`ANCHORED` pooled over ``samples``: one Gauss-Newton step per
    entry of ``trims_px`` (each leaves out detections further than it from the moved
    keypoint, so gross detector errors do not count). Returns the offsets and the systems
    without and with them at the last trim (their ``n`` and ``sse`` give the RMS)."""
    if not samples:
        raise ValueError("no scene to estimate the keypoint offsets from")

    def pooled(offsets: np.ndarray, trim: float) -> SceneSystem:
        systems = [s.system(offsets, min_score, trim) for s in samples]
        return sum(systems[1:], systems[0])

    offsets = np.zeros((len(ANCHORED), 3))
    for trim in trims_px:
        offsets = solve_offsets(pooled(offsets, trim), offsets, ridge, min_observations)
    return offsets, pooled(np.zeros_like(offsets), trims_px[-1]), pooled(offsets, trims_px[-1])


def offsets_table(offsets: np.ndarray, before: SceneSystem, after: SceneSystem,
                  min_observations: int) -> pd.DataFrame:
    """The ``keypoint_offsets`` rows of the keypoints with ``min_observations`` detections."""
    rows = []
    for i, (k, j) in enumerate(zip(ANCHORED, ANCHORS.values())):
        if after.n[i] < min_observations:
            continue
        rows.append({"keypoint": int(k), "name": _NAMES[k], "anchor": j,
                     "dx": float(offsets[i, 0]), "dy": float(offsets[i, 1]),
                     "dz": float(offsets[i, 2]), "observations": int(after.n[i]),
                     "rms_before_px": float(np.sqrt(before.sse[i] / max(before.n[i], 1))),
                     "rms_after_px": float(np.sqrt(after.sse[i] / max(after.n[i], 1)))})
    return pd.DataFrame(rows, columns=list(KEYPOINT_OFFSETS.columns))


def scene_sample(scene_dir: str | os.PathLike, keypoint_model) -> SceneSample:
    """A finished simulated scene's :class:`SceneSample`: ``sim/smplx_gt.parquet``,
    ``sim/cameras.parquet`` (static cameras, or each view's mean camera) and the detector's
    ``perception/keypoints.parquet``, on the frames both have. ``keypoint_model(num_betas,
    num_expression)`` gives the fit's keypoint model for the true body's coefficient counts."""
    from signsplat.fit import data

    d = Path(scene_dir)
    rig, _ = data.read_rig(d / "sim" / "cameras.parquet")
    obs, frames = data.read_keypoints(d / "perception" / "keypoints.parquet", rig.num_views)
    params, gt_frames = data.read_smplx(d / "sim" / "smplx_gt.parquet")
    common = np.intersect1d(frames, gt_frames)
    if not len(common):
        raise ValueError(f"{d}: the detections and the true body share no frame")
    params = {k: v[np.searchsorted(gt_frames, common)] for k, v in params.items()}
    kpm = keypoint_model(params["betas"].shape[1], params["expression"].shape[1])
    kp, rot = segment_rotations(kpm, params)
    return SceneSample(kp=kp, rot=rot, K=rig.K, R=rig.R, t=rig.t,
                       obs=obs[:, np.searchsorted(frames, common)])
