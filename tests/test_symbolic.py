"""Oracle tests of wmr.model.symbolic (CasADi AD) against finite differences, closed forms, the
library.

Layers (STYLE 6): each symbolic Jacobian is checked against central differences of the symbolic
model itself, then against the library's hand-derived closed forms (``wmr.model.kinematics``,
``wmr.estimation.nn``) at seeded random points plus edge points; the printed forms of the paper are
shown
failing the same checks.
"""

from __future__ import annotations

import importlib
import inspect
import subprocess
import sys

import casadi as ca
import numpy as np
import pytest
from numpy.testing import assert_allclose
from oracles import central_fd as _central_fd

from wmr.model import kinematics as kin
from wmr.model import symbolic as sym

SEED = 20240251  # Actuators 13(2):51
N_RANDOM = 256

# AD through the symbolic model and the library's hand-derived formulas are both exact in
# exact arithmetic; in float64 they differ by rounding only (a few ulp of O(1) entries, plus the
# cancellation in (cos a - sinc a)/a just above the sinc series switches, ~1e-16/|a| <= 1e-12).
EXACT_TOL = 1e-12
# Central differences, step FD_STEP: truncation ~FD_STEP^2 |f'''|/6 ~ 1e-13, rounding
# ~eps |f| / FD_STEP ~ 1e-9 for |f| ~ 5; 1e-7 is two decades above both.
FD_STEP = 1e-6
FD_TOL = 1e-7
# An identity checked at random points: terms up to |w e| ~ 30, so rounding ~ 30 eps ~ 1e-14.
IDENTITY_TOL = 1e-13
# Clearly non-zero: the printed rotation's residual is O(|v| + |w e|) at generic points.
CLEARLY_NONZERO = 0.1


def _np(x):
    """A CasADi DM (or tuple of them) as float numpy arrays; vectors flattened to 1-D."""
    if isinstance(x, tuple | list):
        return tuple(_np(xi) for xi in x)
    a = np.asarray(x.full() if isinstance(x, ca.DM) else x, dtype=float)
    return a.ravel() if a.ndim == 2 and a.shape[1] == 1 else a


def central_fd(fun, x, step=FD_STEP):
    return _central_fd(fun, x, step)


def fd_jacobian(fun, args, i, out=0):
    """Central differences of output ``out`` of the CasADi Function ``fun`` with respect to its
    input ``i``, at ``args``; (m, n)."""

    def g(x):
        a = list(args)
        a[i] = x
        r = fun(*a)
        return _np(r[out] if isinstance(r, tuple) else r)

    return central_fd(g, np.atleast_1d(np.asarray(args[i], dtype=float)))


def wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


# ---------------------------------------------------------------------------------------------
# Sample points
# ---------------------------------------------------------------------------------------------


def _random_step_points(n=N_RANDOM, seed=SEED):
    rng = np.random.default_rng(seed)
    q = np.column_stack(
        (rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-2 * np.pi, 2 * np.pi, n))
    )
    u = np.column_stack((rng.uniform(-2, 2, n), rng.uniform(-3, 3, n)))
    dt = rng.uniform(1e-3, 0.5, n)
    return [(q[i], u[i], float(dt[i])) for i in range(n)]


def _edge_step_points():
    pts = []
    dt = 0.01
    for theta in (np.pi, -np.pi, 0.0, np.pi / 4):
        for v in (0.0, 0.8, -1.3):
            # w = 0, +-1e-9, and both sides of the sinc series switches (|a| = 1e-4 in the
            # library, 1e-3 here; a = w dt / 2)
            for w in (0.0, 1e-9, -1e-9, 1.0,
                      2e-4 / dt * (1 - 1e-6), 2e-4 / dt * (1 + 1e-6),
                      -2e-3 / dt * (1 - 1e-6), 2e-3 / dt * (1 + 1e-6)):  # fmt: skip
                pts.append((np.array([0.4, -1.1, theta]), np.array([v, w]), dt))
    return pts


STEP_POINTS = _random_step_points() + _edge_step_points()


