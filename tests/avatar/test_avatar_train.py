"""Trainer and evaluation on a tiny scene rendered from a 'teacher' avatar (real rasterizer)."""

import itertools
import logging

import numpy as np
import pandas as pd
import pytest
import torch
from avatar_scenes import make_scene, random_smplx, rig

from signsplat.avatar import regularize as reg_mod
from signsplat.avatar.checkpoint import build_model
from signsplat.avatar.config import avatar_config
from signsplat.avatar.data import load_scene
from signsplat.avatar.evaluate import evaluate_checkpoint
from signsplat.avatar.train import AvatarTrainer, render_gaussians
from signsplat.body.model import BodyModel
from signsplat.io.images import write_png
from signsplat.io.tables import read_table, write_table
from signsplat.render import rasterization

SIZE = 24
BASE = {
    "upsample": {"edge_length": 0.08, "face_area": 3e-3},
    "model": {"scale_max": {"body": 0.08, "head": 0.06, "hands": 0.05}, "hidden": 8},
    "train": {"iterations": 6, "test_interval": 3, "test_offset": 2, "log_every": 1,
              "accumulate_poses": 2, "checkpoint_every": 3, "render_backend": "cpu"},
    "regularize": {"enabled": True},  # off in the demo profile; the tests exercise it
    "strategy": {"refine_start": 1, "refine_every": 2, "refine_stop": 100,
                 "grad_threshold": 1e-6, "max_new_per_refine": 20},
    "eval": {"crop_size": {"body": 0.0, "head": 0.4, "hands": 0.4}, "refine_steps": 2},
}


def _cfg(**over):
    data = {k: dict(v) for k, v in BASE.items()}
    for k, v in over.items():
        data[k] = {**data.get(k, {}), **v}
    return avatar_config(data)


@pytest.fixture(scope="module")
def scene(tiny_body_path):
    torch.manual_seed(0)
    body = BodyModel.from_file(tiny_body_path)
    vm, K = rig(3, SIZE)
    smplx = random_smplx(6)
    cfg = _cfg()
    teacher = build_model(body, torch.zeros(1, 10), cfg)
    with torch.no_grad():
        teacher.sh_dc.normal_(0, 1.0)
        imgs = []
        for c in range(3):
            row = []
            for f in range(6):
                p = {k: v[f:f + 1] for k, v in smplx.items()}
                o = body(**p)
                g = teacher(o.v_shaped, o.vertices, o.transforms, p["transl"], 0)
                col, _, _ = render_gaussians(rasterization, g, 0, vm[c:c + 1], K[c:c + 1], SIZE,
                                             SIZE, torch.ones(3), "cpu",
                                             **cfg.model.raster_options())
                row.append(col[0])
            imgs.append(torch.stack(row))
    return body, make_scene(torch.stack(imgs), vm, K, smplx)


def _params(model):
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def test_training_improves_psnr_and_writes_a_log(scene, tmp_path):
    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"iterations": 30, "color_init": "constant"}))
    assert list(data.frames[tr.split.test_frames]) == [2, 5]
    log = tr.run(progress=False)
    assert np.isfinite(log["loss"]).all()
    first, last = log["psnr"].iloc[:3].mean(), log["psnr"].iloc[-3:].mean()
    assert last > first + 1.5, (first, last)
    assert log["added"].sum() > 0 and tr.model.num_points > int(tr.model.is_original.sum())
    log.insert(0, "variant", "t")
    log.insert(0, "scene", "tiny")
    write_table(log, tmp_path / "train_log.parquet", "avatar_train_log")
    assert len(read_table(tmp_path / "train_log.parquet", "avatar_train_log")) == 30


