"""Tracking metrics: per-axis RMSE of eq. (64) (theta wrapped) and the Euclidean position RMSE.

Tables 1-3 of the paper report one RMSE per world axis (reproduction-notes §5).  The position
RMSE ``sqrt(mean((x - x_r)^2 + (y - y_r)^2))`` is frame-invariant and also reported.

Two ways to the same numbers: :func:`rmse` over a stored trajectory, and the running sums of a
simulation (:func:`accumulate` per pose, :func:`reduce` at the end), which keep a run O(1) in
memory.  The running sums also give the RMSE after the initial transient (``t >= TRANSIENT``):
the initial pose error dominates the full-run figure (reproduction-notes §5.5).
"""

from __future__ import annotations

import math

import numpy as np

from wmr._jit import njit
from wmr.model.kinematics import wrap_angle

__all__ = [
    "RMSE_KEYS",
    "TRANSIENT",
    "N_ACC",
    "wrap",
    "rmse",
    "accumulate",
    "accumulate_initial",
    "reduce",
]

#: Keys of an RMSE record, in table order.
RMSE_KEYS: tuple[str, ...] = ("x", "y", "theta", "position")
#: Start [s] of the post-transient window of ``RunResult.rmse_after_transient`` (notes §5.5).
TRANSIENT = 5.0
#: Running sums: squares of x, y, theta (world), e1, e2 (robot frame), the count; then x, y,
#: theta and the count again over the poses with ``t >= TRANSIENT``; then the control effort's
#: sum of ``v^2 + w^2`` over the commands.
N_ACC = 11


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


@njit(inline="always")
def accumulate(acc, q, r, tail, u):
    """Add the errors of pose ``q`` against the reference row ``r`` to the running sums ``acc``
    (``tail``: the pose is past the transient) and the command ``u`` that led to it to the
    effort; returns the squared position error."""
    dx = r[0] - q[0]
    dy = r[1] - q[1]
    dth = wrap_angle(r[2] - q[2])
    c = math.cos(q[2])
    sn = math.sin(q[2])
    e1 = c * dx + sn * dy
    e2 = -sn * dx + c * dy
    acc[0] += dx * dx
    acc[1] += dy * dy
    acc[2] += dth * dth
    acc[3] += e1 * e1
    acc[4] += e2 * e2
    acc[5] += 1.0
    if tail:
        acc[6] += dx * dx
        acc[7] += dy * dy
        acc[8] += dth * dth
        acc[9] += 1.0
    acc[10] += u[0] * u[0] + u[1] * u[1]
    return dx * dx + dy * dy


def accumulate_initial(acc, q, r0) -> None:
    """Start the running sums with the pose at ``t_0 = 0`` (before the transient ends)."""
    dx, dy = r0[0] - q[0], r0[1] - q[1]
    dth = math.atan2(math.sin(r0[2] - q[2]), math.cos(r0[2] - q[2]))
    c, s = math.cos(q[2]), math.sin(q[2])
    acc[:6] = (dx * dx, dy * dy, dth * dth, (c * dx + s * dy) ** 2, (-s * dx + c * dy) ** 2, 1.0)
    acc[6:] = 0.0  # t_0 = 0 is before the transient's end; no command yet


def reduce(acc, diverged: bool) -> tuple[dict, dict, dict, float]:
    """``(rmse, rmse_robot_frame, rmse_after_transient, effort)`` from the running sums (NaN when
    the run diverged; the tail is NaN too when no pose was past the transient).

    ``effort = sqrt(mean_k (v_k^2 + w_k^2))`` over the saturated commands ``u_k``: the RMS of
    the command, in the mixed units of ``(m/s, rad/s)`` (a comparison between controllers on
    the same reference, not a physical energy)."""
    nan = math.nan
    tail = dict.fromkeys(RMSE_KEYS, nan)
    if diverged:
        return dict.fromkeys(RMSE_KEYS, nan), {"e1": nan, "e2": nan}, tail, nan
    if acc[9] > 0:
        m_t = acc[9]
        tail = {"x": math.sqrt(acc[6] / m_t), "y": math.sqrt(acc[7] / m_t),
                "theta": math.sqrt(acc[8] / m_t),
                "position": math.sqrt((acc[6] + acc[7]) / m_t)}  # fmt: skip
    m = acc[5]
    full = {
        "x": math.sqrt(acc[0] / m),
        "y": math.sqrt(acc[1] / m),
        "theta": math.sqrt(acc[2] / m),
        "position": math.sqrt((acc[0] + acc[1]) / m),
    }
    effort = math.sqrt(acc[10] / (m - 1)) if m > 1 else nan
    return full, {"e1": math.sqrt(acc[3] / m), "e2": math.sqrt(acc[4] / m)}, tail, effort
