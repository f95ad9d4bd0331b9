"""Scene data for the avatar: images, masks, cameras and SMPL-X parameters of one sequence.

Reads the tables of earlier stages (``frames``, ``cameras``, ``smplx_params``) and holds images
as uint8 tensors. Cameras are OpenCV world-to-camera (``viewmat = [[R, t], [0, 1]]``).
The novel-pose split holds out every ``interval``-th frame (from ``offset``); the novel-view
split holds out the listed cameras.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from signsplat.body.joints import POSE_BLOCKS
from signsplat.errors import InputError
from signsplat.io.images import read_mask, read_rgb
from signsplat.io.tables import read_table

log = logging.getLogger(__name__)

SMPLX_BLOCKS = ("betas", "expression") + tuple(n for n, _ in POSE_BLOCKS) + ("transl",)


@dataclass
class SceneData:
    """One sequence. F frames, C cameras.

    frames: (F,) frame ids (sorted); views: (C,) camera ids; images: (C, F, H, W, 3) uint8;
    masks: (C, F, H, W) uint8 0/255 (255 everywhere when the table has none);
    viewmats: (C, 4, 4) float32; Ks: (C, 3, 3) float32 for the rasterizer (scaled to the loaded
    resolution; principal point + 0.5 px: the rasterizer puts pixel centres at i + 0.5);
    smplx: block name -> (F, k) float32 tensors (NaN replaced, see ``sanitize_smplx``).
    """

    scene: str
    frames: np.ndarray
    views: np.ndarray
    images: torch.Tensor
    masks: torch.Tensor
    viewmats: torch.Tensor
    Ks: torch.Tensor
    smplx: dict[str, torch.Tensor]

    @property
    def height(self) -> int:
        return int(self.images.shape[2])

    @property
    def width(self) -> int:
        return int(self.images.shape[3])


def split_frames(frames: np.ndarray, interval: int, offset: int) -> tuple[np.ndarray, np.ndarray]:
    """(train, test) frame ids: frames with ``(frame - offset) % interval == 0`` are test."""
    frames = np.asarray(frames)
    test = (frames - offset) % interval == 0
    return frames[~test], frames[test]


def sanitize_smplx(params: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Replace NaN/inf (e.g. hands with no keypoints in the fit) by zeros (rest pose), logging
    which blocks and how many frames were affected."""
    out = {}
    for name, t in params.items():
        bad = ~torch.isfinite(t)
        if bool(bad.any()):
            log.warning("SMPL-X '%s': %d frame(s) with missing values set to the rest pose",
                        name, int(bad.any(-1).sum()))
            t = torch.where(bad, torch.zeros_like(t), t)
        out[name] = t
    return out


def smplx_from_table(path: str | os.PathLike, frames: np.ndarray) -> dict[str, torch.Tensor]:
    """SMPL-X blocks (F, k) for ``frames`` from an ``smplx_params`` table."""
    df = read_table(path, "smplx_params").set_index("frame")
    missing = [int(f) for f in frames if f not in df.index]
    if missing:
        raise InputError(f"{path}: no SMPL-X parameters for frame(s) {missing[:10]}")
    df = df.loc[list(frames)]
    out = {}
    for name in SMPLX_BLOCKS:
        if name in df.columns:
            out[name] = torch.tensor(np.stack([np.asarray(v, dtype=np.float32)
                                               for v in df[name]]))
    return sanitize_smplx(out)


def _resize(img: np.ndarray, size: int, nearest: bool = False) -> np.ndarray:
    import cv2

    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_AREA
    return cv2.resize(img, (size, size), interpolation=interp)


def load_scene(frames_path: str | os.PathLike, cameras_path: str | os.PathLike,
               smplx_path: str | os.PathLike, resolution: int = 0,
               max_frames: int = 0) -> SceneData:
    """Load a sequence. ``resolution`` > 0 resizes images to that square size (K scaled)."""
    frames_path = Path(frames_path)
    ftab = read_table(frames_path, "frames")
    ctab = read_table(cameras_path, "cameras")
    scene = str(ftab["scene"].iloc[0])
    frames = np.sort(ftab["frame"].unique())
    if max_frames:
        frames = frames[:max_frames]
    views = np.sort(ftab["view"].unique())
    static = ctab[ctab["frame"] == -1] if (ctab["frame"] == -1).any() else ctab
    viewmats, ks, size = [], [], None
    for v in views:
        row = static[static["view"] == v]
        if row.empty:
            raise InputError(f"{cameras_path}: no camera for view {v}")
        row = row.iloc[0]
        m = np.eye(4, dtype=np.float32)
        m[:3, :3] = np.asarray(row["R"], dtype=np.float32).reshape(3, 3)
        m[:3, 3] = np.asarray(row["t"], dtype=np.float32)
        k = np.array([[row["fx"], 0, row["cx"]], [0, row["fy"], row["cy"]], [0, 0, 1]],
                     dtype=np.float32)
        w, h = int(row["width"]), int(row["height"])
        if resolution:
            sx, sy = resolution / w, resolution / h
            k[0] *= sx
            k[1] *= sy
            # pixel centres at integer coordinates: x' = (x + 0.5) * s - 0.5
            k[0, 2] = (row["cx"] + 0.5) * sx - 0.5
            k[1, 2] = (row["cy"] + 0.5) * sy - 0.5
        # tables put pixel centres at integer coordinates (OpenCV); the rasterizer (gsplat
        # semantics) at i + 0.5: shift the principal point by half a pixel
        k[0, 2] += 0.5
        k[1, 2] += 0.5
        viewmats.append(m)
        ks.append(k)
    rows = ftab.set_index(["view", "frame"])
    imgs, masks = [], []
    for v in views:
        vi, vm = [], []
        for f in frames:
            r = rows.loc[(v, f)]
            img = read_rgb(frames_path.parent / r["image"])
            mask = (read_mask(frames_path.parent / r["mask"]).astype(np.uint8) * 255
                    if r["mask"] else np.full(img.shape[:2], 255, np.uint8))
            if resolution:
                img, mask = _resize(img, resolution), _resize(mask, resolution, nearest=True)
            vi.append(img)
            vm.append(mask)
        imgs.append(np.stack(vi))
        masks.append(np.stack(vm))
    return SceneData(
        scene=scene, frames=frames, views=views,
        images=torch.from_numpy(np.stack(imgs)), masks=torch.from_numpy(np.stack(masks)),
        viewmats=torch.from_numpy(np.stack(viewmats)), Ks=torch.from_numpy(np.stack(ks)),
        smplx=smplx_from_table(smplx_path, frames),
    )


def target(data: SceneData, view_i: int, frame_i: int, background: torch.Tensor,
           use_mask: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """Ground truth (3, H, W) float in [0,1] with the background replaced by ``background`` (3,)
    where the mask is 0 (``use_mask``), and the mask (1, H, W) float."""
    img = data.images[view_i, frame_i].permute(2, 0, 1).float() / 255.0
    mask = (data.masks[view_i, frame_i].float() / 255.0)[None]
    if use_mask:
        img = img * mask + background[:, None, None] * (1 - mask)
    return img, mask
