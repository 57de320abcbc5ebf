"""Sampled-data (one-step) error dynamics and closed loops in corrected error coordinates (CasADi).

The one-step error dynamics (:func:`error_step_function` and its Jacobians) and the closed loops of
the fixed PID (eq. 7, discretised as in ``wmr.controllers.pid``) and of backstepping whose state is
the corrected error (plus the PID's memory), with the controller fed the corrected or the printed
error (errata E3), defined at every heading (no ``T_e^{-1}`` of the printed matrix), and their
Jacobians by CasADi's AD.  Built from the expression builders of :mod:`wmr.model.symbolic` (the
oracle's one model of the step and the error frame); the names are also reachable as
``wmr.model.symbolic.<name>``.
"""

from __future__ import annotations

import functools

import casadi as ca

from wmr.model.symbolic import (
    _backstepping,
    _error_step,
    _poses_from_error,
    _step,
    _sym,
    _tracking_error,
)

__all__ = [
    "error_step_function",
    "error_step_jacobian_function",
    "backstepping_step_jacobian_function",
    "PID_STATE_NAMES",
    "pid_closed_loop_step_function",
    "pid_closed_loop_jacobian_function",
    "backstepping_closed_loop_step_function",
    "backstepping_closed_loop_jacobian_function",
]

# ---------------------------------------------------------------------------------------------
# Sampled-data (one-step) error dynamics
# ---------------------------------------------------------------------------------------------


@functools.cache
def error_step_function(integrator: str = "exact", printed: bool = False) -> ca.Function:
    """Error after one sample period: ``e_next(e, u, u_r, dt[, theta])``.

    Returns ``Function('error_step', [e, u, u_r, dt], [e_next])`` (+ ``theta`` as a fifth input
    if printed: the robot heading at ``t_k``).

    Derivation
    ----------
    At ``t_k`` put the robot at ``q = (0, 0, theta)`` (``theta = 0`` when corrected: SE(2)
    invariance) and the reference at ``q_r = q + (T_e(theta)^{-1} (e1, e2), e3)``.  The robot
    moves by one ``integrator`` step with ``u`` held; the reference by its own exact arc with
    ``u_r = (v_r, w_r)`` held (the ZOH idealisation of a reference whose velocities are constant
    over the step).  Then ``e_next = T_e(theta_next)(q_r_next - q_next)``, ``e3`` unwrapped.
    For ``integrator="exact"`` and ``u = u_r``, ``e = 0`` is a fixed point; for Euler or RK4 the
    robot's discretisation error makes it only approximately one.
    """
    e, u, u_r, dt, theta = (_sym("e", 3), _sym("u", 2), _sym("u_r", 2), _sym("dt", 1),
                            _sym("theta", 1))  # fmt: skip
    e_next = _error_step(e, u, u_r, dt, theta if printed else 0.0, integrator, printed)
    ins, names = [e, u, u_r, dt], ["e", "u", "u_r", "dt"]
    if printed:
        ins, names = [*ins, theta], [*names, "theta"]
    return ca.Function("error_step", ins, [e_next], names, ["e_next"])


@functools.cache
def error_step_jacobian_function(integrator: str = "exact", printed: bool = False) -> ca.Function:
    """Jacobians of :func:`error_step_function`: outputs ``E = de_next/de`` (3, 3) and
    ``B = de_next/du`` (3, 2), by AD; same inputs.  As ``dt -> 0``, ``E = I + dt A + O(dt^2)``
    and ``B = dt B_c + O(dt^2)`` with ``A``, ``B_c`` of :func:`error_dynamics_jacobian_function`.
    """
    f = error_step_function(integrator, printed)
    ins = [_sym(f.name_in(i), f.size1_in(i)) for i in range(f.n_in())]
    e_next = f(*ins)
    return ca.Function(
        "error_step_jacobians",
        ins,
        [ca.jacobian(e_next, ins[0]), ca.jacobian(e_next, ins[1])],
        f.name_in(),
        ["E", "B"],
    )


