"""Procedural albedo of the signer, evaluated at canonical (rest-pose) positions.

A solid 3D texture, so any point of the body (mesh vertex, interpolated pixel position, splat
centre) gets a colour: a gingham shirt on torso and upper arms (checks of ~2.5 cm, darker
crossings), trousers with a faint twill, shoes, a skin tone chosen by the seed on forearms,
hands, neck and face, and face features (hair, brows, eyes with iris and pupil, lips, a
slightly darker nose tip), fingernails and knuckle creases on the hands. Feature sizes are
>= ~1.5 mm only for thin lines; everything is vectorised numpy (~65k points in a few ms).

Feature positions are placed relative to the rest joints (eyes, jaw, head, wrists, fingers),
so a real SMPL-X template can be textured by passing its rest joints.
"""

from __future__ import annotations

import functools

import numpy as np

from signsplat.body import joints as JN

JI = JN.JOINT_INDEX

_SKIN_TONES = np.array([
    [0.96, 0.80, 0.69], [0.92, 0.72, 0.58], [0.83, 0.62, 0.47], [0.70, 0.50, 0.36],
    [0.55, 0.38, 0.26], [0.42, 0.28, 0.19],
])
_SHIRT = np.array([
    [0.15, 0.30, 0.65], [0.70, 0.15, 0.15], [0.15, 0.50, 0.30], [0.45, 0.25, 0.55],
    [0.85, 0.55, 0.10], [0.20, 0.55, 0.60],
])
_TROUSERS = np.array([[0.12, 0.14, 0.22], [0.25, 0.22, 0.18], [0.18, 0.18, 0.18],
                      [0.30, 0.30, 0.35]])
_HAIR = np.array([[0.08, 0.06, 0.05], [0.25, 0.15, 0.08], [0.45, 0.30, 0.15],
                  [0.12, 0.10, 0.10], [0.60, 0.45, 0.25]])


def palette(seed: int) -> dict[str, np.ndarray]:
    """Colours chosen by ``seed``: skin, shirt, shirt_light, trousers, hair, iris (each (3,))."""
    rng = np.random.default_rng([seed, 7919])
    skin = _SKIN_TONES[rng.integers(len(_SKIN_TONES))] * rng.uniform(0.97, 1.03)
    shirt = _SHIRT[rng.integers(len(_SHIRT))]
    return {
        "skin": np.clip(skin, 0, 1),
        "shirt": shirt,
        "shirt_light": 0.35 * shirt + 0.65 * np.array([0.95, 0.95, 0.92]),
        "trousers": _TROUSERS[rng.integers(len(_TROUSERS))],
        "hair": _HAIR[rng.integers(len(_HAIR))],
        "iris": np.array([[0.30, 0.20, 0.10], [0.20, 0.35, 0.55], [0.25, 0.40, 0.20]])[
            rng.integers(3)],
    }




def _band(t: np.ndarray, width: float) -> np.ndarray:
    """1 inside |t| < width/2 with a soft 1 mm edge, else 0."""
    return np.clip((0.5 * width - np.abs(t)) / 0.001 + 0.5, 0.0, 1.0)


def albedo(points: np.ndarray, part_labels: np.ndarray, seed: int = 0,
           joints: np.ndarray | None = None) -> np.ndarray:
    """Colour (N, 3) float32 in [0, 1] of canonical points.

    points (N, 3) rest-pose positions in metres (y up, facing +z); part_labels (N,) values of
    ``joints.PART_*``; seed picks the palette; joints (55, 3) rest joints of the model the
    points belong to (default: the proxy's, with feet on y = 0).
    """
    p = np.asarray(points, dtype=np.float64)
    lab = np.asarray(part_labels)
    j = _default_joints_grounded() if joints is None else np.asarray(joints, dtype=np.float64)
    pal = palette(seed)
    out = np.empty((len(p), 3))
    out[:] = pal["skin"]
    body = lab == JN.PART_BODY
    # the shirt's neckline is geometric: head-labelled neck points below it get the shirt too
    head = lab == JN.PART_HEAD
    low = head & (p[:, 1] < _neckline(p[:, 0], p[:, 2], j[JI["neck"]][1]))
    body = body | low
    head = head & ~low
    if body.any():
        out[body] = _body_colour(p[body], j, pal)
    if head.any():
        out[head] = _head_colour(p[head], j, pal)
    for side, part in (("left", JN.PART_LEFT_HAND), ("right", JN.PART_RIGHT_HAND)):
        m = lab == part
        if m.any():
            out[m] = _hand_colour(p[m], j, pal, side)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


@functools.lru_cache(maxsize=1)
def _default_joints_grounded() -> np.ndarray:
    """Rest joints of the proxy as written (feet on y = 0)."""
    from signsplat.body._proxy_skeleton import GROUND_SHIFT, rest_joints

    return rest_joints() + (0.0, GROUND_SHIFT, 0.0)


