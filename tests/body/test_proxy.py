"""The procedural proxy body model: layout, rest pose, mesh, rig, shapes and expressions."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh
from scipy.spatial import cKDTree

from signsplat.body import joints as JN
from signsplat.body.model import BodyModel

JI = JN.JOINT_INDEX


@pytest.fixture(scope="module")
def model(proxy_body_path):
    return BodyModel.from_file(proxy_body_path, num_betas=10, num_expression=10, dtype=torch.float64)


@pytest.fixture(scope="module")
def J(model):
    return model.rest_joints.numpy()


def test_mesh_is_closed_and_dense(proxy_arrays):
    v, f = proxy_arrays["v_template"], proxy_arrays["f"]
    assert len(v) >= 8000
    assert len(v) > 9929  # smplx's hard-coded extra-joint vertex ids stay in range
    mesh = trimesh.Trimesh(v, f, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume > 0  # outward normals
    assert len(mesh.split(only_watertight=False)) == 1
    assert mesh.euler_number == 2  # one genus-0 surface: fingers are not fused into loops
    assert (mesh.area_faces > 1e-10).all()


def test_official_layout(proxy_arrays):
    a = proxy_arrays
    V = len(a["v_template"])
    assert a["shapedirs"].shape == (V, 3, 20) and int(a["num_shape_dirs"]) == 10
    assert a["posedirs"].shape == (V, 3, 486) and a["posedirs"].dtype == np.float32
    assert a["J_regressor"].shape == (55, V) and a["weights"].shape == (V, 55)
    np.testing.assert_array_equal(a["kintree_table"][0], JN.SMPLX_PARENTS)
    raw = np.load(a["__path__"]) if "__path__" in a else None
    assert raw is None or raw["kintree_table"][0, 0] == 2**32 - 1
    comps = a["hands_componentsl"]
    np.testing.assert_allclose(comps @ comps.T, np.eye(45), atol=1e-10)


def test_rest_pose_like_smplx(model, J, proxy_arrays):
    v = proxy_arrays["v_template"]
    height = v[:, 1].max() - v[:, 1].min()
    assert 1.6 < height < 1.85 and abs(v[:, 1].min()) < 2e-3  # feet on y = 0
    # left is +x, arms along x at shoulder height (T-pose), head above neck above pelvis
    for name in ("hip", "knee", "ankle", "collar", "shoulder", "elbow", "wrist", "eye"):
        assert J[JI[f"left_{name}"], 0] > 0 > J[JI[f"right_{name}"], 0]
    assert J[JI["head"], 1] > J[JI["neck"], 1] > J[JI["spine3"], 1] > J[JI["pelvis"], 1]
    assert J[JI["left_wrist"], 0] > J[JI["left_elbow"], 0] > J[JI["left_shoulder"], 0]
    assert abs(J[JI["left_wrist"], 1] - J[JI["left_shoulder"], 1]) < 0.02
    # fingers: base->tip along +x; index .. pinky ordered from +z (thumb side) to -z
    for finger in ("index", "middle", "ring", "pinky"):
        xs = [J[JI[f"left_{finger}{k}"], 0] for k in (1, 2, 3)]
        assert xs[0] > J[JI["left_wrist"], 0] and xs[0] < xs[1] < xs[2]
    zs = [J[JI[f"left_{f}1"], 2] for f in ("index", "middle", "ring", "pinky")]
    assert zs == sorted(zs, reverse=True)
    # thumb points forward (+z) and out (+x)
    d = J[JI["left_thumb3"]] - J[JI["left_thumb1"]]
    assert d[2] > 0.02 and d[0] > 0.01
    # the eyes look forward: in front of the head joint
    assert J[JI["left_eye"], 2] > J[JI["head"], 2] + 0.03


def test_left_right_symmetry(J, proxy_arrays):
    names = JN.SMPLX_JOINT_NAMES
    for i, n in enumerate(names):
        m = n.replace("left_", "right_") if n.startswith("left_") else \
            n.replace("right_", "left_")
        j = JI[m]
        np.testing.assert_allclose(J[j] * (-1, 1, 1), J[i], atol=1e-4, err_msg=n)
    v = proxy_arrays["v_template"]
    d, _ = cKDTree(v).query(v * (-1, 1, 1))
    assert np.median(d) < 0.006 and np.percentile(d, 99) < 0.02
    labels = proxy_arrays["part_labels"]
    nl, nr = (labels == JN.PART_LEFT_HAND).sum(), (labels == JN.PART_RIGHT_HAND).sum()
    assert abs(nl - nr) < 0.1 * nl


def test_part_labels(proxy_arrays, J):
    v, labels = proxy_arrays["v_template"], proxy_arrays["part_labels"]
    counts = np.bincount(labels, minlength=4)
    assert (counts > 500).all()  # hands and head are well sampled
    for side, part in (("left", JN.PART_LEFT_HAND), ("right", JN.PART_RIGHT_HAND)):
        for name in ("wrist", "index3", "thumb2", "pinky1"):
            p = J[JI[f"{side}_{name}"]]
            near = np.linalg.norm(v - p, axis=1) < 0.015
            near &= np.abs(v[:, 0]) > abs(J[JI[f"{side}_wrist"], 0]) + 0.012
            if near.any():
                assert (labels[near] == part).mean() > 0.95, (side, name)
        sign = 1.0 if side == "left" else -1.0
        tip = sign * v[:, 0] > abs(J[JI[f"{side}_middle3"], 0])
        assert tip.sum() > 50 and (labels[tip] == part).all()
    eyes = 0.5 * (J[JI["left_eye"]] + J[JI["right_eye"]])
    face = np.linalg.norm(v - eyes, axis=1) < 0.05
    assert face.sum() > 100 and (labels[face] == JN.PART_HEAD).all()
    torso = np.linalg.norm(v - J[JI["spine2"]], axis=1) < 0.2
    assert (labels[torso] == JN.PART_BODY).all()


def test_joint_regressor_reproduces_joints(proxy_arrays, J):
    a = proxy_arrays
    np.testing.assert_allclose(a["J_regressor"] @ a["v_template"], J, atol=1e-6)
    np.testing.assert_allclose(a["J_regressor"].sum(axis=1), 1.0, atol=1e-6)


def test_skinning_weights_smooth(proxy_arrays):
    W, f = proxy_arrays["weights"], proxy_arrays["f"]
    assert (W >= 0).all()
    np.testing.assert_allclose(W.sum(axis=1), 1.0, atol=1e-6)
    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    jump = np.abs(W[edges[:, 0]] - W[edges[:, 1]]).sum(axis=1)
    # a hard switch between two joints across an edge would read 2.0; blends spread over
    # several edges (torso edges are ~3 cm for blend zones of ~10 cm)
    assert np.percentile(jump, 99) < 1.0 and jump.max() < 1.5
    # each joint that moves geometry dominates some vertices (eyes and fingers included)
    assert (W.max(axis=0) > 0.6).all()


def _edge_stretch(model, out):
    """Length ratio posed/rest of edges longer than 2 mm, and the largest absolute growth."""
    f = model.faces.numpy()
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    v0 = model.v_template.numpy()
    v1 = out.vertices[0].detach().numpy()
    l0 = np.linalg.norm(v0[e[:, 0]] - v0[e[:, 1]], axis=1)
    l1 = np.linalg.norm(v1[e[:, 0]] - v1[e[:, 1]], axis=1)
    assert (l1 - l0).max() < 0.03  # a vertex left behind would open a gap of many cm
    return (l1 / l0)[l0 > 0.002]


def test_finger_flexion_articulates_cleanly(model, J):
    from signsplat.body._proxy_rig import hand_pose_from_angles

    flex = np.tile([1.4, 1.4, 1.0], (5, 1))
    flex[4] = [0.5, 0.6, 0.6]
    pose = torch.tensor(hand_pose_from_angles(flex))[None]
    out = model(left_hand_pose=pose)
    v0, v1 = model.v_template.numpy(), out.vertices[0].numpy()
    moved = np.linalg.norm(v1 - v0, axis=1)
    labels = model.part_labels.numpy()
    assert moved[labels != JN.PART_LEFT_HAND].max() < 2e-3  # only the left hand moves
    assert (moved[labels == JN.PART_LEFT_HAND] > 0.01).sum() > 500
    stretch = _edge_stretch(model, out)
    assert stretch.max() < 4.0 and stretch.min() > 0.1  # dorsal skin stretches, palm folds
    # fingertips curl down (palm side, -y) and back toward the wrist
    tip = out.joints[0, JI["left_middle3"]].numpy()
    assert tip[1] < J[JI["left_middle3"], 1] - 0.03
    # curled fingertip surface stays outside the palm: no vertex of the distal segment sits
    # deeper than 3 mm inside the rest of the hand (checked against the posed mesh winding)
    mesh = trimesh.Trimesh(v1, model.faces.numpy(), process=False)
    assert mesh.is_watertight


def test_elbow_and_knee_bend_without_tearing(model):
    bp = torch.zeros(1, 63, dtype=torch.float64)
    bp[0, (JI["left_elbow"] - 1) * 3 + 1] = -1.6
    bp[0, (JI["right_knee"] - 1) * 3] = 1.6
    bp[0, (JI["neck"] - 1) * 3 + 1] = 0.6
    out = model(body_pose=bp)
    stretch = _edge_stretch(model, out)
    # LBS compresses the inside of a bent joint; a vertex left behind would stretch > 10x
    assert stretch.max() < 4.0 and stretch.min() > 0.05
    assert np.percentile(stretch, 0.1) > 0.4


def _named(model, which, name):
    from signsplat.body._proxy_rig import EXPRESSION_NAMES, SHAPE_NAMES

    names = SHAPE_NAMES if which == "betas" else EXPRESSION_NAMES
    x = torch.zeros(1, len(names), dtype=torch.float64)
    x[0, names.index(name)] = 1.0
    return model(**{which: x})


def _len(out, a, b):
    j = out.joints[0].numpy()
    return np.linalg.norm(j[JI[a]] - j[JI[b]])


def test_shape_directions_have_their_named_effects(model):
    from signsplat.body._proxy_rig import EXPRESSION_NAMES, SHAPE_NAMES

    assert model.shape_names == SHAPE_NAMES and model.expression_names == EXPRESSION_NAMES
    base = model()
    h0 = np.ptp(base.vertices[0, :, 1].numpy())
    tall = _named(model, "betas", "height")
    assert np.ptp(tall.vertices[0, :, 1].numpy()) > h0 + 0.04
    assert abs(tall.vertices[0, :, 1].min().item()) < 3e-3  # feet stay on the floor
    leg = _named(model, "betas", "leg_length")
    assert _len(leg, "left_hip", "left_ankle") > _len(base, "left_hip", "left_ankle") + 0.03
    arm = _named(model, "betas", "arm_length")
    assert _len(arm, "left_shoulder", "left_wrist") > \
        _len(base, "left_shoulder", "left_wrist") + 0.03
    assert abs(_len(arm, "left_hip", "left_ankle") - _len(base, "left_hip", "left_ankle")) < 1e-6
    hand = _named(model, "betas", "hand_size")
    assert _len(hand, "left_wrist", "left_middle3") > \
        1.05 * _len(base, "left_wrist", "left_middle3")
    fing = _named(model, "betas", "finger_length")
    assert _len(fing, "left_middle1", "left_middle3") > \
        1.07 * _len(base, "left_middle1", "left_middle3")
    sh = _named(model, "betas", "shoulder_width")
    assert _len(sh, "left_shoulder", "right_shoulder") > \
        _len(base, "left_shoulder", "right_shoulder") + 0.02
    girth = _named(model, "betas", "girth")
    assert np.ptp(girth.vertices[0, :, 2].numpy()) > np.ptp(base.vertices[0, :, 2].numpy()) + 0.01
    head = _named(model, "betas", "head_size")
    skull = base.vertices[0, :, 1].numpy() > model.rest_joints[JI["left_eye"], 1].item()
    width = lambda out: np.ptp(out.vertices[0, skull, 0].numpy())  # noqa: E731
    assert width(head) > 1.04 * width(base)
    neck = _named(model, "betas", "neck_length")
    assert _len(neck, "neck", "head") > _len(base, "neck", "head") + 0.005
    # every direction does something, and the joints follow the surface
    for i in range(10):
        b = torch.zeros(1, 10, dtype=torch.float64)
        b[0, i] = 1.0
        out = model(betas=b)
        assert (out.v_shaped - base.v_shaped).abs().max() > 0.005, i


def test_expressions_move_the_face_only(model):
    base = model()
    head = model.part_labels.numpy() == JN.PART_HEAD
    for i in range(10):
        e = torch.zeros(1, 10, dtype=torch.float64)
        e[0, i] = 1.0
        d = (model(expression=e).v_shaped - base.v_shaped)[0].norm(dim=1).numpy()
        assert d[~head].max() == 0.0, i
        assert d[head].max() > 0.002, i
    jaw = _named(model, "expression", "jaw_open")
    lmk_chin = jaw.vertices[0, :, 1].numpy() - base.vertices[0, :, 1].numpy()
    assert lmk_chin.min() < -0.008  # the chin drops


def test_pose_correctives_small_and_local(model):
    P = model.posedirs.numpy().reshape(486, -1, 3)
    assert np.abs(P).max() > 1e-4  # exercised
    bp = torch.zeros(1, 63, dtype=torch.float64)
    bp[0, (JI["left_elbow"] - 1) * 3 + 1] = -1.5
    rot = model(body_pose=bp)
    feat_off = rot.vertices - model(body_pose=bp).vertices  # same call -> zero
    assert feat_off.abs().max() == 0
    from signsplat.body.model import axis_angle_to_matrix

    full = torch.cat([torch.zeros(1, 3, dtype=torch.float64), bp,
                      torch.zeros(1, 99, dtype=torch.float64)], 1)
    R = axis_angle_to_matrix(full.reshape(1, 55, 3))
    feat = (R[:, 1:] - torch.eye(3, dtype=torch.float64)).reshape(1, -1)
    off = (feat @ model.posedirs).reshape(-1, 3).norm(dim=1).numpy()
    assert 1e-3 < off.max() < 0.01
    v = model.v_template.numpy()
    far = np.linalg.norm(v - model.rest_joints[JI["left_elbow"]].numpy(), axis=1) > 0.2
    assert off[far].max() < 1e-4


def test_same_seed_same_arrays():
    """Two builds with one seed are identical (coarser grid than the default, for speed)."""
    from signsplat.body.proxy import build_proxy_arrays

    a = build_proxy_arrays(seed=3, target_vertices=6000, spacing=0.004)
    b = build_proxy_arrays(seed=3, target_vertices=6000, spacing=0.004)
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    assert abs(len(a["v_template"]) - 6000) < 50


def test_seed_changes_appearance_and_hand_basis_only():
    from signsplat.body._proxy_rig import hand_pca
    from signsplat.body.appearance import palette

    c0, m0 = hand_pca(0)
    c1, m1 = hand_pca(1)
    np.testing.assert_array_equal(c0[:5], c1[:5])  # synergies fixed
    assert np.abs(c0[10:] - c1[10:]).max() > 0.1
    np.testing.assert_array_equal(m0, m1)
    assert any(np.any(palette(0)[k] != palette(s)[k]) for s in range(1, 6) for k in palette(0))


def test_fingers_are_separated(proxy_arrays, J):
    """Between neighbouring fingers, beyond the knuckles, there is air (not a webbed paddle)."""
    mesh = trimesh.Trimesh(proxy_arrays["v_template"], proxy_arrays["f"], process=False)
    pts, inside_ref = [], []
    for side in ("left", "right"):
        for a, b in (("index", "middle"), ("middle", "ring"), ("ring", "pinky")):
            for k in (2, 3):  # middle of segment 2 and of segment 3
                pa = 0.5 * (J[JI[f"{side}_{a}{k}"]] + J[JI[f"{side}_{a}{min(k + 1, 3)}"]])
                pb = 0.5 * (J[JI[f"{side}_{b}{k}"]] + J[JI[f"{side}_{b}{min(k + 1, 3)}"]])
                pts.append(0.5 * (pa + pb))
                inside_ref += [pa, pb]
    assert not mesh.contains(np.array(pts)).any()
    assert mesh.contains(np.array(inside_ref)).all()  # the finger axes are inside
