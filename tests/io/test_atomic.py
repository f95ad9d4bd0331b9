"""Atomic writes: a killed writer leaves its temporary file; the next write of the same file
removes it, and leaves other files' temporaries alone."""

import signal
import subprocess
import sys

from signsplat.io.atomic import atomic_path, is_temporary, write_bytes_atomic

WRITER = """
import sys, time
from signsplat.io.atomic import atomic_path
with atomic_path(sys.argv[1]) as tmp:
    tmp.write_bytes(b"half")
    print("writing", flush=True)
    time.sleep(600)
"""


def _killed_writer(path):
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE,
                            text=True)
    assert proc.stdout.readline().strip() == "writing"
    proc.send_signal(signal.SIGKILL)
    assert proc.wait(timeout=30) == -signal.SIGKILL


def test_the_next_write_removes_what_a_killed_writer_left(tmp_path):
    target, other = tmp_path / "table.parquet", tmp_path / "other.png"
    _killed_writer(target)
    _killed_writer(other)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert len(left) == 2 and all(is_temporary(tmp_path / n) for n in left)
    assert not target.exists()
    write_bytes_atomic(target, b"whole")
    assert target.read_bytes() == b"whole"
    rest = [p for p in tmp_path.iterdir() if is_temporary(p)]
    assert [p.name for p in rest] == [n for n in left if n.startswith(".other.png.")]


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "a.txt"
    write_bytes_atomic(target, b"old")
    try:
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"new, half")
            raise RuntimeError("stop")
    except RuntimeError:
        pass
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_a_written_file_gets_the_mode_of_any_new_file(tmp_path):
    """Not the owner-only mode of the temporary file: colleagues on a shared cluster read the
    results and the reports. (Under a umask of 077 both are owner-only and this cannot fail.)"""
    import os

    from signsplat.io.atomic import _MODE

    write_bytes_atomic(tmp_path / "a.bin", b"x")
    with open(tmp_path / "plain.bin", "w"):
        pass
    assert os.stat(tmp_path / "a.bin").st_mode & 0o777 == \
        os.stat(tmp_path / "plain.bin").st_mode & 0o777 == _MODE