def _random_error_points(n=64, seed=SEED + 1, max_err=1.0):
    """``(q, u, ref)`` with a pose error of at most ``max_err`` per component."""
    rng = np.random.default_rng(seed)
    pts = []
    for _ in range(n):
        q = np.array([rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-np.pi, np.pi)])
        q_r = q + rng.uniform(-max_err, max_err, 3)
        u = np.array([rng.uniform(-2, 2), rng.uniform(-3, 3)])
        u_r = np.array([rng.uniform(-2, 2), rng.uniform(-3, 3)])
        pts.append((q, u, np.concatenate((q_r, u_r))))
    return pts


ERROR_POINTS = _random_error_points()


# ---------------------------------------------------------------------------------------------
# Eq. (1) and the ZOH steps
# ---------------------------------------------------------------------------------------------


def test_integrator_names_and_codes_match_the_library():
    assert tuple(sorted(kin.INTEGRATORS, key=kin.INTEGRATORS.get)) == sym.INTEGRATORS
    assert (kin.EXACT, kin.EULER, kin.RK4) == (0, 1, 2)


def test_unknown_integrator_is_rejected():
    with pytest.raises(ValueError, match="unknown integrator 'heun'"):
        sym.step_function("heun")


def test_functions_are_cached():
    assert sym.step_function("rk4") is sym.step_function("rk4")
    assert sym.network_function(2, 4, 3) is sym.network_function(2, 4, 3)


def test_rhs_and_its_jacobians():
    f, jac = sym.rhs_function(), sym.rhs_jacobian_function()
    for q, u, _ in STEP_POINTS[:64]:
        assert_allclose(_np(f(q, u)), kin.unicycle_rhs(q, u), rtol=0, atol=EXACT_TOL)
        A, B = _np(jac(q, u))
        assert_allclose(A, fd_jacobian(f, (q, u), 0), rtol=FD_TOL, atol=FD_TOL)
        assert_allclose(B, fd_jacobian(f, (q, u), 1), rtol=FD_TOL, atol=FD_TOL)
        assert_allclose(B, kin.input_matrix(q[2]), rtol=0, atol=EXACT_TOL)


@pytest.mark.parametrize("integrator", sym.INTEGRATORS)
def test_step_equals_library_step(integrator):
    step, code = sym.step_function(integrator), kin.INTEGRATORS[integrator]
    for q, u, dt in STEP_POINTS:
        assert_allclose(_np(step(q, u, dt)), kin.step(q, u, dt, code), rtol=0, atol=EXACT_TOL)


@pytest.mark.parametrize("integrator", sym.INTEGRATORS)
def test_step_jacobians_equal_library_closed_forms(integrator):
    jac, code = sym.step_jacobian_function(integrator), kin.INTEGRATORS[integrator]
    for q, u, dt in STEP_POINTS:
        F, G = _np(jac(q, u, dt))
        F_lib, G_lib = kin.step_jacobians(q, u, dt, code)
        assert_allclose(F, F_lib, rtol=0, atol=EXACT_TOL, err_msg=f"F at {q}, {u}, {dt}")
        assert_allclose(G, G_lib, rtol=0, atol=EXACT_TOL, err_msg=f"G at {q}, {u}, {dt}")


@pytest.mark.parametrize("integrator", sym.INTEGRATORS)
def test_step_jacobians_equal_central_differences_of_the_symbolic_step(integrator):
    step, jac = sym.step_function(integrator), sym.step_jacobian_function(integrator)
    for q, u, dt in STEP_POINTS:
        F, G = _np(jac(q, u, dt))
        assert_allclose(F, fd_jacobian(step, (q, u, dt), 0), rtol=FD_TOL, atol=FD_TOL)
        assert_allclose(G, fd_jacobian(step, (q, u, dt), 1), rtol=FD_TOL, atol=FD_TOL)


