"""The step benchmark's instrumentation (benchmarks/bench_avatar_step.py): timing the parts of a
training step segment by segment must not change what the step computes."""

import pytest
import torch
from avatar_scenes import make_scene, random_smplx, rig
from benchmark_scripts import load_benchmark

from signsplat.avatar.config import avatar_config
from signsplat.avatar.train import AvatarTrainer
from signsplat.body.model import BodyModel

SIZE = 24
CFG = {
    "upsample": {"edge_length": 0.08, "face_area": 3e-3},
    "model": {"scale_max": {"body": 0.08, "head": 0.06, "hands": 0.05}, "hidden": 8},
    "train": {"iterations": 20, "test_interval": 3, "test_offset": 2, "accumulate_poses": 2,
              "render_backend": "cpu", "color_init": "constant"},
    "strategy": {"refine_start": 1, "refine_every": 2, "refine_stop": 100,
                 "grad_threshold": 1e-6, "max_new_per_refine": 20},
}


def _bench():
    return load_benchmark("bench_avatar_step")


@pytest.fixture(scope="module")
def scene(tiny_body_path):
    body = BodyModel.from_file(tiny_body_path)
    vm, K = rig(2, SIZE)
    g = torch.Generator().manual_seed(3)
    imgs = torch.rand(2, 4, SIZE, SIZE, 3, generator=g)
    return body, make_scene(imgs, vm, K, random_smplx(4))


def _capture_grads(tr, into: list):
    step = tr.optimizer.step

    def capture(*a, **k):
        into.append({f"{g['name']}.{i}": p.grad.detach().clone()
                     for g in tr.optimizer.param_groups for i, p in enumerate(g["params"])
                     if p.grad is not None})
        return step(*a, **k)

    tr.optimizer.step = capture


def test_instrumented_step_computes_the_plain_step_and_times_every_part(scene):
    bench = _bench()
    body, data = scene
    plain = AvatarTrainer(body, data, avatar_config(CFG))
    timed = AvatarTrainer(body, data, avatar_config(CFG))
    ga, gb = [], []
    _capture_grads(plain, ga)
    forward = timed.model.forward
    rec = bench.Recorder()
    a = plain.train_step()
    inst = bench.Instrument(timed, rec)
    _capture_grads(timed, gb)  # inside the instrument: the step captured is its own
    try:
        b = timed.train_step()
    finally:
        inst.remove()
    assert a["loss"] == pytest.approx(b["loss"], rel=1e-6)
    assert ga[0].keys() == gb[0].keys() and len(ga[0]) > 10
    for k, v in ga[0].items():
        scale = float(v.abs().max()) or 1.0
        torch.testing.assert_close(v, gb[0][k], rtol=1e-4, atol=1e-5 * scale, msg=k)
    # the densification statistics (gradients of the projected means) are the same
    torch.testing.assert_close(plain.strategy_state["grad2d"], timed.strategy_state["grad2d"],
                               rtol=1e-4, atol=1e-9)
    parts = {p for p, _ in rec.seconds}
    assert {"posing", "gaussians", "pose_net", "displacement_net", "projection",
            "rasterization", "losses", "ssim", "optimiser", "densification"} <= parts
    for part in ("posing", "gaussians", "projection", "rasterization", "losses"):
        assert rec.seconds[(part, "backward")] > 0, part
    # removed: the trainer's own methods are back
    assert timed.model.forward == forward and "forward" not in vars(timed.body)


def test_segment_passes_gradients_through_nested_parts():
    bench = _bench()
    rec = bench.Recorder()
    inner = bench.segment(rec, "inner", lambda x: (x * 3).sin())
    outer = bench.segment(rec, "outer", lambda x, y: {"z": inner(x) * y, "n": 1})
    x = torch.linspace(-1, 1, 7, requires_grad=True)
    y = torch.linspace(0, 2, 7, requires_grad=True)
    out = outer(x, y)
    assert out["n"] == 1
    out["z"].sum().backward()
    torch.testing.assert_close(x.grad, 3 * (x * 3).cos().detach() * y.detach())
    torch.testing.assert_close(y.grad, (x * 3).sin().detach())
    assert {("inner", "forward"), ("inner", "backward"), ("outer", "forward"),
            ("outer", "backward")} <= set(rec.seconds)
