"""Shared test oracles."""

from __future__ import annotations

import numpy as np


def central_fd(fun, x, step):
    """Jacobian of ``fun`` (vector -> vector) at ``x`` by central differences, shape (m, n).

    Truncation error O(step^2), round-off O(eps / step): step ~ 1e-6 gives ~1e-10 accuracy.
    """
    x = np.asarray(x, dtype=float)
    cols = []
    for j in range(x.size):
        dx = np.zeros_like(x)
        dx[j] = step
        cols.append((np.ravel(fun(x + dx)) - np.ravel(fun(x - dx))) / (2.0 * step))
    return np.column_stack(cols)
