"""Rigging of the proxy mesh (private to ``proxy``): skinning weights, joint regressor,
pose correctives, shape and expression directions, face landmarks, hand PCA, keypoint vertices.

All functions are pure: arrays in, arrays out (float64, metres, radians).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import nnls

from signsplat.body import joints as JN
from signsplat.body._proxy_skeleton import (FINGER_NAMES, PARENTS, finger_direction,
                                            finger_spec, mirror)

JI = JN.JOINT_INDEX
NJ = JN.NUM_JOINTS
_FACE_LEAVES = (JI["jaw"], JI["left_eye"], JI["right_eye"])


def smoothstep(t: np.ndarray) -> np.ndarray:
    """0 for t <= -1, 1 for t >= 1, cubic in between."""
    x = np.clip((t + 1.0) * 0.5, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def vertex_neighbours(faces: np.ndarray, n: int):
    """Sparse row-normalised adjacency (n, n) of the mesh graph."""
    from scipy.sparse import coo_matrix

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    A = coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    A.data[:] = 1.0
    deg = np.asarray(A.sum(axis=1)).ravel()
    from scipy.sparse import diags

    return diags(1.0 / np.maximum(deg, 1)) @ A


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3)."""
    fn = np.cross(verts[faces[:, 1]] - verts[faces[:, 0]], verts[faces[:, 2]] - verts[faces[:, 0]])
    vn = np.zeros_like(verts)
    for k in range(3):
        np.add.at(vn, faces[:, k], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)


# --- skeleton geometry used for blending ---------------------------------------------------
def _main_child(j: int) -> int | None:
    name = JN.SMPLX_JOINT_NAMES[j]
    pref = {"pelvis": "spine1", "spine3": "neck", "left_wrist": "left_middle1",
            "right_wrist": "right_middle1", "neck": "head"}
    if name in pref:
        return JI[pref[name]]
    kids = [c for c in range(NJ) if PARENTS[c] == j and c not in _FACE_LEAVES]
    return kids[0] if kids else None


