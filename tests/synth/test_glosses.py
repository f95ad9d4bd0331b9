"""Synthetic gloss library: size, layout, hand limits, determinism, IK accuracy, I/O."""

import numpy as np
import pytest

from signsplat.body.hand_limits import within_limits
from signsplat.io.tables import TableError
from signsplat.motion import clips as C
from signsplat.synth import _gloss_body as gb
from signsplat.synth import glosses as G


@pytest.fixture(scope="module")
def library():
    return G.build_gloss_library(seed=0, fps=25.0)


def test_library_size_and_kinds(library):
    signs = library[library.kind == "sign"]
    letters = library[library.kind == "letter"]
    assert len(signs) >= 30
    assert sorted(letters.gloss) == [chr(c) for c in range(ord("A"), ord("Z") + 1)]
    assert library.gloss.is_unique
    for words in signs.words:
        assert len(words) >= 1 and all(w == w.lower() for w in words)
    # every English word names one gloss only (unambiguous lookup)
    all_words = [w for ws in signs.words for w in ws]
    assert len(all_words) == len(set(all_words))
    for g in ("HELLO", "THANK-YOU", "NOT", "WHERE", "ME", "SCHOOL"):
        assert g in set(signs.gloss)


def test_tracks_have_table_layout_and_durations(library):
    clips = C.clips_from_table(library)
    for clip in clips.values():
        n = clip.num_frames
        for block, k in C.BLOCK_SIZES.items():
            assert clip.poses[block].shape == (n, k), (clip.gloss, block)
            assert np.isfinite(clip.poses[block]).all()
        dur = n / clip.fps
        if clip.kind == "sign":
            assert 0.55 <= dur <= 1.6, (clip.gloss, dur)
        else:
            assert 0.3 <= dur <= 0.7, (clip.gloss, dur)
        assert clip.hand_mean == "flat"


def test_every_hand_pose_within_limits(library):
    clips = C.clips_from_table(library)
    left = np.concatenate([c.poses["left_hand_pose"] for c in clips.values()])
    right = np.concatenate([c.poses["right_hand_pose"] for c in clips.values()])
    assert within_limits(left, "left").all()
    assert within_limits(right, "right").all()


def test_signs_move_and_use_non_manual_features(library):
    clips = C.clips_from_table(library)
    for clip in clips.values():
        body = clip.poses["body_pose"]
        assert np.abs(body[-1] - body[0]).max() > 1e-3 or np.ptp(body, axis=0).max() > 1e-2
    # questions furrow the brows, YES nods the head
    brow = G.EXPRESSION_INDEX["brow_furrow"]
    assert clips["WHAT"].poses["expression"][:, brow].max() > 0.5
    assert clips["HELLO"].poses["expression"][:, brow].max() < 0.1
    head = gb.BODY_SLOT["head"]
    assert np.ptp(clips["YES"].poses["body_pose"][:, head]) > 0.1


def test_deterministic_for_a_seed_and_varies_with_seed(library):
    G._library_rows.cache_clear()  # rebuild from scratch, not from the in-process cache
    again = G.build_gloss_library(seed=0, fps=25.0)
    for col in ("body_pose", "left_hand_pose", "right_hand_pose", "jaw_pose", "expression"):
        for x, y in zip(library[col], again[col]):
            np.testing.assert_array_equal(x, y)
    signs = [s for s in G.all_signs() if s.gloss in ("HELLO", "BOOK", "WHERE", "A", "M")]
    for sign in signs:
        a = G.build_gloss(sign, seed=4, fps=20.0)
        b = G.build_gloss(sign, seed=4, fps=20.0)
        c = G.build_gloss(sign, seed=5, fps=20.0)
        np.testing.assert_array_equal(a["body_pose"], b["body_pose"])
        assert a["body_pose"].shape != c["body_pose"].shape or \
            not np.array_equal(a["body_pose"], c["body_pose"])


