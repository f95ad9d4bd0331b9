"""One avatar training step, broken into its parts (issue 27).

    .venv/bin/python benchmarks/bench_avatar_step.py [--points 57000 90000] [--threads 1 2]
        [--rounds 2] [--steps 4] [--baseline PATH] [--config-json '{...}']

The trainer of the checkout under test (``signsplat.avatar.train.AvatarTrainer``) trains on a
simulated scene (default ``results/studio6``, ground-truth SMPL-X and cameras; run
``snakemake results/studio6/sim/frames.parquet`` first), demo profile. "57000 points" is the
upsampled mesh as it is (about 57k); a larger count is reached by the densification strategy's
own ``grow`` with seeded random gradient statistics, so the added points are the trainer's
learnable ones on mesh faces. The step counter is set past densification and the SH rise
(step 700 of 800), so the measured steps are the demo's late steps.

Each configuration (points x threads) runs in its own process. It alternates plain training
steps (the figure ``step``: wall clock of ``train_step``) with instrumented ones, where every
part's forward runs on detached inputs that require grad, and the backward is run segment by
segment (loss -> image -> Gaussians -> networks -> posing): a part's backward is the time its own
graph takes to back-propagate the gradient that arrives at its outputs. Parts (exclusive of the
parts nested in them):

- ``posing``: the body model (shape, pose correctives, LBS of the mesh vertices);
- ``gaussians``: the avatar model's forward apart from its networks (displacement along the
  normals, barycentric points, rotations, shading, activations);
- ``displacement_net`` / ``pose_net``: the 1D-conv networks (or the fused network where the
  code has one, ``point_net``);
- ``projection`` (EWA projection and SH colours) and ``rasterization`` (binning and
  compositing), the CPU rasterizer's autograd functions; ``rasterizer_other`` its glue;
- ``losses``: L1 + D-SSIM of the renders, with ``ssim`` nested (the D-SSIM alone);
- ``optimiser``: ``Adam.step``; ``densification``: the strategy's statistics after a step;
- ``other``: the rest of the instrumented step (sampling, targets, hand crops, regularisation,
  the backward engine, zero_grad), i.e. its wall clock minus the parts.

A densification event (prune + grow, every ``refine_every`` steps up to ``refine_stop``) is
timed once at the end and reported on its own (``densify_event``), not inside the step.

``--variant NAME=JSON`` adds runs of this checkout with other config overrides (e.g.
``--variant "points={\"model\": {\"pose_net_on\": \"points\"}}"``, the paper's Omega over every
point; the default runs it over the mesh vertices).

``--baseline PATH`` runs the same benchmark against another checkout (e.g. ``git worktree add
/tmp/base <commit>``) in the same run: the two alternate (ABBA order over the rounds), and the
summary prints baseline / current ratios per part. With ``--side-by-side`` the checkouts'
workers of one configuration run at the same time instead (``--threads 1``: one core each),
so that both meet the same machine where its speed drifts from one process to the next
(``docs/avatar_step.md``). The worker processes import ``signsplat`` from the checkout they
measure (``PYTHONPATH``); the instrumentation uses only names that both have
(missing ones fall into ``other``).

Writes ``benchmarks/results/avatar_step.parquet`` (one row per checkout, points, threads, part,
phase: the median over rounds of each round's median, and the minimum) and
``avatar_step.json`` (the summary printed, the machine's load average before and after).
The machine's cores are shared: compare ratios from one run, not seconds across days.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
import types
from pathlib import Path

if "OMP_WAIT_POLICY" not in os.environ and "GOMP_SPINCOUNT" not in os.environ:
    os.environ["GOMP_SPINCOUNT"] = "10000"  # as signsplat.render; before torch loads

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results"

PARTS = ("posing", "gaussians", "displacement_net", "pose_net", "point_net", "projection",
         "rasterization", "rasterizer_other", "losses", "ssim", "optimiser", "densification",
         "other")


# ----------------------------------------------------------------------------- timing
class Recorder:
    """Exclusive seconds per (part, phase), wall clock and process CPU time (all threads);
    nested parts are subtracted from their parent's time."""

    def __init__(self):
        self.seconds: dict[tuple[str, str], float] = {}
        self.cpu: dict[tuple[str, str], float] = {}
        self._stack: list[list[float]] = []

    def timed(self, name: str, phase: str):
        rec = self

        class _Ctx:
            def __enter__(self):
                rec._stack.append([0.0, 0.0])
                self.t0, self.c0 = time.perf_counter(), time.process_time()

            def __exit__(self, *exc):
                dt = time.perf_counter() - self.t0
                dc = time.process_time() - self.c0
                child, child_cpu = rec._stack.pop()
                key = (name, phase)
                rec.seconds[key] = rec.seconds.get(key, 0.0) + dt - child
                rec.cpu[key] = rec.cpu.get(key, 0.0) + dc - child_cpu
                if rec._stack:
                    rec._stack[-1][0] += dt
                    rec._stack[-1][1] += dc

        return _Ctx()