@pytest.mark.parametrize("final,knots", [(1.0, 1), (0.1, 1), (1.0, 3)])
def test_resume_gives_the_same_result_as_an_uninterrupted_run(scene, tmp_path, final, knots):
    body, data = scene
    cfg = _cfg(train={"lr_final_fraction": final, "pose_knot_spacing": knots})
    a = AvatarTrainer(body, data, cfg)
    a.run(iterations=3, checkpoint=tmp_path / "half.pt", progress=False)
    a.run(iterations=6, progress=False)
    assert a.model.num_points > int(a.model.is_original.sum())  # densified on the way

    b = AvatarTrainer(body, data, cfg)
    b.load_checkpoint(tmp_path / "half.pt")
    assert b.step == 3
    b.run(iterations=6, progress=False)
    pa, pb = _params(a.model), _params(b.model)
    assert pa.keys() == pb.keys()
    for k in pa:
        torch.testing.assert_close(pa[k], pb[k], rtol=0, atol=0, msg=k)
    for (ka, va), (kb, vb) in zip(a.smplx.state_dict().items(), b.smplx.state_dict().items()):
        torch.testing.assert_close(va, vb, rtol=0, atol=0)
    assert [r["loss"] for r in a.log_rows] == [r["loss"] for r in b.log_rows]


def test_learning_rates_decay_to_the_final_fraction():
    from signsplat.avatar.train import lr_factor

    assert lr_factor(1, 100, 0.1) == 1.0 and lr_factor(100, 100, 0.1) == pytest.approx(0.1)
    assert lr_factor(50, 100, 1.0) == 1.0 and lr_factor(500, 100, 0.1) == pytest.approx(0.1)
    mid = lr_factor(51, 101, 0.01)  # halfway in exponent: sqrt(0.01)
    assert mid == pytest.approx(0.1)


def test_optimiser_groups_follow_the_schedule(scene):
    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"lr_final_fraction": 0.1, "iterations": 6}))
    base = {g["name"]: g["base_lr"] for g in tr.optimizer.param_groups}
    for _ in range(6):
        tr.train_step()
    for g in tr.optimizer.param_groups:
        assert g["lr"] == pytest.approx(0.1 * base[g["name"]])


def test_shape_coefficients_have_their_own_learning_rate(scene):
    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"lr_smplx": 1e-4, "lr_betas": 5e-2,
                                                "pose_knot_spacing": 1}))
    lr = {g["name"]: g["lr"] for g in tr.optimizer.param_groups}
    assert lr["betas"] == 5e-2 and lr["smplx"] == 1e-4
    groups = {g["name"]: g["params"] for g in tr.optimizer.param_groups}
    assert [p.shape for p in groups["betas"]] == [tr.smplx.betas.shape]
    assert all(p is not tr.smplx.betas for p in groups["smplx"])
    b0, pose0 = tr.smplx.betas.detach().clone(), tr.smplx.body_pose.detach().clone()
    for _ in range(3):
        tr.train_step()
    moved_b = float((tr.smplx.betas - b0).abs().max())
    moved_p = float((tr.smplx.body_pose - pose0).abs().max())
    # Adam moves each coefficient by about its learning rate per step
    assert 1e-2 < moved_b <= 1.05 * 3 * 5e-2 and 0 < moved_p <= 1.05 * 3 * 1e-4
    same = AvatarTrainer(body, data, _cfg(train={"lr_smplx": 2e-4, "lr_betas": None}))
    assert {g["name"]: g["lr"] for g in same.optimizer.param_groups}["betas"] == 2e-4


