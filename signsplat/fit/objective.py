"""Loss terms of the fit (torch). Every weight is a named field of :class:`Weights`.

Shapes: ``T`` frames, ``V`` views, 133 COCO-WholeBody keypoints. Observations are
``obs (V,T,133,3)`` float: pixel x, y and a confidence (0 = ignore). Every term is normalised
per frame so the weights do not depend on the sequence length.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from signsplat.body import joints as body_joints
from signsplat.fit.cameras import project
from signsplat.fit.robust import kernel as robust_kernel


@dataclass
class Weights:
    """Loss weights (config section ``fit.weights``, where their defaults live; units in
    brackets). Built with :meth:`from_config` from the validated section."""

    reprojection: float  # robust px^2 per keypoint
    body_pose: float  # rad^-2 on body_pose (arms, head)
    torso_pose: float  # rad^-2 on spine1..3, neck and collars (signers move the torso little)
    leg_pose: float  # rad^-2 on hips/knees/ankles/feet (usually out of view)
    shape: float  # on betas^2
    expression: float  # on expression^2
    jaw: float  # rad^-2 on jaw_pose
    hand_pose: float  # rad^-2 on anatomical hand angles (pull towards the flat hand)
    smooth_keypoints: float  # m^-2 on 3D keypoint accelerations
    smooth_pose: float  # rad^-2 on pose-parameter accelerations
    behind_camera: float  # m^-2 on depth below the near plane
    anchor: float  # rad^-2 / m^-2 on the distance to the initial estimate (single view)
    upright: float  # on |pelvis up axis - world up|^2 (standing signer, multi-view)
    camera_anchor: float  # rad^-2 / m^-2 on the free cameras' change from their init

    @classmethod
    def from_config(cls, cfg: dict) -> "Weights":
        """From the validated ``fit.weights`` section (with any overrides applied); a missing
        or unknown weight raises ValueError naming it."""
        known = {f.name for f in fields(cls)}
        unknown = set(cfg) - known
        missing = known - set(cfg)
        if unknown or missing:
            raise ValueError(f"fit.weights: unknown {sorted(unknown)}, missing "
                             f"{sorted(missing)} (validate the fit section first)")
        return cls(**cfg)


TORSO_JOINTS = tuple(body_joints.JOINT_INDEX[n] for n in (
    "spine1", "spine2", "spine3", "neck", "left_collar", "right_collar"))
LEG_JOINTS = tuple(body_joints.JOINT_INDEX[n] for n in (
    "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_foot", "right_foot"))
#: Per side, the leg's joints (SMPL-X) and the COCO-WholeBody keypoints that show them (knee,
#: ankle, big and small toe, heel): the hip joint turns the thigh, so no keypoint above the knee
#: depends on it.
LEG_SIDES = {
    side: (tuple(body_joints.JOINT_INDEX[f"{side}_{j}"] for j in ("hip", "knee", "ankle", "foot")),
           (13 + k, 15 + k, *range(17 + 3 * k, 20 + 3 * k)))
    for k, side in enumerate(("left", "right"))}


def unseen_legs(obs: torch.Tensor, image_sizes=None) -> list[str]:
    """Sides whose leg keypoints no view observes in any frame of ``obs (V,T,133,3)``.

    ``image_sizes (V,2)`` (width, height) px: a point counts as observed only inside its
    view's image (pixel centres at integer coordinates), so a detector's guess of a knee below
    the frame (MediaPipe's pose model makes such guesses) does not release a leg that no image
    shows. None: any point with a confidence counts."""
    seen = obs[..., 2] > 0
    if image_sizes is not None:
        size = torch.as_tensor(np.asarray(image_sizes), dtype=obs.dtype,
                               device=obs.device)[:, None, None, :]  # (V,1,1,2)
        xy = obs[..., :2]
        seen = seen & (xy >= -0.5).all(-1) & (xy <= size - 0.5).all(-1)
    return [side for side, (_, kps) in LEG_SIDES.items() if not bool(seen[:, :, list(kps)].any())]


def held_pose_mask(sides: list[str], device="cpu") -> torch.Tensor:
    """(63,) bool: the body-pose values of the legs of ``sides``."""
    held = torch.zeros(body_joints.NUM_BODY_JOINTS, 3, dtype=torch.bool, device=device)
    for side in sides:
        for j in LEG_SIDES[side][0]:
            held[j - 1] = True
    return held.reshape(-1)


def body_pose_weights(w: Weights, dtype=torch.float32, device="cpu") -> torch.Tensor:
    """Per-value weights (63,) of the body-pose prior: legs heavier than the upper body."""
    per_joint = torch.full((body_joints.NUM_BODY_JOINTS,), w.body_pose, dtype=dtype, device=device)
    for j in LEG_JOINTS:
        per_joint[j - 1] = w.leg_pose
    for j in TORSO_JOINTS:
        per_joint[j - 1] = w.torso_pose
    return per_joint.repeat_interleave(3)


#: COCO body keypoints of the arms (elbows, wrists): the optional part ``limbs`` reweights them
#: (e.g. 0 while only the root is solved and the arms are still in the rest pose).
LIMB_KEYPOINTS = (7, 8, 9, 10)
#: Hand keypoints rigid with the wrist (wrist, thumb CMC and the four MCP joints of each hand):
#: the optional part ``palms`` reweights them, so the wrist orientation can be solved before
#: the fingers.
PALM_KEYPOINTS = tuple(base + k for base in (body_joints.KP_LEFT_HAND[0], body_joints.KP_RIGHT_HAND[0])
                       for k in (0, 1, 5, 9, 13, 17))


def part_weight_vector(part_weights: dict[str, float], dtype=torch.float32,
                       device="cpu") -> torch.Tensor:
    """Per-keypoint weights (133,) from part weights (keys of ``joints.KEYPOINT_PARTS``, plus
    ``limbs`` for :data:`LIMB_KEYPOINTS` and ``palms`` for :data:`PALM_KEYPOINTS`)."""
    w = torch.zeros(body_joints.NUM_KEYPOINTS, dtype=dtype, device=device)
    for part, idx in body_joints.KEYPOINT_PARTS.items():
        w[list(idx)] = float(part_weights.get(part, 1.0))
    if "limbs" in part_weights:
        w[list(LIMB_KEYPOINTS)] = float(part_weights["limbs"])
    if "palms" in part_weights:
        w[list(PALM_KEYPOINTS)] = float(part_weights["palms"])
    return w


def reprojection(kp3d: torch.Tensor, K: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
                 obs: torch.Tensor, kp_weight: torch.Tensor, kernel: str, sigma_px: float,
                 near: float = 0.05) -> tuple[torch.Tensor, torch.Tensor]:
    """Confidence-weighted robust 2D reprojection over all views.

    kp3d (T,133,3) world metres; K, R, t (V,...) cameras; obs (V,T,133,3); kp_weight (133,).
    Returns (data term: sum over views/keypoints, mean over frames; near-plane violation term:
    sum of squared metres below ``near`` over observed points, mean over frames).
    """
    uv, z = project(kp3d, K, R, t)
    r2 = ((uv - obs[..., :2]) ** 2).sum(-1)
    w = obs[..., 2] * kp_weight
    rho = robust_kernel(kernel)(r2, sigma_px)
    front = (z > near).to(w.dtype)
    T = max(kp3d.shape[0], 1)
    data = (w * front * rho).sum() / T
    behind = ((w > 0).to(z.dtype) * torch.relu(near - z) ** 2).sum() / T
    return data, behind


def acceleration(x: torch.Tensor) -> torch.Tensor:
    """Second differences along dim 0: (T,...) -> (T-2,...) (empty when T < 3)."""
    return x[2:] - 2 * x[1:-1] + x[:-2]


def smoothness(kp3d: torch.Tensor, pose: torch.Tensor, contiguous: torch.Tensor | None,
               w: Weights) -> torch.Tensor:
    """Temporal smoothness: accelerations of 3D keypoints (m) and of pose vectors (rad).

    kp3d (T,133,3); pose (T,P) concatenated pose parameters; contiguous (T-2,) bool marks
    triplets of consecutive frames (a gap in the frame numbers breaks smoothness).
    """
    T = kp3d.shape[0]
    if T < 3:
        return kp3d.new_zeros(())
    a_kp = (acceleration(kp3d) ** 2).sum((-1, -2))
    a_pose = (acceleration(pose) ** 2).sum(-1)
    terms = w.smooth_keypoints * a_kp + w.smooth_pose * a_pose
    if contiguous is not None:
        terms = terms * contiguous.to(terms.dtype)
    return terms.sum() / T


def rest_pose_vector(rest_pose: dict[str, list[float]] | None, dtype=torch.float32,
                     device="cpu") -> torch.Tensor:
    """Body-pose prior mean (63,) from ``{joint name: axis-angle}`` (other joints 0)."""
    out = torch.zeros(body_joints.NUM_BODY_JOINTS * 3, dtype=dtype, device=device)
    for name, aa in (rest_pose or {}).items():
        if name not in body_joints.JOINT_INDEX or not 1 <= body_joints.JOINT_INDEX[name] <= body_joints.NUM_BODY_JOINTS:
            raise ValueError(f"rest_pose: {name!r} is not a body joint (joints 1..21 of "
                             "signsplat.body.joints.SMPLX_JOINT_NAMES)")
        j = body_joints.JOINT_INDEX[name] - 1
        out[3 * j:3 * j + 3] = torch.as_tensor(aa, dtype=dtype)
    return out


def upright(global_orient: torch.Tensor, up: torch.Tensor | None = None) -> torch.Tensor:
    """Sum over frames of |R(global_orient) e_y - up|^2: the pelvis tilt away from ``up`` (3,)
    (the world's vertical in the fit frame; default +y)."""
    import roma

    pelvis_up = roma.rotvec_to_rotmat(global_orient)[..., :, 1]
    if up is None:
        up = torch.zeros(3, dtype=pelvis_up.dtype, device=pelvis_up.device)
        up[1] = 1.0
    return ((pelvis_up - up) ** 2).sum()


def level_rig_up(R: torch.Tensor) -> torch.Tensor:
    """World vertical (3,) of a rig of level cameras, differentiable in ``R (V,3,3)``.

    The unit vector most orthogonal to every camera's image x axis (row 0 of ``R``): the
    eigenvector of the smallest eigenvalue of ``X^T X``, signed against the cameras' image-down
    axes. Needs x axes spanning a plane (see :func:`signsplat.fit.cameras.rig_up_direction`,
    which callers use to check that once).
    """
    X = R[:, 0, :]
    _, vecs = torch.linalg.eigh(X.T @ X)
    up = vecs[:, 0]
    down = R[:, 1, :].sum(0)
    return torch.where((up @ down) > 0, -up, up)


def priors(params, w: Weights, pose_w: torch.Tensor, pose_mean: torch.Tensor | None = None,
           up: torch.Tensor | None = None) -> torch.Tensor:
    """Pose, shape, face and hand priors of :class:`~signsplat.fit.bodyfit.FitParams`, per frame.

    ``pose_mean (63,)``: the body-pose prior mean (default zeros, the T-pose).
    """
    T = max(params.num_frames, 1)
    dev = params.body_pose if pose_mean is None else params.body_pose - pose_mean
    loss = (pose_w * dev ** 2).sum() / T
    if w.upright > 0:
        loss = loss + w.upright * upright(params.global_orient, up) / T
    loss = loss + w.shape * (params.betas ** 2).sum()
    loss = loss + w.expression * (params.expression ** 2).sum() / T
    loss = loss + w.jaw * (params.jaw_pose ** 2).sum() / T
    if w.hand_pose > 0:
        hands = sum((params.hand_anatomical(s) ** 2).sum() for s in ("left", "right"))
        loss = loss + w.hand_pose * hands / T
    return loss


def anchor(params, init: dict[str, torch.Tensor], w: Weights) -> torch.Tensor:
    """Distance of pose/translation blocks to an initial estimate (single-view refinement)."""
    if w.anchor <= 0 or not init:
        return params.transl.new_zeros(())
    T = max(params.num_frames, 1)
    total = params.transl.new_zeros(())
    for name in ("global_orient", "body_pose", "transl"):
        if name in init:
            total = total + ((getattr(params, name) - init[name]) ** 2).sum()
    return w.anchor * total / T
