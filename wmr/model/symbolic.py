"""CasADi models of the unicycle, its zero-order-hold steps, the network and the error dynamics.

This module is the **independent oracle** for the library's hand-derived Jacobians (DESIGN §4, STYLE
6): every model is written once more, symbolically, from the paper's mathematics (with the errata of
``paper/reproduction-notes.md`` §3), and every Jacobian is obtained by CasADi's algorithmic
differentiation (``casadi.jacobian`` / ``casadi.jtimes``), never by transcribing a derivative.  It
deliberately imports nothing numeric from ``wmr``, and no library module imports it at import time
(``tests/test_symbolic.py``): the simulator, the compiled controllers and the filters run on the
jitted kernels of :mod:`wmr.model.kinematics`, :mod:`wmr.estimation.nn`, ...; tests and analyses
compare those kernels with the functions built here.  One closed-loop user loads it on first use:
the Python-level ``nmpc`` controller (``wmr.controllers.nmpc.problem``) builds its prediction model
from :func:`step_function` when its optimal control problem is first built (an optimiser needs the
symbolic model; its tests check that model against the jitted ``wmr.model.kinematics.step``, so the
oracle role is kept).

Each model is exposed as a :class:`casadi.Function` (SX graph) with named inputs and outputs,
built on first use and cached (``functools.cache``).  Call them with numpy arrays; outputs
are :class:`casadi.DM` (use ``numpy.asarray`` or ``.full()``).

Contents
--------
- Eq. (1) and its Jacobians: :func:`rhs_function`, :func:`rhs_jacobian_function`.
- ZOH steps (``"exact"`` arc, ``"euler"``, ``"rk4"``) and ``F = dq+/dq``, ``G = dq+/du``:
  :func:`step_function`, :func:`step_jacobian_function`.
- The network of eqs. (18)-(19) with the bias counted once (errata E7), in the flat weight
  layout of ``docs/conventions.md``: :func:`network_function`,
  :func:`network_input_jacobian_function` (``dz/dx``, E7),
  :func:`network_weight_jacobian_function` (``dz/dtheta``, E8).
- The error frame of eqs. (4)/(6), corrected or printed (errata E3):
  :func:`rotation_function`, :func:`rotation_det`, :func:`rotation_det_string`,
  :func:`tracking_error_function`.
- Error dynamics: the chain-rule time derivative of ``e = T_e(theta)(q_r - q)``
  (:func:`error_rate_function`), its residual against Kanayama's closed form
  (:func:`error_dynamics_residual_function`), the same dynamics in error coordinates
  (:func:`error_dynamics_function`, :func:`error_dynamics_jacobian_function`), the backstepping
  closed loop and its Jacobian at ``e = 0`` (:func:`backstepping_law_function`,
  :func:`backstepping_error_dynamics_function`, :func:`backstepping_jacobian_function`), and the
  one-step (sampled-data) versions (:func:`error_step_function`,
  :func:`error_step_jacobian_function`, :func:`backstepping_step_jacobian_function`).
- In ``wmr.model.symbolic_loops`` (reachable here by name): the one-step error dynamics and
  sampled-data closed loops whose state is the corrected error (plus the PID's memory), with the
  controller fed the corrected or the printed error, defined at every heading (no ``T_e^{-1}`` of
  the printed matrix): :func:`pid_closed_loop_step_function` (eq. 7 as discretised in
  ``wmr.controllers.pid``), :func:`pid_closed_loop_jacobian_function`,
  :func:`backstepping_closed_loop_step_function`,
  :func:`backstepping_closed_loop_jacobian_function`.

Error coordinates and the rotation
----------------------------------
With the corrected rotation the error dynamics are invariant under rotations and translations
of the plane (SE(2)), so they can be written in ``e`` alone; the functions in error coordinates
are derived at the robot pose ``q = (0, 0, 0)`` and take no heading.  The printed matrix is not a
rotation, the printed error is not invariant, and its dynamics depend on the robot heading
``theta`` as well: the ``printed=True`` variants take ``theta`` as an extra last input.  Angles
are never wrapped here (the symbolic ``e3 = theta_r - theta`` is continuous).

The sinc near zero
------------------
The exact arc is written ``x+ = x + v dt sinc(a) cos(theta + a)`` with ``a = w dt / 2``
(no division by ``w``).  ``sinc`` switches with ``casadi.if_else`` to its Taylor series
``1 - a^2/6 + a^4/120 - a^6/5040`` for ``|a| < 1e-3`` (truncation below 1e-29; the library
switches at 1e-4, so the two disagree in form between 1e-4 and 1e-3, which the tests cross).
CasADi differentiates ``if_else(c, x, y)`` branch by branch, ``if_else(c, dx, dy)``, and its
(non-short-circuit) ``if_else`` masks the unused branch exactly (``c ? x : 0``, not ``c * x``),
so even ``sin(a)/a`` evaluated at ``a = 0`` would not leak NaN into value or derivative; the
argument of the non-series branch is nevertheless replaced by 1 when ``|a|`` is small
(the "double where" guard), so neither branch ever evaluates ``0/0`` and the result does not rely
on that masking.  The derivative at ``w = 0`` is then the derivative of the series, i.e. the exact
limit ``dx+/dw = -v dt^2 sin(theta) / 2``.
"""