def test_finger_poses_have_their_own_learning_rate(scene):
    """train.lr_hand_poses moves the finger poses (and only them) at their own rate."""
    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"lr_smplx": 1e-4, "lr_hand_poses": 2e-2,
                                               "pose_knot_spacing": 1}))
    groups = {g["name"]: g for g in tr.optimizer.param_groups}
    assert groups["hand_poses"]["lr"] == 2e-2 and groups["smplx"]["lr"] == 1e-4
    assert {id(p) for p in groups["hand_poses"]["params"]} == {
        id(tr.smplx.left_hand_pose), id(tr.smplx.right_hand_pose)}
    before = {n: getattr(tr.smplx, n).detach().clone() for n in ("right_hand_pose", "body_pose")}
    for _ in range(3):
        tr.train_step()
    moved = {n: float((getattr(tr.smplx, n) - v).abs().max()) for n, v in before.items()}
    assert 1e-2 < moved["right_hand_pose"] <= 1.05 * 3 * 2e-2
    assert 0 < moved["body_pose"] <= 1.05 * 3 * 1e-4
    same = AvatarTrainer(body, data, _cfg(train={"lr_smplx": 2e-4, "lr_hand_poses": None}))
    assert {g["name"]: g["lr"] for g in same.optimizer.param_groups}["hand_poses"] == 2e-4
    knotted = AvatarTrainer(body, data, _cfg(train={"lr_hand_poses": 2e-2,
                                                    "pose_knot_spacing": 4}))
    groups = {g["name"]: g for g in knotted.optimizer.param_groups}
    assert groups["hand_poses"]["lr"] == 2e-2  # the fingers' knots learn at the fingers' rate
    assert {id(p) for p in groups["hand_poses"]["params"]} == {
        id(knotted.smplx.left_hand_pose_knots), id(knotted.smplx.right_hand_pose_knots)}


def test_knotted_pose_corrections_move_the_neighbours_of_a_trained_frame(scene):
    """train.pose_knot_spacing: a frame's image loss corrects the frames around it too (the
    correction is piecewise linear in the frame number); per frame, only the frame itself."""
    body, data = scene
    moved = {}
    for spacing in (1, 4):
        tr = AvatarTrainer(body, data, _cfg(train={"pose_knot_spacing": spacing,
                                                   "accumulate_poses": 1}))
        before = tr.smplx.frame_values()["body_pose"]
        (frame, _), = tr._sample()
        tr.sampler.set_state(AvatarTrainer(body, data, tr.cfg).sampler.get_state())
        tr.train_step()
        after = tr.smplx.frame_values()["body_pose"]
        step = (after - before).abs().amax(1)
        assert step[frame] > 0
        others = [i for i in range(len(data.frames)) if i != frame]
        moved[spacing] = int((step[others] > 0).sum())
        if spacing > 1:
            assert set(tr.smplx.knotted) == {"expression", "global_orient", "body_pose",
                                             "jaw_pose", "leye_pose", "reye_pose",
                                             "left_hand_pose", "right_hand_pose", "transl"}
            assert torch.isfinite(after).all()
    assert moved[1] == 0 and moved[4] >= 2, moved


def test_resuming_with_another_knot_spacing_names_the_file_and_both_settings(scene, tmp_path):
    body, data = scene
    AvatarTrainer(body, data, _cfg(train={"pose_knot_spacing": 1})).run(
        iterations=1, checkpoint=tmp_path / "ck.pt", progress=False)
    other = AvatarTrainer(body, data, _cfg(train={"pose_knot_spacing": 4}))
    with pytest.raises(ValueError, match=r"ck.pt: saved with train.pose_knot_spacing 1, "
                                         r"asked to resume with 4"):
        other.load_checkpoint(tmp_path / "ck.pt")


def test_knot_weights_interpolate_linearly_between_knots():
    from signsplat.avatar.checkpoint import knot_weights

    w = knot_weights(np.arange(10, 20), 4)  # knots at frames 10, 14, 18, 22
    assert w.shape == (10, 4)
    torch.testing.assert_close(w.sum(1), torch.ones(10))
    assert w[0, 0] == 1 and w[4, 1] == 1 and w[8, 2] == 1
    torch.testing.assert_close(w[2, :2], torch.tensor([0.5, 0.5]))
    torch.testing.assert_close(w[9, 2:], torch.tensor([0.75, 0.25]))
    gaps = knot_weights(np.array([0, 1, 7]), 2)  # a gap in the frames skips knots
    assert gaps.shape == (3, 5) and gaps[2, 3] == 0.5 and gaps[2, 4] == 0.5


