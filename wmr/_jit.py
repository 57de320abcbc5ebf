"""The one JIT decorator of wmr.

Every numerical kernel of the closed loop is compiled with numba (DESIGN §6: a jitted step is
~100x faster than the same numpy code).  Kernels are cached on disk next to their module, so a
process pays compilation only the first time.  Set ``NUMBA_DISABLE_JIT=1`` to debug them as
plain Python.
"""

from __future__ import annotations

import numba

__all__ = ["njit"]


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