def test_exact_step_jacobian_at_w_zero_is_the_limit():
    """d(x+, y+)/dw at w = 0 is v dt^2/2 (-sin theta, cos theta); AD through the series gives it,
    with no NaN from sin(a)/a, and w = +-1e-9 are continuous with it."""
    jac = sym.step_jacobian_function("exact")
    for theta in (0.3, np.pi, -np.pi, -2.0):
        q, v, dt = np.array([1.0, 2.0, theta]), 0.7, 0.05
        _, G0 = _np(jac(q, [v, 0.0], dt))
        assert np.all(np.isfinite(G0))
        limit = 0.5 * v * dt**2 * np.array([-np.sin(theta), np.cos(theta)])
        assert_allclose(G0[:2, 1], limit, rtol=0, atol=EXACT_TOL)
        assert_allclose(G0[:, 0], dt * np.array([np.cos(theta), np.sin(theta), 0.0]),
                        rtol=0, atol=EXACT_TOL)  # fmt: skip
        for w in (1e-9, -1e-9):
            # G is smooth in w: |dG/dw| <= dt^2 (1 + |v| dt), so |G(w) - G(0)| ~ 1e-12 here
            slack = abs(w) * dt**2 * (1 + abs(v) * dt)
            assert_allclose(_np(jac(q, [v, w], dt))[1], G0, rtol=0, atol=EXACT_TOL + slack)


def test_casadi_if_else_masks_the_unused_branch():
    """What the module docstring relies on (and guards against anyway): CasADi differentiates
    if_else branch by branch and masks the unused one, so even an unguarded sin(a)/a branch
    gives finite values and derivatives at a = 0, in forward, reverse and second order."""
    a, seed = ca.SX.sym("a"), ca.SX.sym("seed")
    naive = ca.if_else(ca.fabs(a) < 1e-3, 1 - a**2 / 6, ca.sin(a) / a)
    outs = [naive, ca.jacobian(naive, a), ca.jtimes(naive, a, seed, True), ca.hessian(naive, a)[0]]
    vals = [float(v) for v in ca.Function("naive", [a, seed], outs)(0.0, 1.0)]
    assert_allclose(vals, [1.0, 0.0, 0.0, -1.0 / 3.0], rtol=0, atol=EXACT_TOL)


def test_exact_step_is_the_arc():
    """Away from w = 0 it equals ``x + v/w (sin theta+ - sin theta)``; everywhere it equals a
    fine RK4 integration of eq. (1)."""
    step, rk4 = sym.step_function("exact"), sym.step_function("rk4")
    rng = np.random.default_rng(SEED + 2)
    for _ in range(8):
        q = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-np.pi, np.pi)])
        u = np.array([rng.uniform(-2, 2), rng.choice([-1, 1]) * rng.uniform(1.0, 3.0)])
        dt = rng.uniform(0.1, 0.5)
        v, w = u
        th1 = q[2] + w * dt
        arc = np.array([q[0] + v / w * (np.sin(th1) - np.sin(q[2])),
                        q[1] - v / w * (np.cos(th1) - np.cos(q[2])), th1])  # fmt: skip
        assert_allclose(_np(step(q, u, dt)), arc, rtol=0, atol=EXACT_TOL)
        for u_i in (u, np.array([v, 0.0]), np.array([v, 1e-7])):
            n_sub = 400  # RK4 global error ~ (dt/n)^4 w^4 ~ 1e-17
            q_fine = q.copy()
            for _ in range(n_sub):
                q_fine = _np(rk4(q_fine, u_i, dt / n_sub))
            # rounding accumulates over n_sub steps: ~ n_sub eps |q| ~ 5e-13
            assert_allclose(_np(step(q, u_i, dt)), q_fine, rtol=0, atol=1e-11)


# ---------------------------------------------------------------------------------------------
# Rotation and tracking error (eqs. 4/6, errata E3)
# ---------------------------------------------------------------------------------------------


