"""Fixtures: a tiny icosphere 'body' with the BodyModel interface, cameras and a scene."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh
from torch import nn

from signsplat.avatar.data import SMPLX_BLOCKS, SceneData
from signsplat.body import joints as J
from signsplat.body.model import (BodyOutput, _tree_levels, axis_angle_to_matrix,
                                  rigid_transforms, skin_points)

SIZES = {"betas": 10, "expression": 10, "global_orient": 3, "body_pose": 63, "jaw_pose": 3,
         "leye_pose": 3, "reye_pose": 3, "left_hand_pose": 45, "right_hand_pose": 45,
         "transl": 3}


class TinyBody(nn.Module):
    """Icosphere of radius 0.3 m centred at y = 1 with 55 SMPL-X joints inside and LBS.

    Parts: y > 1.2 head, x > 0.18 left hand, x < -0.18 right hand, else body.
    """

    def __init__(self, subdivisions: int = 2, seed: int = 0):
        super().__init__()
        g = np.random.default_rng(seed)
        sph = trimesh.creation.icosphere(subdivisions=subdivisions, radius=0.3)
        v = torch.tensor(sph.vertices, dtype=torch.float32) + torch.tensor([0.0, 1.0, 0.0])
        self.register_buffer("v_template", v)
        self.register_buffer("faces", torch.tensor(sph.faces, dtype=torch.long))
        joints = torch.tensor(g.normal(0, 0.12, (55, 3)), dtype=torch.float32)
        joints += torch.tensor([0.0, 1.0, 0.0])
        joints[J.LEFT_HAND_JOINTS, 0] = 0.25
        joints[J.RIGHT_HAND_JOINTS, 0] = -0.25
        self.register_buffer("rest_joints", joints)
        d = torch.cdist(v, joints)
        self.register_buffer("lbs_weights", torch.softmax(-d / 0.05, -1))
        part = torch.full((len(v),), J.PART_BODY)
        part[v[:, 1] > 1.2] = J.PART_HEAD
        part[v[:, 0] > 0.18] = J.PART_LEFT_HAND
        part[v[:, 0] < -0.18] = J.PART_RIGHT_HAND
        self.register_buffer("part_labels", part)
        self.register_buffer("shapedirs", torch.tensor(g.normal(0, 0.002, (len(v), 3, 20)),
                                                       dtype=torch.float32))
        self.register_buffer("parents", torch.tensor(J.SMPLX_PARENTS))
        self.levels = [torch.as_tensor(lv) for lv in _tree_levels(np.array(J.SMPLX_PARENTS))]

    def forward(self, **kw) -> BodyOutput:
        b = max([t.shape[0] for t in kw.values() if t is not None] + [1])
        get = {k: (kw.get(k) if kw.get(k) is not None else torch.zeros(b, n))
               for k, n in SIZES.items()}
        coeffs = torch.cat([get["betas"].expand(b, -1), get["expression"]], 1)
        v_shaped = self.v_template + torch.einsum("bl,vkl->bvk", coeffs, self.shapedirs)
        pose = torch.cat([get[k] for k, _ in J.POSE_BLOCKS], 1).reshape(b, 55, 3)
        rot = axis_angle_to_matrix(pose)
        rest = self.rest_joints.expand(b, -1, -1)
        posed_joints, A = rigid_transforms(rot, rest, self.parents, self.levels)
        verts = skin_points(v_shaped, self.lbs_weights, A, get["transl"])
        return BodyOutput(verts, posed_joints + get["transl"][:, None], A, v_shaped)


def look_at(eye, target=(0.0, 1.0, 0.0)) -> torch.Tensor:
    """OpenCV world-to-camera 4x4 (x right, y down, z forward), world y up."""
    eye = np.asarray(eye, float)
    z = np.asarray(target) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, -1.0, 0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    m = np.eye(4)
    m[:3, :3] = R
    m[:3, 3] = -R @ eye
    return torch.tensor(m, dtype=torch.float32)


def rig(n_views: int = 3, size: int = 32, distance: float = 1.6):
    angles = np.linspace(-0.6, 0.6, n_views)
    vm = torch.stack([look_at((distance * math.sin(a), 1.0, distance * math.cos(a)))
                      for a in angles])
    f = size * 1.2
    K = torch.tensor([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1]],
                     dtype=torch.float32).expand(n_views, -1, -1).clone()
    return vm, K


def random_smplx(n_frames: int, seed: int = 0, scale: float = 0.15) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    out = {k: torch.randn(n_frames, n, generator=g) * scale for k, n in SIZES.items()}
    out["betas"] = out["betas"][:1].expand(n_frames, -1).clone() * 0
    out["expression"] *= 0
    out["transl"] *= 0.1
    return out


def make_scene(images: torch.Tensor, vm, K, smplx) -> SceneData:
    """images (C, F, H, W, 3) float in [0, 1] -> SceneData with full masks."""
    c, f, h, w, _ = images.shape
    return SceneData(
        scene="tiny", frames=np.arange(f), views=np.arange(c),
        images=(images.clamp(0, 1) * 255).round().to(torch.uint8),
        masks=torch.full((c, f, h, w), 255, dtype=torch.uint8),
        viewmats=vm, Ks=K, smplx={k: smplx[k] for k in SMPLX_BLOCKS},
    )


@pytest.fixture
def tiny_body():
    return TinyBody()


@pytest.fixture(autouse=True)
def _one_thread():
    """Two thread pools (torch, Numba) spinning on 2 shared cores are many times slower."""
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        import numba

        old_nb = numba.get_num_threads()
        numba.set_num_threads(1)
    except ImportError:
        old_nb = None
    yield
    torch.set_num_threads(old)
    if old_nb is not None:
        numba.set_num_threads(old_nb)