def _flatten(obj):
    """(tensors, rebuild) for tensors inside tuples, lists, dicts, named tuples and dataclasses;
    everything else passes through ``rebuild`` unchanged."""
    import torch

    tensors: list = []

    def walk(o):
        if isinstance(o, torch.Tensor):
            tensors.append(o)
            return ("T", len(tensors) - 1)
        if dataclasses.is_dataclass(o) and not isinstance(o, type):
            return ("D", type(o), {f.name: walk(getattr(o, f.name)) for f in dataclasses.fields(o)})
        if isinstance(o, tuple) and hasattr(o, "_fields"):
            return ("N", type(o), [walk(x) for x in o])
        if isinstance(o, (list, tuple)):
            return ("L", type(o), [walk(x) for x in o])
        if isinstance(o, dict):
            return ("M", type(o), {k: walk(v) for k, v in o.items()})
        return ("V", o)

    spec = walk(obj)

    def rebuild(ts, s=spec):
        kind = s[0]
        if kind == "T":
            return ts[s[1]]
        if kind == "D":
            return s[1](**{k: rebuild(ts, v) for k, v in s[2].items()})
        if kind == "N":
            return s[1](*[rebuild(ts, v) for v in s[2]])
        if kind == "L":
            return s[1](rebuild(ts, v) for v in s[2])
        if kind == "M":
            out = s[1]() if s[1] is not dict else {}
            out.update({k: rebuild(ts, v) for k, v in s[2].items()})
            return out
        return s[1]

    return tensors, rebuild


def segment(rec: Recorder, name: str, fn, passthrough: int | None = None):
    """``fn`` as a part: its forward runs on detached inputs (inside a custom autograd function),
    its backward runs its own graph when the gradient of its outputs arrives. Gradients are the
    same as without the wrapper (tested in tests/avatar/test_bench_avatar_step.py).

    ``passthrough``: index of an element of a tuple output handed out as it is (the inner
    graph's tensors), e.g. the rasterizer's ``meta``, whose ``means2d`` the densification
    strategy reads the gradient of after the backward."""
    import torch

    class _Seg(torch.autograd.Function):
        @staticmethod
        def forward(ctx, holder, *flat):
            ctx.set_materialize_grads(False)  # an output nothing used gets None, not zeros
            with torch.enable_grad():
                leaves = [t.detach().requires_grad_(t.requires_grad) if t.is_floating_point()
                          else t for t in flat]
                args, kwargs = holder["rebuild_in"](leaves)
                with rec.timed(name, "forward"):
                    out = fn(*args, **kwargs)
            if passthrough is not None:
                holder["kept"] = out[passthrough]
                out = tuple(x for i, x in enumerate(out) if i != passthrough)
            outs, rebuild_out = _flatten(out)
            holder["rebuild_out"] = rebuild_out
            ctx.leaves, ctx.outs = leaves, outs
            det = [o.detach() for o in outs]
            ctx.mark_non_differentiable(*[d for d, o in zip(det, outs)
                                          if not o.is_floating_point() or not o.requires_grad])
            return tuple(det)

        @staticmethod
        def backward(ctx, *grads):
            pairs = [(o, g) for o, g in zip(ctx.outs, grads)
                     if g is not None and o.requires_grad]
            with rec.timed(name, "backward"):
                if pairs:
                    torch.autograd.backward([o for o, _ in pairs], [g for _, g in pairs])
            return (None,) + tuple(leaf.grad if isinstance(leaf, torch.Tensor)
                                   and leaf.requires_grad else None for leaf in ctx.leaves)

    def wrapped(*args, **kwargs):
        flat, rebuild_in = _flatten((args, kwargs))
        if not torch.is_grad_enabled() or not any(t.requires_grad for t in flat):
            with rec.timed(name, "forward"):
                return fn(*args, **kwargs)
        holder = {"rebuild_in": rebuild_in}
        det = _Seg.apply(holder, *flat)
        if not isinstance(det, tuple):
            det = (det,)
        out = holder["rebuild_out"](list(det))
        if passthrough is not None:
            out = out[:passthrough] + (holder["kept"],) + out[passthrough:]
        return out

    return wrapped


