"""Tracking metrics: per-axis RMSE of eq. (64) (theta wrapped) and the Euclidean position RMSE.

Tables 1-3 of the paper report one RMSE per world axis (reproduction-notes §5).  The position
RMSE ``sqrt(mean((x - x_r)^2 + (y - y_r)^2))`` is frame-invariant and also reported.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RMSE_KEYS", "wrap", "rmse"]

#: Keys of an RMSE record, in table order.
RMSE_KEYS: tuple[str, ...] = ("x", "y", "theta", "position")


def wrap(a):
    """Wrap angles [rad] to (-pi, pi] (elementwise)."""
    r = np.arctan2(np.sin(a), np.cos(a))
    return np.where(r == -np.pi, np.pi, r)


def rmse(q, ref) -> dict[str, float]:
    """RMSE of eq. (64) between poses ``q`` (n, 3) and the reference ``ref`` (n, >=3).

    Returns ``{"x", "y", "theta", "position"}``; theta errors are wrapped before squaring.
    """
    q = np.asarray(q, dtype=float)
    ref = np.asarray(ref, dtype=float)
    if q.ndim != 2 or q.shape[1] != 3 or ref.shape[0] != q.shape[0] or ref.shape[1] < 3:
        raise ValueError(f"rmse needs q (n, 3) and ref (n, >=3); got {q.shape} and {ref.shape}")
    ex = ref[:, 0] - q[:, 0]
    ey = ref[:, 1] - q[:, 1]
    et = wrap(ref[:, 2] - q[:, 2])
    return {
        "x": float(np.sqrt(np.mean(ex**2))),
        "y": float(np.sqrt(np.mean(ey**2))),
        "theta": float(np.sqrt(np.mean(et**2))),
        "position": float(np.sqrt(np.mean(ex**2 + ey**2))),
    }