def _write_scene(root, data, smplx_override):
    rows, cams = [], []
    for vi, v in enumerate(data.views):
        R = data.viewmats[vi, :3, :3].double().numpy()
        t = data.viewmats[vi, :3, 3].double().numpy()
        K = data.Ks[vi].double().numpy()
        cams.append(dict(scene="tiny", view=int(v), frame=-1, width=SIZE, height=SIZE,
                         fx=K[0, 0], fy=K[1, 1], cx=K[0, 2] - 0.5, cy=K[1, 2] - 0.5,
                         R=list(R.ravel()),
                         t=list(t)))
        for fi, f in enumerate(data.frames):
            img = f"images/{vi:02d}/{fi:04d}.png"
            msk = f"masks/{vi:02d}/{fi:04d}.png"
            write_png(root / img, data.images[vi, fi].numpy())
            write_png(root / msk, data.masks[vi, fi].numpy())
            rows.append(dict(scene="tiny", view=int(v), frame=int(f), time=fi / 25, image=img,
                             mask=msk))
    write_table(pd.DataFrame(rows), root / "frames.parquet", "frames")
    write_table(pd.DataFrame(cams), root / "cameras.parquet", "cameras")
    srows = []
    for fi, f in enumerate(data.frames):
        r = dict(scene="tiny", frame=int(f))
        for k, v in smplx_override.items():
            r[k] = list(v[fi].numpy().astype(np.float32))
        srows.append(r)
    write_table(pd.DataFrame(srows), root / "smplx.parquet", "smplx_params")


def test_frame_with_missing_hands_trains_without_nan(scene, tmp_path):
    """A fit with no hand keypoints leaves NaN hand poses: loaded as rest hands, trains finite."""
    body, data = scene
    smplx = {k: v.clone() for k, v in data.smplx.items()}
    for k in ("left_hand_pose", "right_hand_pose"):
        smplx[k][[0, 1, 3, 4]] = float("nan")
    _write_scene(tmp_path, data, smplx)
    loaded = load_scene(tmp_path / "frames.parquet", tmp_path / "cameras.parquet",
                        tmp_path / "smplx.parquet")
    assert torch.equal(loaded.images, data.images)
    assert bool(torch.isfinite(loaded.smplx["left_hand_pose"]).all())
    assert float(loaded.smplx["left_hand_pose"][0].abs().sum()) == 0.0
    tr = AvatarTrainer(body, loaded, _cfg(train={"iterations": 8}))
    log = tr.run(progress=False)
    assert np.isfinite(log["loss"]).all() and "hand" in log.columns
    for name, p in tr.model.named_parameters():
        assert bool(torch.isfinite(p).all()), name
    assert bool(torch.isfinite(tr.smplx.left_hand_pose).all())


def test_switches_really_remove_their_computation(scene, monkeypatch):
    body, data = scene
    calls = []

    def counting(**kw):
        calls.append(1)
        return rasterization(**kw)

    # accumulation off: one render per optimiser step (on: accumulate_poses)
    tr = AvatarTrainer(body, data, _cfg(train={"accumulate": False}), rasterize=counting)
    calls.clear()  # renders of the colour initialisation
    tr.train_step()
    assert len(calls) == 1
    calls.clear()
    tr = AvatarTrainer(body, data, _cfg(train={"accumulate_poses": 3}), rasterize=counting)
    calls.clear()
    tr.train_step()
    assert len(calls) == 3

    # regularisation off: neighbourhoods never built, no reg terms
    def boom(*a, **k):
        raise AssertionError("computed although switched off")

    row = AvatarTrainer(body, data, _cfg()).train_step()
    assert any(k.startswith("reg_") for k in row)  # on: the terms are there
    monkeypatch.setattr(reg_mod, "build_neighbourhoods", boom)
    tr = AvatarTrainer(body, data, _cfg(regularize={"enabled": False}))
    row = tr.train_step()
    assert not any(k.startswith("reg_") for k in row)
    monkeypatch.undo()

    # densification off: the strategy is never consulted, the points never change
    tr = AvatarTrainer(body, data, _cfg(strategy={"enabled": False}))
    n0 = tr.model.num_points
    monkeypatch.setattr(tr.strategy, "step_post_backward", boom)
    monkeypatch.setattr(tr.strategy, "step_pre_backward", boom)
    for _ in range(4):
        tr.train_step()
    assert tr.model.num_points == n0

    # pose-dependent networks off: no Omega; SMPL-X fine-tuning off: no SMPL-X parameters
    tr = AvatarTrainer(body, data, _cfg(model={"pose_dependent": False},
                                        train={"finetune_smplx": False}))
    assert tr.model.omega is None
    assert not list(tr.smplx.parameters())
    assert [g["name"] for g in tr.optimizer.param_groups
            if g["name"] in ("smplx", "betas")] == []
    before = tr.smplx.body_pose.clone()
    tr.train_step()
    assert torch.equal(before, tr.smplx.body_pose)