@functools.cache
def backstepping_step_jacobian_function(
    integrator: str = "exact", printed: bool = False
) -> ca.Function:
    """Sampled-data closed loop at ``e = 0``: ``A_d(v_r, w_r, k1, k2, k3, dt[, theta])``.

    ``A_d = d e_next/d e_k`` (3, 3) at ``e_k = 0`` with ``u_k`` the backstepping law of the
    sampled error held over the step, i.e. ``E + B du/de`` of :func:`error_step_jacobian_function`
    (computed by AD through the composition).
    """
    scalars = [_sym(n, 1) for n in ("v_r", "w_r", "k1", "k2", "k3", "dt")]
    v_r, w_r, k1, k2, k3, dt = scalars
    e, theta = _sym("e", 3), _sym("theta", 1)
    u_r, k = ca.vertcat(v_r, w_r), ca.vertcat(k1, k2, k3)
    e_next = _error_step(
        e, _backstepping(e, u_r, k), u_r, dt, theta if printed else 0.0, integrator, printed
    )
    A_d = ca.substitute(ca.jacobian(e_next, e), e, ca.DM.zeros(3))
    ins, names = scalars, ["v_r", "w_r", "k1", "k2", "k3", "dt"]
    if printed:
        ins, names = [*ins, theta], [*names, "theta"]
    return ca.Function("backstepping_step_jacobian", ins, [A_d], names, ["A_d"])


# ---------------------------------------------------------------------------------------------
# Sampled-data closed loops in corrected error coordinates
# ---------------------------------------------------------------------------------------------

#: State of :func:`pid_closed_loop_step_function`: the corrected error at ``t_k``, then the PID's
#: memory from ``t_{k-1}``: the integrals ``I[e1]``, ``I[s]`` and the previous signals ``e1``, ``s``
#: (of the error the controller sees).
PID_STATE_NAMES = ("e1", "e2", "e3", "I_e1", "I_s", "e1_prev", "s_prev")


@functools.cache
def pid_closed_loop_step_function(
    integrator: str = "exact", printed: bool = False, feed_forward: bool = False
) -> ca.Function:
    """One sample of the closed loop with the PID of eq. (7): ``x_next(x, u_r, K, dt[, theta_r])``.

    Returns ``Function('pid_closed_loop_step', [x, u_r, K, dt], [x_next])`` (+ ``theta_r`` as a
    fifth input if printed: the reference heading at ``t_k``).

    Parameters
    ----------
    integrator : {"exact", "euler", "rk4"}
        The robot's step (the reference always moves on its exact arc).
    printed : bool
        The controller sees the printed error ``T_p(theta)(q_r - q)`` of eqs. (4)/(6) (errata
        E3) instead of the corrected one; the state stays the corrected error.
    feed_forward : bool
        Add ``(v_r cos e3, w_r)`` to eq. (7) (``wmr.controllers.pid.Settings.feed_forward``).

    Notes
    -----
    State ``x`` (7,) as in :data:`PID_STATE_NAMES`; ``u_r = (v_r, w_r)`` held over the step;
    ``K = (Kpv, Kiv, Kdv, Kpw, Kiw, Kdw)``; ``dt`` [s].  Derivation: the robot is put at
    ``q = (0, 0, theta)`` and the reference at ``q + (R(theta)^T (e1, e2), e3)``, ``R`` the
    rotation of eq. (6) corrected, with ``theta = 0`` when corrected (SE(2) invariance) and
    ``theta = theta_r - e3`` when printed (the printed error depends on the heading).  The
    controller's error ``e_c = T_e(theta)(q_r - q)`` (printed or not) drives eq. (7) discretised
    as in ``wmr.controllers.pid.pid_output``::

        I1 <- I1 + dt e_c1,   I2 <- I2 + dt s,   s = e_c3 + e_c2
        v = Kpv e_c1 + Kiv I1 + Kdv (e_c1 - e1_prev)/dt      (+ v_r cos e_c3)
        w = Kpw s    + Kiw I2 + Kdw (s - s_prev)/dt          (+ w_r)

    then the robot moves one ``integrator`` step with ``u = (v, w)`` held, the reference its
    exact arc with ``u_r`` held, and ``x_next = (R(theta_next)(q_r_next - q_next), I1, I2, e_c1,
    s)`` (``e3`` unwrapped).  Without feed-forward the equilibrium at perfect tracking is
    ``x* = (0, 0, 0, v_r/Kiv, w_r/Kiw, 0, 0)`` (the integrals carry the nominal input); with it,
    ``x* = 0``.  For ``integrator="exact"`` it is an exact fixed point.
    """
    x, u_r, K = _sym("x", 7), _sym("u_r", 2), _sym("K", 6)
    dt, theta_r = _sym("dt", 1), _sym("theta_r", 1)
    x_next = _pid_closed_loop_step(x, u_r, K, dt, theta_r, integrator, printed, feed_forward)
    ins, names = [x, u_r, K, dt], ["x", "u_r", "K", "dt"]
    if printed:
        ins, names = [*ins, theta_r], [*names, "theta_r"]
    return ca.Function("pid_closed_loop_step", ins, [x_next], names, ["x_next"])


