"""The one JIT decorator of wmr.

Every numerical kernel of the closed loop is compiled with numba (DESIGN §6: a jitted step is
~100x faster than the same numpy code).  Kernels are cached on disk, so a process pays
compilation only the first time.  Set ``NUMBA_DISABLE_JIT=1`` to debug them as plain Python.

numba's cache checks only the timestamp of a function's own file, not of the jitted functions it
calls in other modules, so a cached kernel could outlive a change to one of its callees.  Unless
``NUMBA_CACHE_DIR`` is set by the user, the cache therefore lives in a folder named by a hash of
the whole package's source: any change to ``wmr`` starts from a fresh cache.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numba

__all__ = ["njit", "CACHE_DIR", "KEEP_OLD_CACHES", "prune_old_caches", "source_digest"]


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


def prune_old_caches(current: str | None = None, keep: int = KEEP_OLD_CACHES) -> None:
    """Remove all but the ``keep`` most recently modified ``numba-*`` folders other than
    ``current`` (each edit of the source leaves one behind; only the package's own folder is
    touched, never a user-set ``NUMBA_CACHE_DIR``).  Errors are ignored: another process may
    be pruning too.  Called by the ``wmr`` command (never at import); a no-op when the user set
    ``NUMBA_CACHE_DIR``."""
    if current is None:
        if os.environ.get("NUMBA_CACHE_DIR"):
            return
        current = CACHE_DIR
    here = Path(current)
    try:
        old = [p for p in here.parent.glob("numba-*") if p.is_dir() and p != here]
        old.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    except OSError:
        return
    for path in old[keep:]:
        shutil.rmtree(path, ignore_errors=True)


CACHE_DIR = _cache_dir()
# the kernels of this package cache here (numba reads the setting when it first writes a cache)
numba.config.CACHE_DIR = CACHE_DIR


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
