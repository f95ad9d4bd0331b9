"""Photometric refinement of the training cameras (``train.refine_cameras``).

Cameras solved from detected keypoints are a few pixels off one another (on the default studio
scene: 3.2 degrees and 6 cm after a similarity alignment). Every view then asks for the texture in
a slightly different place and the avatar blurs. The trainer can correct each training camera by
a small rigid motion, learned with the Gaussians from the same image loss. The rasterizer already
passes gradients to ``viewmats``.

Parameterisation: each camera ``c`` has a correction ``(w_c, t_c)`` (rotation vector, translation
in metres). It acts on world points before the camera's own world-to-camera matrix::

    X' = R(w_c) (X - m) + m + t_c,        viewmat'_c = viewmat_c @ T_c

``m`` is the body's mean position. Rotating about the subject keeps rotation and translation
nearly independent, so one learning rate suits both. A correction that every camera shares moves
the whole world rigidly; training images cannot tell it apart from moving the body, and held-out
frames (posed by the fit, not fine-tuned) would no longer line up. So the mean correction over the
training cameras is removed (``delta = raw - mean(raw)``). This holds the gauge to first order and
leaves only relative motion. Held-out cameras are never corrected.
"""

from __future__ import annotations

import roma
import torch
from torch import nn


class CameraRefinement(nn.Module):
    """Learned rigid corrections of the training cameras.

    Args:
        viewmats: (V, 4, 4) world-to-camera matrices of every view in the data.
        centre: (3,) rotation centre in world coordinates (the subject).
        train_views: indices of the views that are corrected (the others stay as given).
        enabled: False keeps every camera fixed (no parameters are learned; ``viewmats()``
            returns the input).
    """

    def __init__(self, viewmats: torch.Tensor, centre: torch.Tensor, train_views, enabled: bool):
        super().__init__()
        v = viewmats.shape[0]
        mask = torch.zeros(v, dtype=torch.bool)
        mask[torch.as_tensor(list(train_views), dtype=torch.long)] = True
        self.enabled = bool(enabled)
        self.register_buffer("base", viewmats.detach().clone().float())
        self.register_buffer("centre", torch.as_tensor(centre, dtype=torch.float32).reshape(3))
        self.register_buffer("train_mask", mask)
        self.raw = nn.Parameter(torch.zeros(v, 6), requires_grad=self.enabled)

    def delta(self) -> torch.Tensor:
        """(V, 6) corrections (rotation vector, translation) with the gauge removed; zero for
        views that are not corrected."""
        m = self.train_mask[:, None].to(self.raw.dtype)
        mean = (self.raw * m).sum(0, keepdim=True) / m.sum().clamp_min(1.0)
        return (self.raw - mean) * m

    def transforms(self) -> torch.Tensor:
        """(V, 4, 4) world-space corrections T_c (identity when disabled)."""
        v = self.base.shape[0]
        eye = torch.eye(4, dtype=self.base.dtype, device=self.base.device).expand(v, 4, 4)
        if not self.enabled:
            return eye
        d = self.delta()
        rot = roma.rotvec_to_rotmat(d[:, :3])
        trans = self.centre - torch.einsum("vij,j->vi", rot, self.centre) + d[:, 3:]
        top = torch.cat([rot, trans[:, :, None]], 2)
        bottom = eye[:, 3:4, :]
        return torch.cat([top, bottom], 1)

    def viewmats(self) -> torch.Tensor:
        """(V, 4, 4) corrected world-to-camera matrices."""
        if not self.enabled:
            return self.base
        return self.base @ self.transforms()

    @torch.no_grad()
    def summary(self) -> dict[str, float]:
        """Largest and mean correction: rotation in degrees, translation in millimetres."""
        d = self.delta()[self.train_mask]
        if not self.enabled or d.numel() == 0:
            return {"camera_rotation_deg_max": 0.0, "camera_shift_mm_max": 0.0,
                    "camera_rotation_deg_mean": 0.0, "camera_shift_mm_mean": 0.0}
        ang = torch.rad2deg(d[:, :3].norm(dim=1))
        mm = 1000.0 * d[:, 3:].norm(dim=1)
        return {"camera_rotation_deg_max": float(ang.max()),
                "camera_shift_mm_max": float(mm.max()),
                "camera_rotation_deg_mean": float(ang.mean()),
                "camera_shift_mm_mean": float(mm.mean())}
