"""Oracle tests of the sampled-data closed loops added to wmr.model.symbolic (PID of eq. 7,
backstepping).

Layers (STYLE 6): the symbolic one-step maps equal the library's own step (the jitted controller
laws of ``wmr.controllers`` plus ``wmr.model.kinematics.step``) at seeded random states; their AD
Jacobians equal central differences of the symbolic maps; the equilibria are exact fixed points;
and the printed-rotation closed loop is related to the existing printed-error Jacobian by the
change of coordinates ``N(theta)`` of errata E3.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose
from oracles import central_fd as _central_fd

from wmr import scenario as scn
from wmr.controllers import backstepping, pid
from wmr.controllers.pid import S_INT, S_PREV, S_STARTED
from wmr.model import kinematics as kin
from wmr.model import symbolic as sym

SEED = 20240251
# Same arithmetic in a different order (CasADi graph vs numba): rounding of O(10) terms.
VALUE_TOL = 1e-12
# Central differences with step 1e-6 of maps with entries up to ~Kd/dt = 50: truncation
# ~1e-12 |f'''|, rounding ~eps*50/1e-6 ~ 1e-8; 1e-6 leaves a margin of two decades.
FD_STEP = 1e-6
FD_TOL = 1e-6
EXACT_TOL = 1e-13


def _np(x):
    return np.asarray(x.full(), dtype=float).squeeze()


def central_fd(fun, x, step=FD_STEP):
    return _central_fd(fun, x, step)


def _rot_T(theta):
    """``R(theta)^T`` on the (x, y) block: robot-frame vector -> world frame."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


def _poses(e, q_r):
    """Robot pose whose corrected error to the reference pose ``q_r`` is ``e``."""
    th = q_r[2] - e[2]
    xy = q_r[:2] - _rot_T(th) @ e[:2]
    return np.array([xy[0], xy[1], th])


@pytest.fixture(scope="module")
def sc():
    return scn.load(scn.builtin("sinusoid"))


def _random_case(rng):
    v_r, w_r = rng.uniform(0.1, 1.0), rng.uniform(-0.8, 0.8)
    K = np.array([rng.uniform(1, 8), rng.uniform(0.5, 6), rng.uniform(0, 0.5),
                  rng.uniform(2, 12), rng.uniform(0.5, 4), rng.uniform(0, 0.5)])  # fmt: skip
    return v_r, w_r, K


def _library_pid_step(sc, x, ref, K, dt, integrator, printed, feed_forward):
    """x_next of the library: pid.law on the pose of x, then kin.step; corrected error state."""
    settings = pid.FixedSettings(gains=tuple(K), printed_rotation=printed,
                                 feed_forward=feed_forward, gain_max=(50.0,) * 6)  # fmt: skip
    p, s, W, P = pid.pack(settings, sc, np.random.default_rng(0))
    s[S_INT], s[S_INT + 1], s[S_PREV], s[S_PREV + 1] = x[3:7]
    s[S_STARTED] = 1.0
    q = _poses(x[:3], ref[:3])
    u = np.zeros(2)
    pid.law(p, s, W, P, q, ref, dt, u)
    q_next = kin.step(q, u, dt, kin.INTEGRATORS[integrator])
    q_r_next = kin.step(ref[:3].copy(), ref[3:5].copy(), dt, kin.EXACT)
    e_next = kin.tracking_error(q_next, q_r_next)
    return np.concatenate((e_next, s[S_INT : S_INT + 2], s[S_PREV : S_PREV + 2]))


@pytest.mark.parametrize("integrator", sym.INTEGRATORS)
@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
@pytest.mark.parametrize("feed_forward", [False, True], ids=["literal", "ff"])
def test_pid_closed_loop_step_equals_the_library_step(sc, integrator, printed, feed_forward):
    rng = np.random.default_rng(SEED)
    f = sym.pid_closed_loop_step_function(integrator, printed, feed_forward)
    dt = 0.01
    for _ in range(20):
        v_r, w_r, K = _random_case(rng)
        x = np.concatenate((rng.normal(scale=0.2, size=3), rng.normal(size=4)))
        ref = np.array([*rng.uniform(-3, 3, size=2), rng.uniform(-math.pi, math.pi), v_r, w_r])
        args = [x, [v_r, w_r], K, dt] + ([ref[2]] if printed else [])
        got = _np(f(*args))
        want = _library_pid_step(sc, x, ref, K, dt, integrator, printed, feed_forward)
        assert_allclose(got, want, rtol=VALUE_TOL, atol=VALUE_TOL)


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_backstepping_closed_loop_step_equals_the_library_step(sc, printed):
    rng = np.random.default_rng(SEED + 1)
    f = sym.backstepping_closed_loop_step_function("exact", printed)
    dt = 0.01
    for _ in range(20):
        v_r, w_r = rng.uniform(0.1, 1.0), rng.uniform(-0.8, 0.8)
        k = rng.uniform(0.5, 12, size=3)
        e = rng.normal(scale=0.2, size=3)
        ref = np.array([*rng.uniform(-3, 3, size=2), rng.uniform(-math.pi, math.pi), v_r, w_r])
        p, _, _, _ = backstepping.pack(backstepping.Settings(tuple(k), printed), sc, None)
        q = _poses(e, ref[:3])
        u = np.zeros(2)
        backstepping.law(p, np.zeros(0), np.zeros(0), np.zeros((0, 0)), q, ref, dt, u)
        want = kin.tracking_error(kin.step(q, u, dt), kin.step(ref[:3].copy(), ref[3:5].copy(), dt))
        args = [e, [v_r, w_r], k, dt] + ([ref[2]] if printed else [])
        assert_allclose(_np(f(*args)), want, rtol=VALUE_TOL, atol=VALUE_TOL)


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
@pytest.mark.parametrize("feed_forward", [False, True], ids=["literal", "ff"])
def test_pid_equilibrium_is_an_exact_fixed_point(printed, feed_forward):
    """x* = (0, 0, 0, v_r/Kiv, w_r/Kiw, 0, 0) (literal) or 0 (feed-forward) maps to itself."""
    rng = np.random.default_rng(SEED + 2)
    f = sym.pid_closed_loop_step_function("exact", printed, feed_forward)
    for _ in range(20):
        v_r, w_r, K = _random_case(rng)
        x = np.zeros(7) if feed_forward else np.array([0, 0, 0, v_r / K[1], w_r / K[4], 0, 0])
        args = [x, [v_r, w_r], K, 0.01] + ([rng.uniform(-math.pi, math.pi)] if printed else [])
        assert_allclose(_np(f(*args)), x, atol=EXACT_TOL)


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_pid_closed_loop_jacobian_equals_central_differences(printed):
    rng = np.random.default_rng(SEED + 3)
    f = sym.pid_closed_loop_step_function("exact", printed)
    J = sym.pid_closed_loop_jacobian_function("exact", printed)
    for _ in range(10):
        v_r, w_r, K = _random_case(rng)
        x = np.concatenate((rng.normal(scale=0.1, size=3), rng.normal(size=4)))
        extra = [rng.uniform(-math.pi, math.pi)] if printed else []
        args = ([v_r, w_r], K, 0.01, *extra)
        fd = central_fd(lambda xx, a=args: _np(f(xx, *a)), x)
        assert_allclose(_np(J(x, *args)), fd, atol=FD_TOL)