@functools.cache
def pid_closed_loop_jacobian_function(
    integrator: str = "exact", printed: bool = False, feed_forward: bool = False
) -> ca.Function:
    """``A_cl = dx_next/dx`` (7, 7) of :func:`pid_closed_loop_step_function`, by AD.

    Same inputs; evaluate it at the equilibrium ``x*`` (its docstring): the loop is nonlinear in
    the integral states through the plant, so the Jacobian depends on where it is taken.
    """
    f = pid_closed_loop_step_function(integrator, printed, feed_forward)
    ins = [_sym(f.name_in(i), f.size1_in(i)) for i in range(f.n_in())]
    return ca.Function(
        "pid_closed_loop_jacobian", ins, [ca.jacobian(f(*ins), ins[0])], f.name_in(), ["A_cl"]
    )


@functools.cache
def backstepping_closed_loop_step_function(
    integrator: str = "exact", printed: bool = False
) -> ca.Function:
    """One sample under backstepping (state: corrected error): ``e_next(e, u_r, k, dt[, theta_r])``.

    As :func:`pid_closed_loop_step_function` with the static law of
    :func:`backstepping_law_function` applied to the controller's error (printed or corrected);
    ``k = (k1, k2, k3)``.  For ``printed=False`` its Jacobian at ``e = 0`` is
    :func:`backstepping_step_jacobian_function`; for ``printed=True`` it is defined at every
    reference heading ``theta_r`` (that function's state, the printed error, is not at +-45 deg).
    """
    e, u_r, k = _sym("e", 3), _sym("u_r", 2), _sym("k", 3)
    dt, theta_r = _sym("dt", 1), _sym("theta_r", 1)
    q, q_r = _closed_loop_poses(e, theta_r, printed)
    u = _backstepping(_tracking_error(q, q_r, printed), u_r, k)
    e_next = _tracking_error(_step(q, u, dt, integrator), _step(q_r, u_r, dt, "exact"), False)
    ins, names = [e, u_r, k, dt], ["e", "u_r", "k", "dt"]
    if printed:
        ins, names = [*ins, theta_r], [*names, "theta_r"]
    return ca.Function("backstepping_closed_loop_step", ins, [e_next], names, ["e_next"])


@functools.cache
def backstepping_closed_loop_jacobian_function(
    integrator: str = "exact", printed: bool = False
) -> ca.Function:
    """``A_d = de_next/de`` (3, 3) of :func:`backstepping_closed_loop_step_function`, by AD."""
    f = backstepping_closed_loop_step_function(integrator, printed)
    ins = [_sym(f.name_in(i), f.size1_in(i)) for i in range(f.n_in())]
    return ca.Function(
        "backstepping_closed_loop_jacobian",
        ins,
        [ca.jacobian(f(*ins), ins[0])],
        f.name_in(),
        ["A_d"],
    )


def _closed_loop_poses(e, theta_r, printed):
    """Robot and reference poses whose corrected error is ``e``; robot heading 0 if corrected,
    ``theta_r - e3`` if printed (then the reference heading is ``theta_r``)."""
    return _poses_from_error(e, theta_r - e[2] if printed else 0.0, False)


def _pid_closed_loop_step(x, u_r, K, dt, theta_r, integrator, printed, feed_forward):
    q, q_r = _closed_loop_poses(x[0:3], theta_r, printed)
    e_c = _tracking_error(q, q_r, printed)
    x1, sw = e_c[0], e_c[2] + e_c[1]
    i1, i2 = x[3] + dt * x1, x[4] + dt * sw
    v = K[0] * x1 + K[1] * i1 + K[2] * (x1 - x[5]) / dt
    w = K[3] * sw + K[4] * i2 + K[5] * (sw - x[6]) / dt
    if feed_forward:
        v, w = v + u_r[0] * ca.cos(e_c[2]), w + u_r[1]
    q_next = _step(q, ca.vertcat(v, w), dt, integrator)
    e_next = _tracking_error(q_next, _step(q_r, u_r, dt, "exact"), False)
    return ca.vertcat(e_next, i1, i2, x1, sw)