def bone_frames(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per joint: unit bone direction (55, 3), bone length (55,), blend half-width (55,)."""
    u = np.zeros((NJ, 3))
    length = np.zeros(NJ)
    for j in range(NJ):
        c = _main_child(j)
        if c is not None:
            d = joints[c] - joints[j]
            length[j] = np.linalg.norm(d)
            u[j] = d / length[j]
    for j in range(NJ):
        if length[j] == 0.0:
            name = JN.SMPLX_JOINT_NAMES[j]
            if name.endswith("3") and ("left_" in name or "right_" in name):
                finger = name.split("_")[1][:-1]
                d = finger_direction(finger)
                u[j] = mirror(d) if name.startswith("right_") else d
                length[j] = finger_spec(finger)["lengths"][2]
            elif name.endswith("_foot"):
                u[j], length[j] = (0.0, 0.0, 1.0), 0.07
            else:
                u[j], length[j] = (0.0, 1.0, 0.0), 0.1
    half = np.full(NJ, 0.04)
    for j, name in enumerate(JN.SMPLX_JOINT_NAMES):
        if any(f in name for f in FINGER_NAMES):
            half[j] = 0.0045 if not name.endswith("1") else 0.008
            if "thumb1" in name:
                half[j] = 0.012
        elif "wrist" in name:
            half[j] = 0.022
        elif "elbow" in name:
            half[j] = 0.035
        elif "knee" in name:
            half[j] = 0.05
        elif "shoulder" in name or "hip" in name:
            half[j] = 0.05
        elif "collar" in name:
            half[j] = 0.04
        elif "ankle" in name or "foot" in name:
            half[j] = 0.03
        elif name in ("neck", "head"):
            half[j] = 0.03
        elif name.startswith("spine"):
            half[j] = 0.05
    return u, length, half


def skinning_weights(verts: np.ndarray, faces: np.ndarray, owner: np.ndarray,
                     joints: np.ndarray, smooth_iters: int = 8) -> np.ndarray:
    """Smooth LBS weights (V, 55): blend across each joint's plane, then smooth on the mesh.

    owner (V,) is the joint whose primitive is nearest to each vertex. A vertex owned by bone b
    shares weight with b's parent across the plane through joint b (normal = bone direction,
    half-width ``half``), and with the nearest child across that child's plane. Jaw and eyes
    use spatial masks (lower face below the lip line; eyeball caps).
    """
    V = len(verts)
    u, length, half = bone_frames(joints)
    W = np.zeros((V, NJ))
    W[np.arange(V), owner] = 1.0

    def plane(j, pts):
        return smoothstep(((pts - joints[j]) @ u[j] if j != JI["head"] else
                           (pts - joints[j])[:, 1]) / half[j])

    children = {j: [c for c in range(NJ) if PARENTS[c] == j and c not in _FACE_LEAVES]
                for j in range(NJ)}
    for b in range(NJ):
        m = np.nonzero(owner == b)[0]
        if len(m) == 0:
            continue
        pts = verts[m]
        wb = np.ones(len(m))
        if b != 0 and b not in _FACE_LEAVES:
            s = plane(b, pts)
            W[m, PARENTS[b]] += 1.0 - s
            wb = s.copy()
        kids = children[b]
        if kids:
            dist = np.stack([_seg_dist(pts, joints[c], joints[c] + length[c] * u[c])
                             for c in kids], 1)
            near = np.asarray(kids)[dist.argmin(axis=1)]
            for c in kids:
                sel = near == c
                s = plane(c, pts[sel])
                amount = s * wb[sel]
                W[m[sel], c] += amount
                wb[sel] -= amount
        W[m, b] = wb
    # face leaves: jaw (lower face) and eyes (eyeball caps), taken from the head weight
    head, jaw = JI["head"], JI["jaw"]
    headish = np.isin(owner, (head, jaw, JI["left_eye"], JI["right_eye"]))
    p = verts
    lip_y = joints[jaw][1] + 0.004
    w_jaw = (smoothstep((lip_y - p[:, 1]) / 0.004) * smoothstep((p[:, 2] - 0.0) / 0.02)
             * smoothstep((p[:, 1] - 1.49) / 0.02) * headish)
    total = W[:, head] + W[:, jaw]
    W[:, jaw] = total * w_jaw
    W[:, head] = total * (1.0 - w_jaw)
    W = np.maximum(W, 0.0)
    W /= W.sum(axis=1, keepdims=True)
    A = vertex_neighbours(faces, V)
    for _ in range(smooth_iters):
        W = 0.5 * W + 0.5 * (A @ W)
    # eyeballs after smoothing: the cap turns with the eye, the lids stay with the head
    for e in (JI["left_eye"], JI["right_eye"]):
        W[:, head] += W[:, e]
        W[:, e] = 0.0
        d = np.linalg.norm(p - joints[e], axis=1)
        w_eye = smoothstep((0.0128 - d) / 0.0012) * (p[:, 2] > joints[e][2])
        W *= (1.0 - w_eye)[:, None]
        W[:, e] = w_eye
    W[W < 1e-4] = 0.0
    return W / W.sum(axis=1, keepdims=True)


def _seg_dist(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
    return np.linalg.norm(p - a - t[:, None] * ab, axis=1)


def joint_regressor(verts: np.ndarray, owner: np.ndarray, joints: np.ndarray,
                    k: int = 24) -> np.ndarray:
    """(55, V) regressor with J_regressor @ verts == joints (to ~1e-9 m).

    Each joint is a convex combination (NNLS, sum to one) of its nearest vertices among those
    owned by the joint, its parent or its children; when the joint is outside their hull an
    affine least-norm combination of more vertices is used.
    """
    V = len(verts)
    R = np.zeros((NJ, V))
    for j in range(NJ):
        related = {j} | {c for c in range(NJ) if PARENTS[c] == j}
        if j > 0:
            related.add(int(PARENTS[j]))
        cand = np.nonzero(np.isin(owner, list(related)))[0]
        d = np.linalg.norm(verts[cand] - joints[j], axis=1)
        for kk in (k, 2 * k, 4 * k):
            sel = cand[np.argsort(d)[:kk]]
            X = verts[sel]
            A = np.vstack([X.T, 10.0 * np.ones(len(sel))])
            b = np.concatenate([joints[j], [10.0]])
            w, res = nnls(A, b)
            if res < 1e-7:
                break
        else:
            sel = cand[np.argsort(d)[: 4 * k]]
            A = np.vstack([verts[sel].T, np.ones(len(sel))])
            b = np.concatenate([joints[j], [1.0]])
            w = np.linalg.lstsq(A, b, rcond=None)[0]
        R[j, sel] = w
    return R


def pose_correctives(verts: np.ndarray, faces: np.ndarray, weights: np.ndarray,
                     joints: np.ndarray) -> np.ndarray:
    """posedirs (V, 3, 486): a bulge along the normal in each joint's blend zone, proportional
    to (1 - cos angle) of that joint = -(trace(R - I))/2 (volume-preserving correctives)."""
    V = len(verts)
    n = vertex_normals(verts, faces)
    _, _, half = bone_frames(joints)
    P = np.zeros((V, 3, (NJ - 1) * 9), dtype=np.float64)
    for j in range(1, NJ):
        bump = 4.0 * weights[:, j] * weights[:, PARENTS[j]]
        if j in _FACE_LEAVES:
            continue
        amp = 0.12 * half[j]
        for e in (0, 4, 8):
            P[:, :, 9 * (j - 1) + e] = -0.5 * amp * bump[:, None] * n
    return P


# --- shape and expression directions --------------------------------------------------------
# 10 shape and 10 expression directions: the layout of the 20-direction official SMPL-X files,
# which smplx's own loader also reads (shape 0..9, expression 10..19).
SHAPE_NAMES = ("height", "girth", "leg_length", "arm_length", "shoulder_width", "hand_size",
               "finger_length", "head_size", "hip_width", "neck_length")
EXPRESSION_NAMES = ("jaw_open", "smile", "brows_up", "brows_down", "eyes_close", "cheeks_puff",
                    "lips_pucker", "mouth_stretch", "sneer", "mouth_corners_down")


def shape_directions(verts: np.ndarray, joints: np.ndarray, labels: np.ndarray,
                     weights: np.ndarray) -> np.ndarray:
    """(V, 3, 10) shape directions, one unit = about one standard deviation (metres)."""
    x, y, z = verts.T
    ax = np.abs(x)
    sx = np.sign(x)
    D = np.zeros((len(verts), 3, len(SHAPE_NAMES)))
    # 0 height: uniform scale about the floor point below the pelvis (+4 %)
    D[:, :, 0] = 0.04 * verts
    # 1 girth: push away from the nearest bone axis on torso and limbs (not hands/head)
    u, length, _ = bone_frames(joints)
    top = weights.argmax(axis=1)
    a = joints[top]
    b = a + length[top, None] * u[top]
    ab = b - a
    t = np.clip(((verts - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-12), 0, 1)
    radial = verts - (a + t[:, None] * ab)
    body = (labels == JN.PART_BODY).astype(float)
    D[:, :, 1] = 0.12 * radial * body[:, None]
    # 2 leg length: the legs stretch, everything above the hips rises (feet stay on y=0)
    hip_y = joints[JI["left_hip"]][1]
    D[:, 1, 2] = 0.05 * np.minimum(y, hip_y) / hip_y
    # 3 arm length: stretch along x beyond the shoulder joint, hands shift
    sh_x = joints[JI["left_shoulder"]][0]
    wr_x = joints[JI["left_wrist"]][0]
    arm = np.clip((ax - sh_x) / (wr_x - sh_x), 0.0, 1.0) * (y > 1.2)
    D[:, 0, 3] = 0.04 * sx * arm
    # 4 shoulder width: upper torso widens, arms shift outwards
    upper = smoothstep((y - 1.27) / 0.06)
    D[:, 0, 4] = 0.02 * sx * np.clip(ax / sh_x, 0.0, 1.0) * upper
    # 5 hand size: scale about the wrist (+8 %)
    for side, lab in (("left", JN.PART_LEFT_HAND), ("right", JN.PART_RIGHT_HAND)):
        w = joints[JI[f"{side}_wrist"]]
        ramp = np.clip((np.abs(x) - abs(w[0]) + 0.01) / 0.02, 0.0, 1.0) * (y > 1.2)
        D[:, :, 5] += 0.08 * (verts - w) * ramp[:, None]
    # 6 finger length: fingers stretch along x beyond the knuckles (+10 %)
    mcp_x = joints[JI["left_middle1"]][0] - 0.012
    fing = np.maximum(ax - mcp_x, 0.0) * (y > 1.2)
    D[:, 0, 6] = 0.10 * sx * fing
    # 7 head size: scale about the head centre (+5 %), faded over the neck
    hc = np.array([0.0, 1.60, 0.0])
    hw = smoothstep((y - 1.52) / 0.03) * (ax < 0.2)
    D[:, :, 7] = 0.05 * (verts - hc) * hw[:, None]
    # 8 hip width: legs and pelvis spread
    hipw = 1.0 - smoothstep((y - 1.0) / 0.08)
    D[:, 0, 8] = 0.02 * sx * np.clip(ax / 0.12, 0.0, 1.0) * hipw * (y < 1.2)
    # 9 neck length: everything above the neck base rises
    D[:, 1, 9] = 0.02 * np.clip((y - 1.43) / 0.08, 0.0, 1.0) * (ax < 0.14)
    return D


def expression_directions(verts: np.ndarray, joints: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(V, 3, 10) expression directions on head vertices only (metres per unit)."""
    x, y, z = verts.T
    head = (labels == JN.PART_HEAD).astype(float)
    front = smoothstep((z - 0.03) / 0.02) * head
    E = np.zeros((len(verts), 3, len(EXPRESSION_NAMES)))
    m = np.array([0.0, 1.556, 0.082])  # mouth centre

    def g(c, s):
        return np.exp(-(((verts - np.asarray(c)) / np.asarray(s)) ** 2).sum(1)) * front

    lower = smoothstep((m[1] - y) / 0.006)
    chin = g((0, 1.53, 0.07), (0.05, 0.04, 0.05)) * lower
    E[:, 1, 0] = -0.012 * chin
    E[:, 2, 0] = -0.004 * chin
    for s in (-1, 1):
        c = g((s * 0.024, m[1], m[2] - 0.004), (0.012, 0.01, 0.02))
        E[:, 0, 1] += 0.004 * s * c
        E[:, 1, 1] += 0.004 * c
        E[:, 2, 1] += -0.002 * c
        brow = g((s * 0.03, 1.652, 0.072), (0.025, 0.012, 0.03))
        E[:, 1, 2] += 0.005 * brow
        inner = g((s * 0.015, 1.648, 0.074), (0.015, 0.012, 0.03))
        E[:, 1, 3] += -0.004 * inner
        E[:, 0, 3] += -0.002 * s * inner
        lid = g((s * 0.031, 1.636, 0.075), (0.015, 0.006, 0.02))
        E[:, 1, 4] += -0.004 * lid
        cheek = g((s * 0.042, 1.575, 0.05), (0.02, 0.02, 0.03))
        E[:, 0, 5] += 0.005 * s * cheek
        E[:, 2, 5] += 0.003 * cheek
        corner = g((s * 0.024, m[1], m[2] - 0.004), (0.01, 0.008, 0.02))
        E[:, 0, 7] += 0.005 * s * corner
        E[:, 1, 9] += -0.004 * corner
        nose_side = g((s * 0.012, 1.59, 0.085), (0.012, 0.015, 0.02))
        E[:, 1, 8] += 0.003 * nose_side
    lips = g(m, (0.03, 0.015, 0.02))
    E[:, 2, 6] = 0.006 * lips
    E[:, 0, 6] = -0.25 * (x - m[0]) * lips
    upper_lip = g((0, 1.562, 0.082), (0.025, 0.005, 0.02)) * smoothstep((y - m[1]) / 0.003)
    E[:, 1, 8] += 0.002 * upper_lip
    return E * head[:, None, None]


