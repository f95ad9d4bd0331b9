"""The masks' verdict on which side of the signer a camera faces (signsplat.fit.side_check)."""

import warnings

import numpy as np
import pytest

from fit_scenes import random_motion, synthetic_rig
from signsplat.fit.bodyfit import keypoints_of
from signsplat.fit.rig_init import project_points, turned_around
from signsplat.fit.side_check import check_side, mean_iou, silhouette
from signsplat.geometry.align import rotation_angle_deg


def test_silhouette_fills_the_pixels_whose_centres_a_triangle_covers():
    K = np.eye(3)  # pixel = (x/z, y/z): vertices at depth 1 land where they are written
    square = np.array([[9.5, 4.5, 1.0], [19.5, 4.5, 1.0], [19.5, 14.5, 1.0], [9.5, 14.5, 1.0],
                       [5.0, 5.0, -1.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 4]])  # the last one reaches behind
    sil = silhouette(K, np.eye(3), np.zeros(3), square, faces, 32, 24)
    ys, xs = np.nonzero(sil)
    assert sil.sum() == 100  # centres 10..19 x 5..14, nothing of the triangle behind
    assert (xs.min(), xs.max(), ys.min(), ys.max()) == (10, 19, 5, 14)
    # a vertex nearly in the camera's plane projects far out: its triangle is left out, not
    # cast to fixed point past int32 (numpy warns of such a cast; here the warning fails)
    grazing = np.vstack([square, [[1000.0, 5.0, 2e-6]]])  # in front, at 5e8 px
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        far = silhouette(K, np.eye(3), np.zeros(3), grazing, np.vstack([faces, [[0, 1, 5]]]),
                         32, 24)
    assert (far == sil).all()
    # a body's front and back overlap in the image: covered twice is covered, not a hole
    twice = silhouette(K, np.eye(3), np.zeros(3), square, faces[[0, 1, 0, 1]], 32, 24)
    assert (twice == sil).all()


@pytest.fixture(scope="module")
def back_view(kpm):
    """A signer seen from behind (a camera turned half a turn from the front one), the
    signer's masks and keypoints in that view, and the fitted body (the truth here)."""
    T = 4
    params = random_motion(T, seed=3)
    params["body_pose"][:, 3 * 16:3 * 17] += [0.0, 0.0, 0.6]  # right arm raised: asymmetric
    front = synthetic_rig(1, size=160)
    _, kp, verts = keypoints_of(kpm, params)
    faces = kpm.model.faces.cpu().numpy()
    centre = kp[:, [5, 6]].mean((0, 1))
    K = front.K[0]
    R, t = turned_around(front.R[0], front.t[0], centre)
    masks = np.stack([silhouette(K, R, t, v, faces, 160, 160) for v in verts])
    uv, _ = project_points(K, R, t, kp)
    obs = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1)
    return dict(K=K, R=R, t=t, front=(front.R[0], front.t[0]), verts=verts, faces=faces, kp=kp,
                masks=masks, obs=obs, centre=centre)


def test_a_camera_placed_in_front_of_a_back_view_is_turned(back_view):
    b = back_view
    wrong = check_side(b["K"], *b["front"], b["verts"], b["faces"], b["kp"], b["masks"],
                       b["obs"], b["centre"], 2.0)
    assert wrong.iou_here < 0.85 and wrong.iou_there > 0.95
    assert wrong.turn(0.1)
    assert rotation_angle_deg(wrong.R, b["R"]) < 1.0
    right = check_side(b["K"], b["R"], b["t"], b["verts"], b["faces"], b["kp"], b["masks"],
                       b["obs"], b["centre"], 2.0)
    assert right.iou_here > 0.95 and not right.turn(0.1)


def test_empty_masks_give_no_verdict(back_view):
    b = back_view
    empty = np.zeros_like(b["masks"])
    assert np.isnan(mean_iou(b["K"], b["R"], b["t"], b["verts"], b["faces"], empty))
    check = check_side(b["K"], *b["front"], b["verts"], b["faces"], b["kp"], empty, b["obs"],
                       b["centre"], 2.0)
    assert np.isnan(check.iou_here) and np.isnan(check.iou_there)
    assert not check.turn(0.1)  # NaN compares false: the view stays
