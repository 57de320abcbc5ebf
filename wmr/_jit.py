"""The one JIT decorator of wmr.

Every numerical kernel of the closed loop is compiled with numba (DESIGN §6: a jitted step is
~100x faster than the same numpy code).  Kernels are cached on disk, so a process pays
compilation only the first time.  Set ``NUMBA_DISABLE_JIT=1`` to debug them as plain Python.

numba's cache checks only the timestamp of a function's own file, not of the jitted functions it
calls in other modules, so a cached kernel could outlive a change to one of its callees.  Unless
``NUMBA_CACHE_DIR`` is set by the user, wmr's kernels therefore cache in a folder named by a hash
of the whole package's source (:data:`CACHE_DIR`): any change to ``wmr`` starts from a fresh cache.
That folder is wmr's alone: a cache locator (:class:`_WmrLocator`) claims the functions whose source
file lies inside the package and no others, so numba's settings -- and every other library's cache
-- stay as they were (``numba.config.CACHE_DIR`` is not touched).  Kernels built around a law from
outside the package (a plugin) carry a digest of that law's source in their names
(``wmr.closedloop.step.law_digest``).  Nothing is pruned behind the user's back: ``wmr cache
--prune`` removes the folders of earlier versions of the source.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numba
from numba.core.caching import CacheImpl, _CacheLocator, _SourceFileBackedLocatorMixin

__all__ = ["njit", "CACHE_DIR", "KEEP_OLD_CACHES", "prune_old_caches", "source_digest"]

_PACKAGE = Path(__file__).resolve().parent


def source_digest(package: Path | None = None) -> str:
    """A hash of every ``*.py`` source of the package (16 hex digits): what its results and
    compiled kernels depend on."""
    package = package or Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def _cache_dir(package: Path | None = None) -> str:
    """``NUMBA_CACHE_DIR`` if set, else ``<package>/__pycache__/numba-<hash of its sources>``."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return os.environ["NUMBA_CACHE_DIR"]
    package = package or Path(__file__).resolve().parent
    return str(package / "__pycache__" / f"numba-{source_digest(package)}")


#: Caches of earlier versions of the source kept beside the current one (the newest first).
KEEP_OLD_CACHES = 3


def prune_old_caches(current: str | None = None, keep: int = KEEP_OLD_CACHES) -> list[Path]:
    """Remove all but the ``keep`` most recently modified ``numba-*`` folders other than
    ``current`` (each edit of the source leaves one behind; only the package's own folder is
    touched, never a user-set ``NUMBA_CACHE_DIR``); returns the removed folders.  Errors are
    ignored: another process may be pruning too.  Run by ``wmr cache --prune`` (never at import
    or at a command's start); a no-op when the user set ``NUMBA_CACHE_DIR``."""
    if current is None:
        if os.environ.get("NUMBA_CACHE_DIR"):
            return []
        current = CACHE_DIR
    here = Path(current)
    try:
        old = [p for p in here.parent.glob("numba-*") if p.is_dir() and p != here]
        old.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return []
    for path in old[keep:]:
        shutil.rmtree(path, ignore_errors=True)
    return old[keep:]


CACHE_DIR = _cache_dir()


class _WmrLocator(_SourceFileBackedLocatorMixin, _CacheLocator):
    """numba's cache locator for wmr's own functions (source file inside the package): their
    cache lives under :data:`CACHE_DIR`, mirroring the package's folders.  Other functions are
    not claimed (``from_function`` returns None) and go to numba's own locators; with
    ``NUMBA_CACHE_DIR`` set by the user, numba's own locator serves wmr too."""

    def __init__(self, py_func, py_file):
        self._py_file = py_file
        self._lineno = py_func.__code__.co_firstlineno
        rel = Path(py_file).resolve().parent.relative_to(_PACKAGE)
        self._cache_path = os.path.join(CACHE_DIR, str(rel))

    def get_cache_path(self):
        return self._cache_path

    @classmethod
    def from_function(cls, py_func, py_file):
        if os.environ.get("NUMBA_CACHE_DIR"):
            return None
        try:
            Path(py_file).resolve().relative_to(_PACKAGE)
        except (ValueError, OSError):
            return None
        return super().from_function(py_func, py_file)


if _WmrLocator not in CacheImpl._locator_classes:
    CacheImpl._locator_classes = [_WmrLocator, *CacheImpl._locator_classes]


def njit(fn=None, **kwargs):
    """``numba.njit`` with on-disk caching and strict IEEE semantics (no fastmath).

    Use as ``@njit`` or ``@njit(...)``.
    """
    kwargs.setdefault("cache", True)
    kwargs.setdefault("fastmath", False)
    kwargs.setdefault("error_model", "numpy")
    if fn is None:
        return lambda f: numba.njit(**kwargs)(f)
    return numba.njit(**kwargs)(fn)
