"""Diagnostic overlays: the fitted mesh and skeleton projected onto the input images (OpenCV).

Drawn per image: mesh vertices as faint grey dots, the fitted COCO-WholeBody skeleton (body
green, left hand blue, right hand red, face yellow dots) and the input keypoints as small white
crosses, so misfits show as offsets between crosses and skeleton. With the person masks, their
outline (magenta) and the fitted body's outline (cyan) too: a camera on the wrong side of the
signer shows as outlines that do not match.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import torch

from signsplat.errors import InputError
from signsplat.fit.bodyfit import KeypointModel, keypoints_of
from signsplat.fit.cameras import project
from signsplat.fit.data import mask_files, read_frames
from signsplat.fit.side_check import silhouette
from signsplat.fit.sequence import FitResult
from signsplat.io.atomic import atomic_path
from signsplat.io.images import read_mask, read_rgb

log = logging.getLogger(__name__)

BODY_EDGES = ((0, 1), (0, 2), (1, 3), (2, 4), (5, 6), (5, 7), (7, 9), (6, 8), (8, 10), (5, 11),
              (6, 12), (11, 12), (11, 13), (13, 15), (12, 14), (14, 16))


def _hand_edges(base: int) -> list[tuple[int, int]]:
    edges = []
    for finger in range(5):
        prev = base
        for k in range(4):
            cur = base + 1 + finger * 4 + k
            edges.append((prev, cur))
            prev = cur
    return edges


LEFT_HAND_EDGES = tuple(_hand_edges(91))
RIGHT_HAND_EDGES = tuple(_hand_edges(112))

COLORS_BGR = {"body": (60, 200, 60), "left": (230, 120, 40), "right": (40, 40, 230),
              "face": (0, 220, 240), "mesh": (170, 170, 170), "obs": (255, 255, 255),
              "mask": (255, 0, 255), "outline": (255, 255, 0)}


def draw_overlay(image_rgb: np.ndarray, uv_kp: np.ndarray, obs: np.ndarray | None = None,
                 uv_mesh: np.ndarray | None = None, scale: int = 2,
                 mask: np.ndarray | None = None, outline: np.ndarray | None = None
                 ) -> np.ndarray:
    """Draw onto a copy of ``image_rgb (H,W,3) uint8``; returns BGR uint8 (H*scale, W*scale, 3).

    uv_kp (133,2) projected fitted keypoints; obs (133,3) input keypoints (score > 0 drawn);
    uv_mesh (N,2) projected vertices (subsampled by the caller); mask and outline (H,W) bool:
    the person mask and the fitted body's silhouette, each drawn as its outline. Non-finite
    points are skipped.
    """
    img = cv2.cvtColor(np.ascontiguousarray(image_rgb), cv2.COLOR_RGB2BGR)
    img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
    for region, color in ((mask, "mask"), (outline, "outline")):
        if region is not None:
            big = cv2.resize(region.astype(np.uint8), None, fx=scale, fy=scale,
                             interpolation=cv2.INTER_NEAREST)
            contours, _ = cv2.findContours(big, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(img, contours, -1, COLORS_BGR[color], 1)

    def p(xy):
        return (int(round((xy[0] + 0.5) * scale - 0.5)), int(round((xy[1] + 0.5) * scale - 0.5)))

    ok = lambda xy: np.isfinite(xy).all() and abs(xy[0]) < 1e5 and abs(xy[1]) < 1e5  # noqa: E731
    if uv_mesh is not None:
        for xy in uv_mesh:
            if ok(xy):
                cv2.circle(img, p(xy), 0, COLORS_BGR["mesh"], -1)
    for edges, color in ((BODY_EDGES, "body"), (LEFT_HAND_EDGES, "left"),
                         (RIGHT_HAND_EDGES, "right")):
        for a, b in edges:
            if ok(uv_kp[a]) and ok(uv_kp[b]):
                cv2.line(img, p(uv_kp[a]), p(uv_kp[b]), COLORS_BGR[color], 1, cv2.LINE_AA)
    for k in range(23, 91):
        if ok(uv_kp[k]):
            cv2.circle(img, p(uv_kp[k]), 1, COLORS_BGR["face"], -1)
    if obs is not None:
        for xy, s in zip(obs[:, :2], obs[:, 2]):
            if s > 0 and ok(xy):
                c = p(xy)
                cv2.drawMarker(img, c, COLORS_BGR["obs"], cv2.MARKER_CROSS, 4, 1)
    return img


def write_overlay(path: str | Path, image_bgr: np.ndarray) -> Path:
    """Write a PNG atomically; returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), image_bgr):
            raise OSError(f"{path}: OpenCV could not write the overlay")
    return path


