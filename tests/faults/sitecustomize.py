"""Test-only hooks for workflow runs (never imported by the library): fault injection, and
faster SLURM status checks.

A test puts this folder on PYTHONPATH and sets ``SIGNSPLAT_TEST_FAULT``; Python then imports
this module at start-up in every process of the run (Snakemake, SLURM job steps, the stage
commands). It acts only in the stage process it names, ``python -m signsplat <stage> ...``
whose command line contains ``match``; everywhere else it does nothing.

    SIGNSPLAT_TEST_FAULT="<action>:<stage>:<match>:<after>"
    SIGNSPLAT_TEST_FAULT_DIR=<folder the test controls>

Stages write every file atomically (temporary file, then ``os.replace``), so the number of
renames is the number of files a stage has finished. On the rename that would finish file
``after + 1`` the hook acts, mid-stage, with ``after`` files complete and one temporary file
on disk:

- ``fail-once``: writes ``<dir>/reached`` and ``<dir>/failed`` and exits at once with status
  17 (a crash: no clean-up). With ``<dir>/failed`` present it does nothing, so a retry runs
  clean.
- ``block``: writes ``<dir>/reached`` and waits until ``<dir>/release`` exists (a stage that
  hangs until the test kills, cancels or releases it; when the process is told to stop, the
  write is abandoned and the process ends).

``reached`` is JSON: the stage's pid, ``SLURM_JOB_ID`` (when in a SLURM job) and the files
finished so far.

``SIGNSPLAT_TEST_STATUS_CHECK_MAX=<seconds>`` caps the wait between two status checks of
snakemake-executor-plugin-slurm. The plugin waits 10 s longer after every check that finds no
job finished (up to 180 s): right for a cluster of hour-long jobs, but a test's jobs last
seconds and each would be noticed up to twice its own time late. Only when Snakemake looks
changes; what runs, and how SLURM runs it, does not.
"""

import os
import sys

_SPEC = os.environ.get("SIGNSPLAT_TEST_FAULT")
_STATUS_CHECK_MAX = os.environ.get("SIGNSPLAT_TEST_STATUS_CHECK_MAX")
SLURM_PLUGIN = "snakemake_executor_plugin_slurm"


def cap_status_checks(executor: type, seconds: float) -> None:
    """Make ``executor``'s wait before its next status check at most ``seconds``."""
    wait = executor.next_seconds_between_status_checks  # the base class's property

    def capped(self, value):
        wait.fset(self, value if value is None else min(value, seconds))

    executor.next_seconds_between_status_checks = property(wait.fget, capped)


def _cap_when_imported(seconds: float) -> None:
    """Cap the SLURM plugin's status-check wait as soon as Snakemake imports the plugin."""
    import importlib.abc
    import importlib.util

    class Finder(importlib.abc.MetaPathFinder):
        def find_spec(self, fullname, path, target=None):
            if fullname != SLURM_PLUGIN:
                return None
            sys.meta_path.remove(self)
            spec = importlib.util.find_spec(fullname)
            if spec is None or spec.loader is None:
                return spec
            load = spec.loader.exec_module

            def exec_module(module):
                load(module)
                cap_status_checks(module.Executor, seconds)

            spec.loader.exec_module = exec_module
            return spec

    sys.meta_path.insert(0, Finder())


def _install(spec: str) -> None:
    import json
    import signal
    import threading
    import time
    from pathlib import Path

    action, stage, match, after = spec.split(":", 3)
    argv = getattr(sys, "orig_argv", [])
    if argv[1:4] != ["-m", "signsplat", stage] or match not in " ".join(argv):
        return
    folder = Path(os.environ["SIGNSPLAT_TEST_FAULT_DIR"])
    if action == "fail-once" and (folder / "failed").exists():
        return
    after = int(after)
    # A blocked write may sit in a worker thread while the main thread, told to stop
    # (SIGTERM), waits for that thread: note the signal, whoever handles it, so that the
    # blocked write gives up as a real one would end.
    stopping = threading.Event()
    real_signal = signal.signal

    def noting(handler):
        def handle(signum, frame):
            stopping.set()
            if callable(handler):
                return handler(signum, frame)
            raise SystemExit(128 + signum)
        return handle

    def signal_hook(signum, handler):
        if signum == signal.SIGTERM and handler not in (signal.SIG_IGN,):
            handler = noting(handler)
        return real_signal(signum, handler)

    signal.signal = signal_hook
    real_signal(signal.SIGTERM, noting(None))
    done: list[str] = []
    busy = [False]  # the hook's own rename is not counted
    fired = [False]

    def hook(event, args):
        if event != "os.rename" or busy[0]:
            return
        busy[0] = True
        try:
            if fired[0] or len(done) < after:
                done.append(str(args[1]))
                return
            folder.mkdir(parents=True, exist_ok=True)
            info = {"pid": os.getpid(), "slurm_job_id": os.environ.get("SLURM_JOB_ID"),
                    "written": done}
            tmp = folder / f".reached.{os.getpid()}"
            tmp.write_text(json.dumps(info))
            os.replace(tmp, folder / "reached")
            fired[0] = True
            if action == "fail-once":
                (folder / "failed").write_text("")
                os._exit(17)
            while not (folder / "release").exists():
                if stopping.is_set():
                    raise SystemExit(143)
                time.sleep(0.1)
            done.append(str(args[1]))
        finally:
            busy[0] = False

    sys.addaudithook(hook)


if _SPEC:
    _install(_SPEC)
if _STATUS_CHECK_MAX:
    _cap_when_imported(float(_STATUS_CHECK_MAX))
