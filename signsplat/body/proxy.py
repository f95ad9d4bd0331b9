"""The procedural proxy body model, written in the official SMPL-X ``.npz`` layout.

The proxy stands in for the licensed SMPL-X file in the embedded default, and runs through the
same loader and LBS code. It has the 55 SMPL-X joints (order, tree and rest pose of SMPL-X:
T-pose, palms down, fingers straight, thumbs forward; y up, faces +z, feet on y = 0, ~1.74 m),
a closed genus-0 surface (~10,475 vertices) meshed from a smooth union of primitives, with
separated three-segment fingers and knuckle bulges, smooth skinning weights, 10 shape and 10
expression directions (the 20-direction layout of older official files, which smplx's own
loader reads too), small pose correctives, a joint regressor that reproduces the joints
from the vertices, hand PCA, 51 + 17 face landmarks, part labels, vertex colours, and named
keypoint surface points (``kp_names``, ``kp_faces_idx``, ``kp_bary_coords``) for
:mod:`signsplat.body.keypoints`.

The 17 face-contour landmarks are written as a ``dynamic_lmk_*`` table of 79 identical rows
(the contour does not follow head yaw). Geometry is the same for every seed; the seed selects
the appearance (skin tone, clothing colours) and the random tail of the hand PCA basis.
Same seed -> identical arrays. Generation takes ~11 s of CPU (marching cubes on a 2 mm grid,
region-budgeted quadric decimation, rigging); the compressed file is ~2 MB.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from signsplat.body import joints as JN
from signsplat.body._proxy_mesh import (decimate_regions, dense_mesh, prim_sdf,
                                        project_to_surface)
from signsplat.body._proxy_rig import (EXPRESSION_NAMES, SHAPE_NAMES, expression_directions,
                                       hand_pca, joint_regressor, mirror_hand_pose,
                                       pose_correctives, shape_directions, skinning_weights)
from signsplat.body._proxy_skeleton import (FINGER_NAMES, GROUND_SHIFT, PARENTS, body_primitives,
                                            finger_direction, fingertips, mirror, rest_joints)
from signsplat.body.model import derive_part_labels
from signsplat.body.model_file import write_model_file

JI = JN.JOINT_INDEX
TARGET_VERTICES = 10475  # as SMPL-X


# iBUG-68 face landmarks 17..67 (brows, nose, eyes, mouth) as (x, y) on the proxy's face;
# they are projected onto the surface along -z. Subject's right is -x.
def _static_landmark_xy() -> np.ndarray:
    eye_x, eye_y = rest_joints()[JI["left_eye"]][:2]
    rb_x = np.array([-0.055, -0.045, -0.034, -0.023, -0.012])
    # on the centre line of the painted brow arc (signsplat.body.appearance)
    rb_y = eye_y + 0.022 + 0.004 * np.cos(np.clip((-rb_x - eye_x) / 0.02, -1.6, 1.6))
    pts = list(zip(rb_x, rb_y))
    pts += list(zip(-rb_x[::-1], rb_y[::-1]))
    pts += [(0.0, y) for y in (1.632, 1.618, 1.604, 1.590)]
    pts += list(zip([-0.014, -0.007, 0.0, 0.007, 0.014], [1.580, 1.577, 1.576, 1.577, 1.580]))
    reye = [(-0.045, 1.627), (-0.036, 1.632), (-0.025, 1.632), (-0.018, 1.626),
            (-0.025, 1.622), (-0.036, 1.622)]
    leye = [(0.018, 1.626), (0.025, 1.632), (0.036, 1.632), (0.045, 1.627), (0.036, 1.622),
            (0.025, 1.622)]
    pts += reye + leye
    pts += [(-0.024, 1.556), (-0.016, 1.562), (-0.006, 1.566), (0.0, 1.565), (0.006, 1.566),
            (0.016, 1.562), (0.024, 1.556), (0.016, 1.549), (0.007, 1.545), (0.0, 1.544),
            (-0.007, 1.545), (-0.016, 1.549)]
    pts += [(-0.019, 1.556), (-0.007, 1.558), (0.0, 1.558), (0.007, 1.558), (0.019, 1.556),
            (0.007, 1.554), (0.0, 1.554), (-0.007, 1.554)]
    return np.array(pts)


def _contour_landmark_xy() -> np.ndarray:
    """17 jaw-contour points 0..16, from the subject's right ear-level to the left."""
    phi = np.linspace(-np.pi / 2, np.pi / 2, 17)
    return np.stack([0.064 * np.sin(phi), 1.585 - 0.072 * np.cos(phi)], axis=1)