def test_rotation_determinants():
    expr_printed = sym.rotation_det(True)
    det_printed = ca.Function("det", ca.symvar(expr_printed), [expr_printed])
    # the corrected determinant is the constant 1 (no free symbol left), evaluate it as such
    det_corrected = ca.Function("det", [ca.SX.sym("theta")], [sym.rotation_det(False)])
    rng = np.random.default_rng(SEED + 3)
    for theta in [*rng.uniform(-2 * np.pi, 2 * np.pi, N_RANDOM), np.pi / 4, -np.pi / 4]:
        assert_allclose(float(det_printed(theta)), np.cos(2 * theta), rtol=0, atol=EXACT_TOL)
        assert_allclose(float(det_corrected(theta)), 1.0, rtol=0, atol=EXACT_TOL)
    # the printed matrix is singular at +-45 deg
    assert abs(float(det_printed(np.pi / 4))) < EXACT_TOL
    s_printed, s_corrected = sym.rotation_det_string(True), sym.rotation_det_string(False)
    assert "cos(theta)" in s_printed and "sin(theta)" in s_printed
    assert s_corrected == "1"  # CasADi folds sq(cos) + sq(sin) to 1 itself


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_rotation_and_tracking_error_equal_library(printed):
    rot, err = sym.rotation_function(printed), sym.tracking_error_function(printed)
    for q, _, ref in ERROR_POINTS:
        assert_allclose(_np(rot(q[2])), kin.rotation(q[2], printed), rtol=0, atol=EXACT_TOL)
        e, e_lib = _np(err(q, ref[:3])), kin.tracking_error(q, ref, printed)
        assert_allclose(e[:2], e_lib[:2], rtol=0, atol=EXACT_TOL)
        assert_allclose(wrap(e[2] - e_lib[2]), 0.0, rtol=0, atol=EXACT_TOL)


# ---------------------------------------------------------------------------------------------
# Continuous-time error dynamics
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_error_rate_is_the_time_derivative_along_the_motion(printed):
    """The chain-rule e' equals a central difference in time of e(q(t), q_r(t)), with robot
    and reference moving along their exact arcs."""
    rate, err = sym.error_rate_function(printed), sym.tracking_error_function(printed)
    step = sym.step_function("exact")
    h = 1e-5  # in time; both poses move smoothly, so the same truncation/rounding balance holds
    for q, u, ref in ERROR_POINTS:
        q_r, u_r = ref[:3], ref[3:]

        def e_at(t, q=q, u=u, q_r=q_r, u_r=u_r):
            return _np(err(_np(step(q, u, t)), _np(step(q_r, u_r, t))))

        _, e_dot = _np(rate(q, u, ref))
        assert_allclose(e_dot, (e_at(h) - e_at(-h)) / (2 * h), rtol=FD_TOL, atol=FD_TOL * 10)


def test_error_dynamics_residual_vanishes_for_the_corrected_rotation():
    res = sym.error_dynamics_residual_function(False)
    r = np.array([_np(res(q, u, ref)) for q, u, ref in _random_error_points(N_RANDOM, max_err=5)])
    assert np.abs(r).max() < IDENTITY_TOL
    # e3' = w_r - w holds structurally (no rounding at all)
    r_sym = res(ca.SX.sym("q", 3), ca.SX.sym("u", 2), ca.SX.sym("ref", 5))
    assert r_sym[2].is_zero()


def test_error_dynamics_residual_is_nonzero_for_the_printed_rotation():
    res = sym.error_dynamics_residual_function(True)
    r = np.array([_np(res(q, u, ref)) for q, u, ref in _random_error_points(N_RANDOM, max_err=5)])
    assert np.abs(r[:, :2]).max() > CLEARLY_NONZERO
    assert np.abs(r[:, 2]).max() < IDENTITY_TOL  # the heading row is untouched by the erratum


