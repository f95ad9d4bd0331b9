"""Image regions of the parts that carry sign language: hands and face, from projected joints.

Crops are squares centred on the projection of a part's joints (the SMPL-X joints of the frame,
so a frame without hand keypoints still has hand regions). A crop partly outside the image is
clipped; one entirely outside (or behind the camera) is None.
"""

from __future__ import annotations

import torch

from signsplat.body.joints import JOINT_INDEX, LEFT_HAND_JOINTS, RIGHT_HAND_JOINTS

PART_JOINTS = {
    "left_hand": (JOINT_INDEX["left_wrist"],) + LEFT_HAND_JOINTS,
    "right_hand": (JOINT_INDEX["right_wrist"],) + RIGHT_HAND_JOINTS,
    "face": (JOINT_INDEX["head"], JOINT_INDEX["jaw"], JOINT_INDEX["left_eye"],
             JOINT_INDEX["right_eye"]),
}


def project(points: torch.Tensor, viewmat: torch.Tensor, K: torch.Tensor) -> tuple[torch.Tensor,
                                                                                    torch.Tensor]:
    """Pixel coordinates (N, 2) and depths (N,) of world points (N, 3) (OpenCV camera)."""
    cam = points @ viewmat[:3, :3].T + viewmat[:3, 3]
    z = cam[:, 2]
    uv = (cam @ K.T)[:, :2] / z.clamp_min(1e-6)[:, None]
    return uv, z


def part_box(joints: torch.Tensor, part: str, viewmat: torch.Tensor, K: torch.Tensor,
             width: int, height: int, size_fraction: float) -> tuple[int, int, int, int] | None:
    """Crop (x0, y0, x1, y1) (exclusive ends) of ``part`` for (55, 3) posed joints, or None."""
    pts = joints[list(PART_JOINTS[part])].detach()
    uv, z = project(pts, viewmat, K)
    if not bool((z > 1e-3).all()) or not bool(torch.isfinite(uv).all()):
        return None
    c = uv.mean(0)
    half = max(1, int(round(size_fraction * max(width, height) / 2)))
    x0, y0 = int(round(float(c[0]))) - half, int(round(float(c[1]))) - half
    x1, y1 = x0 + 2 * half, y0 + 2 * half
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
    if x1 - x0 < 4 or y1 - y0 < 4:
        return None
    return x0, y0, x1, y1
