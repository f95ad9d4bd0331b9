"""Named handshapes as anatomical finger angles that respect the hand joint limits.

A handshape is a (15, 3) array of anatomical angles in degrees per hand joint (SMPL-X order
index1..3, middle1..3, pinky1..3, ring1..3, thumb1..3; columns twist, abduction, flexion; see
:mod:`signsplat.body.hand_limits`). The same angles describe the left and the right hand;
:func:`handshape_pose` turns them into a flat 45-D axis-angle hand pose for a side, clamped into
the limits. Names follow the usual handshape labels of sign-language notation (B, A, S, 1, V,
5, O, C, ...); the finger angles are our own approximations.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch

from signsplat.body import hand_limits as hl

_F = {"index": 0, "middle": 1, "pinky": 2, "ring": 3, "thumb": 4}

STRAIGHT = (0.0, 0.0, 0.0)        # (mcp, pip, dip) flexion in degrees
CURLED = (88.0, 105.0, 70.0)      # a finger folded into a fist
HOOKED = (15.0, 95.0, 75.0)       # claw / hooked
BENT = (80.0, 5.0, 0.0)           # bent at the knuckle only
ROUND = (40.0, 65.0, 40.0)        # O / C curve


def _shape(fingers: dict, thumb: tuple, spread: dict | None = None) -> np.ndarray:
    """Build a (15,3) degree array.

    fingers: finger name -> (mcp, pip, dip) flexion; missing fingers are straight.
    thumb: (cmc_twist, cmc_abduction, cmc_flexion, mcp_flexion, ip_flexion).
    spread: finger name -> MCP abduction in degrees (negative = towards the thumb).
    """
    a = np.zeros((15, 3))
    for name in ("index", "middle", "pinky", "ring"):
        j = 3 * _F[name]
        a[j:j + 3, 2] = fingers.get(name, STRAIGHT)
        a[j, 1] = (spread or {}).get(name, 0.0)
    t = 3 * _F["thumb"]
    a[t, 0], a[t, 1], a[t, 2] = thumb[0], thumb[1], thumb[2]
    a[t + 1, 2], a[t + 2, 2] = thumb[3], thumb[4]
    return a


_FIST = {f: CURLED for f in ("index", "middle", "pinky", "ring")}
_THUMB_ACROSS = (30.0, 40.0, 45.0, 40.0, 30.0)   # thumb folded over the fingers (S)
_THUMB_SIDE = (0.0, 35.0, 10.0, 10.0, 10.0)      # thumb against the index side (A, B)
_THUMB_OUT = (0.0, -20.0, -10.0, 0.0, 0.0)       # thumb extended away from the hand
_THUMB_TIP = (35.0, 30.0, 50.0, 30.0, 30.0)      # thumb tip meets the finger tips (O)
_SPREAD = {"index": -18.0, "middle": 0.0, "ring": 10.0, "pinky": 22.0}

HANDSHAPES_DEG: dict[str, np.ndarray] = {
    "B": _shape({}, _THUMB_SIDE),                                      # flat hand
    "relaxed": _shape({f: (15.0, 20.0, 10.0) for f in ("index", "middle", "pinky", "ring")},
                      (0.0, 20.0, 10.0, 10.0, 10.0)),                  # hand at rest
    "5": _shape({}, _THUMB_OUT, _SPREAD),                              # spread hand
    "A": _shape(_FIST, _THUMB_SIDE),                                   # fist, thumb at side
    "S": _shape(_FIST, _THUMB_ACROSS),                                 # fist, thumb across
    "thumb_up": _shape(_FIST, (0.0, -15.0, -12.0, -5.0, -10.0)),       # good
    "1": _shape({**_FIST, "index": STRAIGHT}, _THUMB_ACROSS),          # index
    "V": _shape({"pinky": CURLED, "ring": CURLED}, _THUMB_ACROSS,
                {"index": -12.0, "middle": 12.0}),
    "W": _shape({"pinky": CURLED}, _THUMB_ACROSS, {"index": -12.0, "ring": 12.0}),
    "L": _shape({**_FIST, "index": STRAIGHT}, _THUMB_OUT),
    "Y": _shape({"index": CURLED, "middle": CURLED, "ring": CURLED}, _THUMB_OUT,
                {"pinky": 25.0}),
    "I": _shape({"index": CURLED, "middle": CURLED, "ring": CURLED}, _THUMB_ACROSS),
    "O": _shape({f: ROUND for f in ("index", "middle", "pinky", "ring")}, _THUMB_TIP),
    "flat_O": _shape({f: (60.0, 20.0, 10.0) for f in ("index", "middle", "pinky", "ring")},
                     (30.0, 35.0, 40.0, 20.0, 10.0)),
    "C": _shape({f: (30.0, 45.0, 25.0) for f in ("index", "middle", "pinky", "ring")},
                (10.0, -5.0, 20.0, 10.0, 10.0)),
    "claw": _shape({f: HOOKED for f in ("index", "middle", "pinky", "ring")},
                   (10.0, -10.0, 20.0, 20.0, 30.0), _SPREAD),
    "bent_B": _shape({f: BENT for f in ("index", "middle", "pinky", "ring")}, _THUMB_SIDE),
    "X": _shape({**_FIST, "index": HOOKED}, _THUMB_ACROSS),            # hooked index
    "F": _shape({"index": (45.0, 60.0, 30.0)}, _THUMB_TIP, {"ring": 8.0, "pinky": 15.0}),
    "H": _shape({"pinky": CURLED, "ring": CURLED}, _THUMB_ACROSS),     # index+middle together
    "R": _shape({"pinky": CURLED, "ring": CURLED}, _THUMB_ACROSS,
                {"index": 10.0, "middle": -8.0}),                       # crossed-ish
    "K": _shape({"pinky": CURLED, "ring": CURLED, "middle": (30.0, 0.0, 0.0)},
                (0.0, 10.0, 25.0, 0.0, 0.0), {"index": -8.0}),
    "E": _shape({f: (20.0, 100.0, 70.0) for f in ("index", "middle", "pinky", "ring")},
                (25.0, 45.0, 55.0, 40.0, 40.0)),
    "M": _shape({"pinky": CURLED, "index": (70.0, 30.0, 10.0), "middle": (70.0, 30.0, 10.0),
                 "ring": (70.0, 30.0, 10.0)}, _THUMB_ACROSS),
}


def handshape_angles(name: str) -> np.ndarray:
    """Anatomical angles (15, 3) in radians of a named handshape, clipped to the limits."""
    if name not in HANDSHAPES_DEG:
        raise KeyError(f"unknown handshape {name!r}; known: {sorted(HANDSHAPES_DEG)}")
    lim = hl.hand_limits("left")  # anatomical limits are the same for both sides
    return np.clip(np.radians(HANDSHAPES_DEG[name]), lim.lo, lim.hi)


@lru_cache(maxsize=None)
def _limits(side: str) -> hl.HandLimits:
    return hl.hand_limits(side)


def angles_to_pose(angles: np.ndarray, side: str) -> np.ndarray:
    """Anatomical angles (..., 15, 3) radians -> flat hand pose (..., 45) float64 for a side."""
    t = torch.as_tensor(np.asarray(angles, dtype=np.float64))
    return hl.anatomical_to_axis_angle(t, _limits(side)).numpy()


@lru_cache(maxsize=None)
def _pose_cached(name: str, side: str) -> np.ndarray:
    return angles_to_pose(handshape_angles(name), side)


def handshape_pose(name: str, side: str) -> np.ndarray:
    """Flat 45-D axis-angle hand pose (float64) of a named handshape for ``side``."""
    return _pose_cached(name, side).copy()
