"""Effect registry: validation errors, what each effect does, and that unlisted effects cost
nothing (never built, never called, their code never runs)."""

import sys

import numpy as np
import pytest
import trimesh

from signsplat.synth import effects as fx
from signsplat.synth.effects import Camera, EffectError, build_effects
from signsplat.synth.scene import camera_rig
from signsplat.synth.simulate import SignerMesh, render_view

KNOWN = {"lighting", "background", "sensor_noise", "motion_blur", "occluder", "camera_jitter"}
TARGET = np.array([0.0, 1.2, 0.0])


def ball_signer():
    ico = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    canon = np.asarray(ico.vertices, np.float32)
    signer = SignerMesh(np.asarray(ico.faces, np.int64), canon, np.zeros(len(canon), np.int64),
                        lambda p, lab: 0.5 + 0.4 * np.sin(12 * p))
    return signer, np.asarray(ico.vertices) + TARGET


def rig(count=2, size=48):
    return camera_rig({"count": count, "layout": "arc", "arc_degrees": 90, "distance": 2.0,
                       "height": 1.2, "target": list(TARGET), "width": size, "height_px": size,
                       "fov_degrees": 40})


def render(chain, view=0, frame=0, cams=None, poses=None, weights=(1.0,)):
    signer, verts = ball_signer()
    cams = cams or rig()
    return render_view(poses or [verts], weights, signer, cams[view], chain, view, frame,
                       TARGET, supersample=2)


# --- registry and validation -----------------------------------------------------------------

def test_registry_has_the_required_effects():
    assert KNOWN <= set(fx.REGISTRY)


def test_unknown_effect_lists_the_known_ones():
    with pytest.raises(EffectError) as err:
        build_effects(["lighting", "lens_flare"])
    msg = str(err.value)
    assert "lens_flare" in msg and all(name in msg for name in KNOWN)


def test_unknown_option_names_it_and_the_allowed_ones():
    with pytest.raises(EffectError) as err:
        build_effects([{"sensor_noise": {"sigma": 0.01, "gamma": 2}}])
    msg = str(err.value)
    assert "'gamma'" in msg and "sensor_noise" in msg and "sigma" in msg


@pytest.mark.parametrize("entry, words", [
    ({"sensor_noise": {"sigma": -1}}, ["sigma", ">= 0.0"]),
    ({"background": {"kind": "plaid"}}, ["kind", "'solid'", "'textured'"]),
    ({"lighting": {"direction": [1, 0]}}, ["direction", "3 numbers"]),
    ({"motion_blur": {"samples": 1}}, ["samples", ">= 2"]),
    ({"occluder": {"views": [-1]}}, ["views", "integers >= 0"]),
    ({"lighting": {"direction": [0, 0, 0]}}, ["direction", "non-zero"]),
    ({"lighting": 3}, ["lighting", "mapping"]),
    ({"lighting": {}, "background": {}}, ["one-key mapping"]),
])
def test_bad_option_values_are_errors(entry, words):
    with pytest.raises(EffectError) as err:
        build_effects([entry])
    for w in words:
        assert w in str(err.value)


def test_an_effect_listed_twice_is_an_error():
    with pytest.raises(EffectError, match="twice"):
        build_effects(["lighting", {"lighting": {"ambient": 0.2}}])


def test_options_get_defaults_and_keep_given_values():
    (light,) = build_effects([{"lighting": {"ambient": 0.1}}]).effects
    assert light.options["ambient"] == 0.1
    assert light.options["intensity"] == fx.Lighting.OPTIONS["intensity"].default


# --- effects off cost nothing ------------------------------------------------------------------

