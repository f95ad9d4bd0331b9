"""Test-only fault injection for workflow runs (never imported by the library).

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
"""

import os
import sys

_SPEC = os.environ.get("SIGNSPLAT_TEST_FAULT")


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
