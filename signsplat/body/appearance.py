"""Procedural albedo of the signer, evaluated at canonical (rest-pose) positions.

A solid 3D texture, so any point of the body (mesh vertex, interpolated pixel position, splat
centre) gets a colour: a gingham shirt on torso and upper arms (checks of 1.2 cm, darker
crossings, buttons and a collar band), trousers with broad diagonal ribs, belt, shoes, a skin
tone chosen by the seed on forearms, hands, neck and face, face features (hair, brows, eyes
with sclera, iris and pupil, lashes, lips with a mouth line, rosy cheeks), fingernails and
knuckle creases on the hands. Lines are >= ~1.5 mm, areas >= ~1 cm (renders are ~4 mm/px).

Each point gets a material id from cheap per-part tests on sub-selections, then one gather
from the seed's colour table; ~65k points take a few tens of ms on a busy core.

Feature positions are placed relative to the rest joints (eyes, jaw, neck, hips, wrists,
fingers), so a real SMPL-X template can be textured by passing its rest joints.
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
_IRIS = np.array([[0.30, 0.20, 0.10], [0.20, 0.35, 0.55], [0.25, 0.40, 0.20]])

# material ids (rows of the colour table)
(SKIN, PALM, SHIRT_LIGHT, SHIRT_MID, SHIRT_DARK, BUTTON, COLLAR, TROUSERS, TROUSERS_RIB, BELT,
 BUCKLE, SHOES, SOLE, HAIR, BROW, SCLERA, IRIS, PUPIL, LASH, LIPS, LIP_LINE, CHEEK, NAIL,
 NAIL_EDGE, CREASE) = range(25)


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
        "iris": _IRIS[rng.integers(len(_IRIS))],
    }


@functools.lru_cache(maxsize=64)
def colour_table(seed: int) -> np.ndarray:
    """(25, 3) float32 colour of every material id for ``seed``."""
    pal = palette(seed)
    skin, shirt, light = pal["skin"], pal["shirt"], pal["shirt_light"]
    t = np.zeros((25, 3))
    t[SKIN] = skin
    t[PALM] = 0.9 * skin + 0.1
    t[SHIRT_LIGHT] = light
    t[SHIRT_MID] = 0.5 * (light + shirt)
    t[SHIRT_DARK] = shirt
    t[BUTTON] = (0.92, 0.92, 0.88)
    t[COLLAR] = 0.8 * shirt
    t[TROUSERS] = pal["trousers"]
    t[TROUSERS_RIB] = 0.85 * pal["trousers"]
    t[BELT] = (0.12, 0.08, 0.05)
    t[BUCKLE] = (0.75, 0.65, 0.30)
    t[SHOES] = (0.10, 0.09, 0.09)
    t[SOLE] = (0.85, 0.85, 0.82)
    t[HAIR] = pal["hair"]
    t[BROW] = 0.7 * pal["hair"] + 0.1
    t[SCLERA] = (0.93, 0.93, 0.90)
    t[IRIS] = pal["iris"]
    t[PUPIL] = (0.03, 0.03, 0.03)
    t[LASH] = (0.10, 0.07, 0.06)
    t[LIPS] = 0.75 * skin + 0.25 * np.array([0.75, 0.25, 0.30])
    t[LIP_LINE] = 0.45 * skin
    t[CHEEK] = 0.93 * skin + 0.07 * np.array([0.9, 0.3, 0.3])
    t[NAIL] = 0.55 * skin + 0.45 * np.array([1.0, 0.86, 0.86])
    t[NAIL_EDGE] = 0.3 * skin + 0.7 * np.array([1.0, 0.97, 0.94])
    t[CREASE] = 0.72 * skin
    return np.clip(t, 0.0, 1.0).astype(np.float32)


@functools.lru_cache(maxsize=1)
def _default_joints_grounded() -> np.ndarray:
    """Rest joints of the proxy as written (feet on y = 0)."""
    from signsplat.body._proxy_skeleton import GROUND_SHIFT, rest_joints

    return rest_joints() + (0.0, GROUND_SHIFT, 0.0)


def albedo(points: np.ndarray, part_labels: np.ndarray, seed: int = 0,
           joints: np.ndarray | None = None) -> np.ndarray:
    """Colour (N, 3) float32 in [0, 1] of canonical points.

    points (N, 3) rest-pose positions in metres (y up, facing +z); part_labels (N,) values of
    ``joints.PART_*``; seed picks the palette; joints (55, 3) rest joints of the model the
    points belong to (default: the proxy's, with feet on y = 0).
    """
    return colour_table(int(seed))[material_ids(points, part_labels, joints)]


def material_ids(points: np.ndarray, part_labels: np.ndarray,
                 joints: np.ndarray | None = None) -> np.ndarray:
    """Material id (N,) int64 of every point (rows of :func:`colour_table`)."""
    p = np.asarray(points, dtype=np.float32)
    lab = np.asarray(part_labels)
    j = _default_joints_grounded() if joints is None else np.asarray(joints, dtype=np.float64)
    mat = np.full(len(p), SKIN, dtype=np.int64)
    # the shirt's neckline is geometric: head-labelled neck points below it get the shirt too
    head = lab == JN.PART_HEAD
    hidx = np.nonzero(head)[0]
    if len(hidx):
        hp = p[hidx]
        low = hp[:, 1] < _neckline(hp[:, 0], hp[:, 2], j[JI["neck"]][1])
        head[hidx[low]] = False
    body = (lab == JN.PART_BODY) | ((lab == JN.PART_HEAD) & ~head)
    for mask, fn in ((body, _body_material), (head, _head_material)):
        idx = np.nonzero(mask)[0]
        if len(idx):
            mat[idx] = fn(p[idx], j)
    for side, part in (("left", JN.PART_LEFT_HAND), ("right", JN.PART_RIGHT_HAND)):
        idx = np.nonzero(lab == part)[0]
        if len(idx):
            mat[idx] = _hand_material(p[idx], j, side)
    return mat


def _neckline(x: np.ndarray, z: np.ndarray, neck_y: float) -> np.ndarray:
    """Height of the shirt's top edge: a round neck, lower at the front (metres)."""
    front = np.clip(1.0 - (x / 0.075) ** 2, 0.0, 1.0) * (z > -0.01)
    shoulders = np.clip((np.abs(x) - 0.06) / 0.03, 0.0, 1.0)  # over the shoulder tops
    return neck_y - 0.005 - 0.035 * front + 0.05 * shoulders


def _body_material(p: np.ndarray, j: np.ndarray) -> np.ndarray:
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    ax = np.abs(x)
    hip_y = j[JI["left_hip"]][1]
    sh_x = j[JI["left_shoulder"]][0]
    el_x = j[JI["left_elbow"]][0]
    ankle_y = j[JI["left_ankle"]][1]
    neck_y = j[JI["neck"]][1]
    mat = np.full(len(p), SKIN, dtype=np.int64)
    # shirt: torso above the waistband and the arms to 80 % of the upper arm
    neckline = _neckline(x, z, neck_y)
    shirt = np.nonzero((y > hip_y + 0.05) & (y < neckline) & (ax < sh_x + 0.8 * (el_x - sh_x)))[0]
    if len(shirt):
        sx, sy, sz, sax = x[shirt], y[shirt], z[shirt], ax[shirt]
        arm = sax > sh_x  # on the arms the checks follow the arm (x along, y/z across)
        per = 0.024
        a = np.mod(np.where(arm, sax, sx) / per, 1.0) < 0.5
        b = np.mod((sy + 0.3 * sz * arm) / per, 1.0) < 0.5
        m = SHIRT_LIGHT + a.astype(np.int64) + b.astype(np.int64)  # light / mid / dark
        buttons = (sax < 0.006) & (sz > 0) & (np.mod(sy / 0.07, 1.0) < 0.12)
        m[buttons] = BUTTON
        m[(sy > neckline[shirt] - 0.012) & (sax < 0.11)] = COLLAR
        mat[shirt] = m
    # trousers below the waist with broad diagonal ribs (period 3 cm), belt and buckle
    trousers = y <= hip_y + 0.05
    rib = np.mod((y + 0.5 * x + 0.5 * z) / 0.03, 1.0) < 0.5
    mat[trousers] = np.where(rib[trousers], TROUSERS_RIB, TROUSERS)
    belt = trousers & (y > hip_y + 0.02)
    mat[belt] = BELT
    mat[belt & (ax < 0.02) & (z > 0)] = BUCKLE
    mat[y < ankle_y + 0.01] = SHOES
    mat[y < 0.012] = SOLE
    return mat


def _head_material(p: np.ndarray, j: np.ndarray) -> np.ndarray:
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    mat = np.full(len(p), SKIN, dtype=np.int64)
    le, re = j[JI["left_eye"]], j[JI["right_eye"]]
    eye_y = 0.5 * (le[1] + re[1])
    eye_z = 0.5 * (le[2] + re[2])
    # hair: the hairline runs from above the brows at the front down to the nape at the back,
    # passing over the ears on the sides (the ears themselves stay skin)
    back = np.clip((eye_z - 0.02 - z) / 0.10, 0.0, 1.0)
    hair = (y > eye_y + 0.042 - 0.095 * back) & ((np.abs(x) < 0.074) | (y > eye_y + 0.03))
    mat[hair] = HAIR
    # cheeks slightly rosy
    cheek = ((np.abs(x) - 0.038) ** 2 + (y - (eye_y - 0.035)) ** 2 < 0.012 ** 2) & (z > 0)
    mat[cheek & ~hair] = CHEEK
    # the face front: brows and eyes, then the mouth
    front = np.nonzero((z > eye_z - 0.02) & (np.abs(y - eye_y) < 0.035))[0]
    if len(front):
        fx, fy, fz = x[front], y[front], z[front]
        m = mat[front]
        for e in (le, re):
            dx = fx - e[0]
            dy = fy - e[1]
            brow_y = 0.022 + 0.004 * np.cos(np.clip(dx / 0.02, -1.6, 1.6))
            m[(np.abs(dx - 0.002 * np.sign(e[0])) < 0.024) & (np.abs(dy - brow_y) < 0.0035)
              & (fz > e[2])] = BROW
            cap = (fz > e[2] + 0.006) & (np.abs(dx) < 0.013)
            r2 = dx * dx + dy * dy
            m[cap & (np.abs(dy) < 0.0055)] = SCLERA
            m[cap & (r2 < 0.0055 ** 2)] = IRIS
            m[cap & (r2 < 0.0024 ** 2)] = PUPIL
            m[cap & (np.abs(dy - 0.0058) < 0.0012)] = LASH
        mat[front] = m
    mouth_y = j[JI["jaw"]][1] + 0.004
    mouth = (np.abs(y - mouth_y) < 0.0095) & (np.abs(x) < 0.025) & (z > eye_z + 0.005)
    mouth = np.nonzero(mouth)[0]
    if len(mouth):
        mx, dy = x[mouth], y[mouth] - mouth_y
        lips = (mx / 0.025) ** 2 + (dy / 0.0095) ** 2 < 1.0
        m = mat[mouth]
        m[lips] = LIPS
        m[lips & (np.abs(dy) < 0.0009)] = LIP_LINE
        mat[mouth] = m
    return mat


@functools.lru_cache(maxsize=8)
def _hand_fingers(jkey: bytes, side: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fingers of one hand (straight in the rest pose): base points (5, 3), tips (5, 3) and
    the distances of joints 2 and 3 from the base along each finger (5, 2)."""
    j = np.frombuffer(jkey, dtype=np.float64).reshape(-1, 3)
    base, tip, cum = [], [], []
    for finger in JN.COCO_FINGERS:
        p1, p2, p3 = (j[JI[f"{side}_{finger}{k}"]] for k in (1, 2, 3))
        d = (p3 - p2) / np.linalg.norm(p3 - p2)
        base.append(p1)
        tip.append(p3 + 0.022 * d)
        l1 = np.linalg.norm(p2 - p1)
        cum.append((l1, l1 + np.linalg.norm(p3 - p2)))
    return np.array(base), np.array(tip), np.array(cum)


def _dot3(P: np.ndarray, M: np.ndarray) -> np.ndarray:
    """P (N, 3) . M (K, 3) -> (N, K) by broadcasting (BLAS threads stall on this shape)."""
    return P[:, :1] * M[:, 0] + P[:, 1:2] * M[:, 1] + P[:, 2:3] * M[:, 2]


def _hand_material(p: np.ndarray, j: np.ndarray, side: str) -> np.ndarray:
    wrist = j[JI[f"{side}_wrist"]]
    base, tip, cum = _hand_fingers(np.ascontiguousarray(j, dtype=np.float64).tobytes(), side)
    mat = np.full(len(p), SKIN, dtype=np.int64)
    mat[p[:, 1] < wrist[1] - 0.004] = PALM  # palms face -y in the rest pose
    # nearest finger axis (base -> tip): |P - A - t AB|^2 expanded into products (N, 5)
    A32, AB = base.astype(np.float32), (tip - base).astype(np.float32)
    L2 = (AB * AB).sum(1)
    proj = _dot3(p, AB) - (A32 * AB).sum(1)[None]
    t = np.clip(proj / L2, 0.0, 1.0)
    PA = (p * p).sum(1)[:, None] - 2.0 * _dot3(p, A32) + (A32 * A32).sum(1)[None]
    f = (PA - 2.0 * t * proj + t * t * L2).argmin(axis=1)
    rows = np.arange(len(p))
    s_all = t[rows, f] * np.sqrt(L2)[f]  # distance from the finger base along the finger
    c1, c2 = cum[f, 0], cum[f, 1]
    k = (s_all > c1).astype(np.int64) + (s_all > c2)  # segment 0, 1, 2
    s = s_all - np.where(k == 2, c2, np.where(k == 1, c1, 0.0))  # from its proximal joint
    L = np.where(k == 2, np.sqrt(L2)[f] - c2, 0.0)  # length of the distal segment (tip)
    dorsal_h = p[:, 1] - A32[f, 1]  # height above the finger axis (palms face -y)
    on_finger = proj[rows, f] > -0.012 * np.sqrt(L2)[f]  # not the palm or the wrist
    # knuckle creases: two thin lines at the middle and end joints, a fold at the base
    crease = (k > 0) & ((s < 0.0012) | (np.abs(s - 0.003) < 0.0007))
    crease |= (k == 0) & (np.abs(s - 0.006) < 0.0009) & (dorsal_h < 0)
    mat[crease & on_finger] = CREASE
    # fingernails: back of the distal segment, last ~1 cm before the tip
    nail = (k == 2) & (s > L - 0.0125) & (s < L - 0.0015) & (dorsal_h > 0.0025)
    mat[nail] = NAIL
    mat[nail & (s > L - 0.0035)] = NAIL_EDGE
    return mat