def _project_front(mesh, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Faces and barycentrics where rays from z=+1 along -z first hit the mesh."""
    origins = np.column_stack([xy, np.full(len(xy), 1.0)])
    return _cast(mesh, origins, np.tile([0.0, 0.0, -1.0], (len(xy), 1)), "face landmarks")


def _keypoint_rays(joints: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Rays (origin, direction) whose first hit on the proxy is each named keypoint; names as
    smplx's ``vertex_ids['smplx']`` (design coordinates)."""
    rays = {"nose": ((0.0, 1.590, 1.0), (0.0, 0.0, -1.0))}
    tips = fingertips()
    for s, side, long in ((1, "l", "left"), (-1, "r", "right")):
        eye = joints[JI[f"{long}_eye"]]
        rays[f"{side}eye"] = ((eye[0], eye[1], 1.0), (0.0, 0.0, -1.0))
        rays[f"{side}ear"] = ((s * 1.0, 1.625, -0.010), (-s * 1.0, 0.0, 0.0))
        for finger in FINGER_NAMES:
            d, tip = finger_direction(finger), tips[finger]
            if s < 0:
                d, tip = mirror(d), mirror(tip)
            rays[f"{side}{finger}"] = (tip + 0.05 * d, -d)
        ankle, foot = joints[JI[f"{long}_ankle"]], joints[JI[f"{long}_foot"]]
        up = "L" if s > 0 else "R"
        rays[f"{up}BigToe"] = ((foot[0] - s * 0.012, 0.022, 1.0), (0.0, 0.0, -1.0))
        rays[f"{up}SmallToe"] = ((foot[0] + s * 0.022, 0.020, 1.0), (0.0, 0.0, -1.0))
        rays[f"{up}Heel"] = ((ankle[0], 0.028, -1.0), (0.0, 0.0, 1.0))
    return {k: (np.asarray(o, float), np.asarray(d, float) / np.linalg.norm(d))
            for k, (o, d) in rays.items()}


def _cast(mesh, origins: np.ndarray, dirs: np.ndarray, what: str):
    """First hits of rays on the mesh -> (faces (N,), barycentrics (N, 3))."""
    import trimesh

    loc, ray, tri = mesh.ray.intersects_location(origins, dirs, multiple_hits=False)
    if len(ray) != len(origins):
        missing = sorted(set(range(len(origins))) - set(ray.tolist()))
        raise RuntimeError(f"{what}: rays {missing} missed the proxy surface")
    order = np.argsort(ray)
    loc, tri = loc[order], tri[order]
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], loc)
    bary = np.clip(bary, 0.0, 1.0)
    return tri.astype(np.int64), bary / bary.sum(axis=1, keepdims=True)


