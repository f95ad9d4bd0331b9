"""Whole-body keypoints in the COCO-WholeBody 133 layout from SMPL-X joints and vertices.

Layout (``joints.COCO_WHOLEBODY_NAMES``): body 17, feet 6, face 68, left hand 21, right hand 21.

- Body: shoulders, elbows, wrists, hips, knees, ankles are SMPL-X joints; nose, eyes and
  ears are surface vertices.
- Feet: big toe, small toe and heel vertices.
- Face: iBUG-68 order; points 0..16 (jaw contour) come from the frontal row (yaw 0) of the
  model's ``dynamic_lmk_*`` table (a fixed choice: the regressor stays one linear map of
  vertices and joints, which the fitting stage exploits), points 17..67 from the 51 static
  landmarks
  (``lmk_faces_idx``, ``lmk_bary_coords``), each a barycentric point of a posed face.
- Hands: wrist joint, then per finger in COCO order (thumb, index, middle, ring, pinky) the
  three SMPL-X finger joints and a fingertip vertex. (SMPL-X's joint order within a hand is
  index, middle, pinky, ring, thumb.)

Surface points (nose, eyes, ears, toes, heels, fingertips): the model file's ``kp_names`` /
``kp_faces_idx`` / ``kp_bary_coords`` (the proxy writes them) or ``kp_vertex_names`` /
``kp_vertex_ids``; for files without them (official SMPL-X) the published SMPL-X vertex ids
of ``smplx.vertex_ids.vertex_ids['smplx']``.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor, nn

from signsplat.body import joints as JN
from signsplat.body.model import BodyModel, BodyOutput

JI = JN.JOINT_INDEX
# Rows of SMPL-X's dynamic landmark table by head yaw (smplx: row = yaw for yaw 0..39 degrees,
# 39 - yaw for negative yaw): row 0 is the frontal contour.
FRONTAL_ROW = 0

_BODY_SOURCES = (
    ("v", "nose"), ("v", "leye"), ("v", "reye"), ("v", "lear"), ("v", "rear"),
    ("j", "left_shoulder"), ("j", "right_shoulder"), ("j", "left_elbow"), ("j", "right_elbow"),
    ("j", "left_wrist"), ("j", "right_wrist"), ("j", "left_hip"), ("j", "right_hip"),
    ("j", "left_knee"), ("j", "right_knee"), ("j", "left_ankle"), ("j", "right_ankle"),
)
_FEET_SOURCES = (("v", "LBigToe"), ("v", "LSmallToe"), ("v", "LHeel"), ("v", "RBigToe"),
                 ("v", "RSmallToe"), ("v", "RHeel"))


def _hand_sources(side: str) -> list[tuple[str, str]]:
    s = "l" if side == "left" else "r"
    out = [("j", f"{side}_wrist")]
    for finger in JN.COCO_FINGERS:
        out += [("j", f"{side}_{finger}{k}") for k in (1, 2, 3)] + [("v", f"{s}{finger}")]
    return out


def keypoint_surface_points(model: BodyModel) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Named keypoint surface points of ``model``: name -> (3 vertex ids, 3 weights).

    The model file's own (``kp_names``/``kp_faces_idx``/``kp_bary_coords`` or
    ``kp_vertex_names``/``kp_vertex_ids``), else SMPL-X's published vertex ids.
    """
    if model.kp_surface_points is not None:
        return dict(model.kp_surface_points)
    from smplx.vertex_ids import vertex_ids

    ids = dict(vertex_ids["smplx"])
    if max(ids.values()) >= model.num_vertices:
        raise ValueError(
            f"body model {model.name!r} has {model.num_vertices} vertices and no keypoint "
            "vertices ('kp_*' keys); SMPL-X's published ids need the 10,475-vertex SMPL-X mesh"
        )
    return {n: (np.array([i] * 3), np.array([1.0, 0.0, 0.0])) for n, i in ids.items()}


class WholeBodyRegressor(nn.Module):
    """Linear map from (joints, vertices) to the 133 COCO-WholeBody keypoints.

    Each keypoint is either one joint or a barycentric combination of up to 3 vertices.
    ``regressor(output)`` with a :class:`BodyOutput` returns (B, 133, 3) world positions
    (metres, ``transl`` included); ``valid`` (133,) is False for keypoints the model cannot
    place (the face contour when the file has no dynamic landmark table; those rows sit on the
    head joint).
    """

    def __init__(self, model: BodyModel) -> None:
        super().__init__()
        pts = keypoint_surface_points(model)
        n = JN.NUM_KEYPOINTS
        joint_idx = np.zeros(n, np.int64)
        joint_w = np.zeros(n, np.float32)
        vert_idx = np.zeros((n, 3), np.int64)
        vert_w = np.zeros((n, 3), np.float32)
        valid = np.ones(n, bool)
        faces = model.faces.cpu().numpy()

        def put(k: int, src: tuple[str, str]) -> None:
            kind, name = src
            if kind == "j":
                joint_idx[k], joint_w[k] = JI[name], 1.0
            else:
                vert_idx[k], vert_w[k] = pts[name]

        sources = list(_BODY_SOURCES) + list(_FEET_SOURCES)
        for k, src in enumerate(sources):
            put(k, src)
        face0 = JN.KP_FACE[0]
        if model.dynamic_lmk_faces_idx is not None:
            dyn_f = model.dynamic_lmk_faces_idx.cpu().numpy()
            dyn_b = model.dynamic_lmk_bary_coords.cpu().numpy()
            row = min(FRONTAL_ROW, dyn_f.shape[0] - 1)
            for i in range(17):
                vert_idx[face0 + i] = faces[dyn_f[row, i]]
                vert_w[face0 + i] = dyn_b[row, i]
        else:
            for i in range(17):
                joint_idx[face0 + i], joint_w[face0 + i] = JI["head"], 1.0
                valid[face0 + i] = False
        lf = model.lmk_faces_idx.cpu().numpy()
        lb = model.lmk_bary_coords.cpu().numpy()
        for i in range(51):
            vert_idx[face0 + 17 + i] = faces[lf[i]]
            vert_w[face0 + 17 + i] = lb[i]
        for side, kp in (("left", JN.KP_LEFT_HAND), ("right", JN.KP_RIGHT_HAND)):
            for k, src in zip(kp, _hand_sources(side)):
                put(k, src)
        dtype = model.v_template.dtype
        self.register_buffer("joint_idx", torch.as_tensor(joint_idx))
        self.register_buffer("joint_w", torch.as_tensor(joint_w, dtype=dtype))
        self.register_buffer("vert_idx", torch.as_tensor(vert_idx))
        self.register_buffer("vert_w", torch.as_tensor(vert_w, dtype=dtype))
        self.register_buffer("valid", torch.as_tensor(valid))
        self.names = JN.COCO_WHOLEBODY_NAMES

    def regress(self, joints: Tensor, vertices: Tensor) -> Tensor:
        """joints (B, 55, 3), vertices (B, V, 3) -> keypoints (B, 133, 3)."""
        kp = joints[:, self.joint_idx] * self.joint_w[:, None]
        v = vertices[:, self.vert_idx.reshape(-1)].reshape(vertices.shape[0], -1, 3, 3)
        return kp + (v * self.vert_w[..., None]).sum(dim=2)

    def forward(self, output: BodyOutput) -> Tensor:
        return self.regress(output.joints, output.vertices)