def test_unlisted_effects_are_never_built_or_called(spy_effects):
    counts = spy_effects
    chain = build_effects(["lighting", {"sensor_noise": {"sigma": 0.02}}])
    cams = rig()
    for view in range(2):
        cam = cams[view]
        for effect in chain.at("camera"):
            cam = effect.camera(cam, view, 0)
        render(chain, view=view, cams=cams)
    assert counts["lighting"] == {"init": 1, "calls": 2}
    assert counts["sensor_noise"] == {"init": 1, "calls": 2}
    for name in KNOWN - {"lighting", "sensor_noise"}:
        assert counts[name] == {"init": 0, "calls": 0}, name


def _effect_code_objects():
    codes = {}
    for name, cls in fx.REGISTRY.items():
        for attr, value in vars(cls).items():
            if callable(value) and hasattr(value, "__code__"):
                codes[value.__code__] = f"{name}.{attr}"
    # helpers only effects use
    for helper in (fx._bilinear_upsample, fx._rodrigues):
        codes[helper.__code__] = helper.__name__
    return codes


def test_render_without_effects_never_runs_effect_code():
    codes = _effect_code_objects()
    seen = set()

    def profiler(frame, event, arg):
        if event == "call" and frame.f_code in codes:
            seen.add(codes[frame.f_code])

    chain = build_effects([])
    sys.setprofile(profiler)
    try:
        bare = render(chain)
    finally:
        sys.setprofile(None)
    assert seen == set()
    # without effects: unlit albedo over black, nothing else
    assert np.all(bare.rgb[bare.coverage == 0] == 0)

    # the profiler does see effect code when effects are listed (the check can fail)
    chain = build_effects(["lighting", "background"])
    sys.setprofile(profiler)
    try:
        render(chain)
    finally:
        sys.setprofile(None)
    assert {"lighting.shade", "background.background"} <= seen
    assert not any(s.startswith(("sensor_noise", "occluder", "camera_jitter", "motion_blur"))
                   for s in seen)


# --- what each effect does -----------------------------------------------------------------------

def test_background_fills_uncovered_pixels_only():
    bare = render(build_effects([]))
    solid = render(build_effects([{"background": {"color": [0.2, 0.4, 0.6]}}]))
    empty = bare.coverage == 0
    np.testing.assert_allclose(solid.rgb[empty], np.broadcast_to([0.2, 0.4, 0.6],
                                                                  solid.rgb[empty].shape), atol=1e-6)
    full = bare.coverage == 1
    np.testing.assert_allclose(solid.rgb[full], bare.rgb[full], atol=1e-6)
    tex = render(build_effects([{"background": {"kind": "textured", "seed": 5}}]))
    assert tex.rgb[empty].std(axis=0).mean() > 0.01  # textured, not flat
    again = render(build_effects([{"background": {"kind": "textured", "seed": 5}}]))
    np.testing.assert_array_equal(tex.rgb, again.rgb)


def test_sensor_noise_is_seeded_and_has_the_requested_sigma():
    base = render(build_effects([{"background": {"color": [0.5, 0.5, 0.5]}}]))
    chain = build_effects([{"background": {"color": [0.5, 0.5, 0.5]}},
                           {"sensor_noise": {"sigma": 0.05}}], seed=3)
    a = render(chain, frame=0)
    b = render(build_effects([{"background": {"color": [0.5, 0.5, 0.5]}},
                              {"sensor_noise": {"sigma": 0.05}}], seed=3), frame=0)
    c = render(chain, frame=1)
    np.testing.assert_array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.rgb, c.rgb)
    assert abs((a.rgb - base.rgb)[base.coverage == 0].std() - 0.05) < 0.005


