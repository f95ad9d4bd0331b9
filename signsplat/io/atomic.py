"""Atomic file writes: write to a temporary file in the target folder, then rename.

A crash or a kill mid-write leaves the old file (or nothing), never a half-written one; its
temporary file stays behind (readers skip it: :func:`is_temporary`) until the next write of
the same file removes it.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

# folder -> {target name: temporaries found there} (listed once per folder and process)
_STALE: dict[Path, dict[str, list[Path]]] = {}


def _file_mode() -> int:
    """The mode a plain ``open(path, 'w')`` would give a new file under the process umask."""
    mask = os.umask(0o022)
    os.umask(mask)
    return 0o666 & ~mask


_MODE = _file_mode()  # read once, at import: setting the umask is process-wide


def _temporary_target(name: str) -> str | None:
    """The target name of a temporary ``.<name>.<random>.tmp<suffix>``, else None."""
    if not (name.startswith(".") and ".tmp" in name):
        return None
    stem = name[1:name.rindex(".tmp")]
    return stem.rsplit(".", 1)[0] if "." in stem else None


def _remove_stale(path: Path) -> None:
    """Remove the temporaries a killed writer of ``path`` left (one writer per file: any
    temporary of ``path`` that exists before this write is a leftover). The folder is listed
    once per process; temporaries made later by this process are not in that listing."""
    folder = path.parent
    if folder not in _STALE:
        found: dict[str, list[Path]] = {}
        with os.scandir(folder) as entries:
            for e in entries:
                target = _temporary_target(e.name)
                if target is not None:
                    found.setdefault(target, []).append(Path(e.path))
        _STALE[folder] = found
    for stale in _STALE[folder].pop(path.name, []):
        with contextlib.suppress(FileNotFoundError):
            stale.unlink()


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success rename it onto ``path``.

    The temporary name keeps the target's suffix (``suffix`` overrides it) so that writers
    which pick a format from the extension (OpenCV, pyarrow, numpy) still work. On any
    exception the temporary file is removed and ``path`` is left untouched. Temporaries of
    ``path`` left by a writer that was killed are removed first.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale(path)
    fd, tmp = tempfile.mkstemp(
        prefix=f".{path.name}.", suffix=".tmp" + (suffix if suffix is not None else path.suffix),
        dir=path.parent,
    )
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        # mkstemp makes the file readable by its owner only; the result gets the mode any
        # new file gets (group members on a shared cluster read the results and reports)
        os.chmod(tmp_path, _MODE)
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def is_temporary(path: str | os.PathLike) -> bool:
    """True for a temporary file of :func:`atomic_path` (``.<name>.<random>.tmp<suffix>``): one
    a writer still holds, or one a process killed outright (SIGKILL) left behind. Readers that
    glob a folder skip these."""
    name = Path(path).name
    return name.startswith(".") and ".tmp" in name


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