class Instrument:
    """Installs the segments on a trainer (and the modules it calls); ``remove()`` undoes it."""

    def __init__(self, trainer, rec: Recorder):
        import signsplat.avatar.losses as losses_mod
        import signsplat.avatar.train as train_mod

        self.undo: list = []
        self.rec = rec

        def patch(obj, attr, new):
            had = isinstance(obj, (type, types.ModuleType)) or attr in vars(obj)
            old = getattr(obj, attr)
            self.undo.append((obj, attr, old, had))
            setattr(obj, attr, new)

        model = trainer.model
        patch(trainer.body, "forward", segment(rec, "posing", trainer.body.forward))
        patch(model, "forward", segment(rec, "gaussians", model.forward))
        for attr, part in (("disp_net", "displacement_net"), ("omega", "pose_net"),
                           ("point_net", "point_net")):
            net = getattr(model, attr, None)
            if net is not None:
                patch(net, "forward", segment(rec, part, net.forward))
        patch(trainer, "rasterize", segment(rec, "rasterizer_other", trainer.rasterize,
                                            passthrough=2))
        try:
            from signsplat.render import _cpu
        except ImportError:  # pragma: no cover
            _cpu = None
        if _cpu is not None:
            for cls_name, part in (("_Project", "projection"), ("_SHColors", "projection"),
                                   ("_Rasterize", "rasterization")):
                cls = getattr(_cpu, cls_name, None)
                if cls is not None:
                    shim = type(cls_name, (), {"apply": staticmethod(segment(rec, part, cls.apply))})
                    patch(_cpu, cls_name, shim)
        if hasattr(train_mod, "image_loss"):
            patch(train_mod, "image_loss", segment(rec, "losses", train_mod.image_loss))
        if hasattr(losses_mod, "dssim"):
            patch(losses_mod, "dssim", segment(rec, "ssim", losses_mod.dssim))
        opt_step = trainer.optimizer.step

        def step(*a, **k):
            with rec.timed("optimiser", "forward"):
                return opt_step(*a, **k)

        patch(trainer.optimizer, "step", step)
        post = trainer.strategy.step_post_backward

        def post_backward(*a, **k):
            with rec.timed("densification", "forward"):
                return post(*a, **k)

        patch(trainer.strategy, "step_post_backward", post_backward)

    def remove(self) -> None:
        for obj, attr, old, had in reversed(self.undo):
            if had:
                setattr(obj, attr, old)
            else:
                delattr(obj, attr)
        self.undo.clear()


# ----------------------------------------------------------------------------- worker
def grow_to(trainer, points: int, seed: int = 1) -> None:
    """Add points with the trainer's own strategy until ``points`` (seeded random statistics)."""
    import torch

    st = trainer.strategy
    gen = torch.Generator().manual_seed(seed)
    keep = (st.max_points, st.max_new_per_refine)
    try:
        while trainer.model.num_points < points:
            n = trainer.model.num_points
            trainer.strategy_state["grad2d"] = torch.rand(n, generator=gen)
            trainer.strategy_state["count"] = torch.ones(n)
            st.max_points = points
            st.max_new_per_refine = min(20000, points - n)
            if st.grow(trainer.model, trainer.optimizer, trainer.strategy_state) == 0:
                break
    finally:
        st.max_points, st.max_new_per_refine = keep
        trainer.strategy_state["grad2d"] = trainer.strategy_state["count"] = None


