"""Closed-form stability conditions, stability regions in gain space and sweeps of the
linearised loops of ``wmr.linear.loops`` (the fixed PID of eq. 7 and backstepping).

Closed forms (straight line, ``w_r = 0``, PI part): Jury's conditions for the ``v`` loop
(:func:`jury_v_loop_stable`, :func:`jury_v_gain_limits`) and the continuous-time Routh-Hurwitz
condition of the ``w`` loop (:func:`routh_w_loop_stable`); :func:`stability_region` and
:func:`stable_gain_interval` compute the same from eigenvalues for any operating point.
:func:`max_stable_delay` finds the largest input delay a loop tolerates and
:func:`printed_rotation_sweep` compares the printed and corrected rotation (eqs. 4/6) over the
heading.  The names are also reachable as ``wmr.linear.loops.<name>`` (moved here to keep each file
to one concept).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from wmr.linear.loops import (
    BSC_GAINS,
    PID_GAINS,
    OperatingPoint,
    _sym,
    closed_loop_matrix,
    error_plant,
    pid_closed_loop_matrix,
    pid_equilibrium,
    spectral_radius,
)

__all__ = [
    "jury_v_loop_stable",
    "jury_v_gain_limits",
    "routh_w_loop_stable",
    "first_crossing",
    "stability_region",
    "stable_gain_interval",
    "max_stable_delay",
    "printed_rotation_sweep",
    "unstable_intervals",
]


def jury_v_loop_stable(Kpv, Kiv, dt):
    """Closed-form stability of the ``v`` loop on a straight line (``w_r = 0``), PI part.

    With ``w_r = 0`` the ``v`` loop decouples: ``e1_{k+1} = e1_k - dt dv_k`` and the PI of eq. (7)
    (``Kdv = 0``) give the characteristic polynomial ``z^2 + (dt (Kpv + Kiv dt) - 2) z +
    (1 - dt Kpv)``.  Jury's conditions ``|a0| < 1``, ``P(1) > 0``, ``P(-1) > 0`` read
    ``0 < Kpv < 2/dt``, ``Kiv > 0`` and ``2 dt Kpv + dt^2 Kiv < 4``.  Vectorised over the gains.
    """
    Kpv, Kiv = np.asarray(Kpv, dtype=float), np.asarray(Kiv, dtype=float)
    return (Kpv > 0) & (Kpv < 2.0 / dt) & (Kiv > 0) & (2 * dt * Kpv + dt * dt * Kiv < 4.0)


def jury_v_gain_limits(Kpv: float, Kiv: float, dt: float) -> tuple[float, float]:
    """Upper limits of ``Kpv`` (``Kiv`` fixed) and of ``Kiv`` (``Kpv`` fixed) from
    :func:`jury_v_loop_stable`: ``min(2/dt, (4 - dt^2 Kiv)/(2 dt))`` and ``(4 - 2 dt Kpv)/dt^2``."""
    return min(2 / dt, (4 - dt * dt * Kiv) / (2 * dt)), (4 - 2 * dt * Kpv) / dt**2


def routh_w_loop_stable(Kpw, Kiw, v_r):
    """Continuous-time (``dt -> 0``) stability of the ``w`` loop on a straight line, PI part.

    ``e3' = -dw``, ``e2' = v_r e3``, ``dw = Kpw s + Kiw int s``, ``s = e3 + e2``:
    ``L(s) = (Kpw s + Kiw)(s + v_r)/s^3``, characteristic polynomial
    ``s^3 + Kpw s^2 + (Kpw v_r + Kiw) s + Kiw v_r``; Routh-Hurwitz: all coefficients positive and
    ``Kpw (Kpw v_r + Kiw) > Kiw v_r``.  (Sampling adds an upper bound, near ``Kpw ~ 2/dt``.)
    """
    Kpw, Kiw = np.asarray(Kpw, dtype=float), np.asarray(Kiw, dtype=float)
    return (Kpw > 0) & (Kiw > 0) & (v_r > 0) & (Kpw * (Kpw * v_r + Kiw) > Kiw * v_r)


def first_crossing(rho: Callable[[float], float], xs: Sequence[float],
                   tol: float = 1e-12) -> float | None:  # fmt: skip
    """First ``x`` of the ordered ``xs`` with ``rho(x) >= 1``, refined by bisection between it
    and its predecessor (relative tolerance ``tol``); None if there is none."""
    prev = xs[0]
    for x in xs[1:]:
        if rho(x) >= 1.0:
            a, b = prev, x
            while abs(b - a) > tol * max(1.0, abs(b)):
                m = 0.5 * (a + b)
                a, b = (a, m) if rho(m) >= 1.0 else (m, b)
            return 0.5 * (a + b)
        prev = x
    return None


def stability_region(op: OperatingPoint, pair: str = "w", n: int = 81,
                     log_range=(-2.0, 3.0), gains=PID_GAINS) -> dict:  # fmt: skip
    """Spectral radius of the PID closed loop over a log grid of two gains, others at ``gains``.

    ``pair="v"``: (Kpv, Kiv); ``pair="w"``: (Kpw, Kiw), each on ``n`` points of
    ``10**log_range``.  Returns ``{"pair", "kp", "ki", "rho", "operating_point"}`` with ``rho``
    (n, n): rows along the integral gain, columns along the proportional gain.
    """
    plant = error_plant(op)
    kp = np.logspace(*log_range, n)
    ki = np.logspace(*log_range, n)
    ip, ii = (0, 1) if pair == "v" else (3, 4)
    rho = np.empty((n, n))
    K = np.array(gains, dtype=float)
    for a, k_i in enumerate(ki):
        for b, k_p in enumerate(kp):
            K[ip], K[ii] = k_p, k_i
            rho[a, b] = spectral_radius(pid_closed_loop_matrix(plant, K))
    return {"pair": pair, "kp": kp, "ki": ki, "rho": rho, "operating_point": op}


def stable_gain_interval(op: OperatingPoint, index: int, gains=PID_GAINS,
                         limits=(1e-6, 1e6)) -> tuple[float, float]:  # fmt: skip
    """The interval of PID gain ``index`` (0..5, order of eq. 7) keeping the loop stable.

    The others at ``gains``: the connected interval of ``max|z| < 1`` containing
    ``gains[index]``, scanned on a log grid within ``limits`` and refined by bisection; ``0`` /
    ``inf`` when stable up to the limit, ``(nan, nan)`` when unstable at ``gains``.  A zero
    default (``Kd``) starts the search at ``limits[0]``.
    """
    plant = error_plant(op)
    K = np.array(gains, dtype=float)

    def rho(lg):
        K[index] = 10.0**lg
        return spectral_radius(pid_closed_loop_matrix(plant, K))

    g0 = max(float(gains[index]), limits[0])
    l0, l_lo, l_hi = math.log10(g0), math.log10(limits[0]), math.log10(limits[1])
    if rho(l0) >= 1.0:
        return (math.nan, math.nan)
    up = first_crossing(rho, np.linspace(l0, l_hi, 241), tol=1e-13)
    down = first_crossing(rho, np.linspace(l0, l_lo, 241), tol=1e-13) if g0 > limits[0] else None
    return (0.0 if down is None else 10.0**down, math.inf if up is None else 10.0**up)


def max_stable_delay(op: OperatingPoint, loops_of: Callable, limit: int = 400) -> int | None:
    """The largest input delay [whole samples] for which the loop ``loops_of(op)`` stays stable.

    ``loops_of`` builds the loops (e.g. :func:`pid_loops`) at an operating point;
    ``op.delay_steps`` is replaced by each delay tried (:func:`error_plant`'s delay line; any
    ``op.actuator_tau`` is kept).  Returns None if the loop is unstable without delay and
    ``limit`` if it is still stable at ``limit`` samples; otherwise the last stable delay below
    the first unstable one (found by doubling, then bisection: the scan assumes a single
    crossing, true of these loops, whose phase only falls as the delay grows).
    """
    import dataclasses

    def stable(d: int) -> bool:
        L = loops_of(dataclasses.replace(op, delay_steps=d))["v"]
        return spectral_radius(closed_loop_matrix(L)) < 1.0

    if not stable(0):
        return None
    lo, hi = 0, 1
    while stable(hi):
        lo = hi
        if hi >= limit:
            return limit
        hi = min(2 * hi, limit)
    while hi - lo > 1:  # stable(lo), not stable(hi)
        mid = (lo + hi) // 2
        lo, hi = (mid, hi) if stable(mid) else (lo, mid)
    return lo


def printed_rotation_sweep(op: OperatingPoint, headings_deg, pid_gains=PID_GAINS,
                           bsc_gains=BSC_GAINS) -> dict:  # fmt: skip
    """Spectral radius vs reference heading with the printed error matrix of eqs. 4/6 (E3).

    Returns ``headings_deg`` and the radii ``pid_rho``, ``bsc_rho`` (printed) per heading, and
    ``pid_rho_corrected``, ``bsc_rho_corrected`` (the same at every heading).

    On a straight line (``w_r = 0`` required: the heading is then constant and the loop LTI) the
    printed error is ``N(theta) e`` with ``N = [[1, 0, 0], [sin 2theta, cos 2theta, 0], [0, 0, 1]]``
    (corrected ``e``), so the loop depends on the heading; the corrected loop does not.  Closed
    loops from :func:`wmr.model.symbolic.pid_closed_loop_jacobian_function` and
    :func:`wmr.model.symbolic.backstepping_closed_loop_jacobian_function` with ``printed=True``.
    """
    if op.w_r != 0.0:
        raise ValueError("the printed-rotation sweep needs a straight line (w_r = 0)")
    fp = _sym().pid_closed_loop_jacobian_function(op.integrator, printed=True)
    fb = _sym().backstepping_closed_loop_jacobian_function(op.integrator, printed=True)
    xs = pid_equilibrium(op, pid_gains)
    th = np.radians(np.asarray(headings_deg, dtype=float))
    rp = np.array([spectral_radius(np.asarray(fp(xs, op.u_r, pid_gains, op.dt, t))) for t in th])
    rb = np.array([spectral_radius(np.asarray(fb(np.zeros(3), op.u_r, bsc_gains, op.dt, t)))
                   for t in th])  # fmt: skip
    A_pid = _sym().pid_closed_loop_jacobian_function(op.integrator)(xs, op.u_r, pid_gains, op.dt)
    A_bsc = _sym().backstepping_closed_loop_jacobian_function(op.integrator)(
        np.zeros(3), op.u_r, bsc_gains, op.dt)  # fmt: skip
    return {"headings_deg": np.asarray(headings_deg, dtype=float), "pid_rho": rp, "bsc_rho": rb,
            "pid_rho_corrected": spectral_radius(np.asarray(A_pid)),
            "bsc_rho_corrected": spectral_radius(np.asarray(A_bsc))}  # fmt: skip


def unstable_intervals(x, unstable) -> list:
    """``[[start, stop], ...]`` of the runs of True in ``unstable`` over the grid ``x``."""
    out, start = [], None
    for i, u in enumerate(unstable):
        if u and start is None:
            start = i
        if not u and start is not None:
            out.append([float(x[start]), float(x[i - 1])])
            start = None
    if start is not None:
        out.append([float(x[start]), float(x[-1])])
    return out