from __future__ import annotations

import functools
import numbers

import casadi as ca

__all__ = [
    "INTEGRATORS",
    "rhs_function",
    "rhs_jacobian_function",
    "step_function",
    "step_jacobian_function",
    "n_weights",
    "network_function",
    "network_input_jacobian_function",
    "network_weight_jacobian_function",
    "rotation_function",
    "rotation_det",
    "rotation_det_string",
    "tracking_error_function",
    "kanayama_error_dynamics_function",
    "error_rate_function",
    "error_dynamics_residual_function",
    "error_dynamics_function",
    "error_dynamics_jacobian_function",
    "backstepping_law_function",
    "backstepping_error_dynamics_function",
    "backstepping_jacobian_function",
]

#: Integrator names accepted by the step functions (the same names as ``wmr.model.kinematics``).
INTEGRATORS = ("exact", "euler", "rk4")

# |a| below which sinc(a) = sin(a)/a is replaced by its series (a = w dt / 2).
_SINC_SERIES_BELOW = 1e-3


# ---------------------------------------------------------------------------------------------
# Unicycle, eq. (1)
# ---------------------------------------------------------------------------------------------


@functools.cache
def rhs_function() -> ca.Function:
    """Eq. (1) as ``Function('rhs', [q, u], [q_dot])``.

    ``q = (x, y, theta)`` (3,), ``u = (v, w)`` (2,), ``q_dot = (v cos theta, v sin theta, w)``.
    """
    q, u = _sym("q", 3), _sym("u", 2)
    return ca.Function("rhs", [q, u], [_rhs(q, u)], ["q", "u"], ["q_dot"])


@functools.cache
def rhs_jacobian_function() -> ca.Function:
    """Jacobians of eq. (1): ``Function('rhs_jacobians', [q, u], [A, B])``.

    ``A = d q_dot / dq`` (3, 3) and ``B = d q_dot / du`` (3, 2), by AD.
    """
    q, u = _sym("q", 3), _sym("u", 2)
    f = _rhs(q, u)
    return ca.Function(
        "rhs_jacobians", [q, u], [ca.jacobian(f, q), ca.jacobian(f, u)], ["q", "u"], ["A", "B"]
    )