def build_trainer(code: Path, results: Path, scene: str, points: int, config: dict):
    from signsplat.avatar.config import avatar_config
    from signsplat.config import deep_merge
    from signsplat.avatar.data import load_scene
    from signsplat.avatar.train import AvatarTrainer
    from signsplat.body.model import BodyModel

    sim = results / scene / "sim"
    cfg = avatar_config(deep_merge({"train": {"smplx_source": "ground_truth"}}, config))
    body = BodyModel.from_file(results / "_assets" / "body_model.npz")
    data = load_scene(sim / "frames.parquet", sim / "cameras.parquet", sim / "smplx_gt.parquet",
                      cfg.train.resolution)
    trainer = AvatarTrainer(body, data, cfg)
    if points > trainer.model.num_points:
        grow_to(trainer, points)
    # the demo's late steps: past densification and the SH rise
    trainer.step = max(trainer.step, cfg.strategy.refine_stop + 1,
                       int(cfg.sh_schedule.rise_at * cfg.train.iterations) + 1)
    if trainer.step >= cfg.train.iterations:
        trainer.cfg.train.iterations = trainer.step + 1000
    return trainer


def worker(args) -> dict:
    import numpy as np
    import torch

    import signsplat
    from signsplat.device import set_threads

    code = Path(args.code).resolve()
    where = Path(signsplat.__file__).resolve()
    if code not in where.parents:
        raise SystemExit(f"signsplat imported from {where}, not from {code}: set PYTHONPATH")
    set_threads(args.threads)
    trainer = build_trainer(code, Path(args.results).resolve(), args.scene, args.points,
                            json.loads(args.config_json))
    for _ in range(args.warmup):
        trainer.train_step()
    plain, plain_cpu, parts, inst_total = [], [], [], []
    for _ in range(args.steps):
        t0, c0 = time.perf_counter(), time.process_time()
        trainer.train_step()
        plain.append(time.perf_counter() - t0)
        plain_cpu.append(time.process_time() - c0)
        rec = Recorder()
        inst = Instrument(trainer, rec)
        try:
            t0, c0 = time.perf_counter(), time.process_time()
            trainer.train_step()
            total, total_cpu = time.perf_counter() - t0, time.process_time() - c0
        finally:
            inst.remove()
        inst_total.append(total)
        row = {f"{k}:{ph}": v for (k, ph), v in rec.seconds.items()}
        row["other:total"] = total - sum(rec.seconds.values())
        row.update({f"cpu|{k}:{ph}": v for (k, ph), v in rec.cpu.items()})
        row["cpu|other:total"] = total_cpu - sum(rec.cpu.values())
        parts.append(row)
    # one densification event (prune + grow) at the end
    st, state = trainer.strategy, trainer.strategy_state
    n = trainer.model.num_points
    gen = torch.Generator().manual_seed(2)
    state["grad2d"], state["count"] = torch.rand(n, generator=gen) * 1e-3, torch.ones(n)
    step = (st.refine_stop // st.refine_every) * st.refine_every
    t0 = time.perf_counter()
    stats = st.step_post_backward(trainer.model, trainer.optimizer, state, step, [])
    event = time.perf_counter() - t0
    keys = sorted({k for r in parts for k in r})
    med = {k: float(np.median([r.get(k, 0.0) for r in parts])) for k in keys}
    return {
        "code": str(code), "points": int(n), "threads": args.threads,
        "step": float(np.median(plain)), "step_min": float(np.min(plain)),
        "step_cpu": float(np.median(plain_cpu)),
        "steps": [float(x) for x in plain], "instrumented": float(np.median(inst_total)),
        "parts": med, "densify_event": event, "densify_event_stats": stats,
        "refine_every": st.refine_every,
    }


# ----------------------------------------------------------------------------- driver
def git_commit(path: Path) -> str:
    try:
        out = subprocess.run(["git", "-C", str(path), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(path), "status", "--porcelain", "--",
                                "signsplat"], capture_output=True, text=True).stdout.strip()
        return out + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def start_worker(code: Path, args, points: int, threads: int,
                 extra: dict | None = None) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(code))
    config = json.loads(args.config_json)
    if extra:
        from signsplat.config import deep_merge

        config = deep_merge(config, extra)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--code", str(code),
           "--results", str(Path(args.results).resolve()), "--scene", args.scene,
           "--points", str(points), "--threads", str(threads), "--steps", str(args.steps),
           "--warmup", str(args.warmup), "--config-json", json.dumps(config)]
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=str(code))


