"""Synthetic scenes of the fit tests: a signing-like motion, rigs, and observations projected
from known SMPL-X parameters and cameras (imported by name: never from a conftest, whose
module name the test packages share)."""

from __future__ import annotations

import numpy as np
import torch

from signsplat.body import hand_limits as hl
from signsplat.fit.cameras import Rig, intrinsics_from_fov, project, rig_prior


def random_motion(T: int, seed: int = 0) -> dict[str, np.ndarray]:
    """A smooth signing-like motion: arms raised in front, fingers within their limits."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    body = np.zeros((T, 63))
    # shoulders (joints 16, 17 -> body_pose index j-1), elbows (18, 19)
    for j, base in ((16, [0.0, 0.0, -1.1]), (17, [0.0, 0.0, 1.1]),
                    (18, [0.0, -1.2, 0.0]), (19, [0.0, 1.2, 0.0])):
        body[:, 3 * (j - 1):3 * j] = np.asarray(base) + 0.25 * np.sin(
            2 * np.pi * (t + rng.uniform()) * rng.uniform(0.5, 1.5, 3))
    body[:, 3 * 8:3 * 9] = 0.05 * np.sin(2 * np.pi * t)  # spine3 sway
    hands = {}
    for side in ("left", "right"):
        lim = hl.hand_limits(side)
        free = rng.normal(0, 1.0, (1, lim.num_free)) + 0.5 * np.sin(2 * np.pi * t * 1.3)
        hands[side] = hl.free_to_hand_pose(torch.as_tensor(free), lim).numpy()
    return {
        "betas": np.repeat(rng.normal(0, 0.5, (1, 10)), T, 0),
        "expression": 0.3 * np.sin(2 * np.pi * t + np.arange(10)),
        "global_orient": np.concatenate([0.05 * np.sin(2 * np.pi * t), 0.1 * t,
                                         np.zeros_like(t)], 1),
        "body_pose": body,
        "jaw_pose": np.concatenate([0.1 + 0.1 * np.sin(2 * np.pi * t), 0 * t, 0 * t], 1),
        "leye_pose": np.zeros((T, 3)), "reye_pose": np.zeros((T, 3)),
        "left_hand_pose": hands["left"], "right_hand_pose": hands["right"],
        "transl": np.concatenate([0.02 * t, 0.01 * np.sin(2 * np.pi * t), 0 * t], 1),
    }


def make_stage(**settings):
    """A :class:`~signsplat.fit.solver.Stage` from settings, the schema filling the rest."""
    from signsplat.fit.solver import Stage, stage_config

    if "groups" in settings:
        settings["groups"] = list(settings["groups"])
    return Stage.from_config(stage_config(**settings))


def truth_init(params: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``FitParams`` initial values at ``params`` (a motion such as :func:`random_motion`'s):
    its arrays but the eye poses, which the fit does not optimise, and one row of betas."""
    init = {k: v for k, v in params.items() if k not in ("leye_pose", "reye_pose")}
    init["betas"] = params["betas"][:1]
    return init


def synthetic_rig(views: int, arc: float = 150.0, size: int = 256) -> Rig:
    K = intrinsics_from_fov(size, size, 36.0)
    return rig_prior(np.tile(K, (views, 1, 1)), [size] * views, [size] * views, views, arc, 2.0,
                     np.array([0.0, 1.2, 0.0]))


def observe(kpm, params: dict[str, np.ndarray], rig: Rig, noise_px: float = 0.0, seed: int = 0
            ) -> np.ndarray:
    """Project the keypoints of ``params`` into ``rig``: obs (V,T,133,3), score 1 inside the
    image (0 outside)."""
    from signsplat.fit.bodyfit import keypoints_of

    _, kp, _ = keypoints_of(kpm, params)
    uv, z = project(torch.as_tensor(kp), *(torch.as_tensor(a) for a in (rig.K, rig.R, rig.t)))
    uv = uv.numpy() + np.random.default_rng(seed).normal(0, noise_px, uv.shape)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < rig.width[:, None, None]) & \
        (uv[..., 1] >= 0) & (uv[..., 1] < rig.height[:, None, None]) & (z.numpy() > 0)
    return np.concatenate([uv, inside[..., None].astype(float)], -1)


def mesh_vertices(kpm, params: dict[str, np.ndarray]) -> torch.Tensor:
    """(T,N,3) float32 vertices of the body model posed by ``params``."""
    inputs = {k: torch.as_tensor(v, dtype=torch.float32) for k, v in params.items()
              if k not in ("leye_pose", "reye_pose")}
    with torch.no_grad():
        return kpm.model(**inputs).vertices


def render_masks(kpm, params: dict[str, np.ndarray], rig: Rig, supersample: int = 1
                 ) -> np.ndarray:
    """(V,T,H,W) masks as the simulator makes them: a pixel is the person's when more than
    half of it is covered (the mesh rasterized ``supersample`` times denser, box-filtered),
    or exactly half and its centre is (1: the pixels whose centre the body covers)."""
    from signsplat.synth import mesh_render as mr
    from signsplat.synth.simulate import coverage_mask

    verts = mesh_vertices(kpm, params).double().numpy()
    faces = kpm.model.faces.numpy()
    V, T = rig.num_views, verts.shape[0]
    H, W = int(rig.height[0]), int(rig.width[0])
    out = np.zeros((V, T, H, W), bool)
    for v in range(V):
        K = mr.scale_intrinsics(rig.K[v], supersample)
        for t in range(T):
            r = mr.rasterize(verts[t], faces, K, rig.R[v], rig.t[v], W * supersample,
                             H * supersample)
            centre = mr.rasterize(verts[t], faces, rig.K[v], rig.R[v], rig.t[v], W, H).mask
            out[v, t] = coverage_mask(mr.downsample(r.mask.astype(np.float32), supersample),
                                      centre)
    return out
