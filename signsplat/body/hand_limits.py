"""Hand joint limits as data, Euler <-> axis-angle conversion and a bounded hand parameterisation.

Paper section 3.1: the 45 hand values of SMPL-X (3 axis-angle values for each of 15 joints)
contain redundant degrees of freedom that let an under-constrained fit converge to impossible
finger twists. We describe every finger joint by Euler angles about anatomical axes, give each
axis an allowed range and lock the axes a joint cannot rotate about.

Conventions
-----------
SMPL-X rest pose (shared with the procedural proxy): T-pose, the signer's left at +x, palms
facing down (-y), fingers straight along +x (left hand) or -x (right hand), thumbs pointing
forward (+z) and outward; every joint's rest frame is aligned with the world axes.

Each joint has a fixed *joint frame* ``F`` (3x3 rotation, columns = anatomical axes expressed in
the joint's rest frame): ``x`` along the bone, ``z`` the flexion axis, ``y`` the abduction axis.
For the four fingers ``F`` is the identity; for the thumb ``x`` points along the thumb.

The three *anatomical angles* of a joint (radians, the same for both hands) are

=========  =====================================================================================
twist      rotation about the bone axis ``x``
abduction  rotation about ``y``; positive moves the finger tip towards the little-finger side
flexion    rotation about ``z``; positive moves the finger tip towards the palm (-y at rest)
=========  =====================================================================================

and a joint's rotation is ``R = F @ Euler(order, s * (angles in order)) @ F^T`` with the
intrinsic Euler order :data:`EULER_ORDER` (``'ZYX'``: flexion, then abduction, then twist; the
middle axis, abduction, has a small range, so the limits never reach gimbal lock). The signs
``s`` make flexion of the LEFT hand a negative rotation about +z and of the RIGHT hand a
positive one: the right hand is the mirror image (x -> -x) of the left, which keeps the x
component of an axis-angle vector and negates y and z.

Limits come from published active ranges of motion of the finger joints (rounded, e.g.
Hume et al. 1990, "Functional range of motion of the joints of the hand", J. Hand Surg.; the
AAOS normal values: MCP flexion 0-90 deg, PIP 0-100/110 deg, DIP 0-80/90 deg, thumb IP 0-80 deg,
thumb MCP 0-50/60 deg) and are deliberately generous; PIP/DIP and the thumb IP joint flex about
one axis only, MCP joints flex and abduct without twist, the thumb's CMC joint has all three.

Public API
----------
- :class:`HandLimits` (data), :func:`hand_limits` (defaults for a side), :data:`JOINT_LIMITS_DEG`.
- :func:`euler_to_axis_angle`, :func:`axis_angle_to_euler`: batched, differentiable, finite
  gradients at gimbal lock.
- :func:`anatomical_to_axis_angle`, :func:`axis_angle_to_anatomical`: (..., 15, 3) <-> (..., 45).
- :func:`clamp_hand_pose`: project a 45-D hand pose onto the limits.
- :class:`HandPoseParam` / :func:`free_to_hand_pose` / :func:`hand_pose_to_free`: unconstrained
  free parameters (one per unlocked axis) -> bounded angles (sigmoid into the range) -> 45-D
  axis-angle, and the inverse for initialisation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import roma
import torch

from signsplat.body.joints import FINGERS, NUM_HAND_JOINTS

EULER_ORDER = "ZYX"  # intrinsic: flexion (z), abduction (y), twist (x)
ANATOMICAL_AXES = ("twist", "abduction", "flexion")  # column order of anatomical angle arrays
SIDES = ("left", "right")

#: Joint names within one hand, in SMPL-X order (index1..3, middle, pinky, ring, thumb).
HAND_JOINT_NAMES: tuple[str, ...] = tuple(f"{f}{k}" for f in FINGERS for k in (1, 2, 3))

#: Allowed anatomical ranges in degrees per joint: (twist, abduction, flexion), each (lo, hi);
#: ``None`` marks a locked axis (held at 0). The same for both hands (mirroring is in the signs).
JOINT_LIMITS_DEG: dict[str, tuple[tuple[float, float] | None, ...]] = {
    # MCP: flexion/hyperextension and abduction (index spreads towards the thumb, negative),
    # no active twist.
    "index1": (None, (-25.0, 12.0), (-20.0, 90.0)),
    "middle1": (None, (-15.0, 15.0), (-20.0, 90.0)),
    "ring1": (None, (-12.0, 20.0), (-20.0, 90.0)),
    "pinky1": (None, (-10.0, 35.0), (-20.0, 90.0)),
    # PIP: flexion only.
    "index2": (None, None, (-5.0, 110.0)),
    "middle2": (None, None, (-5.0, 110.0)),
    "ring2": (None, None, (-5.0, 110.0)),
    "pinky2": (None, None, (-5.0, 110.0)),
    # DIP: flexion only.
    "index3": (None, None, (-10.0, 85.0)),
    "middle3": (None, None, (-10.0, 85.0)),
    "ring3": (None, None, (-10.0, 85.0)),
    "pinky3": (None, None, (-10.0, 85.0)),
    # Thumb CMC (trapeziometacarpal): flexion towards the palm, abduction in the palm plane
    # (positive = towards the index finger), a little axial rotation for opposition.
    "thumb1": ((-20.0, 45.0), (-25.0, 50.0), (-15.0, 70.0)),
    # Thumb MCP: flexion with a little abduction.
    "thumb2": (None, (-10.0, 15.0), (-10.0, 60.0)),
    # Thumb IP: flexion only.
    "thumb3": (None, None, (-15.0, 80.0)),
}

#: Rest direction of the left thumb (unit, rest frame): forward (+z), outward (+x) and a little
#: down, as thumb1 -> thumb3 of the procedural proxy (0.044, -0.009, 0.059). The right thumb is
#: its mirror image. :func:`hand_limits` accepts another direction, e.g. measured from a body
#: model's joints (see :func:`thumb_direction_from_joints`).
LEFT_THUMB_DIRECTION = (0.5934, -0.1214, 0.7957)

_MIRROR = np.diag([-1.0, 1.0, 1.0])


def _side_signs(side: str) -> np.ndarray:
    """Signs turning anatomical (twist, abduction, flexion) into rotations about (x, y, z)."""
    if side == "left":
        return np.array([1.0, 1.0, -1.0])
    if side == "right":
        return np.array([1.0, -1.0, 1.0])
    raise ValueError(f"side must be 'left' or 'right', got {side!r}")


def thumb_direction_from_joints(joints, side: str = "left") -> np.ndarray:
    """Unit rest direction (3,) of a thumb from rest joint positions (55, 3) (thumb1 -> thumb3)."""
    from signsplat.body.joints import JOINT_INDEX

    j = np.asarray(joints, dtype=np.float64)
    d = j[JOINT_INDEX[f"{side}_thumb3"]] - j[JOINT_INDEX[f"{side}_thumb1"]]
    return d / np.linalg.norm(d)


def thumb_frame(direction, side: str = "left") -> np.ndarray:
    """Joint frame (3,3) of the thumb: x along ``direction`` (given for ``side``), y = up.

    The direction is orthogonalised against the palm normal; for the right hand the frame is
    the mirror image ``M F_left M`` of the left one (``direction`` is then the right thumb's).
    """
    d = np.asarray(direction, dtype=np.float64)
    if side == "right":
        d = _MIRROR @ d
    up = np.array([0.0, 1.0, 0.0])
    x = d / np.linalg.norm(d)
    y = up - x * (x @ up)
    y /= np.linalg.norm(y)
    z = np.cross(x, y)
    frame = np.stack([x, y, z], axis=1)
    if side == "right":
        frame = _MIRROR @ frame @ _MIRROR
    return frame


@dataclass(frozen=True)
class HandLimits:
    """Limits of the 15 joints of one hand (arrays in SMPL-X hand-joint order), or of the 30
    of both hands, the left's first (:func:`both_hands`; J below is 15 or 30).

    Attributes:
        side: 'left', 'right' or 'both'.
        names: (J,) joint names (``index1`` ...).
        order: intrinsic Euler order shared by all joints (``'ZYX'``).
        lo, hi: (J, 3) float64 anatomical limits in radians, columns (twist, abduction,
            flexion); ``lo == hi == 0`` on locked axes.
        locked: (J, 3) bool, True where the joint cannot rotate about that axis.
        frames: (J, 3, 3) float64 joint frames (columns: anatomical x, y, z in the rest frame).
        signs: (3,) anatomical -> Euler signs of this side about (x, y, z); (J, 3) for both.
    """

    side: str
    names: tuple[str, ...]
    order: str
    lo: np.ndarray
    hi: np.ndarray
    locked: np.ndarray
    frames: np.ndarray
    signs: np.ndarray

    @property
    def num_free(self) -> int:
        """Number of unlocked axes (free parameters of :class:`HandPoseParam`)."""
        return int((~self.locked).sum())

    def euler_lo_hi(self) -> tuple[np.ndarray, np.ndarray]:
        """Limits as signed Euler angles about (x, y, z) of the joint frame, (J,3) each."""
        a, b = self.lo * self.signs, self.hi * self.signs
        return np.minimum(a, b), np.maximum(a, b)

    def as_table(self):
        """Limits as a pandas DataFrame in degrees (one row per joint and axis), for docs."""
        import pandas as pd

        rows = []
        for j, name in enumerate(self.names):
            for k, axis in enumerate(ANATOMICAL_AXES):
                rows.append({
                    "side": self.side, "joint": name, "axis": axis,
                    "locked": bool(self.locked[j, k]),
                    "lo_deg": math.degrees(self.lo[j, k]), "hi_deg": math.degrees(self.hi[j, k]),
                })
        return pd.DataFrame(rows)


def hand_limits(side: str = "left", thumb_direction=None,
                limits_deg: dict | None = None) -> HandLimits:
    """Default :class:`HandLimits` for ``side``.

    Args:
        side: 'left' or 'right'.
        thumb_direction: rest direction (3,) of this side's thumb; default: the mirror of
            :data:`LEFT_THUMB_DIRECTION` for the side.
        limits_deg: per joint name (twist, abduction, flexion) ranges in degrees or None for
            locked; default :data:`JOINT_LIMITS_DEG`.
    """
    signs = _side_signs(side)
    table = JOINT_LIMITS_DEG if limits_deg is None else limits_deg
    lo = np.zeros((NUM_HAND_JOINTS, 3))
    hi = np.zeros((NUM_HAND_JOINTS, 3))
    locked = np.zeros((NUM_HAND_JOINTS, 3), dtype=bool)
    for j, name in enumerate(HAND_JOINT_NAMES):
        for k, rng in enumerate(table[name]):
            if rng is None:
                locked[j, k] = True
            else:
                if not rng[0] <= 0.0 <= rng[1]:
                    raise ValueError(f"{name} {ANATOMICAL_AXES[k]}: range {rng} must contain 0 "
                                     "(the flat rest hand)")
                lo[j, k], hi[j, k] = math.radians(rng[0]), math.radians(rng[1])
    if thumb_direction is None:
        thumb_direction = np.asarray(LEFT_THUMB_DIRECTION)
        if side == "right":
            thumb_direction = _MIRROR @ thumb_direction
    frames = np.tile(np.eye(3), (NUM_HAND_JOINTS, 1, 1))
    tf = thumb_frame(thumb_direction, side)
    for j, name in enumerate(HAND_JOINT_NAMES):
        if name.startswith("thumb"):
            frames[j] = tf
    return HandLimits(side, HAND_JOINT_NAMES, EULER_ORDER, lo, hi, locked, frames, signs)


def both_hands(left: HandLimits, right: HandLimits) -> HandLimits:
    """The limits of both hands as one set of 30 joints, the left hand's first: their free
    parameters concatenated (left, right) convert in one call, with half the small tensor
    operations of two."""
    if left.order != right.order:
        raise ValueError(f"the hands' Euler orders differ: {left.order} and {right.order}")
    return HandLimits("both", left.names + right.names, left.order,
                      np.concatenate([left.lo, right.lo]), np.concatenate([left.hi, right.hi]),
                      np.concatenate([left.locked, right.locked]),
                      np.concatenate([left.frames, right.frames]),
                      np.concatenate([np.broadcast_to(left.signs, left.lo.shape),
                                      np.broadcast_to(right.signs, right.lo.shape)]))


# --- Euler <-> axis-angle ---------------------------------------------------------------------

_AXIS = {"X": 0, "Y": 1, "Z": 2}


def _parse_order(order: str) -> tuple[int, int, int, float]:
    if len(order) != 3 or not order.isupper() or set(order) != {"X", "Y", "Z"}:
        raise ValueError(f"Euler order must be an intrinsic Tait-Bryan order such as 'ZYX', "
                         f"got {order!r}")
    i, j, k = (_AXIS[c] for c in order)
    parity = 1.0 if (j - i) % 3 == 1 else -1.0
    return i, j, k, parity


def euler_to_axis_angle(euler: torch.Tensor, order: str = EULER_ORDER) -> torch.Tensor:
    """Intrinsic Euler angles (..., 3), radians, ``order[0]``'s angle first -> axis-angle (..., 3).

    ``R = R_{order[0]}(a) @ R_{order[1]}(b) @ R_{order[2]}(c)``. Differentiable everywhere
    (also at the zero rotation).
    """
    _parse_order(order)
    return roma.euler_to_rotvec(order, euler)


def _safe_atan2(y: torch.Tensor, x: torch.Tensor, degenerate: torch.Tensor) -> torch.Tensor:
    """atan2 whose gradient stays finite where ``degenerate`` (x = y = 0); returns 0 there."""
    xs = torch.where(degenerate, torch.ones_like(x), x)
    ys = torch.where(degenerate, torch.zeros_like(y), y)
    return torch.where(degenerate, torch.zeros_like(x), torch.atan2(ys, xs))


def rotmat_to_euler(rotmat: torch.Tensor, order: str = EULER_ORDER,
                    eps: float = 1e-6) -> torch.Tensor:
    """Rotation matrices (..., 3, 3) -> intrinsic Euler angles (..., 3), radians.

    The middle angle lies in [-pi/2, pi/2], the others in (-pi, pi]. At gimbal lock
    (|cos(middle)| < ``eps``) the last angle is set to 0 and the first absorbs the rotation;
    values and gradients stay finite there.
    """
    i, j, k, e = _parse_order(order)
    r = rotmat
    s_b = (e * r[..., i, k]).clamp(-1.0, 1.0)
    c_b = torch.sqrt(r[..., i, i] ** 2 + r[..., i, j] ** 2 + 1e-24)
    b = torch.atan2(s_b, c_b)
    lock = c_b < eps
    a = _safe_atan2(-e * r[..., j, k], r[..., k, k], lock)
    c = _safe_atan2(-e * r[..., i, j], r[..., i, i], lock)
    # gimbal lock: c = 0, R = R_i(a) R_j(+-pi/2) -> a from the j-th column
    a_lock = torch.atan2(torch.where(lock, e * r[..., k, j], torch.zeros_like(b)),
                         torch.where(lock, r[..., j, j], torch.ones_like(b)))
    a = torch.where(lock, a_lock, a)
    return torch.stack([a, b, c], dim=-1)


def axis_angle_to_euler(axis_angle: torch.Tensor, order: str = EULER_ORDER) -> torch.Tensor:
    """Axis-angle (..., 3) -> intrinsic Euler angles (..., 3), radians (:func:`rotmat_to_euler`)."""
    return rotmat_to_euler(roma.rotvec_to_rotmat(axis_angle), order)


# --- anatomical angles <-> 45-D hand pose -----------------------------------------------------

def _order_perm(order: str) -> list[int]:
    """Indices into (x, y, z) giving the angles in Euler-order position."""
    return [_AXIS[c] for c in order]


def anatomical_to_axis_angle(angles: torch.Tensor, limits: HandLimits) -> torch.Tensor:
    """Anatomical angles (..., J, 3) [twist, abduction, flexion] in radians -> hand pose
    (..., 3J): the flat (full rotation, no MANO mean) axis-angle of the hand joints (J = 15;
    30 with :func:`both_hands`' limits, both hands in one call).
    """
    signs = torch.as_tensor(limits.signs, dtype=angles.dtype, device=angles.device)
    xyz = angles * signs
    eul = xyz[..., _order_perm(limits.order)]
    rot = roma.euler_to_rotmat(limits.order, eul)
    frames = torch.as_tensor(limits.frames, dtype=angles.dtype, device=angles.device)
    rot = frames @ rot @ frames.transpose(-1, -2)
    aa = roma.rotmat_to_rotvec(rot)
    return aa.reshape(*angles.shape[:-2], angles.shape[-2] * 3)


def axis_angle_to_anatomical(hand_pose: torch.Tensor, limits: HandLimits) -> torch.Tensor:
    """Hand pose (..., 3J) flat axis-angle -> anatomical angles (..., J, 3) in radians."""
    aa = hand_pose.reshape(*hand_pose.shape[:-1], hand_pose.shape[-1] // 3, 3)
    frames = torch.as_tensor(limits.frames, dtype=aa.dtype, device=aa.device)
    rot = frames.transpose(-1, -2) @ roma.rotvec_to_rotmat(aa) @ frames
    eul = rotmat_to_euler(rot, limits.order)
    xyz = eul[..., list(np.argsort(_order_perm(limits.order)))]
    signs = torch.as_tensor(limits.signs, dtype=aa.dtype, device=aa.device)
    return xyz * signs


def clamp_hand_pose(hand_pose: torch.Tensor | np.ndarray, side: str | HandLimits):
    """Project a flat hand pose (..., 45) onto the joint limits (locked axes set to 0).

    Works on torch tensors (differentiable almost everywhere) and numpy arrays (returns numpy).
    The projection clamps each anatomical Euler angle into its range.
    """
    limits = side if isinstance(side, HandLimits) else hand_limits(side)
    is_np = isinstance(hand_pose, np.ndarray)
    x = torch.as_tensor(hand_pose, dtype=torch.float64 if is_np else None)
    ang = axis_angle_to_anatomical(x, limits)
    lo = torch.as_tensor(limits.lo, dtype=ang.dtype, device=ang.device)
    hi = torch.as_tensor(limits.hi, dtype=ang.dtype, device=ang.device)
    out = anatomical_to_axis_angle(torch.minimum(torch.maximum(ang, lo), hi), limits)
    return out.numpy().astype(hand_pose.dtype) if is_np else out


def within_limits(hand_pose, side: str | HandLimits, tol_deg: float = 0.5) -> np.ndarray:
    """Bool (...,) whether every joint of a flat hand pose (..., 45) lies within the limits."""
    limits = side if isinstance(side, HandLimits) else hand_limits(side)
    x = torch.as_tensor(np.asarray(hand_pose, dtype=np.float64))
    ang = axis_angle_to_anatomical(x, limits).numpy()
    tol = math.radians(tol_deg)
    ok = (ang >= limits.lo - tol) & (ang <= limits.hi + tol)
    return ok.all(axis=(-1, -2))


# --- bounded parameterisation -----------------------------------------------------------------

def free_to_anatomical(free: torch.Tensor, limits: HandLimits) -> torch.Tensor:
    """Free parameters (..., num_free) -> anatomical angles (..., J, 3) within the limits.

    Each unlocked axis gets ``lo + (hi - lo) * sigmoid(u)``; locked axes are 0. ``u = 0`` maps
    to the middle of each range (not the flat hand: use :func:`hand_pose_to_free` for that).
    """
    mask = torch.as_tensor(~limits.locked, device=free.device)
    lo = torch.as_tensor(limits.lo, dtype=free.dtype, device=free.device)[mask]
    hi = torch.as_tensor(limits.hi, dtype=free.dtype, device=free.device)[mask]
    vals = lo + (hi - lo) * torch.sigmoid(free)
    out = free.new_zeros(*free.shape[:-1], len(limits.names), 3)
    out[..., mask] = vals
    return out


def free_to_hand_pose(free: torch.Tensor, limits: HandLimits) -> torch.Tensor:
    """Free parameters (..., num_free) -> feasible flat hand pose (..., 45), differentiable."""
    return anatomical_to_axis_angle(free_to_anatomical(free, limits), limits)


def hand_pose_to_free(hand_pose: torch.Tensor, limits: HandLimits,
                      margin: float = 1e-4) -> torch.Tensor:
    """Inverse of :func:`free_to_hand_pose` for initialisation: (..., 45) -> (..., num_free).

    Angles outside the limits are first clamped to ``margin`` (fraction of the range) inside
    them, so the result is finite for any input.
    """
    ang = axis_angle_to_anatomical(hand_pose, limits)
    mask = torch.as_tensor(~limits.locked, device=ang.device)
    lo = torch.as_tensor(limits.lo, dtype=ang.dtype, device=ang.device)[mask]
    hi = torch.as_tensor(limits.hi, dtype=ang.dtype, device=ang.device)[mask]
    t = ((ang[..., mask] - lo) / (hi - lo)).clamp(margin, 1.0 - margin)
    return torch.logit(t)


class HandPoseParam(torch.nn.Module):
    """A learnable, always-feasible hand pose: ``forward() -> (B, 45)`` flat axis-angle.

    Args:
        side: 'left' or 'right' (or a :class:`HandLimits`).
        init: optional (B, 45) initial hand pose (clamped into the limits); default flat hand.
        batch_size: B when ``init`` is None.
    """

    def __init__(self, side: str | HandLimits = "left", init: torch.Tensor | None = None,
                 batch_size: int = 1, dtype: torch.dtype = torch.float32):
        super().__init__()
        self.limits = side if isinstance(side, HandLimits) else hand_limits(side)
        if init is None:
            init = torch.zeros(batch_size, NUM_HAND_JOINTS * 3, dtype=dtype)
        self.free = torch.nn.Parameter(hand_pose_to_free(init.to(dtype), self.limits))

    def anatomical(self) -> torch.Tensor:
        """Current anatomical angles (B, 15, 3) in radians."""
        return free_to_anatomical(self.free, self.limits)

    def forward(self) -> torch.Tensor:
        return free_to_hand_pose(self.free, self.limits)
