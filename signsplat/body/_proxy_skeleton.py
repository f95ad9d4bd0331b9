"""Rest skeleton and body primitives of the procedural proxy (private to ``proxy``).

World frame: metres, y up, the signer faces +z, the signer's left is +x, feet on y = 0.
Rest pose as SMPL-X: T-pose, arms along +-x, palms down (-y), fingers straight along the arm,
thumbs forward (+z) and out. Only the left side is written out; the right side mirrors x.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from signsplat.body.joints import JOINT_INDEX, NUM_JOINTS, SMPLX_PARENTS

FINGER_NAMES = ("index", "middle", "pinky", "ring", "thumb")  # SMPL-X order

# The skeleton and primitives below are in design coordinates; the smooth union lowers the
# soles ~6 mm below y = 0, so the written model is lifted by this constant (metres).
GROUND_SHIFT = 0.0063

# --- left-side and central joints (metres) -------------------------------------------------
_CENTRAL = {
    "pelvis": (0.0, 0.930, -0.005),
    "spine1": (0.0, 1.040, -0.020),
    "spine2": (0.0, 1.170, -0.015),
    "spine3": (0.0, 1.230, -0.008),
    "neck": (0.0, 1.450, -0.025),
    "head": (0.0, 1.535, -0.012),
    "jaw": (0.0, 1.552, 0.020),
}
_LEFT = {
    "hip": (0.085, 0.850, -0.005),
    "knee": (0.100, 0.480, 0.005),
    "ankle": (0.105, 0.082, -0.035),
    "foot": (0.118, 0.022, 0.095),
    "collar": (0.075, 1.370, -0.022),
    "shoulder": (0.175, 1.400, -0.030),
    "elbow": (0.430, 1.400, -0.040),
    "wrist": (0.680, 1.400, -0.035),
    "eye": (0.031, 1.627, 0.064),
}

# Fingers (left hand): base offset from the wrist, direction angle in the x-z plane (degrees,
# positive toward +z), segment lengths (base->2, 2->3, 3->tip) and radii at base/2/3/tip.
_FINGERS = {
    "index": dict(base=(0.090, -0.004, 0.026), angle=6.5, lengths=(0.040, 0.024, 0.022),
                  radii=(0.0088, 0.0078, 0.0068, 0.0060)),
    "middle": dict(base=(0.094, -0.004, 0.005), angle=1.0, lengths=(0.044, 0.028, 0.023),
                   radii=(0.0090, 0.0080, 0.0070, 0.0062)),
    "ring": dict(base=(0.089, -0.004, -0.015), angle=-4.5, lengths=(0.041, 0.027, 0.022),
                 radii=(0.0085, 0.0076, 0.0066, 0.0058)),
    "pinky": dict(base=(0.080, -0.005, -0.032), angle=-10.0, lengths=(0.032, 0.020, 0.020),
                  radii=(0.0075, 0.0066, 0.0058, 0.0052)),
}
_THUMB = dict(base=(0.022, -0.010, 0.022), direction=(0.60, -0.12, 0.79),
              lengths=(0.042, 0.032, 0.028), radii=(0.0120, 0.0100, 0.0090, 0.0076))


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


def finger_direction(finger: str) -> np.ndarray:
    """Unit direction (3,) of a left-hand finger in the rest pose."""
    if finger == "thumb":
        return _unit(_THUMB["direction"])
    a = np.deg2rad(_FINGERS[finger]["angle"])
    return np.array([np.cos(a), 0.0, np.sin(a)])


def finger_spec(finger: str) -> dict:
    return _THUMB if finger == "thumb" else _FINGERS[finger]


def mirror(p) -> np.ndarray:
    """Mirror positions (..., 3) from the left side to the right (x -> -x)."""
    p = np.array(p, dtype=np.float64)
    p[..., 0] *= -1.0
    return p


def rest_joints() -> np.ndarray:
    """(55, 3) float64 rest-pose joints of the proxy, SMPL-X order, metres."""
    out = np.zeros((NUM_JOINTS, 3))
    for name, p in _CENTRAL.items():
        out[JOINT_INDEX[name]] = p
    for name, p in _LEFT.items():
        out[JOINT_INDEX[f"left_{name}"]] = p
        out[JOINT_INDEX[f"right_{name}"]] = mirror(p)
    wrist = np.array(_LEFT["wrist"])
    for finger in FINGER_NAMES:
        spec = finger_spec(finger)
        d = finger_direction(finger)
        p = wrist + np.array(spec["base"])
        for k in range(3):
            out[JOINT_INDEX[f"left_{finger}{k + 1}"]] = p
            out[JOINT_INDEX[f"right_{finger}{k + 1}"]] = mirror(p)
            p = p + spec["lengths"][k] * d
    return out


def fingertips() -> dict[str, np.ndarray]:
    """Left-hand finger tip points (centre of the tip cap end), name -> (3,)."""
    j = rest_joints()
    out = {}
    for finger in FINGER_NAMES:
        spec = finger_spec(finger)
        d = finger_direction(finger)
        out[finger] = j[JOINT_INDEX[f"left_{finger}3"]] + spec["lengths"][2] * d
    return out


PARENTS = np.array(SMPLX_PARENTS, dtype=np.int64)


# --- primitives ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Prim:
    """One SDF primitive. kind: 'cone' (round cone a->b, radii r1->r2), 'ell' (axis-aligned
    ellipsoid, centre a, radii b), 'box' (rounded box, centre a, half extents b, rounding r1).
    ``k`` is the smooth-union radius with what came before; ``joint`` owns its surface."""

    kind: str
    a: tuple
    b: tuple
    r1: float
    r2: float
    k: float
    joint: int
    tag: str = ""

    def bbox(self) -> tuple[np.ndarray, np.ndarray]:
        a, b = np.array(self.a), np.array(self.b)
        if self.kind == "cone":
            r = max(self.r1, self.r2)
            return np.minimum(a, b) - r, np.maximum(a, b) + r
        if self.kind == "ell":
            return a - b, a + b
        return a - b - self.r1, a + b + self.r1


def _cone(a, b, r1, r2, k, joint, tag=""):
    return Prim("cone", tuple(map(float, a)), tuple(map(float, b)), float(r1), float(r2),
                float(k), JOINT_INDEX[joint], tag)


def _ell(c, r, k, joint, tag=""):
    return Prim("ell", tuple(map(float, c)), tuple(map(float, r)), 0.0, 0.0, float(k),
                JOINT_INDEX[joint], tag)


def _box(c, half, rounding, k, joint, tag=""):
    return Prim("box", tuple(map(float, c)), tuple(map(float, half)), float(rounding), 0.0,
                float(k), JOINT_INDEX[joint], tag)


def _left_prims(j: np.ndarray) -> list[Prim]:
    """Primitives of the left limbs (legs, arm, hand); the right side mirrors them."""
    J = lambda n: j[JOINT_INDEX[n]]  # noqa: E731
    P = []
    hip, knee, ankle, foot = J("left_hip"), J("left_knee"), J("left_ankle"), J("left_foot")
    P.append(_cone(hip + (0.005, 0.02, 0.0), knee, 0.085, 0.052, 0.03, "left_hip", "thigh"))
    P.append(_ell(knee + (0.0, -0.13, -0.022), (0.048, 0.11, 0.05), 0.03, "left_knee", "calf"))
    P.append(_cone(knee, ankle, 0.050, 0.034, 0.02, "left_knee", "shin"))
    heel = np.array([ankle[0], 0.040, ankle[2] - 0.025])
    P.append(_cone(heel, (foot[0], 0.030, foot[2]), 0.040, 0.030, 0.02, "left_ankle", "foot"))
    P.append(_cone((foot[0], 0.022, foot[2]), (foot[0] + 0.008, 0.020, foot[2] + 0.07),
                   0.022, 0.020, 0.015, "left_foot", "toes"))
    P.append(_ell((foot[0] - 0.01, 0.03, foot[2] + 0.03), (0.04, 0.03, 0.06), 0.02,
                  "left_foot", "toe_box"))
    coll, sh, el, wr = J("left_collar"), J("left_shoulder"), J("left_elbow"), J("left_wrist")
    P.append(_cone(coll + (0.0, 0.01, 0.0), sh + (0.0, 0.015, 0.0), 0.055, 0.055, 0.03,
                   "left_collar", "collar"))
    P.append(_ell(sh + (0.02, 0.005, 0.0), (0.065, 0.06, 0.058), 0.03, "left_shoulder", "deltoid"))
    P.append(_cone(sh, el, 0.050, 0.038, 0.03, "left_shoulder", "upper_arm"))
    P.append(_ell(el + (0.06, 0.0, 0.0), (0.07, 0.040, 0.042), 0.025, "left_elbow",
                  "forearm_muscle"))
    P.append(_cone(el, wr, 0.037, 0.026, 0.02, "left_elbow", "forearm"))
    # hand: palm as a rounded box, thenar pad, fingers as round cones with knuckle spheres
    P.append(_box(wr + (0.049, -0.004, -0.003), (0.035, 0.0025, 0.0265), 0.0105, 0.010,
                  "left_wrist", "palm"))
    P.append(_ell(wr + (0.012, -0.003, 0.0), (0.022, 0.014, 0.030), 0.012, "left_wrist", "heel"))
    P.append(_ell(wr + (0.040, -0.010, 0.022), (0.030, 0.011, 0.015), 0.008, "left_wrist",
                  "thenar"))
    for finger in FINGER_NAMES:
        spec = finger_spec(finger)
        d = finger_direction(finger)
        radii = spec["radii"]
        p = j[JOINT_INDEX[f"left_{finger}1"]]
        for k in range(3):
            q = p + spec["lengths"][k] * d
            if k == 2:
                q = q - radii[3] * d  # the round cap ends at the tip point
            name = f"left_{finger}{k + 1}"
            k_blend = 0.012 if (k == 0 and finger == "thumb") else (0.006 if k == 0 else 0.0025)
            P.append(_cone(p, q, radii[k], radii[k + 1] if k < 2 else radii[3], k_blend, name,
                           f"{finger}{k + 1}"))
            if k > 0:  # knuckle bulge at the joint
                P.append(_ell(p + (0.0, 0.0008, 0.0), (radii[k] + 0.0009,) * 3, 0.003, name,
                              f"{finger}{k + 1}_knuckle"))
            p = p + spec["lengths"][k] * d
    return P


def _mirror_prim(p: Prim) -> Prim:
    name = _JOINT_NAMES_BY_INDEX[p.joint]
    mirrored = name.replace("left_", "right_") if name.startswith("left_") else name
    if p.kind == "cone":
        a, b = tuple(mirror(p.a)), tuple(mirror(p.b))
    else:
        a, b = tuple(mirror(p.a)), p.b
    return Prim(p.kind, a, b, p.r1, p.r2, p.k, JOINT_INDEX[mirrored], p.tag)


_JOINT_NAMES_BY_INDEX = {i: n for n, i in JOINT_INDEX.items()}


def body_primitives() -> list[Prim]:
    """All primitives of the proxy, in union order (torso first, then limbs, head, face)."""
    j = rest_joints()
    J = lambda n: j[JOINT_INDEX[n]]  # noqa: E731
    P = [
        _ell((0.0, 0.905, -0.012), (0.165, 0.125, 0.112), 0.0, "pelvis", "hips"),
        _ell((0.0, 0.895, -0.045), (0.14, 0.10, 0.1), 0.04, "pelvis", "buttocks"),
        _ell((0.0, 1.060, 0.000), (0.140, 0.120, 0.100), 0.05, "spine1", "abdomen"),
        _ell((0.0, 1.180, 0.000), (0.150, 0.110, 0.108), 0.05, "spine2", "waist"),
        _ell((0.0, 1.285, -0.005), (0.160, 0.115, 0.112), 0.05, "spine3", "chest"),
        _cone((-0.12, 1.360, -0.025), (0.12, 1.360, -0.025), 0.068, 0.068, 0.04, "spine3",
              "shoulder_girdle"),
    ]
    left = _left_prims(j)
    P += left + [_mirror_prim(p) for p in left]
    neck = J("neck")
    P += [
        _cone(neck + (0.0, -0.04, 0.0), (0.0, 1.575, -0.018), 0.056, 0.052, 0.03, "neck", "neck"),
        _ell((0.0, 1.640, -0.012), (0.075, 0.098, 0.092), 0.03, "head", "cranium"),
        _ell((0.0, 1.585, 0.020), (0.066, 0.060, 0.066), 0.02, "head", "midface"),
        _ell((0.0, 1.538, 0.028), (0.052, 0.035, 0.052), 0.02, "jaw", "jaw"),
        _ell((0.0, 1.522, 0.060), (0.022, 0.018, 0.018), 0.015, "jaw", "chin"),
        _cone((-0.048, 1.648, 0.070), (0.048, 1.648, 0.070), 0.009, 0.009, 0.012, "head", "brow"),
        _ell((0.036, 1.595, 0.058), (0.027, 0.022, 0.020), 0.012, "head", "cheek_l"),
        _ell((-0.036, 1.595, 0.058), (0.027, 0.022, 0.020), 0.012, "head", "cheek_r"),
        _cone((0.0, 1.628, 0.076), (0.0, 1.590, 0.094), 0.0075, 0.0095, 0.008, "head", "nose"),
        _ell((0.0, 1.583, 0.088), (0.016, 0.009, 0.012), 0.006, "head", "nostrils"),
        _ell((0.0, 1.563, 0.080), (0.024, 0.0068, 0.011), 0.004, "head", "upper_lip"),
        _ell((0.0, 1.549, 0.078), (0.022, 0.0072, 0.011), 0.003, "jaw", "lower_lip"),
        _ell((0.077, 1.622, -0.010), (0.009, 0.030, 0.018), 0.008, "head", "ear_l"),
        _ell((-0.077, 1.622, -0.010), (0.009, 0.030, 0.018), 0.008, "head", "ear_r"),
        _ell(tuple(J("left_eye")), (0.0125, 0.0125, 0.0125), 0.003, "left_eye", "eye_l"),
        _ell(tuple(J("right_eye")), (0.0125, 0.0125, 0.0125), 0.003, "right_eye", "eye_r"),
    ]
    return P
