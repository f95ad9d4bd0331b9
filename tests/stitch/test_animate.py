"""Rendering a stitched track with an avatar: cameras, streaming into the video, the CLI.

The avatar is tiny and untrained (an icosphere 'body' file with the SMPL-X joint layout, one
Gaussian per vertex, random colours) and images are 32 px, so the module runs in seconds.
The tiny avatar and its helpers are in tiny_avatar.py and conftest.py.
"""

from __future__ import annotations

import json
import tracemalloc

import numpy as np
import pytest
import torch
from tiny_avatar import (
    FAST,
    SIZE,
    CountingWriter,
    rig_cameras,
    tiny_renderer,
    write_cameras,
)

from signsplat.io.video import VideoWriter, iter_frames
from signsplat.motion.stitching import stitch_clips, stitch_frames
from signsplat.stitch.animate import (
    Identity,
    batch_params,
    choose_camera,
    front_camera,
    load_cameras,
    render_track,
)


# ------------------------------------------------------------------------------ cameras
def test_camera_projection_and_resize():
    cam = rig_cameras(3)[1]
    centre_px = cam.project(np.array([0.0, 1.0, 0.0]))[0]
    np.testing.assert_allclose(centre_px, [(SIZE - 1) / 2] * 2, atol=1e-9)
    big = cam.resized(4 * SIZE, 2 * SIZE)
    p = np.array([[0.1, 1.2, 0.05], [-0.2, 0.8, 0.1]])
    uv, z = cam.project(p)
    uv2, z2 = big.project(p)
    # pixel centres at integers: x' = (x + 0.5) * s - 0.5
    np.testing.assert_allclose(uv2[:, 0], (uv[:, 0] + 0.5) * 4 - 0.5, atol=1e-9)
    np.testing.assert_allclose(uv2[:, 1], (uv[:, 1] + 0.5) * 2 - 0.5, atol=1e-9)
    np.testing.assert_allclose(z, z2)
    assert float(cam.raster_K()[0, 2]) == pytest.approx(cam.K[0, 2] + 0.5)


def test_front_camera_and_choice(tmp_path):
    cams = rig_cameras(4, distance=2.0)
    path = write_cameras(tmp_path / "cameras.parquet", cams)
    loaded = load_cameras(path)
    assert len(loaded) == 4
    np.testing.assert_allclose(loaded[2].viewmat, cams[2].viewmat, atol=1e-12)
    front = front_camera(loaded)
    # straight in front (+z) at the rig's distance from the point the rig looks at
    np.testing.assert_allclose(front.centre, [0.0, 1.0, 2.0], atol=1e-6)
    assert front.project(np.array([0.0, 1.0, 0.0]))[0] == pytest.approx([(SIZE - 1) / 2] * 2)
    # upright image: world up is image up, the signer's left (+x) on the image right
    uv = front.project(np.array([[0.0, 1.5, 0.0], [0.0, 0.5, 0.0], [0.3, 1.0, 0.0]]))[0]
    assert uv[0, 1] < uv[1, 1] and uv[2, 0] > (SIZE - 1) / 2
    assert np.linalg.det(front.viewmat[:3, :3]) == pytest.approx(1.0)
    assert choose_camera("2", 0, path).name == "view2"
    assert choose_camera("front", 64, path).width == 64
    with pytest.raises(Exception, match="no camera 9"):
        choose_camera("9", 0, path)
    with pytest.raises(Exception, match="needs a cameras table"):
        choose_camera("1", 64, None)
    framing = choose_camera("front", 48, None, np.array([[-0.2, 0.8, 0.0], [0.2, 1.4, 0.1]]))
    uv, z = framing.project(np.array([[-0.2, 0.8, 0.0], [0.2, 1.4, 0.0]]))
    assert (z > 0).all() and (uv >= 0).all() and (uv <= 47).all()


# ------------------------------------------------------------------------------ rendering
def test_batch_params_substitute_identity(gloss_library):
    frames = list(stitch_frames([gloss_library["HELLO"]], FAST))[:5]
    ident = Identity(np.full(10, 0.5, np.float32), np.array([0, 0.1, 0], np.float32),
                     np.array([0, 0, 0.2], np.float32))
    p = batch_params(frames, ident)
    assert p["body_pose"].shape == (5, 63) and p["betas"].shape == (5, 10)
    assert torch.all(p["betas"] == 0.5)
    np.testing.assert_allclose(p["transl"].numpy(), np.tile([0, 0, 0.2], (5, 1)), atol=1e-7)
    np.testing.assert_array_equal(p["right_hand_pose"][3].numpy(),
                                  frames[3].params["right_hand_pose"])
    kept = batch_params(frames, Identity(np.zeros(10, np.float32)))
    np.testing.assert_array_equal(kept["transl"].numpy(),
                                  np.stack([f.params["transl"] for f in frames]))


def test_renderer_matches_direct_rasterization(tiny_body, gloss_library):
    from signsplat.render import rasterization

    r = tiny_renderer(tiny_body)
    frames = list(stitch_frames([gloss_library["BOOK"]], FAST))[3:5]
    images, out = r.render(frames)
    assert images.shape == (2, SIZE, SIZE, 3) and images.dtype == np.uint8
    p = batch_params(frames, r.identity)
    with torch.no_grad():
        o = tiny_body(**p)
        g = r.model(o.v_shaped, o.vertices, o.transforms, p["transl"], 0)
        cam = r.camera
        col, _, _ = rasterization(g.means[1], g.quats[1], g.scales[1], g.opacities[1],
                                  g.colors[1], torch.tensor(cam.viewmat, dtype=torch.float32)[None],
                                  cam.raster_K()[None], SIZE, SIZE, sh_degree=0,
                                  backgrounds=torch.ones(1, 3), backend="reference")
    ref = (col[0].clamp(0, 1) * 255).numpy()
    assert np.abs(images[1].astype(float) - ref).max() <= 1.5
    assert (images[1] < 250).any(axis=-1).sum() > 20  # the avatar covers pixels
    torch.testing.assert_close(out.joints, o.joints)


