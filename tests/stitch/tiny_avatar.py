"""The stitch tests' tiny avatar: 32 px cameras around the stand-in body (tests/standins.py),
an untrained avatar on it with random colours, and a frame-counting video writer."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import torch

from signsplat.avatar.checkpoint import build_model
from signsplat.avatar.config import avatar_config
from signsplat.io.tables import write_table
from signsplat.motion.stitching import StitchConfig
from signsplat.stitch.animate import AvatarRenderer, Camera, Identity, look_at

SIZE = 32
AVATAR_CFG = {
    "upsample": {"max_rounds": 0},
    "model": {"hidden": 8, "sh_degree": 0,
              "scale_max": {"body": 0.08, "head": 0.06, "hands": 0.05}},
    "train": {"iterations": 1, "accumulate_poses": 1, "log_every": 1,
              "smplx_source": "ground_truth", "test_interval": 100, "test_offset": 99},
}
FAST = StitchConfig(min_transition=3, max_transition=6, hold_start=1, hold_end=1)


def rig_cameras(n: int = 3, size: int = SIZE, distance: float = 1.6) -> list[Camera]:
    """Cameras on an arc in front of the body (+z), looking at (0, 1, 0)."""
    cams = []
    for i, a in enumerate(np.linspace(-0.6, 0.6, n)):
        eye = np.array([distance * math.sin(a), 1.0, distance * math.cos(a)])
        f = size * 1.2
        K = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1]])
        cams.append(Camera(look_at(eye, [0.0, 1.0, 0.0]), K, size, size, f"view{i}"))
    return cams


def write_cameras(path, cams: list[Camera]):
    rows = [dict(scene="tiny", view=i, frame=-1, width=c.width, height=c.height,
                 fx=c.K[0, 0], fy=c.K[1, 1], cx=c.K[0, 2], cy=c.K[1, 2],
                 R=c.viewmat[:3, :3].reshape(-1).tolist(), t=c.viewmat[:3, 3].tolist())
            for i, c in enumerate(cams)]
    df = pd.DataFrame(rows).astype({"view": "int32", "frame": "int32", "width": "int32",
                                    "height": "int32"})
    return write_table(df, path, "cameras")


def tiny_renderer(body, camera=None, placement="avatar", ckpt=None) -> AvatarRenderer:
    if ckpt is not None:
        return AvatarRenderer.from_checkpoint(ckpt, body, camera or rig_cameras()[1],
                                              placement=placement, backend="cpu")
    model = build_model(body, torch.zeros(1, 10), avatar_config(AVATAR_CFG))
    with torch.no_grad():
        model.sh_dc.normal_(0, 1.5, generator=torch.Generator().manual_seed(1))
    return AvatarRenderer(model, body, Identity(np.zeros(10, np.float32)),
                          camera or rig_cameras()[1], 0, backend="cpu")


class CountingWriter:
    """VideoWriter stand-in: checks and counts frames, keeps a checksum, holds nothing."""

    def __init__(self):
        self.frames = 0
        self.checksum = 0
        self.distinct = set()

    def write(self, frame):
        assert frame.dtype == np.uint8 and frame.shape == (SIZE, SIZE, 3)
        self.frames += 1
        self.distinct.add(hash(frame.tobytes()))
