"""Where Numba keeps the on-disk compile cache of the CPU kernels (``cache=True``).

Compiling the kernels takes a minute or two, so the cache matters. Numba's default places it in
``signsplat/render/__pycache__`` (lost with every fresh clone) or in a per-user directory keyed
by the source's absolute path (lost when the checkout moves). For the kernels of this package
we register a cache locator that is keyed by *content* instead:

- directory: ``$NUMBA_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/signsplat/numba`` (default
  ``~/.cache/signsplat/numba``); if that cannot be written, the package's own ``__pycache__``
  (the in-tree cache, when the package directory is writable), else a directory under the
  system temp dir. When the package directory is not writable and nothing else is either,
  ``NUMBA_CACHE_DIR`` is pointed at the temp directory so Numba still caches.
- inside it, a subdirectory per hash of the kernel sources (``_kernels.py``, ``_constants.py``
  and this file) and the Numba version, so two checkouts of different versions never evict
  each other and any edit of the kernels, their shared formulas (``_ewa.py``) or their
  constants recompiles. Subdirectories unused
  for 30 days are removed.
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

_PKG_DIR = Path(__file__).resolve().parent
_STAMP_FILES = ("_kernels.py", "_ewa.py", "_constants.py", "_numba_setup.py")
_MAX_AGE_DAYS = 30


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


def source_stamp() -> str:
    h = hashlib.sha256(numba.__version__.encode())
    for name in _STAMP_FILES:
        h.update(name.encode())
        h.update((_PKG_DIR / name).read_bytes())
    return h.hexdigest()[:20]


def _candidate_roots() -> list[Path]:
    roots = []
    if os.environ.get("NUMBA_CACHE_DIR"):
        roots.append(Path(os.environ["NUMBA_CACHE_DIR"]) / "signsplat-render")
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


def _choose_dir() -> Path | None:
    stamp = source_stamp()
    for root in _candidate_roots():
        path = root / stamp
        if _writable(path):
            os.utime(path)  # marks it as used, for pruning
            _prune(root, path)
            return path
    return None


CACHE_DIR: Path | None = _choose_dir()
_STAMP = source_stamp()


class RenderCacheLocator(caching._CacheLocator):
    """Numba cache locator for functions defined in this package (see the module docstring)."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        self._cache_path = str(CACHE_DIR)

    def get_cache_path(self):
        return self._cache_path

    def get_source_stamp(self):
        return _STAMP

    def get_disambiguator(self):
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        if CACHE_DIR is None:
            return None
        try:
            if Path(py_file).resolve().parent != _PKG_DIR:
                return None
        except OSError:
            return None
        self = cls(py_func, py_file)
        try:
            self.ensure_cache_path()
        except OSError:
            return None
        return self


if RenderCacheLocator not in caching.CacheImpl._locator_classes:
    caching.CacheImpl._locator_classes.insert(0, RenderCacheLocator)

if CACHE_DIR is None and not os.environ.get("NUMBA_CACHE_DIR"):  # pragma: no cover
    # nothing writable found for our locator: let Numba's own fallbacks try a temp dir
    _tmp = Path(tempfile.gettempdir()) / f"numba-cache-{os.getuid()}"
    if _writable(_tmp):
        os.environ["NUMBA_CACHE_DIR"] = str(_tmp)
        numba.config.CACHE_DIR = str(_tmp)
