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
    if body.any():
        out[body] = _body_colour(p[body], j, pal)
    head = lab == JN.PART_HEAD
    if head.any():
        out[head] = _head_colour(p[head], j, pal)
    for side, part in (("left", JN.PART_LEFT_HAND), ("right", JN.PART_RIGHT_HAND)):
        m = lab == part
        if m.any():
            out[m] = _hand_colour(p[m], j, pal, side)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def _default_joints_grounded() -> np.ndarray:
    """Rest joints of the proxy as written (feet on y = 0)."""
    from signsplat.body._proxy_skeleton import GROUND_SHIFT, rest_joints

    return rest_joints() + (0.0, GROUND_SHIFT, 0.0)


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
    shirt = (y > hip_y + 0.05) & (y < neck_y - 0.005 + 0.02 * (ax > 0.06)) & (ax < sleeve_end)
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
    # collar band
    collar = shirt & (y > neck_y - 0.045) & (ax < 0.09)
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
    # hair: above the brows' top at the front rising to the crown, and the back of the head
    hairline = eye_y + 0.045 - 0.06 * np.clip((eye_z - z) / 0.08, 0, 1)
    hair = (y > hairline) | ((z < eye_z - 0.085) & (y > eye_y - 0.06))
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


def _hand_colour(p: np.ndarray, j: np.ndarray, pal: dict, side: str) -> np.ndarray:
    skin = pal["skin"]
    out = np.empty((len(p), 3))
    out[:] = skin
    wrist = j[JI[f"{side}_wrist"]]
    # palm side (below the bone plane) slightly lighter
    palm = p[:, 1] < wrist[1] - 0.004
    out[palm] = 0.9 * skin + 0.1
    best = np.full(len(p), np.inf)
    t_best = np.zeros(len(p))
    seg_best = np.full(len(p), -1)
    segs = []
    for finger in ("thumb", "index", "middle", "ring", "pinky"):
        ids = [JI[f"{side}_{finger}{k}"] for k in (1, 2, 3)]
        a = j[ids[2]]
        d = a - j[ids[1]]
        d = d / np.linalg.norm(d)
        tip = a + 0.022 * d
        pts = [j[ids[0]], j[ids[1]], j[ids[2]], tip]
        for k in range(3):
            segs.append((pts[k], pts[k + 1], k, finger))
    for si, (a, b, k, finger) in enumerate(segs):
        ab = b - a
        L2 = ab @ ab
        t = np.clip(((p - a) @ ab) / L2, 0.0, 1.0)
        dist = np.linalg.norm(p - a - t[:, None] * ab, axis=1)
        m = dist < best
        best[m], t_best[m], seg_best[m] = dist[m], t[m], si
    dorsal = p[:, 1] > wrist[1] - 0.002
    for si, (a, b, k, finger) in enumerate(segs):
        m = seg_best == si
        if not m.any():
            continue
        L = np.linalg.norm(b - a)
        s = t_best[m] * L  # distance along the segment from its proximal joint
        if k == 2:  # fingernail on the back of the distal segment
            nail = dorsal[m] & (s > L - 0.012) & (s < L - 0.0015) & (p[m, 1] > a[1] + 0.002)
            col = out[m]
            col[nail] = 0.6 * skin + 0.4 * np.array([1.0, 0.85, 0.85])
            out[m] = col
        if k > 0:  # knuckle crease lines near the proximal joint of segments 2 and 3
            crease = (np.abs(s - 0.0) < 0.0012) | (np.abs(s - 0.003) < 0.0008)
            col = out[m]
            col[crease] = 0.75 * skin
            out[m] = col
    return out
