"""Geometry for the synthetic gloss library: a standard skeleton, body locations, hand points
and an analytic two-bone arm IK.

Everything here is numpy (float64) and deterministic. Positions are metres in the body frame
of the SMPL-X rest pose with the pelvis joint at the origin: y up, the signer faces +z, the
signer's left is +x (see docs/architecture.md). The numbers are those of the procedural proxy
(``signsplat.body.proxy``, itself close to the SMPL-X neutral template): joints measured from
its rest skeleton, face and chest points from its surface. The library is built against this
fixed skeleton so that it does not depend on a body-model file; another body of similar
proportions places the hands within a few centimetres of the same points.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.spatial.transform import Rotation

from signsplat.body.joints import JOINT_INDEX

# --- skeleton -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Skeleton:
    """Rest positions (3,) of the joints the gloss generator needs, pelvis at the origin.

    ``shoulder``/``elbow``/``wrist`` are given for the LEFT side; the right side is mirrored
    (x -> -x). ``hand`` holds left-hand rest points relative to the left wrist.
    """

    shoulder: tuple = (0.175, 0.47, -0.025)
    elbow: tuple = (0.43, 0.47, -0.035)
    wrist: tuple = (0.68, 0.47, -0.03)
    face: dict = field(default_factory=lambda: {
        "forehead": (0.0, 0.755, 0.085), "temple": (0.058, 0.725, 0.055),
        "eye": (0.031, 0.691, 0.078), "nose": (0.0, 0.655, 0.108),
        "mouth": (0.0, 0.619, 0.097), "chin": (0.0, 0.585, 0.082),
        "cheek": (0.05, 0.645, 0.072), "ear": (0.083, 0.67, -0.005),
        "neck": (0.0, 0.53, 0.05), "chest": (0.0, 0.37, 0.12),
        "chest_side": (0.10, 0.38, 0.11), "shoulder_front": (0.16, 0.46, 0.06),
        "stomach": (0.0, 0.17, 0.115), "neutral": (0.0, 0.30, 0.34),
        "neutral_side": (0.13, 0.31, 0.32), "high": (0.0, 0.58, 0.36),
        "low": (0.0, 0.10, 0.30), "rest": (0.20, 0.02, 0.10),
    })

    def side_point(self, name: str, side: str) -> np.ndarray:
        """A body location for ``side`` ('left'/'right'); lateral points are mirrored."""
        p = np.array(self.face[name] if name in self.face else getattr(self, name), float)
        return p * np.array([-1.0, 1.0, 1.0]) if side == "right" else p

    @property
    def upper_arm(self) -> float:
        return float(np.linalg.norm(np.subtract(self.elbow, self.shoulder)))

    @property
    def forearm(self) -> float:
        return float(np.linalg.norm(np.subtract(self.wrist, self.elbow)))


STANDARD = Skeleton()

# Left-hand rest joint positions relative to the left wrist (hand frame = rest frame), SMPL-X
# hand-joint order, plus fingertips. Palm faces -y, fingers +x, thumb towards +z.
HAND_JOINTS_REST = np.array([
    [0.09, -0.004, 0.026], [0.13, -0.004, 0.031], [0.154, -0.004, 0.033],      # index
    [0.094, -0.004, 0.005], [0.138, -0.004, 0.006], [0.166, -0.004, 0.006],    # middle
    [0.08, -0.005, -0.032], [0.112, -0.005, -0.038], [0.131, -0.005, -0.041],  # pinky
    [0.089, -0.004, -0.015], [0.13, -0.004, -0.018], [0.157, -0.004, -0.02],   # ring
    [0.022, -0.01, 0.022], [0.047, -0.015, 0.055], [0.066, -0.019, 0.081],     # thumb
])
TIP_OFFSETS = np.array([  # joint 3 -> fingertip, per finger (index, middle, pinky, ring, thumb)
    [0.022, 0.0, 0.002], [0.023, 0.0, 0.0], [0.02, 0.0, -0.003], [0.022, 0.0, -0.002],
    [0.017, -0.003, 0.022],
])
FINGER_ORDER = ("index", "middle", "pinky", "ring", "thumb")
#: Named points on a (left, rest) hand that are not joints, relative to the wrist.
HAND_SURFACE = {
    "palm": np.array([0.055, -0.022, 0.0]),
    "back": np.array([0.055, 0.022, 0.0]),
    "heel": np.array([0.015, -0.02, 0.0]),
    "edge": np.array([0.06, -0.005, -0.045]),  # little-finger side of the palm
    "wrist": np.zeros(3),
}
_MIRROR = np.array([-1.0, 1.0, 1.0])


def hand_points(hand_pose: np.ndarray, side: str) -> dict[str, np.ndarray]:
    """Forward kinematics of one hand in its own frame (wrist at origin, rest axes).

    Args:
        hand_pose: (45,) flat axis-angle of the 15 hand joints of ``side``.
        side: 'left' or 'right'.
    Returns:
        name -> (3,) position: ``{finger}{k}`` joints, ``{finger}_tip`` and the surface points
        of :data:`HAND_SURFACE` (palm points do not move with the fingers).
    """
    m = _MIRROR if side == "right" else np.ones(3)
    rots = Rotation.from_rotvec(np.asarray(hand_pose, float).reshape(15, 3)).as_matrix()
    out = {k: v * m for k, v in HAND_SURFACE.items()}
    for f, finger in enumerate(FINGER_ORDER):
        pos = HAND_JOINTS_REST[3 * f] * m
        glob = rots[3 * f]
        out[f"{finger}1"] = pos
        for k in (1, 2):
            bone = (HAND_JOINTS_REST[3 * f + k] - HAND_JOINTS_REST[3 * f + k - 1]) * m
            pos = pos + glob @ bone
            glob = glob @ rots[3 * f + k]
            out[f"{finger}{k + 1}"] = pos
        out[f"{finger}_tip"] = pos + glob @ (TIP_OFFSETS[f] * m)
    return out


# --- orientations ---------------------------------------------------------------------------

_DIRECTIONS = {
    "up": (0, 1, 0), "down": (0, -1, 0), "forward": (0, 0, 1), "back": (0, 0, -1),
    "left": (1, 0, 0), "right": (-1, 0, 0),
}


def direction(spec, side: str) -> np.ndarray:
    """Unit vector from a name or a sum of names ('up+forward'), or a 3-vector.

    'in' points towards the body midline for ``side`` and 'out' away from it.
    """
    if isinstance(spec, str):
        v = np.zeros(3)
        for part in spec.split("+"):
            if part in ("in", "out"):
                sgn = -1.0 if side == "left" else 1.0
                v += np.array([sgn if part == "in" else -sgn, 0.0, 0.0])
            else:
                v += np.array(_DIRECTIONS[part], float)
    else:
        v = np.asarray(spec, float)
    n = np.linalg.norm(v)
    if n < 1e-9:
        raise ValueError(f"direction {spec!r} is zero")
    return v / n


def hand_rotation(fingers: np.ndarray, palm: np.ndarray, side: str) -> np.ndarray:
    """World rotation (3,3) of a hand whose fingers point along ``fingers`` and whose palm
    faces ``palm`` (made orthogonal to the fingers). Identity = rest (fingers out, palm down)."""
    f = fingers / np.linalg.norm(fingers)
    p = palm - f * (palm @ f)
    if np.linalg.norm(p) < 1e-6:  # palm parallel to fingers: pick any perpendicular
        p = np.cross(f, [0.0, 0.0, 1.0]) if abs(f[2]) < 0.9 else np.cross(f, [1.0, 0.0, 0.0])
    p = p / np.linalg.norm(p)
    x = f if side == "left" else -f
    y = -p
    return np.stack([x, y, np.cross(x, y)], axis=1)


# --- arm IK ---------------------------------------------------------------------------------

ELBOW_POLE = np.array([0.45, -1.0, -0.35])  # left arm: elbow points down, out and back


def arm_ik(wrist_target: np.ndarray, hand_rot: np.ndarray, side: str,
           skel: Skeleton = STANDARD, max_twist: float = np.radians(110.0),
           swivel: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """See :func:`arm_ik_matrices`; returns local axis-angles (T, 3) of shoulder, elbow, wrist."""
    mats = arm_ik_matrices(wrist_target, hand_rot, side, skel, max_twist, swivel)
    return tuple(Rotation.from_matrix(r).as_rotvec() for r in mats)


def arm_ik_matrices(wrist_target: np.ndarray, hand_rot: np.ndarray, side: str,
                    skel: Skeleton = STANDARD, max_twist: float = np.radians(110.0),
                    swivel: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Analytic two-bone IK of one arm, vectorised over frames.

    The shoulder joint turns the upper arm towards the elbow with the hinge axis on the upper
    arm's local y axis (as in the SMPL-X T-pose, palm down); the elbow bends in that plane and
    takes the forearm twist about the bone (up to ``max_twist`` radians); the wrist takes the
    remaining swing. Rest bones may be slightly off the x axis. The elbow swivel follows a pole
    (down, out, back) turned by ``swivel`` radians about the shoulder-wrist axis. Collar and
    spine stay at rest. Unreachable targets are pulled in.

    Args:
        wrist_target: (T, 3) wrist positions, body frame.
        hand_rot: (T, 3, 3) world rotations of the hand (see :func:`hand_rotation`).
        side: 'left' or 'right'.
    Returns:
        Local rotation matrices of shoulder, elbow and wrist, each (T, 3, 3).
    """
    m = _MIRROR if side == "right" else np.ones(3)
    S = np.asarray(skel.shoulder) * m
    L1, L2 = skel.upper_arm, skel.forearm
    d_vec = np.asarray(wrist_target, float) - S
    d = np.linalg.norm(d_vec, axis=-1)
    u = d_vec / np.maximum(d, 1e-9)[:, None]
    d = np.clip(d, abs(L1 - L2) + 0.02, L1 + L2 - 1e-4)
    pole = ELBOW_POLE * m
    v = pole[None] - u * (u @ pole)[:, None]
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    if swivel:
        sgn = 1.0 if side == "left" else -1.0  # mirror-symmetric swivel
        v = Rotation.from_rotvec(u * (sgn * swivel)).apply(v)
    cos_a = np.clip((L1 ** 2 + d ** 2 - L2 ** 2) / (2 * L1 * d), -1.0, 1.0)
    sin_a = np.sqrt(1.0 - cos_a ** 2)
    a_dir = cos_a[:, None] * u + sin_a[:, None] * v  # upper arm direction
    elbow = S + L1 * a_dir
    f_dir = (S + d[:, None] * u) - elbow
    f_dir /= np.linalg.norm(f_dir, axis=-1, keepdims=True)
    # hinge axis = normal of the arm plane spanned by u and the pole (a x f points along
    # v x u); taken from the pole so it stays defined when the elbow is almost straight or
    # fully folded
    k = np.cross(v, u)
    k /= np.linalg.norm(k, axis=-1, keepdims=True)
    # ideal shoulder frame: x-axis -> bone direction (rest bone +x left, -x right), y -> hinge
    if side == "left":
        x_axis, y_axis = a_dir, -k
    else:
        x_axis, y_axis = -a_dir, k
    R_ideal = np.stack([x_axis, y_axis, np.cross(x_axis, y_axis)], axis=-1)
    # the rest bones need not lie exactly on the x axis: correct by the minimal rotation that
    # takes the ideal bone axis to the rest upper-arm bone, so R_s @ e1 = L1 * a_dir exactly
    e1 = (np.asarray(skel.elbow) - skel.shoulder) * m
    e2 = (np.asarray(skel.wrist) - skel.elbow) * m
    axis = np.array([1.0, 0.0, 0.0]) * (1.0 if side == "left" else -1.0)
    R_s = R_ideal @ _min_rotation(tuple(axis), tuple(e1)).T
    # elbow: minimal rotation taking the rest forearm bone to the target forearm direction
    # (in the upper-arm frame this is the hinge), then the forearm twist about the bone
    g = np.einsum("tji,tj->ti", R_s, f_dir)
    e2n = e2 / np.linalg.norm(e2)
    R_hinge = _min_rotations(e2n, g)
    R_h = R_s @ R_hinge
    # forearm twist (pronation/supination): the twist part of the remaining rotation about
    # the forearm bone goes to the elbow, the swing part to the wrist
    rem = Rotation.from_matrix(np.swapaxes(R_h, -1, -2) @ hand_rot).as_quat()  # xyzw
    tau = 2.0 * np.arctan2(rem[:, :3] @ e2n, rem[:, 3])
    tau = (tau + np.pi) % (2.0 * np.pi) - np.pi
    tau = np.unwrap(tau)  # continuous over the frames of a track
    tau -= 2.0 * np.pi * np.round(np.median(tau) / (2.0 * np.pi))
    tau = np.clip(tau, -max_twist, max_twist)
    R_e_local = R_hinge @ Rotation.from_rotvec(e2n[None] * tau[:, None]).as_matrix()
    R_e = R_s @ R_e_local
    R_w_local = np.swapaxes(R_e, -1, -2) @ hand_rot
    return R_s, R_e_local, R_w_local


