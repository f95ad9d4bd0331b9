"""Which side of the signer a doubtful camera faces, decided by the person masks.

Seen from behind, a signer's keypoints with left and right labelled the other way round look
like a (mirrored) front view, so the keypoints alone cannot always tell a back camera from a
front one (:func:`signsplat.fit.rig_init.turn_views` leaves such views in place as
*doubtful*). The outline can: a view from behind shows the mirror image of the view from the
front, and the outline of an asymmetric signing pose does not match its mirror image. Once the
body is fitted on the keypoints, its silhouette in the view, where the view is placed and
turned around, is compared with the view's person masks (mean IoU over frames).

Shapes: ``T`` frames, ``N`` mesh vertices, ``F`` faces, 133 keypoints; a camera is
world-to-camera ``R (3,3)``, ``t (3,)`` with intrinsics ``K (3,3)``; masks ``(T,H,W)`` bool.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from signsplat.fit.rig_init import mirror_index, project_points, refine_view, turned_around
from signsplat.geometry.align import rotation_angle_deg

#: sub-pixel bits of the triangle fill (cv2.fillConvexPoly's ``shift``): vertices at 1/8 px
_SHIFT = 3
#: samples per pixel side: OpenCV's fill also fills the pixels its edges touch, up to half a
#: sample outside the triangle, so the silhouette is filled on a finer grid and a pixel is
#: covered when more than half of its samples are
_SUPERSAMPLE = 4
#: farthest projected vertex (px) a filled triangle may have: the fill's fixed-point
#: coordinates must stay within int32
_FAR_PX = 1e5


def silhouette(K: np.ndarray, R: np.ndarray, t: np.ndarray, vertices: np.ndarray,
               faces: np.ndarray, width: int, height: int) -> np.ndarray:
    """(H,W) bool: the pixels (centres at integer coordinates) more than half covered by the
    triangles of the mesh ``vertices (N,3)``, ``faces (F,3)`` seen by the camera. Triangles
    with a vertex behind the camera, or projected more than ``_FAR_PX`` from the origin (a
    vertex nearly in the camera's plane), are left out."""
    uv, front = project_points(K, R, t, vertices)
    near = front & (np.abs(uv) < _FAR_PX).all(-1)
    keep = near[faces].all(1)
    s = _SUPERSAMPLE
    fine = (uv[faces[keep]] + 0.5) * s - 0.5  # the fine grid's sample centres at integers
    tri = np.round(fine * (1 << _SHIFT)).astype(np.int32)
    H, W = int(height), int(width)
    out = np.zeros((H * s, W * s), np.uint8)
    for corners in tri:  # one at a time: fillPoly's even-odd rule empties overlaps
        cv2.fillConvexPoly(out, corners, 1, lineType=cv2.LINE_8, shift=_SHIFT)
    return out.reshape(H, s, W, s).sum((1, 3)) > s * s // 2


def mean_iou(K: np.ndarray, R: np.ndarray, t: np.ndarray, vertices: np.ndarray,
             faces: np.ndarray, masks: np.ndarray) -> float:
    """Mean over frames of the IoU between the mesh's silhouette (``vertices (T,N,3)``) and
    ``masks (T,H,W)``; frames with an empty mask are skipped (NaN when all are)."""
    H, W = masks.shape[1:]
    ious = []
    for verts, mask in zip(vertices, masks):
        if not mask.any():
            continue
        sil = silhouette(K, R, t, verts, faces, W, H)
        ious.append((sil & mask).sum() / (sil | mask).sum())
    return float(np.mean(ious)) if ious else float("nan")


def other_side_poses(K: np.ndarray, R: np.ndarray, t: np.ndarray, keypoints: np.ndarray,
                     obs_v: np.ndarray, centre: np.ndarray, threshold_px: float,
                     min_score: float = 0.3) -> list[tuple[np.ndarray, np.ndarray]]:
    """Poses of the camera on the other side of the signer: ``R, t`` turned half a turn about
    the vertical through ``centre`` (:func:`turned_around`), and that pose refined on the
    fitted body's ``keypoints (T,133,3)`` against the view's detections ``obs_v (T,133,3)``
    (scores above ``min_score``) as labelled and with left and right exchanged; the refined
    poses only when they stay more than 90 degrees from ``R``."""
    Rt, tt = turned_around(R, t, centre)
    poses = [(Rt, tt)]
    X = keypoints.reshape(-1, 3)
    for idx in (np.arange(obs_v.shape[1]), mirror_index()):
        o = obs_v[:, idx]
        m = (o[..., 2] > min_score).reshape(-1)
        if m.sum() < 12:
            continue
        Rn, tn, _ = refine_view(K, Rt, tt, X[m], o[..., :2].reshape(-1, 2)[m], threshold_px)
        if rotation_angle_deg(Rn, R) > 90.0:
            poses.append((Rn, tn))
    return poses


@dataclass
class SideCheck:
    """The masks' verdict on one view: mean IoU where it is placed (``iou_here``) and at the
    best pose on the other side (``iou_there``, its camera ``R``, ``t``)."""

    iou_here: float
    iou_there: float
    R: np.ndarray
    t: np.ndarray

    def turn(self, margin: float) -> bool:
        """Whether the other side's outline overlaps the masks by more than ``margin`` IoU."""
        return bool(self.iou_there > self.iou_here + margin)


def check_side(K: np.ndarray, R: np.ndarray, t: np.ndarray, vertices: np.ndarray,
               faces: np.ndarray, keypoints: np.ndarray, masks: np.ndarray,
               obs_v: np.ndarray, centre: np.ndarray, threshold_px: float) -> SideCheck:
    """One view's side by its masks: the fitted body (``vertices (T,N,3)``, ``keypoints
    (T,133,3)``) against the view's ``masks (T,H,W)`` where the camera ``K, R, t`` is and at
    each of :func:`other_side_poses` (the best of them; NaN overlaps when every mask is
    empty, and then the view stays)."""
    here = mean_iou(K, R, t, vertices, faces, masks)
    there = [(mean_iou(K, Rn, tn, vertices, faces, masks), Rn, tn)
             for Rn, tn in other_side_poses(K, R, t, keypoints, obs_v, centre, threshold_px)]
    iou, Rn, tn = max(there, key=lambda c: -np.inf if np.isnan(c[0]) else c[0])
    return SideCheck(here, iou, Rn, tn)
