"""Single-view fit: an initialiser, then the paper's low-learning-rate 2D reprojection refinement.

The paper initialises from OSX (body) and HaMeR (hands), whose weights we cannot ship. Any
initialiser with the :class:`Initialiser` signature can be plugged in (e.g. an ONNX regressor);
it returns SMPL-X blocks in the *camera* frame (the fit's world frame in this mode: camera at
the origin, ``R = I``, ``t = 0``). The default, :class:`NeutralPoseInitialiser`, needs no learned
weights:

1. several global-orientation hypotheses (yaw angles about the body's vertical axis, plus the
   PnP pose of the neutral torso) are fitted in one batch to the median of the first frames'
   head/torso keypoints (root only), and the lowest-loss one is kept;
2. the sequence is then fitted chunk by chunk (root and body pose, hands and face), each chunk
   warm-started from the previous chunk's last frame.

The refinement then optimises every block over the whole sequence with a deliberately low
learning rate and an anchor to the initial estimate, so single-view depth ambiguities cannot
pull the estimate away, with the same hand limits as the multi-view fit.
"""

from __future__ import annotations

import logging
import time
from typing import Protocol

import numpy as np
import roma
import torch

from signsplat.fit import objective as obj
from signsplat.fit import sequence as seq
from signsplat.fit.bodyfit import FitParams, KeypointModel
from signsplat.fit.cameras import CameraParams, Rig, pnp
from signsplat.fit.multiview import neutral_keypoints
from signsplat.fit.rig_init import PNP_KEYPOINTS, median_observation
from signsplat.fit.solver import (Stage, make_problem, rest_body_pose, run_stage,
                                  run_warm_started, stage_config)

log = logging.getLogger(__name__)


class Initialiser(Protocol):
    """Initial SMPL-X estimate of a single-view sequence.

    ``__call__(obs (T,133,3) pixels + confidence, K (3,3), width, height)`` returns a dict of
    float (T,k) blocks (``global_orient``, ``transl``, ``body_pose``, optionally
    ``left_hand_pose``/``right_hand_pose`` (flat 45-D), ``jaw_pose``, ``expression``, and
    ``betas`` (1,S) or (T,S)) in the camera frame.
    """

    def __call__(self, obs: np.ndarray, K: np.ndarray, width: int, height: int
                 ) -> dict[str, np.ndarray]: ...


def _camera_rig(K: np.ndarray, width: int, height: int) -> Rig:
    return Rig(K=np.asarray(K, float)[None], R=np.eye(3)[None], t=np.zeros((1, 3)),
               width=np.asarray([width]), height=np.asarray([height]))