def build_proxy_arrays(seed: int = 0, target_vertices: int = TARGET_VERTICES,
                       spacing: float = 0.002) -> dict[str, np.ndarray]:
    """All arrays of the proxy model file (official SMPL-X keys plus our extras).

    ``spacing`` is the marching-cubes grid step in metres before decimation to
    ``target_vertices``. Deterministic for a given (seed, target_vertices, spacing).
    """
    import trimesh

    from signsplat.body.appearance import albedo

    prims = body_primitives()
    joints = rest_joints()
    verts, faces = dense_mesh(prims, h=spacing)
    # vertex budgets: hands and head get a larger share than their area (as in SMPL-X)
    wrist_x = joints[JI["left_wrist"]][0]
    vr = np.zeros(len(verts), dtype=np.int64)
    vr[(verts[:, 1] > 1.50) & (np.abs(verts[:, 0]) < 0.15)] = 1
    vr[verts[:, 0] > wrist_x - 0.01] = 2
    vr[verts[:, 0] < -(wrist_x - 0.01)] = 3
    budget = {0: int(0.535 * target_vertices), 1: int(0.22 * target_vertices),
              2: int(0.145 * target_vertices), 3: int(0.145 * target_vertices)}
    verts, faces = decimate_regions(verts, faces, vr[faces].max(axis=1), budget, target_vertices)
    verts = project_to_surface(prims, verts)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    if not mesh.is_watertight or not mesh.is_winding_consistent:
        raise RuntimeError("proxy mesh is not closed/consistently oriented after decimation")
    if mesh.volume < 0:
        faces = faces[:, ::-1].copy()
        mesh = trimesh.Trimesh(verts, faces, process=False)
    # ownership: the joint of the nearest primitive
    sd = np.stack([prim_sdf(p, verts) for p in prims], axis=1)
    owner = np.array([p.joint for p in prims])[sd.argmin(axis=1)]
    # put the feet on y = 0 (a fixed lift, so that appearance and keypoints agree exactly)
    dy = GROUND_SHIFT
    if abs(verts[:, 1].min() + dy) > 2e-3:
        raise RuntimeError(f"proxy soles at y={verts[:, 1].min() + dy:.4f} after the lift")
    verts = verts + (0.0, dy, 0.0)
    joints = joints + (0.0, dy, 0.0)
    mesh = trimesh.Trimesh(verts, faces, process=False)

    weights = skinning_weights(verts, faces, owner, joints)
    labels = derive_part_labels(weights)
    J_reg = joint_regressor(verts, owner, joints)
    shapedirs = shape_directions(verts, joints, labels, weights)
    exprdirs = expression_directions(verts - (0.0, dy, 0.0), joints - (0.0, dy, 0.0), labels)
    posedirs = pose_correctives(verts, faces, weights, joints)

    xy_static = _static_landmark_xy() + (0.0, dy)
    xy_contour = _contour_landmark_xy() + (0.0, dy)
    lmk_faces, lmk_bary = _project_front(mesh, xy_static)
    c_faces, c_bary = _project_front(mesh, xy_contour)
    rays = _keypoint_rays(joints - (0.0, dy, 0.0))
    kp_faces, kp_bary = _cast(mesh, np.array([o for o, _ in rays.values()]) + (0.0, dy, 0.0),
                              np.array([d for _, d in rays.values()]), "keypoints")

    comps_l, mean_l = hand_pca(seed)
    comps_r, mean_r = mirror_hand_pose(comps_l), mirror_hand_pose(mean_l)
    colors = albedo(verts, labels, seed=seed, joints=joints)

    kintree = np.stack([PARENTS, np.arange(JN.NUM_JOINTS)]).astype(np.int64)
    return {
        "v_template": verts.astype(np.float64),
        "f": faces.astype(np.uint32),
        "shapedirs": np.concatenate([shapedirs, exprdirs], axis=2).astype(np.float64),
        "posedirs": posedirs.astype(np.float32),
        "J_regressor": J_reg.astype(np.float64),
        "weights": weights.astype(np.float64),
        "kintree_table": kintree,
        "hands_componentsl": comps_l, "hands_componentsr": comps_r,
        "hands_meanl": mean_l, "hands_meanr": mean_r,
        "lmk_faces_idx": lmk_faces.astype(np.uint32),
        "lmk_bary_coords": lmk_bary.astype(np.float64),
        "dynamic_lmk_faces_idx": np.tile(c_faces.astype(np.uint32), (79, 1)),
        "dynamic_lmk_bary_coords": np.tile(c_bary[None], (79, 1, 1)),
        "num_shape_dirs": np.array(shapedirs.shape[2]),
        "num_expression_dirs": np.array(exprdirs.shape[2]),
        "shape_names": np.array(SHAPE_NAMES), "expression_names": np.array(EXPRESSION_NAMES),
        "part_labels": labels.astype(np.int64),
        "vertex_colors": colors.astype(np.float32),
        "kp_names": np.array(list(rays.keys())),
        "kp_faces_idx": kp_faces,
        "kp_bary_coords": kp_bary,
        "proxy_seed": np.array(seed),
    }


def write_proxy_model(path: str | os.PathLike, seed: int = 0,
                      target_vertices: int = TARGET_VERTICES) -> Path:
    """Generate the proxy for ``seed`` and write it (compressed ``.npz``, atomically)."""
    return write_model_file(path, build_proxy_arrays(seed=seed, target_vertices=target_vertices))