def test_printed_error_dynamics_closed_form():
    """The printed error obeys the forms stated in error_dynamics_residual_function."""
    rate = sym.error_rate_function(True)
    for q, u, ref in ERROR_POINTS:
        e, e_dot = _np(rate(q, u, ref))
        (v, w), (v_r, w_r), th = u, ref[3:], q[2]
        c2, s2 = np.cos(2 * th), np.sin(2 * th)
        expected = [w / c2 * (e[1] - s2 * e[0]) - v + v_r * np.cos(e[2]),
                    w / c2 * (e[0] - s2 * e[1]) - v * s2 + v_r * np.sin(ref[2] + th),
                    w_r - w]  # fmt: skip
        # 1/cos(2 theta) amplifies rounding near +-45 deg
        assert_allclose(e_dot, expected, rtol=0, atol=IDENTITY_TOL / min(1.0, abs(c2)))


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_error_dynamics_in_error_coordinates_equal_the_chain_rule(printed):
    """Substituting q_r = q + T_e^{-1} e (and, when corrected, theta = 0) loses nothing."""
    f, rate = sym.error_dynamics_function(printed), sym.error_rate_function(printed)
    kanayama = sym.kanayama_error_dynamics_function()
    for q, u, ref in ERROR_POINTS:
        e, e_dot = _np(rate(q, u, ref))
        args = (e, u, ref[3:], q[2]) if printed else (e, u, ref[3:])
        tol = IDENTITY_TOL / min(1.0, abs(np.cos(2 * q[2]))) if printed else IDENTITY_TOL
        assert_allclose(_np(f(*args)), e_dot, rtol=0, atol=tol)
        if not printed:
            assert_allclose(_np(kanayama(e, u, ref[3:])), e_dot, rtol=0, atol=IDENTITY_TOL)
    if not printed:
        # derived at theta = 0, the trigonometry of the heading folds to constants: e_dot has
        # exactly Kanayama's dependence on e (w e2, v_r cos e3 / -w e1, v_r sin e3 / nothing).
        assert f.sparsity_jac("e", "e_dot").nnz() == 4


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_error_dynamics_jacobians_equal_central_differences(printed):
    f, jac = sym.error_dynamics_function(printed), sym.error_dynamics_jacobian_function(printed)
    rng = np.random.default_rng(SEED + 4)
    for _ in range(32):
        e, u, u_r = rng.uniform(-1, 1, 3), rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2)
        extra = (rng.uniform(-0.6, 0.6),) if printed else ()  # |theta| < 45 deg
        A, B = _np(jac(e, u, u_r, *extra))
        assert_allclose(A, fd_jacobian(f, (e, u, u_r, *extra), 0),
                        rtol=FD_TOL, atol=FD_TOL)  # fmt: skip
        assert_allclose(B, fd_jacobian(f, (e, u, u_r, *extra), 1),
                        rtol=FD_TOL, atol=FD_TOL)  # fmt: skip


def test_backstepping_jacobian_is_kanayamas_matrix():
    A_fun = sym.backstepping_jacobian_function()
    closed = sym.backstepping_error_dynamics_function()
    rng = np.random.default_rng(SEED + 5)
    for _ in range(64):
        v_r, w_r = rng.uniform(-2, 2), rng.uniform(-3, 3)
        k1, k2, k3 = rng.uniform(0.1, 20, 3)
        A = _np(A_fun(v_r, w_r, k1, k2, k3))
        # fmt: off
        expected = np.array([[-k1,   w_r,        0.0],
                             [-w_r,  0.0,        v_r],
                             [0.0,  -v_r * k2,  -v_r * k3]])
        # fmt: on
        assert_allclose(A, expected, rtol=0, atol=EXACT_TOL)
        fd = fd_jacobian(closed, (np.zeros(3), [v_r, w_r], [k1, k2, k3]), 0)
        assert_allclose(A, fd, rtol=FD_TOL, atol=FD_TOL)
        if v_r > 0:  # Kanayama: asymptotically stable for k > 0, v_r > 0
            assert np.linalg.eigvals(A).real.max() < 0
    # and symbolically: A - expected simplifies to the zero matrix
    s = [ca.SX.sym(n) for n in ("v_r", "w_r", "k1", "k2", "k3")]
    v_r, w_r, k1, k2, k3 = s
    expected = ca.blockcat([[-k1, w_r, 0], [-w_r, 0, v_r], [0, -v_r * k2, -v_r * k3]])
    assert ca.simplify(A_fun(*s) - expected).is_zero()