def test_views_per_pose_renders_each_pose_from_distinct_cameras(scene):
    body, data = scene
    seen = []

    def recording(**kw):
        seen.append(kw["viewmats"].detach().clone())
        return rasterization(**kw)

    tr = AvatarTrainer(body, data, _cfg(train={"accumulate_poses": 2, "views_per_pose": 2}),
                       rasterize=recording)
    pairs = tr._sample()
    assert len(pairs) == 2 and all(len(v) == 2 and v[0] != v[1] for _, v in pairs)
    seen.clear()  # renders of the colour initialisation
    row = tr.train_step()
    assert len(seen) == 4 and np.isfinite(row["loss"])
    # more cameras asked for than there are: each pose gets every training camera once
    tr = AvatarTrainer(body, data, _cfg(train={"views_per_pose": 99}))
    (_, views), *_ = tr._sample()
    assert sorted(views) == sorted(int(v) for v in tr.split.train_views)


def test_evaluation_table_images_and_far_view_warning(scene, tmp_path, caplog):
    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"iterations": 4, "test_views": [2]}))
    tr.run(checkpoint=tmp_path / "ck.pt", progress=False)
    with caplog.at_level(logging.WARNING, logger="signsplat.avatar.evaluate"):
        df, views = evaluate_checkpoint(tmp_path / "ck.pt", body, data, "tiny-test",
                                        tmp_path / "img", overrides={"save_images": 2})
    assert any("degrees from the nearest training camera" in r.message for r in caplog.records)
    write_table(df, tmp_path / "metrics.parquet", "avatar_metrics")
    write_table(views, tmp_path / "views.parquet", "avatar_view_metrics")
    # per camera: the held-out camera 2 only in the novel-view splits; the per-view means,
    # weighted by their image counts, give the whole-split figure of the metrics table
    assert set(views[views.split == "novel_view"].view) == {int(data.views[2])}
    assert int(data.views[2]) not in set(views[views.split == "novel_pose"].view)
    full = df[(df.protocol == "bg_replaced") & (df.part == "full") & (df.metric == "psnr")]
    for (split, refine), g in views.groupby(["split", "refine"]):
        want = full[(full.split == split) & (full.refine == refine)]
        got = float((g.psnr * g.n_images).sum() / g.n_images.sum())
        assert abs(got - want.value.item()) < 1e-9, (split, refine)
        assert g.n_images.sum() == want.n_images.item()
    assert set(df.split) == {"novel_pose", "novel_view", "novel_pose_view", "train"}
    assert set(df.protocol) == {"bg_replaced", "mask_only", "raw_gt"}
    assert {"full", "left_hand", "right_hand", "face"} <= set(df.part)
    assert set(df.metric) == {"psnr", "ssim"}  # no LPIPS weights configured: not reported
    assert set(df[df.split == "novel_pose"].refine) == {False, True}
    assert set(df[df.split == "train"].refine) == {False}
    assert np.isfinite(df.value).all() and (df.train_seconds > 0).all()
    assert len(list((tmp_path / "img").glob("*.png"))) == 2
    full = df[(df.split == "novel_pose") & (df.part == "full") & (df.metric == "psnr")]
    assert (full.value > 10).all()