def _neckline(x: np.ndarray, z: np.ndarray, neck_y: float) -> np.ndarray:
    """Height of the shirt's top edge: a round neck, lower at the front (metres)."""
    front = np.clip(1.0 - (x / 0.075) ** 2, 0.0, 1.0) * (z > -0.01)
    shoulders = np.clip((np.abs(x) - 0.06) / 0.03, 0.0, 1.0)  # over the shoulder tops
    return neck_y - 0.005 - 0.035 * front + 0.05 * shoulders


def _body_colour(p: np.ndarray, j: np.ndarray, pal: dict) -> np.ndarray:
    x, y, z = p.T
    ax = np.abs(x)
    hip_y = j[JI["left_hip"]][1]
    sh_x = j[JI["left_shoulder"]][0]
    el_x = j[JI["left_elbow"]][0]
    ankle_y = j[JI["left_ankle"]][1]
    neck_y = j[JI["neck"]][1]
    out = np.empty((len(p), 3))
    out[:] = pal["skin"]
    # shirt: torso above the waistband and arms up to mid-forearm... sleeves end above elbow
    sleeve_end = sh_x + 0.8 * (el_x - sh_x)
    neckline = _neckline(x, z, neck_y)
    shirt = (y > hip_y + 0.05) & (y < neckline) & (ax < sleeve_end)
    # gingham: stripes along two axes (period 2.4 cm), crossings darker
    per = 0.024
    # on the arms the checks follow the arm (x along, y/z across)
    u = np.where(ax > sh_x, ax, x)
    a = (np.mod(u / per, 1.0) < 0.5).astype(float)
    b = (np.mod((y + 0.3 * z * (ax > sh_x)) / per, 1.0) < 0.5).astype(float)
    k = (a + b) / 2.0
    shirt_col = (pal["shirt_light"][None] * (1 - k)[:, None] + pal["shirt"][None] * k[:, None])
    # a placket line of buttons down the front
    buttons = (np.abs(x) < 0.006) & (z > 0) & (np.mod(y / 0.07, 1.0) < 0.12) & (ax < 0.05)
    shirt_col[buttons] = [0.92, 0.92, 0.88]
    out[shirt] = shirt_col[shirt]
    # collar band along the neckline
    collar = shirt & (y > neckline - 0.012) & (ax < 0.11)
    out[collar] = 0.8 * pal["shirt"]
    # trousers below the waist, with a faint diagonal twill (period 6 mm) and belt
    trousers = y <= hip_y + 0.05
    tw = 0.92 + 0.08 * (np.mod((y + x + z) / 0.006, 1.0) < 0.5)
    out[trousers] = pal["trousers"][None] * tw[trousers, None]
    belt = trousers & (y > hip_y + 0.02)
    out[belt] = [0.12, 0.08, 0.05]
    buckle = belt & (ax < 0.02) & (z > 0)
    out[buckle] = [0.75, 0.65, 0.30]
    # shoes
    shoes = y < ankle_y + 0.01
    out[shoes] = [0.10, 0.09, 0.09]
    sole = y < 0.012
    out[sole] = [0.85, 0.85, 0.82]
    return out


def _head_colour(p: np.ndarray, j: np.ndarray, pal: dict) -> np.ndarray:
    x, y, z = p.T
    skin = pal["skin"]
    out = np.empty((len(p), 3))
    out[:] = skin
    le, re = j[JI["left_eye"]], j[JI["right_eye"]]
    eye_y = 0.5 * (le[1] + re[1])
    eye_z = 0.5 * (le[2] + re[2])
    # hair: the hairline runs from above the brows at the front down to the nape at the back,
    # passing over the ears on the sides (the ears themselves stay skin)
    back = np.clip((eye_z - 0.02 - z) / 0.10, 0.0, 1.0)
    hairline = eye_y + 0.042 - 0.095 * back
    hair = (y > hairline) & ((np.abs(x) < 0.074) | (y > eye_y + 0.03))
    out[hair] = pal["hair"]
    # eyebrows: arcs 2.3 cm above the eye centres
    for e in (le, re):
        dx = x - e[0]
        brow_y = e[1] + 0.022 + 0.004 * np.cos(np.clip(dx / 0.02, -1.6, 1.6))
        brow = (np.abs(dx) < 0.022) & (np.abs(y - brow_y) < 0.0035) & (z > e[2])
        out[brow] = 0.7 * pal["hair"] + 0.1
        # eye: sclera, iris, pupil on the eyeball cap
        r = np.hypot(dx, y - e[1])
        front = z > e[2] + 0.006
        sclera = front & (np.abs(dx) < 0.013) & (np.abs(y - e[1]) < 0.0055)
        out[sclera] = [0.93, 0.93, 0.90]
        iris = front & (r < 0.0055)
        out[iris] = pal["iris"]
        pupil = front & (r < 0.0024)
        out[pupil] = [0.03, 0.03, 0.03]
        lash = front & (np.abs(dx) < 0.013) & (np.abs(y - e[1] - 0.0058) < 0.0012)
        out[lash] = [0.1, 0.07, 0.06]
    # lips around the mouth line (between upper and lower lip)
    jaw = j[JI["jaw"]]
    mouth_y = jaw[1] + 0.004
    lips = (np.abs(x) < 0.024 - 0.18 * np.abs(y - mouth_y) ** 1.0 * 0 - 0.0) & (
        np.abs(y - mouth_y) < 0.0095) & (z > eye_z + 0.005) & (
        (x / 0.025) ** 2 + ((y - mouth_y) / 0.0095) ** 2 < 1.0)
    out[lips] = 0.75 * skin + 0.25 * np.array([0.75, 0.25, 0.30])
    line = lips & (np.abs(y - mouth_y) < 0.0009)
    out[line] = 0.45 * skin
    # cheeks slightly rosy, nose tip slightly darker
    cheek = ((np.abs(x) - 0.038) ** 2 + (y - (eye_y - 0.035)) ** 2) < 0.012 ** 2
    out[cheek & ~hair & (z > 0)] = 0.93 * skin + 0.07 * np.array([0.9, 0.3, 0.3])
    return out