def test_feed_forward_does_not_change_the_linearisation():
    """d(v_r cos e3)/de3 = 0 at e3 = 0 and w_r is constant: both loops linearise alike."""
    rng = np.random.default_rng(SEED + 4)
    J0 = sym.pid_closed_loop_jacobian_function("exact", False, False)
    J1 = sym.pid_closed_loop_jacobian_function("exact", False, True)
    for _ in range(10):
        v_r, w_r, K = _random_case(rng)
        xs = np.array([0, 0, 0, v_r / K[1], w_r / K[4], 0, 0])
        assert_allclose(_np(J0(xs, [v_r, w_r], K, 0.01)), _np(J1(np.zeros(7), [v_r, w_r], K, 0.01)),
                        atol=EXACT_TOL)  # fmt: skip


def test_backstepping_closed_loop_jacobian_equals_the_existing_one_at_zero():
    rng = np.random.default_rng(SEED + 5)
    J = sym.backstepping_closed_loop_jacobian_function()
    Jold = sym.backstepping_step_jacobian_function()
    for _ in range(10):
        v_r, w_r, dt = rng.uniform(0.1, 1), rng.uniform(-0.8, 0.8), rng.uniform(0.001, 0.05)
        k = rng.uniform(0.5, 12, size=3)
        assert_allclose(_np(J(np.zeros(3), [v_r, w_r], k, dt)),
                        _np(Jold(v_r, w_r, *k, dt)), atol=EXACT_TOL)  # fmt: skip


def _N(theta):
    """Printed error as a function of the corrected one at the same pose: ``T_p(theta) R^T``."""
    N = np.eye(3)
    N[1, 0], N[1, 1] = math.sin(2 * theta), math.cos(2 * theta)
    return N


def test_printed_closed_loop_is_the_existing_printed_jacobian_in_corrected_coordinates():
    """Existing state = printed error: A_p = N(theta+) A N(theta)^-1, theta+ = theta + w_r dt
    (errata E3), wherever N is invertible (cos 2theta != 0)."""
    rng = np.random.default_rng(SEED + 6)
    J = sym.backstepping_closed_loop_jacobian_function("exact", printed=True)
    Jold = sym.backstepping_step_jacobian_function("exact", printed=True)
    n = 0
    while n < 20:
        th = rng.uniform(-math.pi, math.pi)
        if abs(math.cos(2 * th)) < 0.2:
            continue
        v_r, w_r, dt = rng.uniform(0.1, 1), rng.uniform(-0.8, 0.8), 0.01
        k = rng.uniform(0.5, 12, size=3)
        A = _np(J(np.zeros(3), [v_r, w_r], k, dt, th))
        A_p = _np(Jold(v_r, w_r, *k, dt, th))
        want = _N(th + w_r * dt) @ A @ np.linalg.inv(_N(th))
        assert_allclose(A_p, want, atol=1e-11)
        n += 1


def test_printed_closed_loop_is_defined_at_45_degrees():
    """The printed error's own coordinates are singular at 45 deg; the corrected ones are not."""
    A = _np(sym.backstepping_closed_loop_jacobian_function("exact", True)(
        np.zeros(3), [0.5, 0.0], [2, 10, 4], 0.01, math.pi / 4))  # fmt: skip
    assert np.all(np.isfinite(A))
    # At 45 deg the printed lateral error is e1: the lateral mode is left uncontrolled, |z| = 1.
    assert max(abs(np.linalg.eigvals(A))) == pytest.approx(1.0, abs=1e-12)