def pick_frames(frames: np.ndarray, provenance: np.ndarray, count: int) -> list[int]:
    """Up to ``count`` evenly spaced positions of fitted frames (indices into ``frames``)."""
    idx = np.nonzero(np.asarray(provenance) == "fitted")[0]
    if count <= 0 or len(idx) == 0:
        return []
    pos = np.linspace(0, len(idx) - 1, min(count, len(idx))).round().astype(int)
    return [int(idx[i]) for i in np.unique(pos)]


def overlay_views(num_views: int, max_views: int, flagged=()) -> list[int]:
    """The views (ascending) that get overlays: the ``flagged`` ones first (views the camera
    initialisation left unplaced, turned around or doubted), then the others in order, at
    most ``max_views``."""
    first = [v for v in dict.fromkeys(int(v) for v in flagged) if 0 <= v < num_views]
    rest = [v for v in range(num_views) if v not in first]
    return sorted((first + rest)[:max_views])


def flagged_views(result: FitResult) -> list[int]:
    """The views a user should look at first: unplaced, then turned around, then doubted by
    the camera initialisation (the fit log's ``camera_init_turned_views`` and
    ``camera_init_doubtful_views``)."""
    unplaced = [v for v, s in enumerate(result.camera_status) if s == "unplaced"]
    return unplaced + list(result.log.get("camera_init_turned_views", [])) \
        + list(result.log.get("camera_init_doubtful_views", []))


def _mask_for(png: Path | None, shape: tuple[int, int]) -> np.ndarray | None:
    """The person mask at ``png`` when it is readable and of the image's ``shape (H,W)``;
    else None (with a warning: the overlay goes without the outlines)."""
    if png is None:
        return None
    try:
        mask = read_mask(png)
    except InputError as exc:
        log.warning("overlay without the masks' outlines: %s", exc)
        return None
    if mask.shape != shape:
        log.warning("overlay without the masks' outlines: %s is %dx%d, the image %dx%d", png,
                    mask.shape[1], mask.shape[0], shape[1], shape[0])
        return None
    return mask


def write_overlays(kpm: KeypointModel, result: FitResult, obs: np.ndarray, frames_path,
                   out_dir: Path, cfg: dict, view: int | None = None,
                   masks_path=None) -> list[Path]:
    """Overlay PNGs ``overlays/view{v:02d}_frame{f:04d}.png`` in ``out_dir`` of a few fitted
    frames per view (config ``fit.overlay``), drawn on the images of the frames table
    ``frames_path``; ``view``: the source camera of a one-view fit. With more views than
    ``max_views``, the flagged ones (:func:`flagged_views`) are among them. ``masks_path``: a
    masks (or frames) table whose person masks are outlined beside the fitted body's."""
    oc = cfg["overlay"]
    (out_dir / "overlays").mkdir(parents=True, exist_ok=True)
    df = read_frames(frames_path)
    try:
        masks = mask_files(masks_path) if masks_path else {}
    except InputError as exc:  # the fit did not need them: the overlays go without outlines
        log.warning("overlays without the masks' outlines: %s", exc)
        masks = {}
    faces = kpm.model.faces.cpu().numpy()
    pos = pick_frames(result.frames, result.provenance, oc["frames_per_view"])
    if not pos:
        return []
    sub = {k: v[pos] for k, v in result.params.items()}
    _, kp, verts = keypoints_of(kpm, sub)
    rig = result.rig
    step = max(1, verts.shape[1] // 3000)
    allpts = np.concatenate([kp, verts[:, ::step]], axis=1)
    uv, z = project(torch.as_tensor(allpts), torch.as_tensor(rig.K), torch.as_tensor(rig.R),
                    torch.as_tensor(rig.t))
    uv = uv.numpy()
    uv[z.numpy() <= 0.05] = np.nan
    paths = []
    for v in overlay_views(rig.num_views, oc["max_views"], flagged_views(result)):
        src_view = v if view is None else view
        for i, p in enumerate(pos):
            f = int(result.frames[p])
            row = df[(df["view"] == src_view) & (df["frame"] == f)]
            if row.empty:
                continue
            img = read_rgb(row["image_path"].iloc[0])
            mask = _mask_for(masks.get((src_view, f)), img.shape[:2])
            outline = None if mask is None else silhouette(
                rig.K[v], rig.R[v], rig.t[v], verts[i], faces, img.shape[1], img.shape[0])
            drawn = draw_overlay(img, uv[v, i, :133], obs[v, p], uv[v, i, 133:],
                                 mask=mask, outline=outline)
            paths.append(write_overlay(out_dir / "overlays" / f"view{v:02d}_frame{f:04d}.png",
                                       drawn))
    return paths