# --- hands ----------------------------------------------------------------------------------
_HAND_FINGER_ORDER = ("index", "middle", "pinky", "ring", "thumb")  # SMPL-X order in a hand


def _flex_axis(finger: str) -> np.ndarray:
    """Left-hand flexion axis (unit): curls the finger toward the palm (-y)."""
    d = finger_direction(finger)
    target = np.array([0.0, -1.0, 0.0]) if finger != "thumb" else np.array([0.0, -0.75, -0.65])
    a = np.cross(d, target)
    return a / np.linalg.norm(a)


def hand_pose_from_angles(flex: np.ndarray, spread: np.ndarray | None = None) -> np.ndarray:
    """Left-hand 45-D axis-angle from flexion angles (5 fingers x 3 joints, SMPL-X finger order)
    and optional abduction angles (5,) about the palm normal (radians)."""
    pose = np.zeros((15, 3))
    for fi, finger in enumerate(_HAND_FINGER_ORDER):
        for k in range(3):
            pose[3 * fi + k] = flex[fi, k] * _flex_axis(finger)
        if spread is not None:
            pose[3 * fi] += spread[fi] * np.array([0.0, 1.0, 0.0])
    return pose.reshape(45)


def mirror_hand_pose(pose: np.ndarray) -> np.ndarray:
    """Left-hand axis-angle (..., 45) -> the mirrored right-hand pose (x kept, y and z negated)."""
    p = np.array(pose, dtype=np.float64).reshape(*np.shape(pose)[:-1], 15, 3)
    p[..., 1:] *= -1.0
    return p.reshape(*np.shape(pose))


