"""Real workflow runs shared by the test modules that need one: a session-wide run of two tiny
sequences end to end (computed once, even across make test's workers), and the helpers it is
built from. The cluster tests compare their SLURM run against it; the workflow and batch tests
start from its outputs, so each runs only what it is about."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import subprocess
import sys
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]


@contextlib.contextmanager
def locked(path: Path):
    """An exclusive lock on ``path`` (made if missing) while the block runs."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        yield


def shared_once(tmp_path_factory, name: str, make):
    """``make(folder) -> JSON-able value``, computed once per test session even with
    pytest-xdist workers (the others wait and reuse it)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of one session
    done = root / f"{name}.json"
    with locked(root / f"{name}.lock"):
        if not done.exists():
            try:
                value = {"value": make(root / name)}
            except Exception as exc:  # noqa: BLE001 - kept for the other workers, re-raised
                value = {"error": f"{type(exc).__name__}: {exc}"}
                done.write_text(json.dumps(value))
                raise
            done.write_text(json.dumps(value))
    value = json.loads(done.read_text())
    if "error" in value:
        raise AssertionError(f"{name} failed in another test process: {value['error']}")
    return value["value"]


def snakemake(*args, timeout=1800, env=None, **kw):
    """``python -m snakemake --nolock *args`` from the repository root, output captured."""
    cmd = [sys.executable, "-m", "snakemake", "--nolock", *args]
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env=env, **kw)


#: Threads of the tiny runs' jobs, the same in the local run and the SLURM run (the cluster
#: tests compare their outputs bit for bit, which holds only at equal thread counts): one, so
#: that two jobs run at once on two CPUs, but two for the fit, so that a job asking for more
#: than one CPU is still among them.
TINY_THREADS = ["--set-threads", "simulate=1", "segment=1", "detect_keypoints=1",
                "perception_eval=1", "fit_smplx=2", "train_avatar=1", "evaluate_avatar=1",
                "stitch_video=1"]


def proxy_body(tmp_path_factory) -> Path:
    """The procedural proxy body (seed 0) in the official SMPL-X layout, written once per test
    session for all of make test's workers."""
    def write(folder: Path) -> str:
        from signsplat.body.proxy import write_proxy_model

        folder.mkdir(parents=True, exist_ok=True)
        write_proxy_model(folder / "body.npz", seed=0)
        return str(folder / "body.npz")

    return Path(shared_once(tmp_path_factory, "proxy_body", write))


def tiny_config(work: Path, name: str = "config.yaml", body: Path | None = None,
                single_view: bool = True) -> Path:
    """Two tiny sequences end to end: `tiny` (config/scenes/tiny.yaml: 2 views x 4 frames) and
    `tiny1` (1 view, another body, appearance, gloss and seed: the single-view fit), with the
    smallest fit, avatar (4 steps) and stitching settings; results and report under ``work``.
    With ``body`` (the session's proxy body file) the body_model rule checks and copies that
    file, as for a user's SMPL-X file, instead of building the same proxy again. Without
    ``single_view``, `tiny` alone (its outputs are the same as in the run of both)."""
    spec = yaml.safe_load((ROOT / "config" / "scenes" / "tiny.yaml").read_text())
    spec.update(seed=11, cameras={**spec["cameras"], "count": 1},
                signer={"betas": [-0.3, 0.2] + [0.0] * 8, "appearance_seed": 3},
                motion={**spec["motion"], "glosses": ["SCHOOL"]})
    (work / "tiny1.yaml").write_text(yaml.safe_dump(spec))
    (work / "sequences.tsv").write_text(
        "sequence\tsource\tspec\n"
        + (f"tiny1\tsynthetic\t{work / 'tiny1.yaml'}\n" if single_view else ""))
    cfg = {
        "results": str(work / "results"), "sequences": str(work / "sequences.tsv"),
        "scenes": ["tiny"],
        "fit": yaml.safe_load((ROOT / "config" / "fit_few_steps.yaml").read_text())["fit"],
        "avatar": {"upsample": {"max_rounds": 0},
                   "train": {"iterations": 4, "test_interval": 2, "test_offset": 1,
                             "log_every": 2, "checkpoint_every": 50},
                   "eval": {"refine_steps": 0, "save_images": 2},
                   "strategy": {"refine_start": 1, "refine_every": 2, "refine_stop": 4}},
        "stitch": {"sentences": ["Why are you sad?"], "size": 64},
        "report": {"html": str(work / "report" / "index.html")},
    }
    if body is not None:
        cfg["body_model"] = {"path": str(body)}
    path = work / name
    path.write_text(yaml.safe_dump(cfg))
    return path


def _local_run(work: Path, body: Path) -> dict:
    work.mkdir(parents=True, exist_ok=True)
    cfg = tiny_config(work, body=body)
    res = snakemake("--cores", "2", *TINY_THREADS, "--configfile", str(cfg))
    assert res.returncode == 0, (res.stdout + res.stderr)[-6000:]
    return {"work": str(work)}


def tiny_local_run(tmp_path_factory) -> Path:
    """The folder of the two tiny sequences' local run (``config.yaml``, ``results/``,
    ``report/``), made once per test session. Tests must not write into it: copy
    ``results`` (with its times, ``shutil.copytree``) and point a config at the copy."""
    body = proxy_body(tmp_path_factory)
    return Path(shared_once(tmp_path_factory, "local_run",
                            lambda work: _local_run(work, body))["work"])