@functools.cache
def step_function(integrator: str = "exact") -> ca.Function:
    """One zero-order-hold step: ``Function('step', [q, u, dt], [q_next])``.

    Parameters
    ----------
    integrator : {"exact", "euler", "rk4"}
        ``"exact"``: the arc of constant ``(v, w)``, for ``w != 0``
        ``x+ = x + v/w (sin(theta + w dt) - sin(theta))``,
        ``y+ = y - v/w (cos(theta + w dt) - cos(theta))``, written without the division by
        ``w`` as ``x + v dt sinc(a) cos(theta + a)``, ``y + v dt sinc(a) sin(theta + a)``,
        ``a = w dt/2`` (``2 sin(a) cos(theta + a) = sin(theta + 2a) - sin(theta)``);
        ``"euler"``: ``q + dt f(q, u)``; ``"rk4"``: the classical four-stage Runge-Kutta map.

    Returns
    -------
    casadi.Function
        Inputs ``q`` (3,) [m, m, rad], ``u`` (2,) [m/s, rad/s], ``dt`` (1,) [s]; output
        ``q_next`` (3,), theta not wrapped.
    """
    q, u, dt = _sym("q", 3), _sym("u", 2), _sym("dt", 1)
    return ca.Function(
        "step", [q, u, dt], [_step(q, u, dt, integrator)], ["q", "u", "dt"], ["q_next"]
    )


@functools.cache
def step_jacobian_function(integrator: str = "exact") -> ca.Function:
    """Jacobians of :func:`step_function`: ``Function('step_jacobians', [q, u, dt], [F, G])``.

    ``F = dq_next/dq`` (3, 3) and ``G = dq_next/du`` (3, 2), by AD through the step (for
    ``"exact"`` through the guarded sinc, so they are exact at ``w = 0`` too).
    """
    q, u, dt = _sym("q", 3), _sym("u", 2), _sym("dt", 1)
    q_next = _step(q, u, dt, integrator)
    return ca.Function(
        "step_jacobians",
        [q, u, dt],
        [ca.jacobian(q_next, q), ca.jacobian(q_next, u)],
        ["q", "u", "dt"],
        ["F", "G"],
    )


# ---------------------------------------------------------------------------------------------
# Network, eqs. (18)-(24) corrected (errata E7, E8)
# ---------------------------------------------------------------------------------------------


def n_weights(n_in: int, n_h: int, n_out: int) -> int:
    """Length of the flat weight vector, ``n_h n_in + n_h + n_out n_h + n_out``."""
    _check_sizes(n_in, n_h, n_out)
    return n_h * n_in + n_h + n_out * n_h + n_out


@functools.cache
def network_function(n_in: int, n_h: int, n_out: int) -> ca.Function:
    """Forward pass: ``Function('network', [theta, x], [z, h])``.

    ``a = V x + b_v``, ``h = tanh(a)``, ``z = W h + b_w`` with ``theta`` (n,) laid out
    ``[V (n_h x n_in, row-major), b_v (n_h), W (n_out x n_h, row-major), b_w (n_out)]``
    (``docs/conventions.md``); ``x`` (n_in,), ``z`` (n_out,), ``h`` (n_h,).
    """
    theta, x = _sym("theta", n_weights(n_in, n_h, n_out)), _sym("x", n_in)
    z, h = _network(theta, x, n_in, n_h, n_out)
    return ca.Function("network", [theta, x], [z, h], ["theta", "x"], ["z", "h"])


@functools.cache
def network_input_jacobian_function(n_in: int, n_h: int, n_out: int) -> ca.Function:
    """Input Jacobian ``dz/dx`` (n_out, n_in) by AD: ``Function(..., [theta, x], [J])``.

    It equals ``W diag(1 - h^2) V`` (errata E7); that closed form is not used here.
    """
    theta, x = _sym("theta", n_weights(n_in, n_h, n_out)), _sym("x", n_in)
    z, _ = _network(theta, x, n_in, n_h, n_out)
    return ca.Function(
        "network_input_jacobian", [theta, x], [ca.jacobian(z, x)], ["theta", "x"], ["J"]
    )


@functools.cache
def network_weight_jacobian_function(n_in: int, n_h: int, n_out: int) -> ca.Function:
    """Weight Jacobian ``H = dz/dtheta`` (n_out, n) by AD: ``Function(..., [theta, x], [H])``.

    The weight EKF's measurement matrix (errata E8), columns in the flat layout of ``theta``.
    """
    theta, x = _sym("theta", n_weights(n_in, n_h, n_out)), _sym("x", n_in)
    z, _ = _network(theta, x, n_in, n_h, n_out)
    return ca.Function(
        "network_weight_jacobian", [theta, x], [ca.jacobian(z, theta)], ["theta", "x"], ["H"]
    )