def test_lighting_is_lambertian_plus_ambient():
    cam = rig()[1]
    towards_cam = cam.center - TARGET
    bare = render(build_effects([]), view=1)
    m = bare.coverage == 1
    front = render(build_effects([{"lighting": {"direction": list(towards_cam), "ambient": 0.2,
                                                "intensity": 0.8}}]), view=1)
    back = render(build_effects([{"lighting": {"direction": list(-towards_cam), "ambient": 0.2,
                                               "intensity": 0.8}}]), view=1)
    ratio_f = front.rgb[m].sum(-1) / np.maximum(bare.rgb[m].sum(-1), 1e-6)
    ratio_b = back.rgb[m].sum(-1) / np.maximum(bare.rgb[m].sum(-1), 1e-6)
    np.testing.assert_allclose(ratio_b, 0.2, atol=1e-3)  # unlit side: ambient only
    assert ratio_f.max() > 0.97 and ratio_f.max() <= 1.0 + 1e-3  # facing the light
    # brightest at the centre of the ball, dimmer towards the silhouette
    ys, xs = np.nonzero(m)
    r = np.hypot(ys - ys.mean(), xs - xs.mean())
    assert ratio_f[r < 0.3 * r.max()].mean() > ratio_f[r > 0.8 * r.max()].mean() + 0.2


def test_occluder_hides_the_signer_in_its_views_and_frames_only():
    chain = build_effects([{"occluder": {"views": [1], "start": 2, "stop": 4,
                                         "size": [0.3, 0.3, 0.02]}}])
    bare = render(build_effects([]), view=1)
    hidden = render(chain, view=1, frame=2)
    other_view = render(chain, view=0, frame=2)
    other_frame = render(chain, view=1, frame=4)
    assert hidden.mask.sum() < 0.5 * bare.mask.sum()
    assert other_frame.mask.sum() == bare.mask.sum()
    assert other_view.mask.sum() == render(build_effects([]), view=0).mask.sum()
    # the occluder is nearer than the signer and takes part in the depth test
    c = 24
    assert hidden.depth[c, c] < bare.depth[c, c] - 0.5


def test_camera_jitter_is_small_and_seeded():
    (jit,) = build_effects([{"camera_jitter": {"rotation_deg": 0.5, "translation": 0.01}}],
                           seed=1).effects
    cam = rig()[0]
    a, b, c = jit.camera(cam, 0, 5), jit.camera(cam, 0, 5), jit.camera(cam, 0, 6)
    np.testing.assert_array_equal(a.R, b.R)
    assert not np.allclose(a.R, c.R)
    np.testing.assert_allclose(a.R @ a.R.T, np.eye(3), atol=1e-12)
    angle = np.degrees(np.arccos(np.clip((np.trace(a.R @ cam.R.T) - 1) / 2, -1, 1)))
    assert 0 < angle < 5 * 0.5 * np.sqrt(3)
    assert 0 < np.linalg.norm(a.center - cam.center) < 0.1


def test_motion_blur_averages_subframe_renders():
    (blur,) = build_effects([{"motion_blur": {"samples": 3, "shutter": 0.6}}]).effects
    offsets, weights = blur.subframes()
    np.testing.assert_allclose(offsets, [-0.3, 0.0, 0.3])
    np.testing.assert_allclose(weights.sum(), 1.0)
    signer, verts = ball_signer()
    shifts = [np.array([dx, 0, 0]) for dx in (-0.2, 0.0, 0.2)]
    poses = [verts + s for s in shifts]
    chain = build_effects([])
    blurred = render(chain, poses=poses, weights=weights)
    sharp = render(chain, poses=[verts])
    # the average of the three sharp renders (linear in colour and coverage)
    parts = [render(chain, poses=[p]) for p in poses]
    np.testing.assert_allclose(blurred.rgb, sum(w * p.rgb for w, p in zip(weights, parts)),
                               atol=1e-5)
    assert (blurred.coverage > 0).sum() > (sharp.coverage > 0).sum()
    # depth for keypoints comes from the middle pose
    np.testing.assert_array_equal(blurred.depth, sharp.depth)


def test_camera_dataclass_centre():
    R = fx._rodrigues(np.array([0.1, 0.2, 0.3]))
    c = np.array([1.0, 2.0, 3.0])
    cam = Camera(np.eye(3), R, -R @ c, 4, 4)
    np.testing.assert_allclose(cam.center, c)