def test_colour_init_from_images_starts_closer_to_the_images(scene):
    body, data = scene
    grey = AvatarTrainer(body, data, _cfg(train={"color_init": "constant"}))
    init = AvatarTrainer(body, data, _cfg(train={"color_init": "images",
                                                 "color_init_images": 12}))
    assert grey.colour_init_seen == 0 and 0 < init.colour_init_seen < init.model.num_points

    def l1(tr):
        errs = []
        with torch.no_grad():
            for f in tr.split.train_frames:
                out, g = tr.pose(torch.tensor([int(f)]), 0)
                for v in range(3):
                    col, _, _ = render_gaussians(rasterization, g, 0, data.viewmats[v:v + 1],
                                                 data.Ks[v:v + 1], SIZE, SIZE, torch.ones(3),
                                                 "cpu", **tr.cfg.model.raster_options())
                    gt = data.images[v, int(f)].float() / 255
                    errs.append(float((col[0] - gt).abs().mean()))
        return np.mean(errs)

    assert l1(init) < 0.8 * l1(grey), (l1(init), l1(grey))
    unseen = init.model.sh_dc[:, 0].sub(grey.model.sh_dc[:, 0]).abs().sum(-1) == 0
    assert bool(torch.isfinite(init.model.sh_dc).all()) and bool(unseen.any())


def test_rendering_above_the_training_resolution_keeps_the_dilation_footprint(scene):
    from signsplat.avatar.train import eval_eps2d
    from signsplat.render import DEFAULT_EPS2D as EPS2D

    assert eval_eps2d(EPS2D, 0, 256) == EPS2D and eval_eps2d(EPS2D, 256, 256) == EPS2D
    assert eval_eps2d(EPS2D, 128, 256) == pytest.approx(4 * EPS2D)
    # an avatar whose Gaussians are far below a pixel relies on the dilation for coverage:
    # with the footprint kept, rendering at twice the size covers as much of the body
    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"color_init": "constant"}))
    with torch.no_grad():
        tr.model.scale_raw.fill_(-20.0)  # scales at scale_min (0.2 mm)
        out, g = tr.pose(torch.tensor([0]), 0)
    vm, K = data.viewmats[:1], data.Ks[:1].clone()
    cover = []
    twice = eval_eps2d(EPS2D, SIZE, 2 * SIZE)
    for size, eps in ((SIZE, EPS2D), (2 * SIZE, EPS2D), (2 * SIZE, twice)):
        Ks = K.clone()
        Ks[:, :2] *= size / SIZE
        _, alpha, _ = render_gaussians(rasterization, g, 0, vm, Ks, size, size, torch.ones(3),
                                       "cpu", eps2d=eps)
        cover.append(float(alpha.mean()))
    assert cover[1] < 0.8 * cover[0], cover  # holes at twice the size with the same dilation
    assert cover[2] > 0.9 * cover[0], cover