# ---------------------------------------------------------------------------------------------
# Error frame, eqs. (4)/(6) (errata E3)
# ---------------------------------------------------------------------------------------------


@functools.cache
def rotation_function(printed: bool = False) -> ca.Function:
    """``T_e(theta)`` (3, 3) as ``Function('rotation', [theta], [T])``.

    ``printed=False``: ``[[c, s, 0], [-s, c, 0], [0, 0, 1]]`` (errata E3);
    ``printed=True``: the paper's ``[[c, s, 0], [s, c, 0], [0, 0, 1]]``.
    """
    theta = _sym("theta", 1)
    return ca.Function("rotation", [theta], [_rotation(theta, printed)], ["theta"], ["T"])


def rotation_det(printed: bool = False) -> ca.SX:
    """``det T_e(theta)`` as an SX expression in the symbol ``theta``.

    CasADi's own simplification rule ``sq(sin x) + sq(cos x) -> 1`` makes the corrected
    determinant the constant 1; the printed one is ``cos^2 theta - sin^2 theta = cos 2 theta``.
    """
    theta = ca.SX.sym("theta")
    return ca.det(_rotation(theta, printed))


def rotation_det_string(printed: bool = False) -> str:
    """``str(casadi.simplify(det T_e))``, e.g. ``'(sq(cos(theta))-sq(sin(theta)))'`` if printed."""
    return str(ca.simplify(rotation_det(printed)))


@functools.cache
def tracking_error_function(printed: bool = False) -> ca.Function:
    """Eq. (6) without wrapping: ``Function('tracking_error', [q, q_r], [e])``.

    ``e = T_e(theta) (q_r - q)``, ``q``, ``q_r``, ``e`` all (3,); ``e3 = theta_r - theta`` is
    left continuous (the library wraps it to (-pi, pi]).
    """
    q, q_r = _sym("q", 3), _sym("q_r", 3)
    return ca.Function(
        "tracking_error", [q, q_r], [_tracking_error(q, q_r, printed)], ["q", "q_r"], ["e"]
    )


# ---------------------------------------------------------------------------------------------
# Continuous-time error dynamics
# ---------------------------------------------------------------------------------------------


@functools.cache
def kanayama_error_dynamics_function() -> ca.Function:
    """Kanayama's error dynamics (1990): ``Function('kanayama', [e, u, u_r], [e_dot])``.

    ``e1' = w e2 - v + v_r cos e3``, ``e2' = -w e1 + v_r sin e3``, ``e3' = w_r - w``;
    ``u_r = (v_r, w_r)``.  Written from the literature, not derived; :func:`error_rate_function`
    derives them and :func:`error_dynamics_residual_function` compares the two.
    """
    e, u, u_r = _sym("e", 3), _sym("u", 2), _sym("u_r", 2)
    return ca.Function(
        "kanayama", [e, u, u_r], [_kanayama(e, u, u_r)], ["e", "u", "u_r"], ["e_dot"]
    )


@functools.cache
def error_rate_function(printed: bool = False) -> ca.Function:
    """``de/dt`` by the chain rule: ``Function('error_rate', [q, u, ref], [e, e_dot])``.

    Derivation
    ----------
    ``e = T_e(theta)(q_r - q)`` depends on time through ``q`` and ``q_r``; with
    ``q' = G(theta) u`` (eq. 1) and the reference moving as ``q_r' = G(theta_r) u_r``
    (eq. 2 with ``v_r``, errata E1), ``e' = de/dq q' + de/dq_r q_r'``, computed as one
    forward-mode directional derivative (``casadi.jtimes``) of ``e`` along ``(q', q_r')``.
    ``ref = (x_r, y_r, theta_r, v_r, w_r)`` (5,) as in ``docs/conventions.md``.
    """
    q, u, ref = _sym("q", 3), _sym("u", 2), _sym("ref", 5)
    e, e_dot = _error_rate(q, u, ref, printed)
    return ca.Function("error_rate", [q, u, ref], [e, e_dot], ["q", "u", "ref"], ["e", "e_dot"])