def test_printed_backstepping_jacobian_depends_on_heading():
    A_fun = sym.backstepping_jacobian_function(True)
    closed = sym.backstepping_error_dynamics_function(True)
    args = (0.8, 0.3, 2.0, 10.0, 4.0)
    for theta in (0.0, 0.3, -0.6, 2.0):
        A = _np(A_fun(*args, theta))
        fd = fd_jacobian(closed, (np.zeros(3), args[:2], args[2:], theta), 0)
        assert_allclose(A, fd, rtol=FD_TOL, atol=FD_TOL)
        # linearising the printed forms of test_printed_error_dynamics_closed_form about e = 0
        v_r, w_r, k1, k2, k3 = args
        c2, s2 = np.cos(2 * theta), np.sin(2 * theta)
        # fmt: off
        expected = np.array([[-w_r * s2 / c2 - k1,  w_r / c2,         0.0],
                             [w_r / c2 - k1 * s2,  -w_r * s2 / c2,    v_r * c2],
                             [0.0,                 -v_r * k2,        -v_r * k3]])
        # fmt: on
        assert_allclose(A, expected, rtol=0, atol=EXACT_TOL)
    # Even at theta = 0, where the printed matrix is the identity, the printed error's dynamics
    # differ: dT/dtheta is not the rotation's, so e2' gets +w e1 instead of -w e1.
    A_c = _np(sym.backstepping_jacobian_function()(*args))
    A_p0 = _np(A_fun(*args, 0.0))
    assert_allclose(A_p0[1, 0], -A_c[1, 0], rtol=0, atol=EXACT_TOL)
    A_p0[1, 0] = A_c[1, 0]
    assert_allclose(A_p0, A_c, rtol=0, atol=EXACT_TOL)


# ---------------------------------------------------------------------------------------------
# Sampled-data error dynamics
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
@pytest.mark.parametrize("integrator", sym.INTEGRATORS)
def test_error_step_equals_library_simulation(integrator, printed):
    """One step of robot (library ``step``) and reference (library exact arc), then the library
    error, equals the symbolic error step from the library error at t_k."""
    f, code = sym.error_step_function(integrator, printed), kin.INTEGRATORS[integrator]
    for q, u, ref in ERROR_POINTS:
        if printed and abs(np.cos(2 * q[2])) < 0.1:
            continue  # T_e^{-1} of the printed matrix is ill-conditioned near +-45 deg
        dt = 0.05
        e = kin.tracking_error(q, ref, printed)
        q1, q_r1 = kin.step(q, u, dt, code), kin.step(ref[:3], ref[3:], dt, kin.EXACT)
        e1_lib = kin.tracking_error(q1, q_r1, printed)
        args = (e, u, ref[3:], dt, q[2]) if printed else (e, u, ref[3:], dt)
        e1 = _np(f(*args))
        assert_allclose(e1[:2], e1_lib[:2], rtol=0, atol=EXACT_TOL * 10)
        assert_allclose(wrap(e1[2] - e1_lib[2]), 0.0, rtol=0, atol=EXACT_TOL)


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
@pytest.mark.parametrize("integrator", sym.INTEGRATORS)
def test_error_step_jacobians(integrator, printed):
    f = sym.error_step_function(integrator, printed)
    jac = sym.error_step_jacobian_function(integrator, printed)
    cont = sym.error_dynamics_jacobian_function(printed)
    rng = np.random.default_rng(SEED + 6)
    for _ in range(32):
        e, u, u_r = rng.uniform(-1, 1, 3), rng.uniform(-2, 2, 2), rng.uniform(-2, 2, 2)
        extra = (rng.uniform(-0.6, 0.6),) if printed else ()
        dt = rng.uniform(1e-3, 0.2)
        E, B = _np(jac(e, u, u_r, dt, *extra))
        assert_allclose(E, fd_jacobian(f, (e, u, u_r, dt, *extra), 0),
                        rtol=FD_TOL, atol=FD_TOL)  # fmt: skip
        assert_allclose(B, fd_jacobian(f, (e, u, u_r, dt, *extra), 1),
                        rtol=FD_TOL, atol=FD_TOL)  # fmt: skip
        # consistency with continuous time: E = I + dt A + O(dt^2), B = dt B_c + O(dt^2)
        h = 1e-6
        E_h, B_h = _np(jac(e, u, u_r, h, *extra))
        A_c, B_c = _np(cont(e, u, u_r, *extra))
        assert_allclose((E_h - np.eye(3)) / h, A_c, rtol=0, atol=1e-4)  # O(dt) ~ 1e-5
        assert_allclose(B_h / h, B_c, rtol=0, atol=1e-4)


