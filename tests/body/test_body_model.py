"""BodyModel: LBS against smplx.lbs, transforms, hard cases, gradients."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from smplx.lbs import lbs as smplx_lbs

from signsplat.body import joints as JN
from signsplat.body.model import (
    BodyModel,
    axis_angle_to_matrix,
    derive_part_labels,
    skin_points,
)


def _random_inputs(B, gen, scale=0.5, dtype=torch.float32):
    r = lambda *s: (torch.randn(*s, generator=gen, dtype=torch.float64) * scale).to(dtype)  # noqa
    return dict(betas=r(B, 10) * 2, expression=r(B, 10) * 2, global_orient=r(B, 3),
                body_pose=r(B, 63), jaw_pose=r(B, 3), leye_pose=r(B, 3), reye_pose=r(B, 3),
                left_hand_pose=r(B, 45), right_hand_pose=r(B, 45), transl=r(B, 3))


def _reference(model, inp):
    """smplx.lbs.lbs on the same buffers."""
    B = inp["betas"].shape[0]
    pose = torch.cat([inp[k] for k in ("global_orient", "body_pose", "jaw_pose", "leye_pose",
                                       "reye_pose", "left_hand_pose", "right_hand_pose")], 1)
    if model.hand_mean == "mano":
        pose = pose.clone()
        pose[:, 75:120] += model.hands_mean_l
        pose[:, 120:] += model.hands_mean_r
    coeffs = torch.cat([inp["betas"], inp["expression"]], 1)
    v, j = smplx_lbs(coeffs, pose, model.v_template, model.shapedirs, model.posedirs,
                     model.J_regressor, model.parents, model.lbs_weights)
    return v + inp["transl"][:, None], j + inp["transl"][:, None]


@pytest.fixture(scope="module")
def proxy(proxy_body_path):
    return BodyModel.from_file(proxy_body_path)


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-7)])
def test_lbs_matches_smplx_on_proxy(proxy_body_path, dtype, tol):
    model = BodyModel.from_file(proxy_body_path, dtype=dtype)
    gen = torch.Generator().manual_seed(0)
    inp = _random_inputs(6, gen, scale=0.6, dtype=dtype)
    out = model(**inp)
    v, j = _reference(model, inp)
    assert (out.vertices - v).abs().max().item() < tol
    assert (out.joints - j).abs().max().item() < tol


def test_lbs_matches_smplx_on_fake_official_file(fake_path):
    model = BodyModel.from_file(fake_path, hand_mean="mano")
    inp = _random_inputs(3, torch.Generator().manual_seed(1))
    out = model(**inp)
    v, j = _reference(model, inp)
    assert out.vertices.shape == (3, model.num_vertices, 3)
    assert (out.vertices - v).abs().max().item() < 1e-5
    assert (out.joints - j).abs().max().item() < 1e-5
    # part labels derived from the skinning weights when the file has none
    assert model.part_labels.shape == (model.num_vertices,)
    assert model.vertex_colors is None


def test_rest_pose_is_template(proxy):
    out = proxy()
    assert out.vertices.shape == (1, proxy.num_vertices, 3)
    torch.testing.assert_close(out.vertices[0], proxy.v_template, atol=1e-6, rtol=0)
    torch.testing.assert_close(out.joints[0], proxy.rest_joints, atol=1e-6, rtol=0)
    eye = torch.eye(4).expand(JN.NUM_JOINTS, 4, 4)
    torch.testing.assert_close(out.transforms[0], eye, atol=1e-6, rtol=0)


def test_transforms_skin_arbitrary_points(proxy):
    inp = _random_inputs(4, torch.Generator().manual_seed(2))
    out = proxy(**inp)
    # rest joints with one-hot weights on themselves land on the posed joints
    rest = torch.einsum("jv,bvk->bjk", proxy.J_regressor, out.v_shaped)
    posed = torch.stack([skin_points(rest[b], torch.eye(JN.NUM_JOINTS), out.transforms[b:b + 1],
                                     inp["transl"][b:b + 1])[0] for b in range(4)])
    torch.testing.assert_close(posed, out.joints, atol=1e-5, rtol=0)
    # vertices: skinning v_shaped + pose correctives reproduces the output
    rot = axis_angle_to_matrix(torch.cat([inp[k] for k in (
        "global_orient", "body_pose", "jaw_pose", "leye_pose", "reye_pose", "left_hand_pose",
        "right_hand_pose")], 1).reshape(4, -1, 3))
    feat = (rot[:, 1:] - torch.eye(3)).reshape(4, -1)
    v_posed = out.v_shaped + (feat @ proxy.posedirs).reshape(4, -1, 3)
    verts = skin_points(v_posed, proxy.lbs_weights, out.transforms, inp["transl"])
    torch.testing.assert_close(verts, out.vertices, atol=1e-5, rtol=0)


def test_axis_angle_hard_cases():
    vecs = torch.tensor([[0.0, 0, 0], [math.pi, 0, 0], [0, math.pi, 0], [0, 0, -math.pi],
                         [1e-9, 0, 0], [2.0, -1.0, 0.5]], dtype=torch.float64)
    R = axis_angle_to_matrix(vecs)
    eye = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(R @ R.transpose(1, 2), eye.expand(6, 3, 3), atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.linalg.det(R), torch.ones(6, dtype=torch.float64))
    torch.testing.assert_close(R[1], torch.diag(torch.tensor([1.0, -1, -1], dtype=torch.float64)),
                               atol=1e-12, rtol=0)
    from smplx.lbs import batch_rodrigues

    torch.testing.assert_close(R[5], batch_rodrigues(vecs[5:6])[0], atol=1e-7, rtol=0)


@pytest.mark.parametrize("B", [1, 17])
def test_hard_poses_finite_with_gradients(proxy, B):
    gen = torch.Generator().manual_seed(3)
    body = torch.zeros(B, 63)
    body[:, :3] = torch.tensor([math.pi, 0.0, 0.0])  # 180 degrees
    body[:, 3:6] = torch.tensor([0.0, 0.0, -math.pi])
    body[B // 2:, 6:] = torch.randn(B - B // 2, 57, generator=gen)
    params = {
        "body_pose": body.requires_grad_(),
        "global_orient": torch.zeros(B, 3, requires_grad=True),  # identity
        "left_hand_pose": torch.full((B, 45), math.pi / math.sqrt(3)).requires_grad_(),
        "right_hand_pose": torch.zeros(B, 45, requires_grad=True),
        "betas": torch.zeros(B, 10, requires_grad=True),
        "expression": torch.zeros(B, 10, requires_grad=True),
    }
    out = proxy(**params)
    assert out.vertices.shape == (B, proxy.num_vertices, 3)
    assert torch.isfinite(out.vertices).all() and torch.isfinite(out.transforms).all()
    (out.vertices.square().sum() + out.joints.sum()).backward()
    for name, p in params.items():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
    assert params["global_orient"].grad.abs().sum() > 0  # gradient flows at the identity


def test_batch_broadcast_and_sizes(proxy):
    betas = torch.randn(5, 4)  # fewer betas than the model: padded with zeros
    out = proxy(betas=betas, transl=torch.tensor([[0.0, 1.0, 0.0]]))
    assert out.vertices.shape[0] == 5
    torch.testing.assert_close(out.joints[:, 0, 1] - 1.0,
                               proxy(betas=betas).joints[:, 0, 1], atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="betas"):
        proxy(betas=torch.zeros(1, 11))
    with pytest.raises(ValueError, match="batch"):
        proxy(betas=torch.zeros(2, 10), body_pose=torch.zeros(3, 63))


def test_hand_mean_mano_adds_the_mean(proxy_body_path):
    flat = BodyModel.from_file(proxy_body_path)
    mano = BodyModel.from_file(proxy_body_path, hand_mean="mano")
    a = mano()
    b = flat(left_hand_pose=flat.hands_mean_l[None], right_hand_pose=flat.hands_mean_r[None])
    torch.testing.assert_close(a.vertices, b.vertices)
    assert (a.vertices - flat().vertices).abs().max() > 1e-3
    with pytest.raises(ValueError):
        BodyModel.from_file(proxy_body_path, hand_mean="relaxed")


def test_float64_and_device_move(proxy_body_path):
    m = BodyModel.from_file(proxy_body_path, dtype=torch.float64)
    assert m.v_template.dtype == torch.float64
    out = m.to("cpu")(body_pose=torch.zeros(1, 63))
    assert out.vertices.dtype == torch.float64
    assert {n for n, p in m.named_parameters()} == set()  # buffers only


def test_derive_part_labels():
    W = np.zeros((5, 55))
    W[0, JN.JOINT_INDEX["left_index2"]] = 1
    W[1, JN.JOINT_INDEX["right_wrist"]] = 1
    W[2, JN.JOINT_INDEX["jaw"]] = 1
    W[3, JN.JOINT_INDEX["spine2"]] = 1
    W[4, JN.JOINT_INDEX["neck"]] = 1
    np.testing.assert_array_equal(
        derive_part_labels(W),
        [JN.PART_LEFT_HAND, JN.PART_RIGHT_HAND, JN.PART_HEAD, JN.PART_BODY, JN.PART_HEAD])


def test_smplx_package_reads_the_proxy_file_the_same_way(proxy_body_path):
    """The proxy is a valid official-layout file: smplx.SMPLX loads it and poses it alike."""
    import smplx

    B = 2
    ref = smplx.SMPLX(str(proxy_body_path), ext="npz", use_pca=False, flat_hand_mean=True,
                      num_betas=10, num_expression_coeffs=10, use_face_contour=False,
                      batch_size=B)
    model = BodyModel.from_file(proxy_body_path)
    inp = _random_inputs(B, torch.Generator().manual_seed(5), scale=0.4)
    with torch.no_grad():
        want = ref(return_verts=True, **inp)
        got = model(**inp)
    assert (got.vertices - want.vertices).abs().max().item() < 1e-5
    assert (got.joints - want.joints[:, :55]).abs().max().item() < 1e-5


def test_per_joint_pose_shapes_are_flattened(proxy):
    gen = torch.Generator().manual_seed(7)
    bp = 0.3 * torch.randn(2, 21, 3, generator=gen)
    hp = 0.3 * torch.randn(2, 15, 3, generator=gen)
    a = proxy(body_pose=bp, left_hand_pose=hp)
    b = proxy(body_pose=bp.reshape(2, 63), left_hand_pose=hp.reshape(2, 45))
    torch.testing.assert_close(a.vertices, b.vertices)
    c = proxy(body_pose=bp[0].reshape(63).numpy())  # numpy and unbatched inputs work too
    torch.testing.assert_close(c.vertices, proxy(body_pose=bp[:1].reshape(1, 63)).vertices)


def test_corrective_rows_skip_only_all_zero_rows(proxy):
    from signsplat.body.model import corrective_rows

    P = torch.ones(4, 6)
    P[1] = 0.0
    P[3, :5] = 0.0  # one non-zero entry keeps a row
    assert corrective_rows(P).tolist() == [0, 2, 3]
    assert corrective_rows(torch.ones(3, 2)) is None
    # the proxy body's correctives use each joint's rotation diagonal: posing multiplies those
    rows = proxy.pose_rows
    assert rows is not None and len(rows) <= 486 // 3
    assert proxy.posedirs[rows].abs().sum(1).min() > 0
    left_out = torch.ones(486, dtype=torch.bool)
    left_out[rows] = False
    assert proxy.posedirs[left_out].abs().max() == 0
