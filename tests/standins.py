"""The one stand-in body of the tests: a small icosphere in the SMPL-X file layout.

162 vertices (radius 0.3 m, centre y = 1 m) with the 55 SMPL-X joints inside, LBS weights
and a joint regressor by distance, 10 shape directions and no expression directions. Parts:
y > 1.2 head, x > 0.18 left hand, x < -0.18 right hand, else body. Loads with
:meth:`signsplat.body.model.BodyModel.from_file` like a real model, so every stage's code runs
on it unchanged, in milliseconds.
"""

from __future__ import annotations

import numpy as np

from signsplat.body import joints as J

KP_NAMES = ("nose", "leye", "reye", "lear", "rear", "LBigToe", "LSmallToe", "LHeel", "RBigToe",
            "RSmallToe", "RHeel") + tuple(f"{s}{f}" for s in "lr"
                                          for f in ("thumb", "index", "middle", "ring", "pinky"))


def tiny_body_arrays(seed: int = 0) -> dict[str, np.ndarray]:
    """An SMPL-X-layout body: icosphere (162 vertices, radius 0.3 m, centre y = 1) with 55
    joints inside, LBS weights by distance, shape directions (no expression directions)."""
    import trimesh

    g = np.random.default_rng(seed)
    sph = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    v = np.asarray(sph.vertices) + [0.0, 1.0, 0.0]
    n = len(v)
    joints = g.normal(0, 0.12, (55, 3)) + [0.0, 1.0, 0.0]
    joints[list(J.LEFT_HAND_JOINTS), 0] = 0.25
    joints[list(J.RIGHT_HAND_JOINTS), 0] = -0.25
    d = np.linalg.norm(v[None] - joints[:, None], axis=-1)  # (55, V)
    reg = np.exp(-d / 0.03)
    reg /= reg.sum(1, keepdims=True)
    w = np.exp(-d.T / 0.05)
    w /= w.sum(1, keepdims=True)
    part = np.full(n, J.PART_BODY)
    part[v[:, 1] > 1.2] = J.PART_HEAD
    part[v[:, 0] > 0.18] = J.PART_LEFT_HAND
    part[v[:, 0] < -0.18] = J.PART_RIGHT_HAND
    shapedirs = np.zeros((n, 3, 20))
    shapedirs[..., :10] = g.normal(0, 0.002, (n, 3, 10))
    return {
        "v_template": v, "f": np.asarray(sph.faces), "shapedirs": shapedirs,
        "posedirs": np.zeros((n, 3, 486)), "J_regressor": reg, "weights": w,
        "kintree_table": np.stack([np.array(J.SMPLX_PARENTS), np.arange(55)]),
        "hands_componentsl": np.eye(45), "hands_componentsr": np.eye(45),
        "hands_meanl": np.zeros(45), "hands_meanr": np.zeros(45),
        "lmk_faces_idx": np.arange(51) % len(sph.faces), "lmk_bary_coords": np.full((51, 3), 1 / 3),
        "part_labels": part, "num_shape_dirs": np.array(10), "num_expression_dirs": np.array(10),
        "kp_vertex_names": np.array(KP_NAMES), "kp_vertex_ids": g.integers(0, n, len(KP_NAMES)),
    }