@functools.cache
def error_dynamics_residual_function(printed: bool = False) -> ca.Function:
    """``Function('error_dynamics_residual', [q, u, ref], [r])``, ``r`` (3,).

    ``r = e'(chain rule) - kanayama(e, u, u_r)`` with ``e = T_e(theta)(q_r - q)``.  It vanishes
    identically for the corrected rotation; for the printed one it does not: the printed error
    obeys (module tests check these forms)::

        e1' = (w / cos 2theta)(e2 - sin 2theta e1) - v + v_r cos e3
        e2' = (w / cos 2theta)(e1 - sin 2theta e2) - v sin 2theta + v_r sin(theta_r + theta)
        e3' = w_r - w
    """
    q, u, ref = _sym("q", 3), _sym("u", 2), _sym("ref", 5)
    e, e_dot = _error_rate(q, u, ref, printed)
    r = e_dot - _kanayama(e, u, ref[3:5])
    return ca.Function("error_dynamics_residual", [q, u, ref], [r], ["q", "u", "ref"], ["r"])


@functools.cache
def error_dynamics_function(printed: bool = False) -> ca.Function:
    """Error dynamics in error coordinates: ``e_dot(e, u, u_r[, theta])``.

    Returns ``Function('error_dynamics', [e, u, u_r], [e_dot])`` for the corrected rotation and
    ``Function('error_dynamics', [e, u, u_r, theta], [e_dot])`` for the printed one.

    Derivation
    ----------
    The chain-rule ``e'`` of :func:`error_rate_function` evaluated at ``q = (0, 0, theta)`` and
    ``q_r = q + (T_e(theta)^{-1} (e1, e2), e3)``, ``theta_r = theta + e3``, which inverts eq. (6)
    (translation drops out structurally since ``e`` depends on ``q_r - q`` only).  Corrected: the
    result is independent of theta (SE(2) invariance; tests check it against the chain rule at
    random headings), so it is taken at ``theta = 0`` and equals Kanayama's form.  Printed:
    ``T_e^{-1}`` carries ``1/cos 2theta`` (singular at theta = +-45 deg).
    """
    e, u, u_r, theta = _sym("e", 3), _sym("u", 2), _sym("u_r", 2), _sym("theta", 1)
    e_dot = _error_dynamics(e, u, u_r, theta if printed else 0.0, printed)
    ins, names = [e, u, u_r], ["e", "u", "u_r"]
    if printed:
        ins, names = [*ins, theta], [*names, "theta"]
    return ca.Function("error_dynamics", ins, [e_dot], names, ["e_dot"])


@functools.cache
def error_dynamics_jacobian_function(printed: bool = False) -> ca.Function:
    """Open-loop linearisation of :func:`error_dynamics_function`: outputs ``A`` and ``B``.

    ``A = d e_dot/de`` (3, 3), ``B = d e_dot/du`` (3, 2); same inputs as
    :func:`error_dynamics_function` (evaluate at ``e = 0``, ``u = u_r`` for the linearisation
    about perfect tracking).
    """
    f = error_dynamics_function(printed)
    ins = [_sym(f.name_in(i), f.size1_in(i)) for i in range(f.n_in())]
    e_dot = f(*ins)
    return ca.Function(
        "error_dynamics_jacobians",
        ins,
        [ca.jacobian(e_dot, ins[0]), ca.jacobian(e_dot, ins[1])],
        f.name_in(),
        ["A", "B"],
    )


@functools.cache
def backstepping_law_function() -> ca.Function:
    """Kanayama's backstepping law: ``Function('backstepping', [e, u_r, k], [u])``.

    ``v = v_r cos e3 + k1 e1``, ``w = w_r + v_r (k2 e2 + k3 sin e3)``; ``k = (k1, k2, k3)``.
    """
    e, u_r, k = _sym("e", 3), _sym("u_r", 2), _sym("k", 3)
    return ca.Function(
        "backstepping", [e, u_r, k], [_backstepping(e, u_r, k)], ["e", "u_r", "k"], ["u"]
    )


