"""SMPL-X body model in torch: batched, differentiable linear blend skinning.

The model follows the SMPL-X formulation (Pavlakos et al. 2019):

    v_shaped = T + S(beta, psi)              shape + expression blend shapes
    J        = J_regressor @ v_shaped        rest joints (55, 3)
    v_posed  = v_shaped + P(R(theta) - I)    pose correctives, 486 pose features
    v        = sum_j w_j A_j [v_posed; 1]    skinning with the relative joint transforms A

Pose is axis-angle per joint relative to its parent (55 joints, see ``joints.py``). Rest
rotations are identity, so ``A_j = G_j @ translate(-J_j)`` where ``G_j`` is the global
transform of joint j. Everything is a registered buffer: move the module with ``.to(device)``.
Checked against ``smplx.lbs.lbs`` on the same file (tests/body/test_model.py).
"""

from __future__ import annotations

import os
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from signsplat.body import joints as J
from signsplat.body.model_file import load_model_arrays, split_shapedirs


class BodyOutput(NamedTuple):
    """Output of :meth:`BodyModel.forward` (B = batch size, V vertices, metres)."""

    vertices: Tensor  # (B, V, 3) posed vertices, transl applied
    joints: Tensor  # (B, 55, 3) posed joints, transl applied
    transforms: Tensor  # (B, 55, 4, 4) LBS transforms A (canonical -> posed, without transl)
    v_shaped: Tensor  # (B, V, 3) canonical vertices with shape + expression, rest pose


def axis_angle_to_matrix(rotvec: Tensor) -> Tensor:
    """Rodrigues' formula, (..., 3) axis-angle (radians) -> (..., 3, 3) rotation matrices.

    Uses Taylor expansions of sin(t)/t and (1-cos t)/t^2 near t = 0 so that values and
    gradients stay finite at the identity; exact at 180 degrees.
    """
    t2 = (rotvec * rotvec).sum(-1, keepdim=True)
    small = t2 < 1e-6
    t2_safe = torch.where(small, torch.ones_like(t2), t2)
    t = torch.sqrt(t2_safe)
    a = torch.where(small, 1.0 - t2 / 6.0 + t2 * t2 / 120.0, torch.sin(t) / t)
    b = torch.where(small, 0.5 - t2 / 24.0 + t2 * t2 / 720.0, (1.0 - torch.cos(t)) / t2_safe)
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1)
    K = K.reshape(*rotvec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device)
    return eye + a[..., None] * K + b[..., None] * (K @ K)


def _tree_levels(parents: np.ndarray) -> list[np.ndarray]:
    """Joints grouped by depth in the kinematic tree (root first)."""
    depth = np.zeros(len(parents), dtype=np.int64)
    for i in range(1, len(parents)):
        depth[i] = depth[parents[i]] + 1
    return [np.nonzero(depth == d)[0] for d in range(depth.max() + 1)]


def rigid_transforms(rotmats: Tensor, rest_joints: Tensor, parents: Tensor,
                     levels: list[Tensor]) -> tuple[Tensor, Tensor]:
    """Forward kinematics.

    rotmats (B, J, 3, 3) local rotations, rest_joints (B, J, 3), parents (J,) long (root -1),
    levels: joint indices per tree depth. Returns posed joints (B, J, 3) and the LBS
    transforms A (B, J, 4, 4) mapping rest-pose points to posed points.
    """
    B, nj = rotmats.shape[:2]
    rel = rest_joints.clone()
    rel[:, 1:] = rest_joints[:, 1:] - rest_joints[:, parents[1:]]
    local = torch.zeros(B, nj, 4, 4, dtype=rotmats.dtype, device=rotmats.device)
    local[..., :3, :3] = rotmats
    local[..., :3, 3] = rel
    local[..., 3, 3] = 1.0
    glob = local
    for idx in levels[1:]:
        new = glob[:, parents[idx]] @ local[:, idx]
        glob = glob.index_copy(1, idx, new)
    posed_joints = glob[..., :3, 3]
    # A_j = G_j @ [I, -J_j; 0, 1]
    shift = (glob[..., :3, :3] @ rest_joints.unsqueeze(-1)).squeeze(-1)
    A = glob.clone()
    A[..., :3, 3] = glob[..., :3, 3] - shift
    return posed_joints, A


