"""COCO-WholeBody 133 keypoint regressor on the proxy and on files without keypoint keys."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from signsplat.body import joints as JN
from signsplat.body.keypoints import WholeBodyRegressor
from signsplat.body.model import BodyModel

JI = JN.JOINT_INDEX
NAMES = JN.COCO_WHOLEBODY_NAMES


@pytest.fixture(scope="module")
def model(proxy_body_path):
    return BodyModel.from_file(proxy_body_path, dtype=torch.float64)


@pytest.fixture(scope="module")
def reg(model):
    return WholeBodyRegressor(model)


def _kp(name):
    return NAMES.index(name)


def test_layout_and_joint_keypoints(model, reg):
    gen = torch.Generator().manual_seed(0)
    B = 3
    out = model(body_pose=0.3 * torch.randn(B, 63, generator=gen, dtype=torch.float64),
                left_hand_pose=0.3 * torch.randn(B, 45, generator=gen, dtype=torch.float64),
                transl=torch.randn(B, 3, generator=gen, dtype=torch.float64))
    kp = reg(out)
    assert kp.shape == (B, 133, 3) and torch.isfinite(kp).all()
    assert bool(reg.valid.all())
    pairs = {"left_wrist": "left_wrist", "right_elbow": "right_elbow", "left_knee": "left_knee",
             "left_hand_wrist": "left_wrist", "right_hand_wrist": "right_wrist",
             "left_hand_index1": "left_index1", "left_hand_thumb3": "left_thumb3",
             "right_hand_pinky2": "right_pinky2", "right_hand_ring3": "right_ring3",
             "left_hand_middle1": "left_middle1"}
    for k, j in pairs.items():
        torch.testing.assert_close(kp[:, _kp(k)], out.joints[:, JI[j]])


def test_rest_pose_geometry(model, reg):
    kp = reg(model())[0].numpy()
    J = model.rest_joints.numpy()
    p = lambda n: kp[_kp(n)]  # noqa: E731
    # left is +x; nose between the eyes and in front of them; ears behind the eyes
    assert p("left_eye")[0] > 0.01 > -0.01 > p("right_eye")[0]
    assert abs(p("nose")[0]) < 2e-3 and p("nose")[2] > p("left_eye")[2]
    assert p("left_ear")[0] > p("left_eye")[0] and p("left_ear")[2] < p("left_eye")[2]
    # fingertips beyond the last finger joint, along the finger
    for side in ("left", "right"):
        for finger in ("thumb", "index", "middle", "ring", "pinky"):
            j3 = J[JI[f"{side}_{finger}3"]]
            d = j3 - J[JI[f"{side}_{finger}2"]]
            tip = p(f"{side}_hand_{finger}4")
            assert (tip - j3) @ d / np.linalg.norm(d) > 0.012, (side, finger)
    # feet: toes in front of the heel, all near the floor
    for side in ("left", "right"):
        assert p(f"{side}_big_toe")[2] > p(f"{side}_heel")[2] + 0.2
        assert p(f"{side}_small_toe")[1] < 0.05
    # face: 68 points on the head, contour below the eyes, mouth below the nose
    face = kp[list(JN.KP_FACE)]
    head = J[JI["head"]]
    assert (np.linalg.norm(face - head - (0, 0.06, 0.06), axis=1) < 0.12).all()
    assert face[8, 1] < face[30, 1] < face[39, 1]  # chin < nose tip < eye corner
    assert face[0, 0] < 0 < face[16, 0]  # contour from the subject's right to left
    assert face[36, 0] < face[45, 0]  # right eye outer corner at -x
    assert face[51, 1] > face[57, 1]  # upper lip above lower lip


def test_face_landmarks_lie_on_head_vertices(model, reg):
    lab = model.part_labels.numpy()
    verts = reg.vert_idx[list(JN.KP_FACE)].numpy()
    assert (lab[verts] == JN.PART_HEAD).all()
    w = reg.vert_w[list(JN.KP_FACE)].numpy()
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-6)


def test_keypoints_follow_expressions_and_are_differentiable(model, reg):
    expr = torch.zeros(1, 10, dtype=torch.float64, requires_grad=True)
    kp = reg(model(expression=expr))
    kp[0, _kp("face_57"), 1].backward()
    assert expr.grad.abs().sum() > 0  # the lower lip moves with the expressions


def test_official_layout_uses_smplx_vertex_ids(proxy_arrays, tmp_path):
    from smplx.vertex_ids import vertex_ids

    arrays = {k: v for k, v in proxy_arrays.items() if not k.startswith("kp_")}
    path = tmp_path / "nokp.npz"
    np.savez(path, **arrays)
    model = BodyModel.from_file(path)
    reg = WholeBodyRegressor(model)
    out = model()
    kp = reg(out)
    torch.testing.assert_close(kp[0, _kp("nose")], out.vertices[0, vertex_ids["smplx"]["nose"]])
    torch.testing.assert_close(kp[0, _kp("left_hand_thumb4")],
                               out.vertices[0, vertex_ids["smplx"]["lthumb"]])


def test_small_model_without_keypoint_vertices_is_an_error(fake_path):
    with pytest.raises(ValueError, match="10,475"):
        WholeBodyRegressor(BodyModel.from_file(fake_path))


def test_contour_uses_the_frontal_row(proxy_arrays, tmp_path):
    """Row 0 of SMPL-X's dynamic landmark table is yaw 0 (smplx's indexing)."""
    arrays = dict(proxy_arrays)
    dyn = np.array(arrays["dynamic_lmk_faces_idx"])
    dyn[1:] = (dyn[1:] + 7) % len(arrays["f"])  # other yaw rows point elsewhere
    arrays["dynamic_lmk_faces_idx"] = dyn
    path = tmp_path / "lut.npz"
    np.savez(path, **arrays)
    model = BodyModel.from_file(path)
    reg = WholeBodyRegressor(model)
    faces = model.faces.numpy()
    first = JN.KP_FACE[0]
    np.testing.assert_array_equal(reg.vert_idx[first:first + 17].numpy(), faces[dyn[0]])