_FINGERS_COCO = ("thumb", "index", "middle", "ring", "pinky")


@functools.lru_cache(maxsize=8)
def _hand_segments(jkey: bytes, side: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Finger segments of one hand: starts (15, 3), ends (15, 3), segment rank k (15,)."""
    j = np.frombuffer(jkey, dtype=np.float64).reshape(-1, 3)
    A, B, K = [], [], []
    for finger in _FINGERS_COCO:
        ids = [JI[f"{side}_{finger}{k}"] for k in (1, 2, 3)]
        d = j[ids[2]] - j[ids[1]]
        tip = j[ids[2]] + 0.022 * d / np.linalg.norm(d)
        pts = [j[ids[0]], j[ids[1]], j[ids[2]], tip]
        for k in range(3):
            A.append(pts[k])
            B.append(pts[k + 1])
            K.append(k)
    return np.array(A), np.array(B), np.array(K)


def _dot3(P: np.ndarray, M: np.ndarray) -> np.ndarray:
    """P (N, 3) . M (K, 3) -> (N, K) by broadcasting (BLAS threads stall on this shape)."""
    return P[:, :1] * M[:, 0] + P[:, 1:2] * M[:, 1] + P[:, 2:3] * M[:, 2]


def _hand_colour(p: np.ndarray, j: np.ndarray, pal: dict, side: str) -> np.ndarray:
    skin = pal["skin"]
    wrist = j[JI[f"{side}_wrist"]]
    A, B, K = _hand_segments(np.ascontiguousarray(j, dtype=np.float64).tobytes(), side)
    # nearest finger segment of every point (N, 15), in float32 for speed
    # |P - A - t AB|^2 expanded into matrix products (N, 15)
    P = p.astype(np.float32)
    A32, AB = A.astype(np.float32), (B - A).astype(np.float32)
    L2 = (AB * AB).sum(1)
    PA = (P * P).sum(1)[:, None] - 2.0 * _dot3(P, A32) + (A32 * A32).sum(1)[None]
    proj = _dot3(P, AB) - (A32 * AB).sum(1)[None]
    t = np.clip(proj / L2, 0.0, 1.0)
    dist = PA - 2.0 * t * proj + t * t * L2
    seg = dist.argmin(axis=1)
    rows = np.arange(len(p))
    L = np.sqrt(L2)[seg]
    s = t[rows, seg] * L  # distance from the segment's proximal joint along the finger
    k = K[seg]
    dorsal_h = P[:, 1] - A32[seg, 1]  # height above the finger axis (palms face -y)
    out = np.empty((len(p), 3))
    out[:] = skin
    palm = P[:, 1] < wrist[1] - 0.004
    out[palm] = 0.9 * skin + 0.1
    # fingernails: back of the distal segment, last ~1 cm before the tip
    nail = (k == 2) & (s > L - 0.0125) & (s < L - 0.0015) & (dorsal_h > 0.0025)
    out[nail] = 0.55 * skin + 0.45 * np.array([1.0, 0.86, 0.86])
    edge = nail & (s > L - 0.0035)
    out[edge] = 0.3 * skin + 0.7 * np.array([1.0, 0.97, 0.94])
    # knuckle creases: two thin lines at the middle and end joints, a fold at the base
    crease = (k > 0) & ((s < 0.0012) | (np.abs(s - 0.003) < 0.0007))
    crease |= (k == 0) & (np.abs(s - 0.006) < 0.0009) & (dorsal_h < 0)
    out[crease] = 0.72 * skin
    return out