def corrective_rows(posedirs: Tensor) -> Tensor | None:
    """Indices of the pose features whose correctives (rows of ``posedirs``, one per feature)
    are not all zero; None when every row has some. The proxy body's correctives use the
    diagonal of each joint's rotation only (two thirds of the rows are zero); the official
    SMPL-X files have none zero."""
    used = (posedirs != 0).any(dim=1)
    return None if bool(used.all()) else torch.nonzero(used).squeeze(1)


def pose_shaped(v_shaped: Tensor, rest_joints: Tensor, pose: Tensor, posedirs: Tensor,
                lbs_weights: Tensor, parents: Tensor, levels: list[Tensor],
                transl: Tensor, pose_rows: Tensor | None = None
                ) -> tuple[Tensor, Tensor, Tensor]:
    """SMPL-X posing of shaped vertices: pose blend shapes, forward kinematics, LBS.

    v_shaped (B, V, 3), rest_joints (B, J, 3), pose (B, J, 3) axis-angle, posedirs
    ((J - 1) * 9, V * 3), or only its rows ``pose_rows`` (R,) when given (the others being
    zero: :func:`corrective_rows`), lbs_weights (V, J), transl (B, 3). Returns the posed
    vertices (B, V, 3), joints (B, J, 3) (both translated) and the LBS transforms A (B, J, 4, 4).
    """
    B = pose.shape[0]
    rotmats = axis_angle_to_matrix(pose)
    eye = torch.eye(3, dtype=pose.dtype, device=pose.device)
    pose_feature = (rotmats[:, 1:] - eye).reshape(B, -1)
    if pose_rows is not None:
        pose_feature = pose_feature.index_select(1, pose_rows)
    v_posed = v_shaped + (pose_feature @ posedirs).reshape(B, -1, 3)
    joints, A = rigid_transforms(rotmats, rest_joints, parents, levels)
    verts = skin_points(v_posed, lbs_weights, A, transl)
    return verts, joints + transl.unsqueeze(1), A


def skin_points(points: Tensor, weights: Tensor, transforms: Tensor,
                transl: Tensor | None = None) -> Tensor:
    """Pose canonical points with LBS.

    points (B, P, 3) or (P, 3) canonical rest-pose positions (metres), weights (P, 55) or
    (B, P, 55) skinning weights, transforms (B, 55, 4, 4) from :class:`BodyOutput`, transl
    (B, 3) or None. Returns (B, P, 3) = sum_j w_j (A_j @ [p; 1]) + transl.
    """
    B = transforms.shape[0]
    if points.dim() == 2:
        points = points.unsqueeze(0).expand(B, -1, -1)
    # only the transforms' top three rows move a point; [p; 1] takes the rotation and the
    # translation in one product (slicing the blended 4x4s apart cost a zero fill of their
    # whole size per slice in the backward)
    T = torch.matmul(weights, transforms[:, :, :3].reshape(B, -1, 12)).reshape(B, -1, 3, 4)
    hom = torch.cat([points, points.new_ones(points.shape[:-1] + (1,))], -1)
    out = (T @ hom.unsqueeze(-1)).squeeze(-1)
    if transl is not None:
        out = out + transl.reshape(B, 1, 3)
    return out