def finish_worker(proc: subprocess.Popen) -> dict:
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"worker failed ({' '.join(proc.args[2:])}):\n{err[-4000:]}")
    return json.loads(out.strip().splitlines()[-1])


def summarise(rows: list[dict]):
    import numpy as np
    import pandas as pd

    recs = []
    for r in rows:
        base = dict(code=r["label"], commit=r["commit"], points=r["points_asked"],
                    n_points=r["points"], threads=r["threads"], round=r["round"])
        recs.append(dict(base, part="step", phase="total", seconds=r["step"],
                         cpu_seconds=r["step_cpu"]))
        recs.append(dict(base, part="instrumented_step", phase="total",
                         seconds=r["instrumented"]))
        recs.append(dict(base, part="densify_event", phase="total", seconds=r["densify_event"]))
        by_part: dict[str, list[float]] = {}
        for key, v in r["parts"].items():
            if key.startswith("cpu|"):
                continue
            part, phase = key.split(":")
            cpu = r["parts"].get(f"cpu|{key}", float("nan"))
            recs.append(dict(base, part=part, phase=phase, seconds=v, cpu_seconds=cpu))
            acc = by_part.setdefault(part, [0.0, 0.0])
            acc[0] += v
            acc[1] += cpu
        for part, (v, cpu) in by_part.items():
            if part != "other":
                recs.append(dict(base, part=part, phase="total", seconds=v, cpu_seconds=cpu))
    per_round = pd.DataFrame(recs)
    keys = ["code", "commit", "points", "threads", "part", "phase"]
    agg = per_round.groupby(keys, sort=False).agg(
        seconds=("seconds", "median"), seconds_min=("seconds", "min"),
        cpu_seconds=("cpu_seconds", "median"), rounds=("seconds", "size"),
        n_points=("n_points", "median")).reset_index()
    agg["n_points"] = agg["n_points"].astype(np.int64)
    return per_round, agg