def test_ik_reaches_contact_points():
    """Analytic arm IK: forward kinematics of the solved angles hits reachable targets."""
    rng = np.random.default_rng(0)
    for side in ("left", "right"):
        sx = -1.0 if side == "right" else 1.0
        shoulder = np.array(gb.STANDARD.shoulder) * [sx, 1, 1]
        tgt = shoulder + rng.normal(size=(100, 3)) * 0.12 + [-sx * 0.15, -0.15, 0.25]
        arm = gb.STANDARD.upper_arm + gb.STANDARD.forearm
        reach = np.linalg.norm(tgt - shoulder, axis=1) < arm - 0.01
        rot = np.stack([gb.hand_rotation(rng.normal(size=3), rng.normal(size=3), side)
                        for _ in range(100)])
        s, e, w = gb.arm_ik(tgt, rot, side)
        pos, hand = gb.arm_fk(s, e, w, side)
        assert reach.sum() > 50
        np.testing.assert_allclose(pos[reach], tgt[reach], atol=1e-9)
        np.testing.assert_allclose(hand, rot, atol=1e-9)


def test_fingertip_contact_lands_on_location():
    """HELLO's index tip starts at the temple (plus small offset and jitter)."""
    sign = next(s for s in G.all_signs() if s.gloss == "HELLO")
    blocks = G.build_gloss(sign, seed=0, fps=25.0)
    body = blocks["body_pose"].astype(np.float64)
    sl = lambda j: body[:, gb.BODY_SLOT[f"right_{j}"]:gb.BODY_SLOT[f"right_{j}"] + 3]
    wrist, rot = gb.arm_fk(sl("shoulder"), sl("elbow"), sl("wrist"), "right")
    tip = gb.hand_points(blocks["right_hand_pose"][0].astype(np.float64), "right")["index_tip"]
    p0 = wrist[0] + rot[0] @ tip
    temple = gb.STANDARD.side_point("temple", "right")
    assert np.linalg.norm(p0 - temple) < 0.05


def test_write_and_load_round_trip(tmp_path, library, gloss_library_path):
    clips = C.load_gloss_library(gloss_library_path)  # written by write_gloss_library(seed=0)
    df = library
    assert set(clips) == set(df.gloss)
    row = df[df.gloss == "BOOK"].iloc[0]
    np.testing.assert_array_equal(clips["BOOK"].poses["body_pose"].reshape(-1), row.body_pose)
    assert clips["A"].kind == "letter" and clips["A"].words == ("a",)
    with pytest.raises(TableError):
        C.load_gloss_library(tmp_path / "missing.parquet")


def test_handshape_names_and_movement_errors():
    from signsplat.synth._gloss_shapes import handshape_angles
    with pytest.raises(KeyError, match="unknown handshape"):
        handshape_angles("nope")
    with pytest.raises(ValueError, match="unknown movement"):
        G.movement_offsets(G.Move("wobble"), "right", np.linspace(0, 1, 5))


def test_proxy_lbs_agrees_with_gloss_kinematics(proxy_body_path, library):
    """Posing the proxy body model with gloss frames puts wrists and finger joints where the
    library's own kinematics (standard skeleton, analytic IK, hand FK) put them."""
    import torch

    from signsplat.body.joints import JOINT_INDEX
    from signsplat.body.model import BodyModel

    model = BodyModel.from_file(proxy_body_path, dtype=torch.float64)
    clips = C.clips_from_table(library)
    pelvis = model().joints[0, 0].numpy()
    worst = 0.0
    for name in ("HELLO", "BOOK", "MOTHER", "WHERE", "A", "M"):
        clip = clips[name]
        p = {b: torch.as_tensor(clip.poses[b], dtype=torch.float64)
             for b in ("body_pose", "left_hand_pose", "right_hand_pose", "jaw_pose")}
        joints = model(**p).joints.numpy() - pelvis
        body = clip.poses["body_pose"].astype(np.float64)
        for side in ("left", "right"):
            sl = lambda j: body[:, gb.BODY_SLOT[f"{side}_{j}"]:gb.BODY_SLOT[f"{side}_{j}"] + 3]
            wrist, rot = gb.arm_fk(sl("shoulder"), sl("elbow"), sl("wrist"), side)
            worst = max(worst, np.abs(joints[:, JOINT_INDEX[f"{side}_wrist"]] - wrist).max())
            hand = clip.poses[f"{side}_hand_pose"].astype(np.float64)
            for f in range(0, clip.num_frames, 3):
                pts = gb.hand_points(hand[f], side)
                for j in ("index3", "thumb3", "pinky3"):
                    pred = wrist[f] + rot[f] @ pts[j]
                    worst = max(worst, np.abs(joints[f, JOINT_INDEX[f"{side}_{j}"]] - pred).max())
    assert worst < 0.002, worst