@lru_cache(maxsize=64)
def _min_rotation(a: tuple, b: tuple) -> np.ndarray:
    """Rotation matrix (3,3) of the smallest rotation taking direction ``a`` to ``b``."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    if s < 1e-12:
        if a @ b > 0:
            return np.eye(3)
        return Rotation.from_rotvec(np.pi * _any_perp(a)).as_matrix()
    return Rotation.from_rotvec(axis / s * np.arctan2(s, a @ b)).as_matrix()


def _min_rotations(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotations (T,3,3) taking direction ``a`` (3,) to each of ``b`` (T,3)
    (vectorised; antiparallel cases use :func:`_min_rotation`)."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    axis = np.cross(a[None], b)
    s = np.linalg.norm(axis, axis=-1)
    c = b @ a
    rotvec = axis / np.maximum(s, 1e-12)[:, None] * np.arctan2(s, c)[:, None]
    out = Rotation.from_rotvec(rotvec).as_matrix()
    for i in np.nonzero((s < 1e-9) & (c < 0))[0]:
        out[i] = _min_rotation(tuple(a), tuple(b[i]))
    return out


def _any_perp(a: np.ndarray) -> np.ndarray:
    p = np.cross(a, [0.0, 1.0, 0.0]) if abs(a[1]) < 0.9 else np.cross(a, [1.0, 0.0, 0.0])
    return p / np.linalg.norm(p)


def wrist_swing(wrist_aa: np.ndarray) -> np.ndarray:
    """Angle (T,) in radians of the wrist rotation left after :func:`arm_ik`'s twist."""
    return np.linalg.norm(wrist_aa, axis=-1)