@functools.cache
def backstepping_error_dynamics_function(printed: bool = False) -> ca.Function:
    """Closed-loop error dynamics under backstepping: ``e_dot(e, u_r, k[, theta])``.

    :func:`error_dynamics_function` with ``u`` from :func:`backstepping_law_function` applied
    to the (corrected or printed) error.  Inputs ``[e, u_r, k]`` (+ ``theta`` if printed).
    """
    e, u_r, k, theta = _sym("e", 3), _sym("u_r", 2), _sym("k", 3), _sym("theta", 1)
    e_dot = _error_dynamics(e, _backstepping(e, u_r, k), u_r, theta if printed else 0.0, printed)
    ins, names = [e, u_r, k], ["e", "u_r", "k"]
    if printed:
        ins, names = [*ins, theta], [*names, "theta"]
    return ca.Function("backstepping_error_dynamics", ins, [e_dot], names, ["e_dot"])


@functools.cache
def backstepping_jacobian_function(printed: bool = False) -> ca.Function:
    """Closed-loop Jacobian at ``e = 0``: ``Function(..., [v_r, w_r, k1, k2, k3], [A])``.

    ``A = d e_dot/de`` (3, 3) of :func:`backstepping_error_dynamics_function` at ``e = 0``, by
    AD.  For the corrected rotation it is Kanayama's
    ``[[-k1, w_r, 0], [-w_r, 0, v_r], [0, -v_r k2, -v_r k3]]``.  The printed variant takes the
    robot heading ``theta`` as a sixth input (its linearisation depends on it).
    """
    scalars = [_sym(n, 1) for n in ("v_r", "w_r", "k1", "k2", "k3")]
    v_r, w_r, k1, k2, k3 = scalars
    e, theta = _sym("e", 3), _sym("theta", 1)
    u_r, k = ca.vertcat(v_r, w_r), ca.vertcat(k1, k2, k3)
    e_dot = _error_dynamics(e, _backstepping(e, u_r, k), u_r, theta if printed else 0.0, printed)
    A = ca.substitute(ca.jacobian(e_dot, e), e, ca.DM.zeros(3))
    ins, names = scalars, ["v_r", "w_r", "k1", "k2", "k3"]
    if printed:
        ins, names = [*ins, theta], [*names, "theta"]
    return ca.Function("backstepping_jacobian", ins, [A], names, ["A"])


# ---------------------------------------------------------------------------------------------
# Private expression builders
# ---------------------------------------------------------------------------------------------


def _sym(name: str, n: int) -> ca.SX:
    return ca.SX.sym(name, n)


def _check_integrator(integrator: str) -> None:
    if integrator not in INTEGRATORS:
        raise ValueError(f"unknown integrator {integrator!r}; expected one of {INTEGRATORS}")


def _check_sizes(n_in: int, n_h: int, n_out: int) -> None:
    for name, n in (("n_in", n_in), ("n_h", n_h), ("n_out", n_out)):
        if not isinstance(n, numbers.Integral) or isinstance(n, bool) or n < 1:
            raise ValueError(f"{name} must be a positive int, got {n!r}")


def _rhs(q, u):
    """Eq. (1): ``(v cos theta, v sin theta, w)``."""
    return ca.vertcat(u[0] * ca.cos(q[2]), u[0] * ca.sin(q[2]), u[1])


def _sinc(a):
    """``sin(a)/a`` with its series for ``|a| < 1e-3`` and a guarded argument (module docs)."""
    small = ca.fabs(a) < _SINC_SERIES_BELOW
    a_safe = ca.if_else(small, 1.0, a)  # the sin/a branch never sees a = 0
    a2 = a * a
    series = 1.0 - a2 / 6.0 * (1.0 - a2 / 20.0 * (1.0 - a2 / 42.0))  # 1 - a^2/3! + a^4/5! - a^6/7!
    return ca.if_else(small, series, ca.sin(a_safe) / a_safe)


