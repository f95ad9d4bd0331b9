"""Run-to-run reproducibility of avatar training (issue 6: "deterministic with a seed on the CPU").

Trains the same configuration several times, each in its own process (``signsplat
train-avatar``), on a finished sequence's fitted inputs, and compares the checkpoints entry by
entry: model, SMPL-X, optimiser moments, densification state, sampler and RNG state, and the
loss log. Bit-identical runs print ``identical``; otherwise the differing entries and the first
logged step whose loss differs. Each run's training seconds are printed beside the verdict.

    .venv/bin/python benchmarks/check_reproducible.py --steps 300 --threads 2 [--at-once]

``--at-once`` starts the runs together (they share the cores, so their thread timing differs
from a run alone); without it they run one after the other. The verdict and times are saved to
``benchmarks/results/reproducibility.json``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from signsplat.io.atomic import atomic_path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "benchmarks" / "results"


def differing_entries(a, b, path: str = "") -> list[str]:
    """Paths of the entries where two checkpoint states differ (timings are not compared)."""
    if isinstance(a, dict) and isinstance(b, dict):
        keys = sorted(set(a) | set(b), key=str)
        return [p for k in keys if k != "seconds"
                for p in differing_entries(a.get(k), b.get(k), f"{path}.{k}")]
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return [f"{path} (length {len(a)} vs {len(b)})"]
        return [p for i, (x, y) in enumerate(zip(a, b))
                for p in differing_entries(x, y, f"{path}[{i}]")]
    if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
        same = (isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor)
                and a.shape == b.shape and a.dtype == b.dtype and torch.equal(a, b))
        return [] if same else [path]
    return [] if a == b else [path]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", default="results", help="the workflow's results folder")
    p.add_argument("--scene", default="studio6")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--runs", type=int, default=2)
    p.add_argument("--at-once", action="store_true", help="start the runs together")
    args = p.parse_args()
    if args.runs < 2 or args.steps < 1 or args.threads < 1:
        p.error("--runs must be at least 2, --steps and --threads at least 1")

    res = ROOT / args.results
    seq = res / args.scene
    inputs = {"--body": res / "_assets" / "body_model.npz",
              "--frames": seq / "sim" / "frames.parquet",
              "--cameras": seq / "fit" / "cameras_fit.parquet",
              "--smplx": seq / "fit" / "smplx_fit.parquet"}
    missing = [str(f) for f in inputs.values() if not f.exists()]
    if missing:
        sys.exit(f"missing inputs (run the workflow for {args.scene!r} first): {missing}")
    cfg = json.dumps({"train": {"iterations": args.steps}})
    with tempfile.TemporaryDirectory(prefix="signsplat-repro-") as tmp:
        outs = [Path(tmp) / f"run{i}" for i in range(args.runs)]
        cmds = [[sys.executable, "-m", "signsplat", "train-avatar",
                 *[x for k, v in inputs.items() for x in (k, str(v))],
                 "--config-json", cfg, "--variant", "repro", "--out", str(o), "--no-progress",
                 "--threads", str(args.threads)]
                for o in outs]
        t0 = time.perf_counter()
        if args.at_once:
            procs = [subprocess.Popen(c, cwd=ROOT, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.PIPE, text=True) for c in cmds]
            errs = [pr.communicate()[1] for pr in procs]
            codes = [pr.returncode for pr in procs]
        else:
            done = [subprocess.run(c, check=False, cwd=ROOT, capture_output=True, text=True)
                    for c in cmds]
            errs, codes = [d.stderr for d in done], [d.returncode for d in done]
        wall = time.perf_counter() - t0
        for code, err in zip(codes, errs):
            if code:
                sys.exit(f"a training run failed ({code}):\n{err[-2000:]}")
        states = [torch.load(o / "checkpoint.pt", map_location="cpu", weights_only=False)
                  for o in outs]
    ref = states[0]
    report = {"scene": args.scene, "steps": args.steps, "threads": args.threads,
              "runs": args.runs, "at_once": args.at_once, "wall_seconds": round(wall, 1),
              "train_seconds": [round(s["seconds"], 1) for s in states], "comparisons": []}
    for i, s in enumerate(states[1:], start=1):
        diff = differing_entries(ref, s)
        first = next((a["step"] for a, b in zip(ref["log"], s["log"]) if a["loss"] != b["loss"]),
                     None)
        report["comparisons"].append({"runs": [0, i], "identical": not diff,
                                      "differing_entries": diff[:50],
                                      "first_logged_step_with_other_loss": first})
        verdict = "identical" if not diff else f"{len(diff)} entries differ, e.g. {diff[:5]}"
        print(f"run 0 vs run {i}: {verdict}"
              + (f"; losses part at logged step {first}" if first is not None else ""))
    print(f"{args.runs} runs of {args.steps} steps at {args.threads} threads "
          f"({'at once' if args.at_once else 'one after the other'}): training "
          + ", ".join(f"{t:.0f} s" for t in report["train_seconds"]) + f"; {wall:.0f} s wall")
    OUT.mkdir(parents=True, exist_ok=True)
    with atomic_path(OUT / "reproducibility.json") as tmp:
        tmp.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