def best_swivel(wrist_target: np.ndarray, hand_rot: np.ndarray, side: str,
                skel: Skeleton = STANDARD, max_swivel: float = np.radians(70.0),
                steps: int = 11, stride: int = 2) -> float:
    """The elbow swivel (radians, one value for the whole track so the motion stays smooth)
    that keeps the wrist least bent: minimises the largest wrist swing over the frames (every
    ``stride``-th) plus a small preference for the default pole and a penalty on elbows
    raised towards shoulder height."""
    best, best_cost = 0.0, np.inf
    m = _MIRROR if side == "right" else np.ones(3)
    shoulder_y = (np.asarray(skel.shoulder) * m)[1]
    e1 = (np.asarray(skel.elbow) - skel.shoulder) * m
    idx = np.unique(np.r_[np.arange(0, len(wrist_target), stride), len(wrist_target) - 1])
    for sw in np.linspace(-max_swivel, max_swivel, steps):
        rs, _, rw = arm_ik_matrices(wrist_target[idx], hand_rot[idx], side, skel, swivel=sw)
        swing = np.arccos(np.clip((np.trace(rw, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0))
        elbow_y = shoulder_y + (rs @ e1)[:, 1]
        cost = (swing.max() + 0.15 * abs(sw)
                + 8.0 * np.maximum(elbow_y - shoulder_y + 0.12, 0.0).max())
        if cost < best_cost - 1e-9:
            best, best_cost = float(sw), cost
    return best


def arm_fk(shoulder_aa, elbow_aa, wrist_aa, side: str, skel: Skeleton = STANDARD):
    """Forward kinematics of :func:`arm_ik`'s chain: -> (wrist position (T,3), hand rot (T,3,3))."""
    m = _MIRROR if side == "right" else np.ones(3)
    S = np.asarray(skel.shoulder) * m
    Rs = Rotation.from_rotvec(shoulder_aa).as_matrix()
    Re = Rs @ Rotation.from_rotvec(elbow_aa).as_matrix()
    Rw = Re @ Rotation.from_rotvec(wrist_aa).as_matrix()
    E = S + Rs @ ((np.asarray(skel.elbow) - skel.shoulder) * m)
    W = E + Re @ ((np.asarray(skel.wrist) - skel.elbow) * m)
    return W, Rw


BODY_SLOT = {name: (JOINT_INDEX[name] - 1) * 3 for name in (
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
    "right_wrist", "head", "neck", "spine3")}
