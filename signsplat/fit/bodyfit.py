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

    def hand_pose(self, side: str) -> torch.Tensor:
        """Feasible flat hand pose (T,45) of ``side``."""
        return hl.free_to_hand_pose(getattr(self, f"{side}_free"), self.limits[side])

    def hand_anatomical(self, side: str) -> torch.Tensor:
        """Anatomical angles (T,15,3) radians of ``side``."""
        return hl.free_to_anatomical(getattr(self, f"{side}_free"), self.limits[side])

    def model_inputs(self, frames: torch.Tensor | slice | None = None) -> dict[str, torch.Tensor]:
        """Keyword arguments for ``BodyModel.forward`` of the selected frames."""
        sel = slice(None) if frames is None else frames
        T = self.transl[sel].shape[0]
        return {
            "betas": self.betas.expand(T, -1),
            "expression": self.expression[sel],
            "global_orient": self.global_orient[sel],
            "body_pose": self.body_pose[sel],
            "jaw_pose": self.jaw_pose[sel],
            "left_hand_pose": self.hand_pose("left")[sel],
            "right_hand_pose": self.hand_pose("right")[sel],
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


class KeypointModel(torch.nn.Module):
    """Body model + whole-body regressor: parameters -> joints (B,55,3), keypoints (B,133,3).

    ``model`` is a :class:`signsplat.body.model.BodyModel`, ``regressor`` a
    :class:`signsplat.body.keypoints.WholeBodyRegressor` built on it. All outputs are metres in
    the fit's world frame.
    """

    def __init__(self, model, regressor):
        super().__init__()
        self.model = model
        self.regressor = regressor

    def forward(self, **inputs) -> tuple[torch.Tensor, torch.Tensor, object]:
        out = self.model(**inputs)
        return out.joints, self.regressor(out), out
