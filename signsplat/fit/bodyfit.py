"""The learnable SMPL-X parameters of a sequence and the differentiable keypoints they produce.

Unknowns (torch, float32 by default, on the device given):

- ``betas (1,S)`` shared over the sequence;
- per frame ``global_orient (T,3)``, ``transl (T,3)`` metres, ``body_pose (T,63)``,
  ``jaw_pose (T,3)``, ``expression (T,E)``;
- per frame and hand the *free* hand parameters ``(T, F)`` of
  :func:`signsplat.body.hand_limits.free_to_hand_pose`: every unlocked anatomical Euler axis
  squashed into its allowed range, so the full 45-D axis-angle hand pose (flat convention, no
  MANO mean, no PCA truncation) can never leave the joint limits.

Eye poses are not observable from 2D keypoints and stay zero.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch

from signsplat.body import hand_limits as hl

HAND_MEAN = "flat"  # hand poses are full rotations (stated in the output table metadata)


@dataclass
class SequenceParams:
    """Plain SMPL-X parameters of a sequence: name -> numpy float (T,k) (betas (T,S))."""

    arrays: dict[str, np.ndarray]

    @property
    def num_frames(self) -> int:
        return int(self.arrays["transl"].shape[0])


class FitParams(torch.nn.Module):
    """Learnable parameters of ``T`` frames (see the module docstring for the blocks)."""

    def __init__(self, num_frames: int, num_betas: int, num_expression: int,
                 dtype=torch.float32, device: torch.device | str = "cpu",
                 init: dict[str, np.ndarray] | None = None):
        super().__init__()
        T = int(num_frames)
        kw = dict(dtype=dtype, device=device)
        self.limits = {"left": hl.hand_limits("left"), "right": hl.hand_limits("right")}
        self._both_hands = hl.both_hands(self.limits["left"], self.limits["right"])
        init = init or {}

        def block(name, shape):
            if name in init:
                arr = np.asarray(init[name], dtype=np.float64).reshape(shape)
                return torch.nn.Parameter(torch.as_tensor(arr, **kw).clone())
            return torch.nn.Parameter(torch.zeros(shape, **kw))

        self.betas = block("betas", (1, num_betas))
        self.global_orient = block("global_orient", (T, 3))
        self.transl = block("transl", (T, 3))
        self.body_pose = block("body_pose", (T, 63))
        self.jaw_pose = block("jaw_pose", (T, 3))
        self.expression = block("expression", (T, num_expression))
        for side in ("left", "right"):
            pose = torch.as_tensor(np.asarray(init.get(f"{side}_hand_pose", np.zeros((T, 45))),
                                              dtype=np.float64).reshape(T, 45), **kw)
            free = hl.hand_pose_to_free(pose.double(), self.limits[side]).to(dtype)
            setattr(self, f"{side}_free", torch.nn.Parameter(free.clone()))

    @property
    def num_frames(self) -> int:
        return int(self.transl.shape[0])

    def hand_poses(self, frames: torch.Tensor | slice | None = None
                   ) -> tuple[torch.Tensor, torch.Tensor]:
        """Feasible flat hand poses (T,45) of the left and the right hand of the selected
        ``frames``, both converted in one call (what the fit's every iteration needs)."""
        sel = slice(None) if frames is None else frames
        free = torch.cat([self.left_free[sel], self.right_free[sel]], dim=-1)
        both = hl.free_to_hand_pose(free, self._both_hands)
        return both[..., :45], both[..., 45:]

    def hand_anatomical(self, side: str, frames: torch.Tensor | slice | None = None
                        ) -> torch.Tensor:
        """Anatomical angles (T,15,3) radians of ``side`` (of the selected ``frames``)."""
        free = getattr(self, f"{side}_free")
        return hl.free_to_anatomical(free if frames is None else free[frames],
                                     self.limits[side])

    def model_inputs(self, frames: torch.Tensor | slice | None = None) -> dict[str, torch.Tensor]:
        """Keyword arguments for ``BodyModel.forward`` of the selected frames."""
        sel = slice(None) if frames is None else frames
        T = self.transl[sel].shape[0]
        left, right = self.hand_poses(sel)
        return {
            "betas": self.betas.expand(T, -1),
            "expression": self.expression[sel],
            "global_orient": self.global_orient[sel],
            "body_pose": self.body_pose[sel],
            "jaw_pose": self.jaw_pose[sel],
            "left_hand_pose": left,
            "right_hand_pose": right,
            "transl": self.transl[sel],
        }

    def groups(self) -> dict[str, list[torch.nn.Parameter]]:
        """Parameter groups by role (for per-group learning rates and freezing)."""
        return {
            "betas": [self.betas],
            "root": [self.global_orient, self.transl],
            "body": [self.body_pose],
            "hands": [self.left_free, self.right_free],
            "face": [self.jaw_pose, self.expression],
        }

    def export(self) -> dict[str, np.ndarray]:
        """Every SMPL-X block as numpy float64 (T,k), hands as 45-D flat axis-angle."""
        with torch.no_grad():
            T = self.num_frames
            out = {k: v.detach().double().cpu().numpy() for k, v in self.model_inputs().items()}
            out["betas"] = np.repeat(self.betas.detach().double().cpu().numpy(), T, axis=0)
            out["leye_pose"] = np.zeros((T, 3))
            out["reye_pose"] = np.zeros((T, 3))
        return out


def linearise_regressor(model, regressor, tol_m: float = 1e-5, seed: int = 0
                        ) -> tuple[np.ndarray, np.ndarray] | None:
    """Express a keypoint regressor as fixed linear maps of the posed vertices and joints.

    Probes ``regressor(BodyOutput)`` with autograd: ``kp = Wv @ vertices + Wj @ joints``.
    Returns ``(Wv (133,V), Wj (133,55))`` float64, or None when the regressor is not of that
    form (checked on a random pose to ``tol_m`` metres), e.g. when it depends on the transforms
    or selects landmarks by head pose.
    """
    from signsplat.body.model import BodyOutput

    ref = model.v_template
    with torch.no_grad():
        out = model()
    verts = out.vertices.detach().clone().requires_grad_(True)
    joints = out.joints.detach().clone().requires_grad_(True)
    kp = regressor(BodyOutput(verts, joints, out.transforms.detach(), out.v_shaped.detach()))
    n = kp.shape[1]
    Wv = np.zeros((n, verts.shape[1]))
    Wj = np.zeros((n, joints.shape[1]))
    for k in range(n):
        gv, gj = torch.autograd.grad(kp[0, k, 0], (verts, joints), retain_graph=True,
                                     allow_unused=True)
        if gv is not None:
            Wv[k] = gv[0, :, 0].double().cpu().numpy()
        if gj is not None:
            Wj[k] = gj[0, :, 0].double().cpu().numpy()
    # check on a random pose (also catches weights that differ between x, y, z)
    g = torch.Generator().manual_seed(seed)
    B = 2
    rnd = lambda k, s: (torch.randn(B, k, generator=g) * s).to(ref)  # noqa: E731
    with torch.no_grad():
        test = model(global_orient=rnd(3, 0.5), body_pose=rnd(63, 0.3), jaw_pose=rnd(3, 0.2),
                     left_hand_pose=rnd(45, 0.3), right_hand_pose=rnd(45, 0.3),
                     betas=rnd(model.num_betas, 1.0), transl=rnd(3, 0.5))
        want = regressor(test).double().cpu().numpy()
    got = (np.einsum("kv,bvc->bkc", Wv, test.vertices.double().cpu().numpy())
           + np.einsum("kj,bjc->bkc", Wj, test.joints.double().cpu().numpy()))
    if not np.isfinite(got).all() or np.abs(got - want).max() > tol_m:
        return None
    return Wv, Wj


class KeypointModel(torch.nn.Module):
    """Body model + whole-body regressor: parameters -> joints (B,55,3), keypoints (B,133,3).

    ``model`` is a :class:`signsplat.body.model.BodyModel`, ``regressor`` a
    :class:`signsplat.body.keypoints.WholeBodyRegressor` built on it. All outputs are metres in
    the fit's world frame.

    When the regressor is a fixed linear map of vertices and joints (probed once by
    :func:`linearise_regressor`), the fit's forward pass only skins the few vertices the
    keypoints use (exactly the same LBS, with the model's own kinematics), which is ~50x faster
    than posing all vertices. ``forward(full=True)`` always runs the full model.
    """

    def __init__(self, model, regressor, fast: bool = True, offsets: np.ndarray | None = None):
        super().__init__()
        self.model = model
        self.regressor = regressor
        self.fast = False
        # a detector's own keypoints (signsplat.fit.keypoint_offsets); None = the regressor's
        ref = model.v_template
        self.register_buffer("offsets", None if offsets is None else torch.as_tensor(
            offsets, dtype=ref.dtype, device=ref.device))
        if offsets is not None:  # index tensors made once, not per forward pass
            from signsplat.fit.keypoint_offsets import ANCHOR_JOINTS, ANCHORED

            self.register_buffer("_anchored", torch.as_tensor(ANCHORED, device=ref.device))
            self.register_buffer("_anchor_joints",
                                 torch.as_tensor(ANCHOR_JOINTS, device=ref.device))
        if fast:
            lin = linearise_regressor(model, regressor)
            if lin is not None:
                self._build_sparse(*lin)
                self.fast = True

    def _build_sparse(self, Wv: np.ndarray, Wj: np.ndarray) -> None:
        m = self.model
        ref = m.v_template
        used = np.nonzero(np.abs(Wv).sum(0) > 0)[0]
        S = len(used)
        idx = torch.as_tensor(used, device=ref.device)
        self.register_buffer("_Wv", torch.as_tensor(Wv[:, used], dtype=ref.dtype, device=ref.device))
        self.register_buffer("_Wj", torch.as_tensor(Wj, dtype=ref.dtype, device=ref.device))
        self.register_buffer("_v_template", m.v_template[idx])
        self.register_buffer("_shapedirs", m.shapedirs[idx])
        V = m.v_template.shape[0]
        cols = (idx[:, None] * 3 + torch.arange(3, device=ref.device)).reshape(-1)
        from signsplat.body.model import corrective_rows

        posedirs = m.posedirs[:, cols]
        rows = corrective_rows(posedirs)
        self.register_buffer("_pose_rows", rows)
        self.register_buffer("_posedirs", posedirs if rows is None else posedirs[rows])
        self.register_buffer("_weights", m.lbs_weights[idx])
        self.register_buffer("_J_template", m.J_regressor @ m.v_template)
        self.register_buffer("_J_dirs", torch.einsum("jv,vkl->jkl", m.J_regressor, m.shapedirs))
        self._num_sparse = S
        assert V >= S

    def _sparse_forward(self, inputs: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        from signsplat.body.model import pose_shaped

        m = self.model
        ref = self._v_template
        B = max([v.shape[0] for v in inputs.values() if v is not None] + [1])

        def blk(name, size):
            v = inputs.get(name)
            if v is None:
                return ref.new_zeros(B, size)
            v = v.to(ref.dtype)
            if v.shape[-1] < size:
                v = torch.cat([v, v.new_zeros(v.shape[0], size - v.shape[-1])], -1)
            return v.expand(B, size)

        lh, rh = blk("left_hand_pose", 45), blk("right_hand_pose", 45)
        if m.hand_mean == "mano":
            lh, rh = lh + m.hands_mean_l, rh + m.hands_mean_r
        pose = torch.cat([blk("global_orient", 3), blk("body_pose", 63), blk("jaw_pose", 3),
                          blk("leye_pose", 3), blk("reye_pose", 3), lh, rh], 1).reshape(B, -1, 3)
        coeffs = torch.cat([blk("betas", m.num_betas), blk("expression", m.num_expression)], 1)
        transl = blk("transl", 3)
        v_shaped = self._v_template + torch.einsum("bl,vkl->bvk", coeffs, self._shapedirs)
        rest_joints = self._J_template + torch.einsum("bl,jkl->bjk", coeffs, self._J_dirs)
        verts, joints, A = pose_shaped(v_shaped, rest_joints, pose, self._posedirs,
                                       self._weights, m.parents, m.levels(), transl,
                                       self._pose_rows)
        kp = torch.einsum("ks,bsc->bkc", self._Wv, verts) + torch.einsum("kj,bjc->bkc",
                                                                         self._Wj, joints)
        return joints, self._offset(kp, A)

    def _offset(self, kp: torch.Tensor, A: torch.Tensor) -> torch.Tensor:
        """The keypoints moved by the detector's offsets, turned with their segments (LBS
        transforms ``A (B,55,4,4)``); as they are without offsets."""
        if self.offsets is None:
            return kp
        moved = torch.einsum("bkij,kj->bki", A[:, self._anchor_joints, :3, :3], self.offsets)
        return kp.index_add(1, self._anchored, moved)

    def forward(self, full: bool = False, **inputs) -> tuple[torch.Tensor, torch.Tensor, object]:
        """-> (joints (B,55,3), keypoints (B,133,3), BodyOutput or None on the fast path)."""
        if self.fast and not full:
            joints, kp = self._sparse_forward(inputs)
            return joints, kp, None
        out = self.model(**inputs)
        return out.joints, self._offset(self.regressor(out), out.transforms), out


def load_keypoint_model(body_path: str | os.PathLike, num_betas: int, num_expression: int,
                        device: torch.device | str = "cpu",
                        offsets: np.ndarray | None = None) -> KeypointModel:
    """Body model + whole-body regressor of the file ``body_path`` as a :class:`KeypointModel`
    on ``device``; ``offsets (K,3)``: a detector's keypoints
    (:func:`signsplat.fit.keypoint_offsets.offsets_array`), none = the regressor's."""
    from signsplat.body.keypoints import WholeBodyRegressor
    from signsplat.body.model import BodyModel

    model = BodyModel.from_file(body_path, num_betas=num_betas,
                                num_expression=num_expression).to(device)
    regressor = WholeBodyRegressor(model)
    if isinstance(regressor, torch.nn.Module):
        regressor = regressor.to(device)
    return KeypointModel(model, regressor, offsets=offsets)


#: SMPL-X parameter blocks :func:`keypoints_of` passes to the body model when present
PARAM_BLOCKS = ("betas", "expression", "global_orient", "body_pose", "jaw_pose", "leye_pose",
                "reye_pose", "left_hand_pose", "right_hand_pose", "transl")


def keypoints_of(kpm: KeypointModel, params: dict[str, np.ndarray], batch: int = 64
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joints (T,55,3), keypoints (T,133,3) and vertices (T,V,3), float64 metres, of the
    SMPL-X parameter blocks ``params`` (name -> (T,k); flat hand poses), posed in batches."""
    ref = kpm.model.v_template
    T = params["transl"].shape[0]
    js, ks, vs = [], [], []
    with torch.no_grad():
        for s in range(0, T, batch):
            inp = {n: torch.as_tensor(np.asarray(params[n][s:s + batch]), dtype=ref.dtype,
                                      device=ref.device) for n in PARAM_BLOCKS if n in params}
            j, k, out = kpm(full=True, **inp)
            js.append(j.double().cpu().numpy())
            ks.append(k.double().cpu().numpy())
            vs.append(out.vertices.double().cpu().numpy())
    return np.concatenate(js), np.concatenate(ks), np.concatenate(vs)