def test_zero_error_is_a_fixed_point_of_the_exact_error_step():
    f = sym.error_step_function("exact")
    for v_r, w_r in ((0.5, 0.0), (1.0, 0.7), (-0.3, -2.0)):
        e1 = _np(f(np.zeros(3), [v_r, w_r], [v_r, w_r], 0.1))
        assert_allclose(e1, 0.0, rtol=0, atol=EXACT_TOL)


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_backstepping_step_jacobian_is_E_plus_B_K(printed):
    A_d_fun = sym.backstepping_step_jacobian_function("exact", printed)
    jac = sym.error_step_jacobian_function("exact", printed)
    rng = np.random.default_rng(SEED + 7)
    for _ in range(16):
        v_r, w_r, dt = rng.uniform(0.1, 2), rng.uniform(-2, 2), rng.uniform(1e-3, 0.2)
        k1, k2, k3 = rng.uniform(0.1, 20, 3)
        extra = (rng.uniform(-0.6, 0.6),) if printed else ()
        E, B = _np(jac(np.zeros(3), [v_r, w_r], [v_r, w_r], dt, *extra))
        # du/de of v = v_r cos e3 + k1 e1, w = w_r + v_r (k2 e2 + k3 sin e3) at e = 0
        K = np.array([[k1, 0.0, 0.0], [0.0, v_r * k2, v_r * k3]])
        A_d = _np(A_d_fun(v_r, w_r, k1, k2, k3, dt, *extra))
        assert_allclose(A_d, E + B @ K, rtol=0, atol=EXACT_TOL)
        if not printed:
            A_c = _np(sym.backstepping_jacobian_function()(v_r, w_r, k1, k2, k3))
            h = 1e-6
            A_h = _np(A_d_fun(v_r, w_r, k1, k2, k3, h))
            assert_allclose((A_h - np.eye(3)) / h, A_c, rtol=0, atol=1e-3)  # O(dt |A|^2)


# ---------------------------------------------------------------------------------------------
# Network (eqs. 18-24 corrected, errata E7/E8)
# ---------------------------------------------------------------------------------------------

NET_SIZES = [(2, 5, 3), (4, 8, 3), (1, 1, 1), (3, 2, 4)]


def _net_point(rng, n_in, n_h, n_out):
    V = rng.standard_normal((n_h, n_in))
    b_v = rng.standard_normal(n_h)
    W = rng.standard_normal((n_out, n_h))
    b_w = rng.standard_normal(n_out)
    theta = np.concatenate((V.ravel(), b_v, W.ravel(), b_w))  # docs/conventions.md layout
    return theta, rng.uniform(-2, 2, n_in), (V, b_v, W, b_w)