def test_render_track_streams_every_frame_into_mp4(tmp_path, tiny_files, tiny_body,
                                                   gloss_library):
    r = tiny_renderer(tiny_body, ckpt=tiny_files[2])
    assert r.scene == "tiny"
    clips = [gloss_library[g] for g in ("HELLO", "BOOK", "WHERE")]
    n = len(stitch_clips(clips, FAST)["label"])
    seen = []
    with VideoWriter(tmp_path / "s.mp4", fps=25) as w:
        stats = render_track(stitch_frames(clips, FAST), r, w, batch=5,
                             on_batch=lambda fr, out: seen.append(len(fr)))
    assert stats.frames == n and sum(seen) == n and max(seen) <= 5
    assert stats.render_fps > 0 and stats.cpu_ms_per_frame > 0
    decoded = [img for _, img in iter_frames(tmp_path / "s.mp4")]
    assert len(decoded) == n and decoded[0].shape == (SIZE, SIZE, 3)
    # the avatar moves: first and middle frames differ clearly
    assert np.abs(decoded[0].astype(int) - decoded[n // 2].astype(int)).mean() > 0.5


def test_long_sentence_memory_stays_flat(tiny_body, gloss_library):
    """Frames are written as rendered: the peak of Python allocations does not grow with the
    number of frames."""
    r = tiny_renderer(tiny_body)
    signs = [g for g, c in gloss_library.items() if c.kind == "sign"]

    def peak(n_glosses):
        clips = [gloss_library[signs[i % len(signs)]] for i in range(n_glosses)]
        w = CountingWriter()
        tracemalloc.start()
        render_track(stitch_frames(clips, FAST), r, w, batch=4)
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return w.frames, top

    render_track(stitch_frames([gloss_library["HELLO"]], FAST), r, CountingWriter())  # warm
    n_short, short = peak(1)
    n_long, long = peak(6)
    assert n_long > 4 * n_short
    assert long < 1.5 * short + 2e6, (short, long)


# ------------------------------------------------------------------------------ CLI
def _sign(tmp_path, tiny_files, gloss_library, sentences, *extra, ids=None):
    from signsplat.cli import main
    from signsplat.motion.clips import write_library

    lib = tmp_path / "glosses.parquet"
    if not lib.exists():
        write_library(gloss_library.values(), lib)
    body, cams, ckpt = tiny_files
    cfg = {"min_transition": 3, "max_transition": 5, "size": SIZE, "camera": "front",
           "render_batch": 4}
    argv = ["sign", *sentences, "--library", str(lib), "--out", str(tmp_path / "out"),
            "--avatar", str(ckpt), "--body", str(body), "--cameras", str(cams),
            "--config-json", json.dumps(cfg), "--threads", "1", *extra]
    for i in ids or []:
        argv += ["--id", i]
    return main(argv)


def test_sign_command_renders_videos_and_eval(tmp_path, tiny_files, gloss_library, capsys):
    from signsplat.io.tables import read_table

    import torch

    rc = _sign(tmp_path, tiny_files, gloss_library, ["Where is the book?", "Qwx!"],
               ids=["book", "qwx"])
    assert rc == 0, capsys.readouterr().err
    # rendering ran without autograd, and left the process's grad mode as it found it (a
    # command run in-process, as here, must not switch autograd off for what runs next)
    assert torch.is_grad_enabled()
    out = tmp_path / "out"
    for name in ("book", "qwx"):
        track = read_table(out / f"{name}.smplx.parquet", "smplx_params")
        video = [img for _, img in iter_frames(out / f"{name}.mp4")]
        base = [img for _, img in iter_frames(out / f"{name}.baseline2d.mp4")]
        assert len(video) == len(base) == len(track) > 0
        assert video[0].shape == (SIZE, SIZE, 3)
    # unknown words are fingerspelled, not dropped
    plan = json.loads((out / "qwx.plan.json").read_text())
    assert plan["glosses"] == ["Q", "W", "X"]
    ev = read_table(out / "stitch_eval.parquet", "stitch_eval")
    assert set(ev.sentence) == {"book", "qwx"} and (ev.scene == "tiny").all()
    fps = ev[(ev.metric == "render_fps")]
    assert len(fps) == 2 and (fps.value > 0).all()
    joins = ev[(ev.sentence == "qwx") & (ev.metric == "transition_frames")]
    assert list(joins["join"]) == [0, 1] and joins.value.between(3, 5).all()
    assert "frames/s" in capsys.readouterr().out


def test_sign_command_empty_sentence_is_a_clear_error(tmp_path, tiny_files, gloss_library,
                                                      capsys):
    rc = _sign(tmp_path, tiny_files, gloss_library, ["  ...  "], ids=["empty"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "nothing to render" in err and "coverage" in err
    out = tmp_path / "out"
    assert (out / "empty.plan.txt").exists() and not (out / "empty.mp4").exists()
