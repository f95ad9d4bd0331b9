"""Fixtures of the stitch tests: the files of a tiny untrained avatar (session-wide)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tiny_avatar import AVATAR_CFG, SIZE, rig_cameras, write_cameras

from signsplat.avatar.config import avatar_config
from signsplat.avatar.data import SceneData
from signsplat.avatar.train import AvatarTrainer
from signsplat.body import joints as J
from signsplat.body.model import BodyModel


@pytest.fixture(scope="session")
def tiny_files(tmp_path_factory, tiny_body_path):
    """(body .npz, cameras table, checkpoint of an untrained avatar with random colours, as
    ``signsplat train-avatar`` writes it)."""
    root = tmp_path_factory.mktemp("tiny_avatar")
    body = BodyModel.from_file(tiny_body_path)
    cams = rig_cameras()
    cam_path = write_cameras(root / "cameras.parquet", cams)
    g = torch.Generator().manual_seed(0)
    smplx = {k: torch.zeros(3, n) for k, n in J.PARAM_BLOCKS}
    smplx["body_pose"] = torch.randn(3, 63, generator=g) * 0.1
    smplx["transl"][:, 2] = 0.05
    images = (torch.rand(len(cams), 3, SIZE, SIZE, 3, generator=g) * 255).to(torch.uint8)
    data = SceneData("tiny", np.arange(3), np.arange(len(cams)), images,
                     torch.full((len(cams), 3, SIZE, SIZE), 255, dtype=torch.uint8),
                     torch.tensor(np.stack([c.viewmat for c in cams]), dtype=torch.float32),
                     torch.stack([c.raster_K() for c in cams]), smplx)
    trainer = AvatarTrainer(body, data, avatar_config(AVATAR_CFG))
    with torch.no_grad():
        trainer.model.sh_dc.normal_(0, 1.5, generator=g)
    ckpt = trainer.save_checkpoint(root / "checkpoint.pt")
    return tiny_body_path, cam_path, ckpt