@pytest.mark.parametrize("sizes", NET_SIZES, ids=[f"{a}-{b}-{c}" for a, b, c in NET_SIZES])
def test_network_layout_and_jacobians(sizes):
    n_in, n_h, n_out = sizes
    net = sym.network_function(*sizes)
    jx = sym.network_input_jacobian_function(*sizes)
    jw = sym.network_weight_jacobian_function(*sizes)
    assert net.size1_in("theta") == sym.n_weights(*sizes) == n_h * n_in + n_h + n_out * n_h + n_out
    rng = np.random.default_rng(SEED + 8)
    for _ in range(32):
        theta, x, (V, b_v, W, b_w) = _net_point(rng, *sizes)
        z, h = _np(net(theta, x))
        h_np = np.tanh(V @ x + b_v)
        assert_allclose(h, h_np, rtol=0, atol=EXACT_TOL)
        assert_allclose(z, W @ h_np + b_w, rtol=0, atol=EXACT_TOL)
        J, H = np.atleast_2d(_np(jx(theta, x))), np.atleast_2d(_np(jw(theta, x)))
        assert J.shape == (n_out, n_in) and H.shape == (n_out, theta.size)
        fd_x = fd_jacobian(net, (theta, x), 1)
        fd_w = fd_jacobian(net, (theta, x), 0)
        assert_allclose(J, fd_x, rtol=FD_TOL, atol=FD_TOL)
        assert_allclose(H, fd_w, rtol=FD_TOL, atol=FD_TOL)
        # errata E7: the chain rule sums over hidden units
        assert_allclose(J, W @ np.diag(1 - h_np**2) @ V, rtol=0, atol=EXACT_TOL)


def test_network_sizes_are_validated():
    with pytest.raises(ValueError, match="n_h must be a positive int"):
        sym.network_function(2, 0, 3)


@pytest.mark.parametrize("sizes", NET_SIZES, ids=[f"{a}-{b}-{c}" for a, b, c in NET_SIZES])
def test_library_network_matches_symbolic(sizes):
    """wmr.estimation.nn (written in parallel) against the oracle; skipped until the module exists.

    Signatures read from wmr/estimation/nn.py: ``forward(theta, x, n_h, n_out) -> (z, h)``,
    ``input_jacobian(theta, x, n_h, n_out, h)``, ``weight_jacobian(theta, x, n_h, n_out, h, H)``
    writing ``H`` in place; the calls adapt if ``h``/``H`` are not parameters.
    """
    nn = pytest.importorskip("wmr.estimation.nn")
    n_in, n_h, n_out = sizes
    net = sym.network_function(*sizes)
    jx = sym.network_input_jacobian_function(*sizes)
    jw = sym.network_weight_jacobian_function(*sizes)
    ij_params = inspect.signature(nn.input_jacobian).parameters
    wj_params = inspect.signature(nn.weight_jacobian).parameters
    rng = np.random.default_rng(SEED + 9)
    for _ in range(32):
        theta, x, _ = _net_point(rng, *sizes)
        z, h = nn.forward(theta, x, n_h, n_out)
        z_s, h_s = _np(net(theta, x))
        assert_allclose(z, z_s, rtol=0, atol=EXACT_TOL)
        assert_allclose(h, h_s, rtol=0, atol=EXACT_TOL)
        J = nn.input_jacobian(theta, x, n_h, n_out, *((h,) if "h" in ij_params else ()))
        J_s = np.atleast_2d(_np(jx(theta, x)))
        assert_allclose(np.atleast_2d(J), J_s, rtol=0, atol=EXACT_TOL)
        w_args = (theta, x, n_h, n_out, *((h,) if "h" in wj_params else ()))
        if "H" in wj_params:
            H = np.full((n_out, theta.size), np.nan)  # every entry must be written
            nn.weight_jacobian(*w_args, H)
        else:
            H = nn.weight_jacobian(*w_args)
        H_s = np.atleast_2d(_np(jw(theta, x)))
        assert_allclose(np.atleast_2d(H), H_s, rtol=0, atol=EXACT_TOL)


# ---------------------------------------------------------------------------------------------
# The oracle stays out of the hot loop
# ---------------------------------------------------------------------------------------------


def test_no_library_module_imports_casadi():
    import pkgutil

    import wmr

    names = [m.name for m in pkgutil.walk_packages(wmr.__path__, "wmr.")]
    oracle = ("wmr.model.symbolic", "wmr.model.symbolic_loops")  # the CasADi oracle itself
    names = [n for n in names if n not in oracle]
    code = (
        "import importlib, sys\n"
        f"for n in {names!r}: importlib.import_module(n)\n"
        "bad = sorted(m for m in sys.modules if m == 'casadi' or m == 'wmr.model.symbolic')\n"
        "assert not bad, bad\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert importlib.import_module("wmr.model.symbolic") is sym