def _root_for_rigid(R: np.ndarray, t: np.ndarray, pelvis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """SMPL-X (global_orient, transl) placing the rest body at ``x -> R x + t``.

    The global orientation rotates about the rest pelvis ``pelvis (3,)``, so
    ``transl = t + R @ pelvis - pelvis``.
    """
    go = roma.rotmat_to_rotvec(torch.as_tensor(R)).numpy()
    return go, t + R @ pelvis - pelvis


class NeutralPoseInitialiser:
    """Default initialiser without learned weights (see the module docstring).

    Args: kpm keypoint model; cfg the ``fit`` config section; device, dtype for torch.
    """

    def __init__(self, kpm: KeypointModel, cfg: dict, device="cpu", dtype=torch.float32):
        self.kpm, self.cfg, self.device, self.dtype = kpm, cfg, device, dtype

    def hypotheses(self, obs: np.ndarray, K: np.ndarray) -> np.ndarray:
        """Candidate rigid poses (H,4,4) of the rest body in the camera frame."""
        sv = self.cfg["singleview"]
        kp0 = neutral_keypoints(self.kpm, self.dtype, self.device)
        idx = np.asarray(PNP_KEYPOINTS)
        med = median_observation(obs, sv["init_frames"])
        m = med[idx, 2] > 0
        pts3, pts2 = kp0[idx][m], med[idx][m][:, :2]
        # depth from the spread of the torso/head points (scale-invariant to orientation-ish)
        spread3 = np.sqrt(((pts3 - pts3.mean(0)) ** 2).sum(-1).mean())
        spread2 = np.sqrt(((pts2 - pts2.mean(0)) ** 2).sum(-1).mean()) if len(pts2) > 1 else 0
        f = float(K[0, 0])
        depth = f * spread3 / spread2 if spread2 > 1 else sv["default_depth_m"]
        c2 = pts2.mean(0) if len(pts2) else K[:2, 2]
        centre = np.array([(c2[0] - K[0, 2]) / f * depth, (c2[1] - K[1, 2]) / f * depth, depth])
        facing = np.diag([1.0, -1.0, -1.0])  # body y up -> camera y down, body faces the camera
        out = []
        for yaw in sv["hypotheses_yaw_degrees"]:
            Ry = roma.rotvec_to_rotmat(torch.tensor([0.0, np.radians(yaw), 0.0],
                                                    dtype=torch.float64)).numpy()
            R = facing @ Ry
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = centre - R @ pts3.mean(0)
            out.append(T)
        if m.sum() >= 6:
            sol = pnp(pts3, pts2, K)
            if sol is not None:
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = sol[0], sol[1]
                out.append(T)
        return np.stack(out)

    def choose_root(self, obs: np.ndarray, K: np.ndarray, width: int, height: int
                    ) -> tuple[np.ndarray, np.ndarray, list[float]]:
        """Fit every hypothesis' root to the first frames; return the best (go, transl, losses)."""
        sv = self.cfg["singleview"]
        hyp = self.hypotheses(obs, K)
        H = len(hyp)
        pelvis = self.kpm.model.rest_joints[0].double().cpu().numpy()
        roots = [_root_for_rigid(h[:3, :3], h[:3, 3], pelvis) for h in hyp]
        med = median_observation(obs, sv["init_frames"])
        med[:, 2] = np.where(med[:, 2] > 0, 1.0, 0.0)
        mask = np.zeros(med.shape[0], bool)
        mask[np.asarray(PNP_KEYPOINTS)] = True
        med[~mask, 2] = 0.0  # root only: head and torso keypoints
        obs_h = np.repeat(med[None, None], H, axis=1)  # (1,H,133,3): hypotheses as frames
        params = FitParams(H, self.kpm.model.num_betas, self.kpm.model.num_expression,
                           dtype=self.dtype, device=self.device,
                           init={"global_orient": np.stack([r[0] for r in roots]),
                                 "transl": np.stack([r[1] for r in roots]),
                                 "body_pose": rest_body_pose(self.cfg, H)})
        cams = CameraParams(_camera_rig(K, width, height), fixed=[0], dtype=self.dtype,
                            device=self.device)
        problem = make_problem(self.kpm, obs_h, self.cfg, dtype=self.dtype, device=self.device)
        w = problem.weights
        stage = Stage.from_config(stage_config(
            name="hypotheses", iterations=sv["hypothesis_iterations"], lr=sv["hypothesis_lr"],
            groups=["root"], smooth=False))
        run_stage(problem, params, cams, stage)
        with torch.no_grad():
            _, kp3d, _ = self.kpm(**params.model_inputs())
            Kt, Rt, tt = cams()
            losses = []
            for h in range(H):
                data, behind = obj.reprojection(kp3d[h:h + 1], Kt, Rt, tt,
                                                problem.obs[:, h:h + 1],
                                                torch.ones(133, dtype=self.dtype,
                                                           device=self.device),
                                                problem.kernel, problem.sigma_px)
                losses.append(float(data + w.behind_camera * behind))
        best = int(np.argmin(losses))
        ex = params.export()
        return ex["global_orient"][best], ex["transl"][best], losses

    def __call__(self, obs: np.ndarray, K: np.ndarray, width: int, height: int
                 ) -> dict[str, np.ndarray]:
        sv = self.cfg["singleview"]
        T = obs.shape[0]
        go, tr, losses = self.choose_root(obs, K, width, height)
        log.info("orientation hypotheses losses: %s -> %d", np.round(losses, 1).tolist(),
                 int(np.argmin(losses)))
        params = FitParams(T, self.kpm.model.num_betas, self.kpm.model.num_expression,
                           dtype=self.dtype, device=self.device,
                           init={"global_orient": np.repeat(go[None], T, 0),
                                 "transl": np.repeat(tr[None], T, 0),
                                 "body_pose": rest_body_pose(self.cfg, T)})
        cams = CameraParams(_camera_rig(K, width, height), fixed=[0], dtype=self.dtype,
                            device=self.device)
        fitted, _ = seq.fitted_mask(obs[None], self.cfg["min_keypoints"])
        problem = make_problem(self.kpm, obs[None], self.cfg, dtype=self.dtype,
                               device=self.device, image_sizes=[(width, height)])
        solved: set[str] = set()
        for st_cfg in sv["init_stages"]:
            stage = Stage.from_config(st_cfg)
            run_warm_started(problem, params, cams, stage, sv["chunk"], fitted, solved)
            solved |= set(stage.groups)
        out = params.export()
        out["betas"] = out["betas"][:1]
        return out


INITIALISERS = {"neutral": NeutralPoseInitialiser}


def fit_singleview(kpm: KeypointModel, obs: np.ndarray, frames: np.ndarray, K: np.ndarray,
                   width: int, height: int, cfg: dict, device="cpu", dtype=torch.float32,
                   initialiser: Initialiser | None = None) -> seq.FitResult:
    """Fit SMPL-X to one view: obs (T,133,3) cleaned; K (3,3) (approximate) intrinsics.

    The world frame of the result is the camera frame (R = I, t = 0).
    """
    t0 = time.perf_counter()
    sv = cfg["singleview"]
    T = obs.shape[0]
    fitted, count = seq.fitted_mask(obs[None], cfg["min_keypoints"])
    if not fitted.any():
        raise ValueError("no frame has enough keypoints to fit")
    if initialiser is None:
        initialiser = INITIALISERS[sv["initialiser"]](kpm, cfg, device, dtype)
    init = initialiser(obs, K, width, height)
    t_init = time.perf_counter()
    init = dict(init)
    if "betas" in init:
        init["betas"] = np.asarray(init["betas"])[:1]
    params = FitParams(T, kpm.model.num_betas, kpm.model.num_expression, dtype=dtype,
                       device=device, init=init)
    cams = CameraParams(_camera_rig(K, width, height), fixed=[0], dtype=dtype, device=device)
    anchor = {k: init[k] for k in ("global_orient", "body_pose", "transl") if k in init}
    problem = make_problem(kpm, obs[None], cfg, frames, anchor=anchor,
                           weights={"anchor": sv["anchor_weight"]}, dtype=dtype, device=device,
                           image_sizes=[(width, height)])
    for st_cfg in sv["refine_stages"]:
        run_stage(problem, params, cams, Stage.from_config(st_cfg))
    filled, prov = seq.fill_gaps(params.export(), fitted)
    t1 = time.perf_counter()
    return seq.FitResult(params=filled, rig=cams.to_rig(), frames=np.asarray(frames),
                         provenance=prov, num_keypoints=count.astype(np.int64),
                         camera_status=["fixed"],
                         seconds={"initialise": t_init - t0, "refine": t1 - t_init,
                                  "total": t1 - t0},
                         log={"legs_held": problem.legs_held})
