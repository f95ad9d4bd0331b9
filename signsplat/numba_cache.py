"""Where Numba keeps the on-disk compile cache of signsplat's CPU kernels (``cache=True``).

Compiling the kernels takes a minute or two, so the cache matters. Numba's default places it in
the package's ``__pycache__`` (lost with every fresh clone) or in a per-user directory keyed
by the source's absolute path (lost when the checkout moves). A kernel module calls
:func:`cache_kernels_of` before its first ``@njit``; its kernels are then cached by *content*:

- directory: ``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/signsplat/numba`` (default
  ``~/.cache/signsplat/numba``); if that cannot be written, the package's own ``__pycache__``
  (the in-tree cache, when the package directory is writable), else a directory under the
  system temp dir. When the package directory is not writable and nothing else is either,
  ``NUMBA_CACHE_DIR`` is pointed at the temp directory so Numba still caches.
- inside it, a subdirectory per hash of the kernel module, the files it names as its
  dependencies (the rasterizer's shared formulas and constants), this file and the Numba
  version, so two checkouts of different versions never evict each other and any edit of the
  kernels or what they depend on recompiles. Subdirectories unused for 30 days are removed.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import tempfile
import time
from pathlib import Path

import numba
from numba.core import caching

_PKG_DIR = Path(__file__).resolve().parent  # the in-tree fallback is under signsplat/
_MAX_AGE_DAYS = 30


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


def _stamp(files) -> str:
    h = hashlib.sha256(numba.__version__.encode())
    for path in files:
        h.update(Path(path).name.encode())
        h.update(Path(path).read_bytes())
    return h.hexdigest()[:20]


def _candidate_roots() -> list[Path]:
    roots = []
    if os.environ.get("NUMBA_CACHE_DIR"):
        roots.append(Path(os.environ["NUMBA_CACHE_DIR"]) / "signsplat")
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    roots.append(Path(base) / "signsplat" / "numba")
    roots.append(_PKG_DIR / "__pycache__" / "numba")
    roots.append(Path(tempfile.gettempdir()) / f"signsplat-numba-{os.getuid()}")
    return roots


def _prune(root: Path, keep: Path) -> None:
    cutoff = time.time() - _MAX_AGE_DAYS * 86400
    try:
        for d in root.iterdir():
            if d.is_dir() and d != keep and d.stat().st_mtime < cutoff:
                shutil.rmtree(d, ignore_errors=True)
    except OSError:
        pass


def _choose_dir(stamp: str) -> Path | None:
    for root in _candidate_roots():
        path = root / stamp
        if _writable(path):
            os.utime(path)  # marks it as used, for pruning
            _prune(root, path)
            return path
    return None


# resolved kernel module -> its cache directory (named by its source stamp)
_FILES: dict[Path, Path] = {}


def cache_kernels_of(py_file: str | os.PathLike, *depends: str | os.PathLike) -> Path | None:
    """Cache the ``cache=True`` kernels defined in ``py_file`` by content: in a directory of
    their own (returned; None when nothing is writable and Numba's own fallbacks apply),
    recompiled when ``py_file``, one of ``depends`` (files whose edits must recompile its
    kernels too) or this module changes. Call it at the top of the kernel module, before its
    first ``@njit``."""
    stamp = _stamp([Path(py_file), *map(Path, depends), Path(__file__)])
    path = _choose_dir(stamp)
    if path is not None:
        _FILES[Path(py_file).resolve()] = path
    elif not os.environ.get("NUMBA_CACHE_DIR"):  # pragma: no cover
        # nothing writable found for our locator: let Numba's own fallbacks try a temp dir
        tmp = Path(tempfile.gettempdir()) / f"numba-cache-{os.getuid()}"
        if _writable(tmp):
            os.environ["NUMBA_CACHE_DIR"] = str(tmp)
            numba.config.CACHE_DIR = str(tmp)
    return path


class ContentCacheLocator(caching._CacheLocator):
    """Numba cache locator for the registered kernel files (see the module docstring)."""

    def __init__(self, py_func, py_file, cache_path: Path):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = cache_path

    def get_cache_path(self):
        return str(self._cache_path)

    def get_source_stamp(self):
        return self._cache_path.name  # the folder is named by the sources' hash

    def get_disambiguator(self):
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        try:
            cache_path = _FILES.get(Path(py_file).resolve())
        except OSError:
            return None
        if cache_path is None:
            return None
        self = cls(py_func, py_file, cache_path)
        try:
            self.ensure_cache_path()
        except OSError:
            return None
        return self


if ContentCacheLocator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, ContentCacheLocator)