def _step(q, u, dt, integrator):
    _check_integrator(integrator)
    if integrator == "exact":
        v, w = u[0], u[1]
        a = 0.5 * w * dt
        chord = v * dt * _sinc(a)  # signed length of the arc's chord
        return ca.vertcat(
            q[0] + chord * ca.cos(q[2] + a), q[1] + chord * ca.sin(q[2] + a), q[2] + w * dt
        )
    if integrator == "euler":
        return q + dt * _rhs(q, u)
    k1 = _rhs(q, u)
    k2 = _rhs(q + 0.5 * dt * k1, u)
    k3 = _rhs(q + 0.5 * dt * k2, u)
    k4 = _rhs(q + dt * k3, u)
    return q + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _network(theta, x, n_in, n_h, n_out):
    i1 = n_h * n_in
    i2 = i1 + n_h
    i3 = i2 + n_out * n_h
    # CasADi reshapes column-major: a row-major (r, c) block is the transpose of a (c, r) reshape.
    V = ca.reshape(theta[0:i1], n_in, n_h).T
    b_v = theta[i1:i2]
    W = ca.reshape(theta[i2:i3], n_h, n_out).T
    b_w = theta[i3 : i3 + n_out]
    h = ca.tanh(ca.mtimes(V, x) + b_v)
    return ca.mtimes(W, h) + b_w, h


def _rotation(theta, printed):
    c, s = ca.cos(theta), ca.sin(theta)
    T = ca.SX.eye(3)
    T[0, 0], T[0, 1] = c, s
    T[1, 0], T[1, 1] = (s if printed else -s), c
    return T


def _tracking_error(q, q_r, printed):
    return ca.mtimes(_rotation(q[2], printed), q_r - q)


def _kanayama(e, u, u_r):
    v, w, v_r, w_r = u[0], u[1], u_r[0], u_r[1]
    return ca.vertcat(w * e[1] - v + v_r * ca.cos(e[2]), -w * e[0] + v_r * ca.sin(e[2]), w_r - w)


def _error_rate(q, u, ref, printed):
    q_r, u_r = ref[0:3], ref[3:5]
    e = _tracking_error(q, q_r, printed)
    e_dot = ca.jtimes(e, ca.vertcat(q, q_r), ca.vertcat(_rhs(q, u), _rhs(q_r, u_r)))
    return e, e_dot


def _poses_from_error(e, theta, printed):
    """Robot pose ``(0, 0, theta)`` and the reference pose whose error (eq. 6) is ``e``."""
    q = ca.vertcat(0.0, 0.0, theta)
    d_xy = ca.mtimes(ca.inv(_rotation(theta, printed)[0:2, 0:2]), e[0:2])
    return q, ca.vertcat(d_xy, theta + e[2])


def _error_dynamics(e, u, u_r, theta, printed):
    q, q_r = _poses_from_error(e, theta, printed)
    # jtimes needs symbols, so differentiate in (q, u, ref) first, then evaluate the graph here.
    _, e_dot = error_rate_function(printed)(q, u, ca.vertcat(q_r, u_r))
    return e_dot


def _backstepping(e, u_r, k):
    v_r, w_r = u_r[0], u_r[1]
    return ca.vertcat(
        v_r * ca.cos(e[2]) + k[0] * e[0], w_r + v_r * (k[1] * e[1] + k[2] * ca.sin(e[2]))
    )


def _error_step(e, u, u_r, dt, theta, integrator, printed):
    q, q_r = _poses_from_error(e, theta, printed)
    q_next = _step(q, u, dt, integrator)
    q_r_next = _step(q_r, u_r, dt, "exact")
    return _tracking_error(q_next, q_r_next, printed)


def __getattr__(name: str):
    """The sampled-data closed loops live in ``wmr.model.symbolic_loops`` (one concept per file);
    their names stay reachable here."""
    from wmr.model import symbolic_loops

    if name in symbolic_loops.__all__:
        return getattr(symbolic_loops, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
