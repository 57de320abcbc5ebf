"""Adaptive backstepping: Kanayama's law with online estimates of the robot's input map.

The true robot (DESIGN §3.3) applies, instead of the command ``u_c = (v_c, w_c)``::

    v = a v_c + b w_c,   w = c w_c + d v_c,
    (a, b, c, d) = (v_gain, v_from_w, w_gain, w_from_v)                                     (A1)

(wheel-radius error: ``a = c``; unequal wheels: ``b = eps*half_axle``, ``d = eps/half_axle``).
The controller keeps an estimate ``th^ = (a^, b^, c^, d^)`` and commands, by certainty
equivalence, the backstepping input ``u* = (v*, w*)`` of ``wmr.controllers.backstepping``
(Kanayama et al. 1990) through the inverse of the estimated map::

    v* = v_r cos e3 + k1 e1,   w* = w_r + v_r (k2 e2 + k3 sin e3),
    u_c = G^^-1 u*,   G^ = [[a^, b^], [d^, c^]]                                               (A2)

with ``e = T_e(theta)(q_r - q)`` of eq. (6), corrected rotation (``wmr.model.kinematics``).

**Tracking-error part** (the classical adaptive tracker; Fukao, Nakagawa & Adachi, IEEE T-RA
16(5), 2000, Sec. III, adapt the wheel radius and axle length the same way; the equations here
are this module's own).  With the actual ``(v, w)`` the error dynamics are (Kanayama 1990)::

    e1' = w e2 - v + v_r cos e3,   e2' = -w e1 + v_r sin e3,   e3' = w_r - w.              (A3)

With ``th~ = th^ - th``, (A1)-(A2) give ``(v, w) = u* - (G^ - G) u_c``, and along (A3) (constant
``G``) the cross terms of Kanayama's proof cancel as for the nominal law::

    d/dt [(e1^2 + e2^2)/2 + (1 - cos e3)/k2]
        = -k1 e1^2 - (k3/k2) v_r sin^2 e3 + th~ . Y,
    Y = (e1 v_c, e1 w_c, s w_c, s v_c),   s = sin(e3)/k2.                                    (A4)

**Identification part** (composite adaptation, Slotine & Li, Automatica 25(4), 1989).  (A4)
drives ``c^, d^`` only through ``sin e3``, which a gain error barely moves (the lateral loop
absorbs it into ``e2``): measured here, the update from ``Y`` alone leaves ``w_gain^`` 0.1 off
after 20 s on the wheel-radius lemniscate.  The pose increments identify the map directly.  With
the ZOH command held over ``[t_j, t_j + dt]`` the kinematic robot turns by ``dth_j = dt w_j``
and advances ``ds_j = dt v_j`` along its mid-step heading, so the exponentially weighted sums
(forgetting ``rho = exp(-dt/memory)``)::

    Phi = sum_j rho^(k-1-j) dt (v_c,j, w_c,j),   z = sum_j rho^(k-1-j) (ds_j, dth_j),
    ds_j = [(x_{j+1} - x_j) cos m_j + (y_{j+1} - y_j) sin m_j] / sinc(dth_j / 2),
    m_j = theta_j + dth_j / 2                                                                (A5)

satisfy, exactly for (A1) without lag or delay, ``z_v = a Phi_v + b Phi_w`` and
``z_w = c Phi_w + d Phi_v``: the prediction errors ``eps_v = a^ Phi_v + b^ Phi_w - z_v`` and
``eps_w = c^ Phi_w + d^ Phi_v - z_w`` are ``W_v . th~_v`` and ``W_w . th~_w`` with the channel
regressors ``W_v = (Phi_v, Phi_w)`` for ``th_v = (a, b)`` and ``W_w = (Phi_w, Phi_v)`` for
``th_w = (c, d)``.

**Update and Lyapunov function.**  Per channel ``i in {v, w}``, with a gain matrix ``P_i``
(2 x 2, ``P_i(0) = diag(adaptation)``)::

    th^_i' = -P_i (Y_i + kappa_i W_i eps_i)                                                 (A6)
    (P_i^-1)' = kappa_i W_i W_i^T - lambda (P_i^-1 - P_i(0)^-1)                             (A7)

    V = (e1^2 + e2^2)/2 + (1 - cos e3)/k2 + sum_i th~_i^T P_i^-1 th~_i / 2                  (A8)

    V' = -k1 e1^2 - (k3/k2) v_r sin^2 e3 - sum_i kappa_i eps_i^2 / 2
         - (lambda/2) sum_i th~_i^T (P_i^-1 - P_i(0)^-1) th~_i  <=  0                       (A9)

for ``v_r > 0`` (``P_i^-1 >= P_i(0)^-1`` along (A7)); ``kappa = 0`` and ``lambda = 0`` leave the
tracking-error update with the constant gains ``diag(adaptation)``.  ``lambda`` (forgetting)
keeps ``P`` from vanishing, so the estimates follow a plant that changes (``[[plant.change]]``).
The estimates are projected onto the box ``a^, c^ in [g_min, g_max]``, ``|b^| <= b_max``,
``|d^| <= d_max`` in the metric ``P_i^-1`` of (A8) (:func:`_project`): a metric projection onto
a convex set containing the truth cannot increase ``th~^T P^-1 th~``; the box keeps
``det G^ >= g_min^2 - b_max d_max > 0`` (checked in :class:`Settings`), so (A2) exists.

**Sampled law** (the loop's zero-order hold, ``t_k = k dt``).  At step ``k`` the command (A2)
uses ``th^_k`` and ``P_k``; ``th^_{k+1}`` is the forward-Euler step of (A6) from the data of step
``k``, projected; ``P_{k+1}`` the exact information update of (A7) without forgetting
(``P - P W W^T P dt kappa / (1 + dt kappa W^T P W)``), then the forgetting over one step,
``P^-1 <- f P^-1 + (1 - f) P(0)^-1`` with ``f = exp(-lambda dt)``.
Then ``V_{k+1} - V_k = dt V'(t_k) + O(dt^2)``: the Lyapunov function decreases up to the
``O(dt^2)`` of the sampled law (``tests/test_adaptive_bsc.py``).  Saturation (``[limits]``),
measurement noise, slip and a delayed or lagged plant are outside (A9): the update then uses the
command as saturated and the measured poses.

What is estimated, and why: all four entries of ``G`` (the coupling too: the law needs only
``G^`` invertible, which the box guarantees, and the pose increments separate ``c`` from ``d``
when ``w_c / v_c`` varies, as on the lemniscate).  An adaptation gain of 0 freezes that entry
(e.g. ``adaptation = [a, 0, c, 0]`` estimates the two gains only); with every gain 0 the law is
backstepping, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wmr._jit import njit
from wmr._settings import check
from wmr.controllers import backstepping
from wmr.model.kinematics import sinc_and_derivative, tracking_error, wrap_angle

__all__ = ["Settings", "State", "STATE_NAMES", "ESTIMATE_NAMES", "GAIN_NAMES", "pack",
           "final_state", "law", "lyapunov"]

#: The estimates of (A1) in force at each step's command, in the order of ``adaptation``.
ESTIMATE_NAMES = ("v_gain_hat", "v_from_w_hat", "w_gain_hat", "w_from_v_hat")
#: The gain matrices ``P_v``, ``P_w`` of (A6) at each step: ``(P11, P12, P22)`` per channel.
GAIN_NAMES = ("P_a", "P_ab", "P_b", "P_c", "P_cd", "P_d")
#: Logged along a run.
STATE_NAMES: tuple[str, ...] = ESTIMATE_NAMES + GAIN_NAMES

# Layout of the parameter vector p: the first four entries are backstepping's own p.
P_BSC = 0  # k1, k2, k3, printed (backstepping.pack)
P_GAMMA = 4  # initial gains diag(P_v(0)), diag(P_w(0)): (g_a, g_b, g_c, g_d)
P_LO = 8  # lower bounds of the four estimates
P_HI = 12  # upper bounds
P_LIMITS = 16  # v_max, w_max
P_KAPPA = 18  # identification weights (kappa_v, kappa_w)
P_RHO = 20  # forgetting factor of the regression sums (A5), exp(-dt / memory)
P_FORGET = 21  # exp(-lambda dt): the forgetting of (A7) over one step
P_SIZE = 22
# Layout of the state vector s.
S_EST = 0  # th^_k (a^, b^, c^, d^): in force at this step
S_P = 4  # P_k: (P11, P12, P22) of channel v, then of channel w
S_NEXT = 10  # th^_{k+1}
S_PNEXT = 14  # P_{k+1}
S_PHI = 20  # (Phi_v [m], Phi_w [rad]) of (A5)
S_Z = 22  # (z_v [m], z_w [rad])
S_PREV_Q = 24  # pose estimate of the previous step
S_PREV_U = 27  # command of the previous step (as saturated)
S_STARTED = 29  # 0 before the first step
S_SIZE = 30


@dataclass(frozen=True)
class Settings(backstepping.Settings):
    """Adaptive backstepping settings: backstepping's, plus the adaptation and its bounds.

    Attributes
    ----------
    adaptation : tuple of float [1/m^2, 1/rad^2, 1/(m^2 rad), rad/m^4]
        Initial adaptation gains ``diag P(0)`` of (A6) for the estimates of ``v_gain``,
        ``v_from_w``, ``w_gain`` and ``w_from_v``, each >= 0 (0 freezes that estimate).
        Default ``(2, 0.02, 2, 2)`` (``v_from_w`` is ~100 x smaller than the others on a
        robot with a 0.15 m half-axle).  With the defaults, measured on the lemniscate at
        seed 0: every estimate within 0.03 of the truth from 5.2 s (wheel-radius plant) and
        5.7 s (wheel-asymmetry plant) on, within 0.006 after 20 s.
    identification : tuple of float [1/s, m^2/(rad^2 s)]
        ``(kappa_v, kappa_w)``: weights of the prediction errors in (A6)-(A7), each >= 0;
        ``(0, 0)`` leaves the tracking-error update (A4) with constant gains.  Default
        ``(100, 100)``: of 10, 30 and 100, the one that settles both plants within 6 s
        (10: 6.9 s and 17.5 s; 30: 5.8 s and 7.0 s; 300 settles 0.4 s sooner).
    memory : float [s]
        Time constant of the exponential weighting of the pose increments (A5), > 0.
    forgetting : float [1/s]
        ``lambda`` of (A7), >= 0: the rate at which ``P`` returns towards ``P(0)``, so the
        estimates can follow a plant that changes (the data weigh ``exp(-lambda t)``).
        Default 0.5, a memory of 2 s: after the wheel radius drops from 0.8 to 0.7 the gains
        are within 0.03 of 0.7 some 15 s later (0.2: 19 s), at the price of a noise-driven
        spread of 0.006 (0.2: 0.001).
    gain_bounds : tuple of float [-]
        ``(g_min, g_max)``: the projection box of the ``v_gain`` and ``w_gain`` estimates;
        ``0 < g_min <= 1 <= g_max`` (the nominal robot must be inside).  Default ``(0.5, 1.5)``.
    coupling_bounds : tuple of float [m/rad, rad/m]
        ``(b_max, d_max)``: ``|v_from_w^| <= b_max``, ``|w_from_v^| <= d_max``, each >= 0, with
        ``b_max d_max < g_min^2`` so the estimated map stays invertible.  Default ``(0.05, 1.0)``
        (the wheel-asymmetry plant has ``0.0075`` and ``0.333``).
    """

    adaptation: tuple[float, ...] = (2.0, 0.02, 2.0, 2.0)
    identification: tuple[float, ...] = (100.0, 100.0)
    memory: float = 2.0
    forgetting: float = 0.5
    gain_bounds: tuple[float, ...] = (0.5, 1.5)
    coupling_bounds: tuple[float, ...] = (0.05, 1.0)

    def __post_init__(self):
        super().__post_init__()
        for name in ("adaptation", "identification"):
            for x in getattr(self, name):
                check(math.isfinite(x) and x >= 0, name, getattr(self, name),
                      "entries must be >= 0")  # fmt: skip
        check(math.isfinite(self.memory) and self.memory > 0, "memory", self.memory,
              "must be > 0")  # fmt: skip
        check(math.isfinite(self.forgetting) and self.forgetting >= 0, "forgetting",
              self.forgetting, "must be >= 0")  # fmt: skip
        lo, hi = self.gain_bounds
        check(lo > 0, "gain_bounds", self.gain_bounds, "g_min must be > 0")
        check(lo <= 1.0 <= hi, "gain_bounds", self.gain_bounds,
              "must include 1 (the nominal robot): g_min <= 1 <= g_max")  # fmt: skip
        b_max, d_max = self.coupling_bounds
        check(b_max >= 0 and d_max >= 0, "coupling_bounds", self.coupling_bounds,
              "entries must be >= 0")  # fmt: skip
        check(b_max * d_max < lo * lo, "coupling_bounds", self.coupling_bounds,
              f"b_max * d_max must be < g_min^2 = {lo * lo:g} (an invertible estimated map)")


def pack(settings: Settings, scenario, rng: np.random.Generator):
    """``p`` (:data:`P_SIZE`: backstepping's ``p``, the gains, the box, the limits, the
    identification weights and forgetting) and the initial state: the nominal map
    ``(1, 0, 1, 0)``, ``P = diag(adaptation)``, an empty regression."""
    p_bsc, _, _, _ = backstepping.pack(settings, scenario, rng)
    lo, hi = settings.gain_bounds
    b_max, d_max = settings.coupling_bounds
    rho = math.exp(-scenario.dt / settings.memory)
    forget = math.exp(-scenario.dt * settings.forgetting)
    p = np.concatenate((p_bsc, settings.adaptation, (lo, -b_max, lo, -d_max),
                        (hi, b_max, hi, d_max), (scenario.limits.v_max, scenario.limits.w_max),
                        settings.identification, (rho, forget)))  # fmt: skip
    s = np.zeros(S_SIZE)
    g = settings.adaptation
    for base in (S_EST, S_NEXT):
        s[base] = s[base + 2] = 1.0
    for base in (S_P, S_PNEXT):
        s[base : base + 6] = (g[0], 0.0, g[1], g[2], 0.0, g[3])
    return p, s, np.zeros(0), np.zeros((0, 0))


@dataclass(frozen=True)
class State:
    """Adaptive backstepping's state after a run: the estimated input map (A1) and the gain
    matrices after the last update (what a next step would use).

    Attributes
    ----------
    v_gain, w_gain : float [-]
        Estimates ``a^``, ``c^``.
    v_from_w : float [m/rad]
        Estimate ``b^``.
    w_from_v : float [rad/m]
        Estimate ``d^``.
    gain_v, gain_w : ndarray, shape (2, 2)
        ``P_v`` (of ``(a^, b^)``) and ``P_w`` (of ``(c^, d^)``).
    """

    v_gain: float
    v_from_w: float
    w_gain: float
    w_from_v: float
    gain_v: np.ndarray
    gain_w: np.ndarray

    @property
    def input_map(self) -> np.ndarray:
        """``G^ = [[v_gain, v_from_w], [w_from_v, w_gain]]``, shape (2, 2)."""
        return np.array([[self.v_gain, self.v_from_w], [self.w_from_v, self.w_gain]])


def _sym(x) -> np.ndarray:
    return np.array([[x[0], x[1]], [x[1], x[2]]], dtype=float)


def final_state(p, s, theta, P) -> State:
    """The estimates and gains after the last update (``th^_{k+1}``, ``P_{k+1}``)."""
    est = s[S_NEXT : S_NEXT + 4]
    return State(v_gain=float(est[0]), v_from_w=float(est[1]), w_gain=float(est[2]),
                 w_from_v=float(est[3]), gain_v=_sym(s[S_PNEXT : S_PNEXT + 3]),
                 gain_w=_sym(s[S_PNEXT + 3 : S_PNEXT + 6]))  # fmt: skip


@njit
def _project(y0, y1, lo0, hi0, lo1, hi1, p11, p12, p22):
    """The point of the box ``[lo0, hi0] x [lo1, hi1]`` nearest to ``(y0, y1)`` in the metric
    ``P^-1`` (``P = [[p11, p12], [p12, p22]]``).  A frozen entry (``P`` singular) has a zero row:
    the other is then clipped, which is its projection in the 1-d metric.

    Outside the box the minimiser of the convex quadratic lies on an edge; each edge's minimiser
    is the unconstrained one along it, clipped; the nearest of the four is the projection.
    """
    inside = lo0 <= y0 <= hi0 and lo1 <= y1 <= hi1
    det = p11 * p22 - p12 * p12
    if inside or det <= 1e-12 * p11 * p22 or p11 <= 0.0 or p22 <= 0.0:
        return min(max(y0, lo0), hi0), min(max(y1, lo1), hi1)
    m11, m12, m22 = p22 / det, -p12 / det, p11 / det
    best, b0, b1 = math.inf, y0, y1
    for j in range(4):
        if j < 2:
            x0 = lo0 if j == 0 else hi0
            x1 = min(max(y1 - m12 * (x0 - y0) / m22, lo1), hi1)
        else:
            x1 = lo1 if j == 2 else hi1
            x0 = min(max(y0 - m12 * (x1 - y1) / m11, lo0), hi0)
        d0, d1 = x0 - y0, x1 - y1
        f = m11 * d0 * d0 + 2.0 * m12 * d0 * d1 + m22 * d1 * d1
        if f < best:
            best, b0, b1 = f, x0, x1
    return b0, b1


@njit
def _channel(p, s, i, y0, y1, w0, w1, eps, dt):
    """Update channel ``i`` (0: ``(a^, b^)``, 1: ``(c^, d^)``): (A6) by forward Euler, (A7) by
    the exact information step plus the Euler step of the forgetting, then the projection; into
    the ``NEXT`` slots of ``s``."""
    e0, e1 = S_EST + 2 * i, S_EST + 2 * i + 1
    q = S_P + 3 * i
    p11, p12, p22 = s[q], s[q + 1], s[q + 2]
    kappa = p[P_KAPPA + i]
    g0 = y0 + kappa * w0 * eps
    g1 = y1 + kappa * w1 * eps
    x0 = s[e0] - dt * (p11 * g0 + p12 * g1)
    x1 = s[e1] - dt * (p12 * g0 + p22 * g1)
    pw0 = p11 * w0 + p12 * w1  # P W
    pw1 = p12 * w0 + p22 * w1
    c = dt * kappa / (1.0 + dt * kappa * (w0 * pw0 + w1 * pw1))
    n11, n12, n22 = p11 - c * pw0 * pw0, p12 - c * pw0 * pw1, p22 - c * pw1 * pw1
    # forgetting, exactly: P^-1 <- f P^-1 + (1 - f) Gamma^-1, f = exp(-lambda dt), Gamma = P(0),
    # on the entries that adapt (a frozen entry has a zero row in P and stays frozen)
    ga, gb = p[P_GAMMA + 2 * i], p[P_GAMMA + 2 * i + 1]
    f = p[P_FORGET]
    if ga > 0.0 and gb > 0.0:
        det = n11 * n22 - n12 * n12
        m11 = f * n22 / det + (1.0 - f) / ga
        m12 = -f * n12 / det
        m22 = f * n11 / det + (1.0 - f) / gb
        det = m11 * m22 - m12 * m12
        n11, n12, n22 = m22 / det, -m12 / det, m11 / det
    elif ga > 0.0:
        n11 = 1.0 / (f / n11 + (1.0 - f) / ga)
    elif gb > 0.0:
        n22 = 1.0 / (f / n22 + (1.0 - f) / gb)
    r = S_PNEXT + 3 * i
    s[r], s[r + 1], s[r + 2] = n11, n12, n22
    x0, x1 = _project(x0, x1, p[P_LO + 2 * i], p[P_HI + 2 * i], p[P_LO + 2 * i + 1],
                      p[P_HI + 2 * i + 1], n11, n12, n22)  # fmt: skip
    s[S_NEXT + 2 * i] = x0
    s[S_NEXT + 2 * i + 1] = x1


@njit
def _regress(p, s, q_hat, dt):
    """Advance the sums (A5) by the increment from the previous step to this one."""
    rho = p[P_RHO]
    if s[S_STARTED] != 0.0:
        dth = wrap_angle(q_hat[2] - s[S_PREV_Q + 2])
        mid = s[S_PREV_Q + 2] + 0.5 * dth
        sinc, _ = sinc_and_derivative(0.5 * dth)
        ds = ((q_hat[0] - s[S_PREV_Q]) * math.cos(mid)
              + (q_hat[1] - s[S_PREV_Q + 1]) * math.sin(mid)) / sinc  # fmt: skip
        s[S_Z] = rho * s[S_Z] + ds
        s[S_Z + 1] = rho * s[S_Z + 1] + dth
        s[S_PHI] = rho * s[S_PHI] + dt * s[S_PREV_U]
        s[S_PHI + 1] = rho * s[S_PHI + 1] + dt * s[S_PREV_U + 1]
    s[S_PREV_Q : S_PREV_Q + 3] = q_hat
    s[S_STARTED] = 1.0


@njit
def law(p, s, theta, P, q_hat, ref, dt, u):
    """Write the command ``u = G^^-1 u*`` of (A2), saturated, and compute ``th^_{k+1}``,
    ``P_{k+1}`` from this step's data (A6)-(A7).  ``s[S_EST:S_P+6]`` hold the estimate and gains
    this command uses (the logged signals)."""
    if s[S_STARTED] != 0.0:
        s[S_EST : S_EST + 10] = s[S_NEXT : S_NEXT + 10]
    _regress(p, s, q_hat, dt)
    e = tracking_error(q_hat, ref, p[3] != 0.0)
    backstepping.command(p, e, ref, u)  # u = u* of (A2)
    a, b, c, d = s[S_EST], s[S_EST + 1], s[S_EST + 2], s[S_EST + 3]
    det = a * c - b * d
    v_c = min(max((c * u[0] - b * u[1]) / det, -p[P_LIMITS]), p[P_LIMITS])
    w_c = min(max((a * u[1] - d * u[0]) / det, -p[P_LIMITS + 1]), p[P_LIMITS + 1])
    u[0] = v_c
    u[1] = w_c
    s[S_PREV_U] = v_c
    s[S_PREV_U + 1] = w_c
    sn = math.sin(e[2]) / p[1]
    phi_v, phi_w = s[S_PHI], s[S_PHI + 1]
    eps_v = a * phi_v + b * phi_w - s[S_Z]
    eps_w = c * phi_w + d * phi_v - s[S_Z + 1]
    _channel(p, s, 0, e[0] * v_c, e[0] * w_c, phi_v, phi_w, eps_v, dt)
    _channel(p, s, 1, sn * w_c, sn * v_c, phi_w, phi_v, eps_w, dt)


def lyapunov(e, estimates, gains, truth, settings: Settings) -> np.ndarray:
    """The Lyapunov function (A8) along a run.

    Parameters
    ----------
    e : ndarray, shape (n, 3)
        Tracking errors of eq. (6) [m, m, rad].
    estimates : ndarray, shape (n, 4)
        ``th^`` in :data:`ESTIMATE_NAMES` order.
    gains : ndarray, shape (n, 6)
        ``P`` in :data:`GAIN_NAMES` order.
    truth : sequence of 4 floats
        The true ``(v_gain, v_from_w, w_gain, w_from_v)``.
    settings : Settings
        Its ``k2`` (a frozen entry, gain 0, is left out: ``P``'s pseudo-inverse).

    Returns
    -------
    ndarray, shape (n,)
        ``V`` [m^2].
    """
    e = np.asarray(e, dtype=float)
    out = 0.5 * (e[:, 0] ** 2 + e[:, 1] ** 2) + (1.0 - np.cos(e[:, 2])) / settings.gains[1]
    err = np.asarray(estimates, dtype=float) - np.asarray(truth, dtype=float)
    gains = np.asarray(gains, dtype=float)
    for i in range(2):
        Pk = gains[:, [3 * i, 3 * i + 1, 3 * i + 1, 3 * i + 2]].reshape(-1, 2, 2)
        x = err[:, 2 * i : 2 * i + 2]
        out = out + 0.5 * np.einsum("ni,nij,nj->n", x, np.linalg.pinv(Pk), x)
    return out