def hand_pca(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Left-hand (components (45, 45) orthonormal rows, relaxed mean (45,)).

    The first rows are synergies (all flex, spread, thumb opposition, index point, claw), the
    rest completes an orthonormal basis from seeded random vectors.
    """
    ones = np.ones((5, 3))
    syn = [
        hand_pose_from_angles(ones * [1.0, 1.0, 0.7]),
        hand_pose_from_angles(np.zeros((5, 3)), spread=np.array([1.0, 0.2, -1.0, -0.5, 0.6])),
        hand_pose_from_angles(np.array([[0, 0, 0]] * 4 + [[1.0, 0.6, 0.4]])),
        hand_pose_from_angles(np.array([[-0.3, -0.2, -0.1], [1, 1, 0.8], [1, 1, 0.8],
                                        [1, 1, 0.8], [0.5, 0.5, 0.3]])),
        hand_pose_from_angles(np.array([[-0.5, 1, 1]] * 4 + [[0, 0.5, 0.5]])),
    ]
    rng = np.random.default_rng(seed)
    M = np.vstack(syn + [rng.standard_normal(45) for _ in range(45 - len(syn))])
    Q, R = np.linalg.qr(M.T)
    Q = Q * np.sign(np.diag(R))[None, :]
    mean = hand_pose_from_angles(np.array([[0.15, 0.25, 0.12]] * 4 + [[0.1, 0.15, 0.1]]))
    return Q.T, mean