def print_table(agg, labels: list[str], column: str = "seconds") -> list[str]:
    lines = [f"{'wall-clock' if column == 'seconds' else 'process CPU'} milliseconds"]
    configs = agg[["points", "threads"]].drop_duplicates().sort_values(["points", "threads"])
    order = ["step", "instrumented_step"] + [p for p in PARTS] + ["densify_event"]
    for _, (pts, thr) in configs.iterrows():
        sub = agg[(agg.points == pts) & (agg.threads == thr)]
        npts = int(sub.n_points.max())
        head = f"{npts} points, {thr} thread(s)"
        lines.append(head)
        cols = "".join(f"{lab + ' fwd':>14}{lab + ' bwd':>14}{lab + ' all':>14}"
                       for lab in labels)
        base = "baseline" if "baseline" in labels else None
        others = [lab for lab in labels if lab != base] if base else []
        ratio = "".join(f"{'base/' + lab:>16}" for lab in others)
        lines.append(f"  {'part':<20}{cols}{ratio}")
        for part in order:
            cells, totals = "", {}
            present = False
            for lab in labels:
                s = sub[(sub.code == lab) & (sub.part == part)].set_index("phase")[column]
                f = s.get("forward", float("nan"))
                b = s.get("backward", float("nan"))
                t = s.get("total", float("nan"))
                present |= bool(len(s))
                totals[lab] = t
                cells += "".join(f"{x * 1e3:14.1f}" if x == x else f"{'-':>14}" for x in (f, b, t))
            if not present:
                continue
            r = ""
            for lab in others:
                t = totals[lab]
                r += f"{totals[base] / t:16.2f}" if t == t and t > 0 else f"{'-':>16}"
            lines.append(f"  {part:<20}{cells}{r}")
    lines.append("(milliseconds; median over rounds of each round's median step; parts exclusive "
                 "of nested ones; 'other' = instrumented step minus the parts)")
    for ln in lines:
        print(ln)
    return lines


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--results", default=str(ROOT / "results"))
    ap.add_argument("--scene", default="studio6")
    ap.add_argument("--points", type=int, nargs="+", default=[57000, 90000])
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=4, help="timed steps of each kind per process")
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--baseline", default=None, help="another checkout to compare against")
    ap.add_argument("--config-json", default="{}", help="avatar config overrides (both codes)")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=JSON",
                    help="also run this checkout with these config overrides (repeatable)")
    ap.add_argument("--side-by-side", action="store_true",
                    help="run the codes' workers of a configuration at the same time (each "
                    "with its threads: 1 thread each for two codes on 2 cores), so that both "
                    "meet the same machine; without it they run one after the other")
    ap.add_argument("--out", default=str(OUT / "avatar_step.parquet"))
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--code", default=str(ROOT), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        args.points, args.threads = args.points[0], args.threads[0]
        print(json.dumps(worker(args)))
        return 0

    codes = [("current", ROOT)]
    extras: dict[str, dict] = {}
    for v in args.variant:
        name, _, cfg = v.partition("=")
        codes.append((name, ROOT))
        extras[name] = json.loads(cfg)
    if args.baseline:
        codes.append(("baseline", Path(args.baseline).resolve()))
    commits = {lab: git_commit(path) + (f" {json.dumps(extras[lab])}" if lab in extras else "")
               for lab, path in codes}
    load_before = os.getloadavg()
    print(f"avatar step benchmark: {platform.machine()}, {os.cpu_count()} cores, load "
          f"{load_before[0]:.1f}; codes " + ", ".join(f"{lab} {commits[lab]} ({path})"
                                                   for lab, path in codes), flush=True)
    rows = []
    t_start = time.time()
    for rnd in range(args.rounds):
        for pts in args.points:
            for thr in args.threads:
                order = codes if rnd % 2 == 0 else codes[::-1]
                if args.side_by_side:
                    procs = [start_worker(path, args, pts, thr, extras.get(lab))
                             for lab, path in order]
                    done = [finish_worker(p) for p in procs]
                else:
                    done = [finish_worker(start_worker(path, args, pts, thr, extras.get(lab)))
                            for lab, path in order]
                for (lab, path), r in zip(order, done):
                    r.update(label=lab, commit=commits[lab], points_asked=pts, round=rnd)
                    rows.append(r)
                    print(f"  round {rnd} {lab:<8} {r['points']} points {thr} thread(s): step "
                          f"{r['step'] * 1e3:.0f} ms (min {r['step_min'] * 1e3:.0f}), "
                          f"instrumented {r['instrumented'] * 1e3:.0f} ms, load "
                          f"{os.getloadavg()[0]:.1f}", flush=True)
    per_round, agg = summarise(rows)
    lines = print_table(agg, [lab for lab, _ in codes])
    lines += print_table(agg, [lab for lab, _ in codes], "cpu_seconds")
    load_after = os.getloadavg()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    agg["date"] = time.strftime("%Y-%m-%d %H:%M")
    agg.to_parquet(out, index=False)
    summary = {
        "date": time.strftime("%Y-%m-%d %H:%M"), "machine": f"{platform.machine()} "
        f"{os.cpu_count()} cores", "load_before": load_before, "load_after": load_after,
        "minutes": (time.time() - t_start) / 60, "side_by_side": args.side_by_side,
        "codes": {lab: {"path": str(p), "commit": commits[lab]} for lab, p in codes},
        "args": {k: v for k, v in vars(args).items() if k not in ("worker", "code")},
        "table": lines,
    }
    with open(out.with_suffix(".json"), "w") as f:
        json.dump(summary, f, indent=1)
    print(f"wrote {out} and {out.with_suffix('.json')} (load {load_before[0]:.1f} -> "
          f"{load_after[0]:.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