def test_training_evaluation_and_the_sign_renderer_use_the_avatars_own_filter(scene, tmp_path):
    """model.eps2d and model.rasterize_mode reach every image render of the avatar: training,
    evaluation (at the training resolution) and the sign-video renderer of its checkpoint."""
    from signsplat.avatar.checkpoint import load_avatar
    from signsplat.motion.stitching import FRAME_BLOCKS, Frame
    from signsplat.render import DEFAULT_EPS2D as EPS2D
    from signsplat.stitch.animate import AvatarRenderer, Camera

    body, data = scene
    seen = []

    def spy(**kw):  # the images (the colour init's depth renders only test visibility)
        if kw.get("render_mode", "RGB") == "RGB":
            seen.append((kw["eps2d"], kw["rasterize_mode"]))
        return rasterization(**kw)

    cfg = _cfg(train={"iterations": 2}, model={"eps2d": 0.05, "rasterize_mode": "antialiased"})
    tr = AvatarTrainer(body, data, cfg, rasterize=spy)
    tr.run(checkpoint=tmp_path / "ck.pt", progress=False)
    trained, seen[:] = list(seen), []
    evaluate_checkpoint(tmp_path / "ck.pt", body, data, "t", rasterize=spy,
                        overrides={"refine_steps": 0})
    evaluated, seen[:] = list(seen), []
    cam = Camera(data.viewmats[0].numpy(), data.Ks[0].numpy(), SIZE, SIZE)
    renderer = AvatarRenderer.from_checkpoint(tmp_path / "ck.pt", body, cam, backend="cpu")
    renderer._rasterize = spy
    frame = Frame("rest", 0, {b: np.zeros(k, np.float32) for b, k in FRAME_BLOCKS.items()})
    renderer.render([frame])
    assert trained and evaluated and seen
    assert set(trained) == set(evaluated) == set(seen) == {(0.05, "antialiased")}
    # a checkpoint saved before the settings existed was trained with 3DGS's filter
    state = torch.load(tmp_path / "ck.pt", weights_only=False)
    for key in ("eps2d", "rasterize_mode"):
        del state["config"]["model"][key]
    torch.save(state, tmp_path / "old.pt")
    cfg = load_avatar(tmp_path / "old.pt", body)[3]
    assert (cfg.model.eps2d, cfg.model.rasterize_mode) == (EPS2D, "classic")


def test_test_time_refinement_never_keeps_a_pose_that_fits_worse(scene, tmp_path):
    # a learning rate far too high throws every pose away from its (exact) input: the input
    # pose must be kept, so the refined scores equal the unrefined ones
    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"iterations": 4, "smplx_source": "ground_truth"}))
    tr.run(checkpoint=tmp_path / "ck.pt", progress=False)
    df, _ = evaluate_checkpoint(tmp_path / "ck.pt", body, data, "t", None,
                                overrides={"refine_steps": 4, "refine_lr": 1.0})
    nov = df[df.split == "novel_pose"].sort_values(["protocol", "part", "metric"])
    a, b = nov[~nov.refine], nov[nov.refine]
    np.testing.assert_array_equal(a.value.to_numpy(), b.value.to_numpy())


def test_held_out_frames_take_the_interpolated_fine_tuning_of_their_neighbours(scene, tmp_path):
    from signsplat.avatar import load_avatar
    from signsplat.avatar.evaluate import apply_heldout_pose
    from signsplat.avatar.poses import interpolation_weights

    body, data = scene
    tr = AvatarTrainer(body, data, _cfg(train={"iterations": 4, "lr_smplx": 1e-2,
                                               "pose_knot_spacing": 1}))
    tr.run(checkpoint=tmp_path / "ck.pt", progress=False)
    _, smplx, state, cfg = load_avatar(tmp_path / "ck.pt", body)
    train = np.isin(data.frames, state["split"]["train_frames"])
    assert train.any() and (~train).any()
    tuned = smplx.body_pose.detach().clone()
    delta = tuned - data.smplx["body_pose"]
    assert float(delta[train].abs().max()) > 1e-3  # the fine-tuning moved the training poses
    assert float(delta[~train].abs().max()) == 0  # and never the held-out ones
    assert apply_heldout_pose(smplx, data, state["split"], cfg) == "interpolated"
    w = interpolation_weights(data.frames, train)
    want = data.smplx["body_pose"] + w @ (delta * torch.as_tensor(train)[:, None])
    torch.testing.assert_close(smplx.body_pose[~train], want[~train])
    torch.testing.assert_close(smplx.body_pose[train], tuned[train])
    # the table says which pose the held-out frames had; "fit" leaves them as fitted
    df_i, _ = evaluate_checkpoint(tmp_path / "ck.pt", body, data, "t", None)
    df_f, _ = evaluate_checkpoint(tmp_path / "ck.pt", body, data, "t", None,
                                  overrides={"heldout_pose": "fit"})
    assert set(df_i.heldout_pose) == {"interpolated"} and set(df_f.heldout_pose) == {"fit"}
    sel = (df_i.split == "novel_pose") & (df_i.part == "full") & (df_i.metric == "psnr")
    assert not np.allclose(df_i[sel].value.to_numpy(), df_f[sel].value.to_numpy())
    tr = {"split": "train", "part": "full", "metric": "psnr", "protocol": "bg_replaced"}
    pick = [df[(df[list(tr)] == pd.Series(tr)).all(axis=1)].value.item() for df in (df_i, df_f)]
    assert pick[0] == pick[1]  # training frames render the same either way
    _, smplx, state, cfg = load_avatar(tmp_path / "ck.pt", body)
    cfg.train.finetune_smplx = False  # nothing was fine-tuned: nothing to carry
    assert apply_heldout_pose(smplx, data, state["split"], cfg) == "fit"
    torch.testing.assert_close(smplx.body_pose, tuned)