def test_flexion_moves_proxy_fingertips_to_the_palm_side(proxy_body_path):
    """Positive anatomical flexion (hand_limits) curls every finger towards -y on both hands."""
    import torch

    from signsplat.body import hand_limits as hl
    from signsplat.body.joints import JOINT_INDEX
    from signsplat.body.model import BodyModel

    model = BodyModel.from_file(proxy_body_path, dtype=torch.float64)
    rest = model().joints[0].numpy()
    for side in ("left", "right"):
        lim = hl.hand_limits(side)
        ang = torch.zeros(15, 3, dtype=torch.float64)
        ang[:, 2] = 0.6  # flex every joint, thumb included
        pose = hl.anatomical_to_axis_angle(ang, lim)[None]
        joints = model(**{f"{side}_hand_pose": pose}).joints[0].numpy()
        for finger in ("index", "middle", "ring", "pinky", "thumb"):
            j = JOINT_INDEX[f"{side}_{finger}3"]
            assert joints[j, 1] - rest[j, 1] < -0.01, (side, finger)
        # thumb frame from the proxy's own joints matches the default
        d = hl.thumb_direction_from_joints(rest, side)
        default = np.array(hl.LEFT_THUMB_DIRECTION) * ([-1, 1, 1] if side == "right" else 1)
        assert d @ default > 0.999


def test_hands_stay_outside_head_and_torso(proxy_body_path, library):
    """Contact signs touch the face/chest of the proxy without sinking into it (< 8 mm)."""
    import torch
    import trimesh
    from scipy.spatial import cKDTree

    from signsplat.body.joints import JOINT_INDEX, PART_LEFT_HAND, PART_RIGHT_HAND
    from signsplat.body.model import BodyModel

    model = BodyModel.from_file(proxy_body_path)
    labels = model.part_labels.numpy()
    core = [JOINT_INDEX[n] for n in ("pelvis", "spine1", "spine2", "spine3", "neck", "head",
                                     "jaw", "left_collar", "right_collar")]
    is_core = model.lbs_weights.numpy()[:, core].sum(1) > 0.95
    hands = np.isin(labels, [PART_LEFT_HAND, PART_RIGHT_HAND])
    faces = model.faces.numpy()
    clips = C.clips_from_table(library)
    for name in ("THANK-YOU", "WHO", "NAME", "SCHOOL", "DEAF", "LIKE", "ME", "EAT"):
        clip = clips[name]
        idx = np.arange(0, clip.num_frames, 4)
        p = {b: torch.as_tensor(clip.poses[b][idx]) for b in
             ("body_pose", "left_hand_pose", "right_hand_pose", "jaw_pose", "expression")}
        with torch.no_grad():
            verts = model(**p).vertices.numpy()
        for v in verts:
            normals = trimesh.Trimesh(v, faces, process=False).vertex_normals
            d, i = cKDTree(v[is_core]).query(v[hands])
            depth = -np.einsum("ij,ij->i", v[hands] - v[is_core][i], normals[is_core][i])
            assert depth[d < 0.05].max(initial=0.0) < 0.008, name


def test_tracks_are_smooth(library):
    """No joint of any gloss turns more than 15 degrees between consecutive frames at 25 fps
    (the IK keeps the elbow swivel and forearm twist continuous)."""
    from scipy.spatial.transform import Rotation

    clips = C.clips_from_table(library)
    for clip in clips.values():
        for block in ("body_pose", "left_hand_pose", "right_hand_pose"):
            r = clip.poses[block].astype(np.float64).reshape(clip.num_frames, -1, 3)
            a = Rotation.from_rotvec(r[:-1].reshape(-1, 3))
            b = Rotation.from_rotvec(r[1:].reshape(-1, 3))
            step = np.degrees((b * a.inv()).magnitude())
            assert step.max() < 15.0, (clip.gloss, block, step.max())