def derive_part_labels(weights: np.ndarray) -> np.ndarray:
    """Part label per vertex (values of ``joints.PART_*``) from skinning weights (V, 55).

    Hands: most weight on the wrist or finger joints of one hand; head: on head, jaw, eyes
    or neck; everything else body.
    """
    top = weights.argmax(axis=1)
    labels = np.full(len(top), J.PART_BODY, dtype=np.int64)
    head = [J.JOINT_INDEX[n] for n in ("neck", "head", "jaw", "left_eye", "right_eye")]
    labels[np.isin(top, head)] = J.PART_HEAD
    labels[np.isin(top, (J.JOINT_INDEX["left_wrist"],) + J.LEFT_HAND_JOINTS)] = J.PART_LEFT_HAND
    labels[np.isin(top, (J.JOINT_INDEX["right_wrist"],) + J.RIGHT_HAND_JOINTS)] = J.PART_RIGHT_HAND
    return labels


_INPUT_SIZES = {
    "global_orient": 3, "body_pose": 63, "jaw_pose": 3, "leye_pose": 3, "reye_pose": 3,
    "left_hand_pose": 45, "right_hand_pose": 45, "transl": 3,
}


class BodyModel(nn.Module):
    """SMPL-X-layout body model (buffers only; batched and differentiable).

    Build it with :meth:`from_file` or from the arrays of :func:`load_model_arrays`.
    Attributes: ``faces`` (F, 3) long, ``v_template`` (V, 3), ``parents`` (55,) long,
    ``lbs_weights`` (V, 55), ``part_labels`` (V,) long, ``vertex_colors`` (V, 3) or None,
    ``rest_joints`` (55, 3) joints of the template, ``num_betas``, ``num_expression``,
    ``hand_mean`` ('flat' or 'mano'), ``shape_names`` / ``expression_names`` (tuples of the
    directions' names, or None), ``kp_surface_points`` (name -> (3 vertex ids, 3
    barycentric weights), from the file's ``kp_*`` keys) or None.
    """

    def __init__(self, arrays: dict[str, np.ndarray], num_betas: int = 10,
                 num_expression: int = 10, dtype: torch.dtype = torch.float32,
                 hand_mean: str = "flat", name: str = "") -> None:
        super().__init__()
        if hand_mean not in ("flat", "mano"):
            raise ValueError(f"hand_mean must be 'flat' or 'mano', got {hand_mean!r}")
        self.name = name
        self.hand_mean = hand_mean
        n_shape, n_expr = split_shapedirs(arrays)
        self.num_betas = min(int(num_betas), n_shape)
        self.num_expression = min(int(num_expression), n_expr)
        sd = arrays["shapedirs"]
        shapedirs = np.concatenate(
            [sd[:, :, : self.num_betas], sd[:, :, n_shape: n_shape + self.num_expression]], axis=2
        )
        V = arrays["v_template"].shape[0]
        f = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dtype)  # noqa: E731
        self.register_buffer("v_template", f(arrays["v_template"]))
        self.register_buffer("faces", torch.as_tensor(arrays["f"], dtype=torch.long))
        self.register_buffer("shapedirs", f(shapedirs))
        # (V, 3, 486) -> (486, V*3) as in smplx
        posedirs = np.asarray(arrays["posedirs"]).reshape(V * 3, -1).T
        self.register_buffer("posedirs", f(posedirs))
        # what posing multiplies: the rows of posedirs that are not all zero (a third of the
        # proxy's), with their pose features' indices (None: all rows)
        rows = corrective_rows(self.posedirs)
        self.register_buffer("pose_rows", rows, persistent=False)
        self.register_buffer("_posedirs_used", None if rows is None else self.posedirs[rows],
                             persistent=False)
        self.register_buffer("J_regressor", f(arrays["J_regressor"]))
        self.register_buffer("lbs_weights", f(arrays["weights"]))
        parents = np.asarray(arrays["kintree_table"][0], dtype=np.int64).copy()
        parents[0] = -1
        self.register_buffer("parents", torch.as_tensor(parents))
        levels = _tree_levels(parents)
        self._num_levels = len(levels)
        for i, lv in enumerate(levels):
            self.register_buffer(f"_level{i}", torch.as_tensor(lv), persistent=False)
        labels = arrays.get("part_labels")
        if labels is None:
            labels = derive_part_labels(np.asarray(arrays["weights"]))
        self.register_buffer("part_labels", torch.as_tensor(np.asarray(labels), dtype=torch.long))
        colors = arrays.get("vertex_colors")
        if colors is not None:
            colors = np.asarray(colors, dtype=np.float64)
            if colors.max() > 1.0:
                colors = colors / 255.0
            self.register_buffer("vertex_colors", f(colors))
        else:
            self.register_buffer("vertex_colors", None)
        for side in ("l", "r"):
            self.register_buffer(f"hands_components_{side}", f(arrays[f"hands_components{side}"]))
            mean = np.asarray(arrays[f"hands_mean{side}"]).reshape(45)
            self.register_buffer(f"hands_mean_{side}", f(mean))
        self.register_buffer("lmk_faces_idx",
                             torch.as_tensor(arrays["lmk_faces_idx"], dtype=torch.long))
        self.register_buffer("lmk_bary_coords", f(arrays["lmk_bary_coords"]))
        if "dynamic_lmk_faces_idx" in arrays and "dynamic_lmk_bary_coords" in arrays:
            self.register_buffer("dynamic_lmk_faces_idx",
                                 torch.as_tensor(arrays["dynamic_lmk_faces_idx"], dtype=torch.long))
            self.register_buffer("dynamic_lmk_bary_coords", f(arrays["dynamic_lmk_bary_coords"]))
        else:
            self.register_buffer("dynamic_lmk_faces_idx", None)
            self.register_buffer("dynamic_lmk_bary_coords", None)
        # names of the shape/expression directions when the file has them (the proxy does)
        self.shape_names = tuple(str(n) for n in arrays["shape_names"])[: self.num_betas] \
            if "shape_names" in arrays else None
        self.expression_names = tuple(str(n) for n in arrays["expression_names"])[
            : self.num_expression] if "expression_names" in arrays else None
        # named surface points for keypoints: name -> (3 vertex ids, 3 weights)
        self.kp_surface_points: dict[str, tuple[np.ndarray, np.ndarray]] | None = None
        faces_np = np.asarray(arrays["f"], dtype=np.int64)
        if {"kp_names", "kp_faces_idx", "kp_bary_coords"} <= arrays.keys():
            self.kp_surface_points = {
                str(n): (faces_np[int(fi)], np.asarray(b, np.float64))
                for n, fi, b in zip(arrays["kp_names"], arrays["kp_faces_idx"],
                                    arrays["kp_bary_coords"])}
        elif {"kp_vertex_names", "kp_vertex_ids"} <= arrays.keys():
            self.kp_surface_points = {
                str(n): (np.array([int(i)] * 3), np.array([1.0, 0.0, 0.0]))
                for n, i in zip(arrays["kp_vertex_names"], arrays["kp_vertex_ids"])}
        self.register_buffer("rest_joints", self.J_regressor @ self.v_template)

    @classmethod
    def from_file(cls, path: str | os.PathLike, num_betas: int = 10, num_expression: int = 10,
                  dtype: torch.dtype = torch.float32, hand_mean: str = "flat") -> "BodyModel":
        """Load a body model from an ``.npz`` in the official SMPL-X layout (checked)."""
        return cls(load_model_arrays(path), num_betas=num_betas, num_expression=num_expression,
                   dtype=dtype, hand_mean=hand_mean, name=str(path))

    @property
    def num_vertices(self) -> int:
        return int(self.v_template.shape[0])

    def hand_pca_to_pose(self, coeffs: Tensor, side: str) -> Tensor:
        """(B, k) PCA coefficients of the 'l' or 'r' hand -> (B, 45) axis-angle (flat, no mean)."""
        comps = getattr(self, f"hands_components_{side}")[: coeffs.shape[-1]]
        return coeffs @ comps

    def _batch(self, kwargs: dict[str, Tensor | None]) -> int:
        sizes = {int(v.shape[0]) for v in kwargs.values() if v is not None and v.ndim > 1}
        sizes.discard(1)
        if len(sizes) > 1:
            raise ValueError(f"inconsistent batch sizes {sorted(sizes)}")
        return sizes.pop() if sizes else 1

    def _block(self, value: Tensor | None, size: int, B: int, name: str) -> Tensor:
        ref = self.v_template
        if value is None:
            return ref.new_zeros(B, size)
        value = torch.as_tensor(value).to(dtype=ref.dtype, device=ref.device)
        if value.dim() == 1:
            value = value.unsqueeze(0)
        elif value.dim() > 2:  # e.g. body_pose as (B, 21, 3)
            value = value.reshape(value.shape[0], -1)
        if value.shape[-1] > size:
            raise ValueError(f"{name} has {value.shape[-1]} values, the model takes at most {size}")
        if value.shape[-1] < size:
            value = torch.cat([value, value.new_zeros(value.shape[0], size - value.shape[-1])], -1)
        return value.expand(B, size)

    def forward(self, betas: Tensor | None = None, expression: Tensor | None = None,
                global_orient: Tensor | None = None, body_pose: Tensor | None = None,
                jaw_pose: Tensor | None = None, leye_pose: Tensor | None = None,
                reye_pose: Tensor | None = None, left_hand_pose: Tensor | None = None,
                right_hand_pose: Tensor | None = None, transl: Tensor | None = None) -> BodyOutput:
        """Pose the model. Every argument is (B, k) or None (zeros); returns :class:`BodyOutput`.

        Poses may also be given per joint, e.g. body_pose (B, 21, 3); (k,) means batch 1 and a
        batch of 1 broadcasts against the others.

        betas (B, <=num_betas), expression (B, <=num_expression), global_orient (B, 3),
        body_pose (B, 63), jaw/leye/reye_pose (B, 3), left/right_hand_pose (B, 45) full
        axis-angle ('mano' models add the hand mean), transl (B, 3) metres.
        """
        args = dict(betas=betas, expression=expression, global_orient=global_orient,
                    body_pose=body_pose, jaw_pose=jaw_pose, leye_pose=leye_pose,
                    reye_pose=reye_pose, left_hand_pose=left_hand_pose,
                    right_hand_pose=right_hand_pose, transl=transl)
        B = self._batch(args)
        blocks = {k: self._block(args[k], n, B, k) for k, n in _INPUT_SIZES.items()}
        lh, rh = blocks["left_hand_pose"], blocks["right_hand_pose"]
        if self.hand_mean == "mano":
            lh = lh + self.hands_mean_l
            rh = rh + self.hands_mean_r
        full_pose = torch.cat([blocks["global_orient"], blocks["body_pose"], blocks["jaw_pose"],
                               blocks["leye_pose"], blocks["reye_pose"], lh, rh], dim=1)
        coeffs = torch.cat([self._block(betas, self.num_betas, B, "betas"),
                            self._block(expression, self.num_expression, B, "expression")], 1)
        return self.lbs(coeffs, full_pose.reshape(B, J.NUM_JOINTS, 3), blocks["transl"])

    def lbs(self, coeffs: Tensor, pose: Tensor, transl: Tensor) -> BodyOutput:
        """Core LBS: coeffs (B, num_betas + num_expression), pose (B, 55, 3), transl (B, 3)."""
        v_shaped = self.v_template + torch.einsum("bl,vkl->bvk", coeffs, self.shapedirs)
        rest_joints = torch.einsum("jv,bvk->bjk", self.J_regressor, v_shaped)
        posedirs = self.posedirs if self.pose_rows is None else self._posedirs_used
        verts, joints, A = pose_shaped(v_shaped, rest_joints, pose, posedirs,
                                       self.lbs_weights, self.parents, self.levels(), transl,
                                       self.pose_rows)
        return BodyOutput(verts, joints, A, v_shaped)

    def levels(self) -> list[Tensor]:
        """Joint indices per depth of the kinematic tree (for :func:`rigid_transforms`)."""
        return [getattr(self, f"_level{i}") for i in range(self._num_levels)]