def test_refinement_learning_rate_schedules():
    from signsplat.avatar.evaluate import refine_lr_at

    assert [refine_lr_at(s, 60, 2e-3, "constant") for s in (0, 30, 59)] == [2e-3] * 3
    cos = [refine_lr_at(s, 60, 2e-3, "cosine") for s in range(60)]
    assert cos[0] == pytest.approx(2e-3) and cos[30] == pytest.approx(1e-3)
    assert all(a > b for a, b in itertools.pairwise(cos)) and 0 < cos[-1] < 2e-5
    with pytest.raises(ValueError, match="refine_decay"):
        refine_lr_at(0, 60, 2e-3, "linear")


def test_training_ignores_the_settings_the_workflow_marks_evaluation_only(scene):
    """The workflow leaves EVAL_ONLY_KEYS out of the training rule's params, so changing them
    re-runs only the evaluation; the trainer must then really not read them."""
    from signsplat.avatar.config import EVAL_ONLY_KEYS as keys

    assert "refine_steps" in keys and "crop_size" not in keys
    odd = {"refine_steps": 0, "refine_lr": 0.5, "refine_decay": "cosine", "far_view_degrees": 1.0,
           "save_images": 0, "max_frames": 1, "heldout_pose": "fit"}
    assert set(keys) <= set(odd)
    body, data = scene
    runs = []
    for ev in ({}, {k: odd[k] for k in keys}):
        tr = AvatarTrainer(body, data, _cfg(eval=ev))
        for _ in range(3):
            tr.train_step()
        runs.append([r["loss"] for r in tr.log_rows])
    assert runs[0] == runs[1]


def test_a_camera_far_below_the_others_is_named_in_a_warning(caplog):
    from signsplat.avatar.evaluate import warn_weak_views

    def table(psnrs, split="novel_pose"):
        v = pd.DataFrame({"split": split, "refine": False, "view": range(len(psnrs)),
                          "psnr": psnrs})
        v["below_median_db"] = v.psnr.median() - v.psnr
        return v

    with caplog.at_level(logging.WARNING, logger="signsplat.avatar.evaluate"):
        weak = warn_weak_views(table([26.2, 25.5, 18.0, 24.3, 24.2, 25.8]))
    assert list(weak.view) == [2]
    assert any("camera 2 scores 18.00 dB on novel_pose" in r.message for r in caplog.records)
    caplog.clear()
    # within the threshold, or too few cameras to have a median worth comparing: no warning
    assert warn_weak_views(table([26.2, 25.5, 23.5, 24.3])).empty
    assert warn_weak_views(table([26.0, 18.0])).empty
    assert warn_weak_views(table([])).empty
    assert not caplog.records


def test_trainer_asks_torch_for_deterministic_kernels(scene):
    body, data = scene
    torch.use_deterministic_algorithms(False)
    try:
        AvatarTrainer(body, data, _cfg(train={"iterations": 1, "color_init": "constant"}))
        assert torch.are_deterministic_algorithms_enabled()
    finally:
        torch.use_deterministic_algorithms(False)
