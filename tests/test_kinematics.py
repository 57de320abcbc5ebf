"""Kinematics: exact arc, integrator orders, step Jacobians, error rotation, angle wrapping.

Oracles: the closed-form arc of eq. (1) under constant input; the known convergence orders of
Euler (1) and RK4 (4); central finite differences for the Jacobians; orthogonality of a rotation
and ``det = cos 2 theta`` for the printed matrix of eqs. (4)/(6); ``|e|`` = world distance.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from wmr.model import kinematics as km
from wmr.model.kinematics import EULER, EXACT, RK4

INTEGRATOR_PARAMS = [pytest.param(code, id=name) for name, code in km.INTEGRATORS.items()]

#: The closed form x + v/w (sin th+ - sin th) cancels: its own error is ~ eps |v/w| per unit
#: of the arc; with |v| <= 2, |w| >= 0.1 below that is <= 20 eps ~ 4.4e-15, so 1e-13 has margin.
ARC_ATOL = 1e-13
#: Central differences with h = 1e-6: truncation h^2 |f'''| / 6 <= 1e-12 * (v dt^3 ~ 1) and
#: rounding eps |q| / h ~ 2.2e-16 * 10 / 1e-6 = 2.2e-9 for |q| <= 10.
FD_STEP = 1e-6
FD_ATOL = 1e-8


def _random_points(seed: int, n: int):
    """Seeded poses, inputs and sample periods spanning the regimes of use."""
    rng = np.random.default_rng(seed)
    q = np.column_stack((rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-7, 7, n)))
    u = np.column_stack((rng.uniform(-2, 2, n), rng.choice([-1, 1], n) * rng.uniform(0.1, 5, n)))
    dt = rng.uniform(0.001, 0.5, n)
    return q, u, dt


# --- the exact step is the arc --------------------------------------------------------------------


def test_exact_step_is_the_closed_form_arc():
    q, u, dt = _random_points(seed=1, n=200)
    for qi, ui, h in zip(q, u, dt, strict=True):
        x, y, th = qi
        v, w = ui
        expected = (
            x + v / w * (math.sin(th + w * h) - math.sin(th)),
            y - v / w * (math.cos(th + w * h) - math.cos(th)),
            th + w * h,
        )
        assert_allclose(km.step(qi, ui, h, EXACT), expected, rtol=0, atol=ARC_ATOL)


@pytest.mark.parametrize("theta", [0.0, 0.3, -2.5, math.pi, -math.pi], ids=lambda t: f"θ={t:.3g}")
def test_exact_step_with_w_zero_is_the_straight_line(theta):
    q = np.array([1.5, -0.25, theta])
    v, dt = 0.7, 0.1
    out = km.step(q, np.array([v, 0.0]), dt, EXACT)
    # with w = 0 the arc degenerates exactly (sinc(0) = 1): same operations, same bits
    assert_array_equal(
        out, [q[0] + v * dt * math.cos(theta), q[1] + v * dt * math.sin(theta), theta]
    )


@pytest.mark.parametrize("w", [1e-12, -1e-12, 1e-9, 1e-300], ids=lambda w: f"w={w:g}")
def test_exact_step_with_tiny_w_has_no_cancellation(w):
    """For tiny w the arc is the chord turned by half the heading change,
    x+ = x + v dt cos(th + w dt/2) up to O((w dt)^2); the division form v/w (...) would lose
    ~eps v/w here (1e-4 at w = 1e-12)."""
    q = np.array([0.3, 0.2, 0.9])
    v, dt = 1.3, 0.05
    out = km.step(q, np.array([v, w]), dt, EXACT)
    phi = q[2] + 0.5 * w * dt
    # the chord differs from v dt (cos, sin)(phi) by v dt (1 - sinc(w dt / 2)) ~ v dt (w dt)^2 / 24
    assert_allclose(
        out[:2], q[:2] + v * dt * np.array([math.cos(phi), math.sin(phi)]), rtol=0, atol=1e-15
    )
    assert out[2] == q[2] + w * dt


def test_exact_step_is_continuous_across_the_series_switch():
    """The sinc is a Taylor series for |w dt/2| < 1e-4: both sides must agree to rounding."""
    q = np.array([0.0, 0.0, 0.4])
    dt = 0.1
    a_switch = 1e-4
    w_lo = 2 * a_switch / dt * (1 - 1e-12)
    w_hi = 2 * a_switch / dt * (1 + 1e-12)
    lo = km.step(q, np.array([1.0, w_lo]), dt, EXACT)
    hi = km.step(q, np.array([1.0, w_hi]), dt, EXACT)
    # the true change between the two w is ~ v dt^2/2 * dw ~ 1e-14; rounding ~1e-16
    assert_allclose(lo, hi, rtol=0, atol=1e-14)
    F_lo, G_lo = km.step_jacobians(q, np.array([1.0, w_lo]), dt, EXACT)
    F_hi, G_hi = km.step_jacobians(q, np.array([1.0, w_hi]), dt, EXACT)
    assert_allclose(F_lo, F_hi, rtol=0, atol=1e-12)
    assert_allclose(G_lo, G_hi, rtol=0, atol=1e-12)


# --- integrator orders ----------------------------------------------------------------------------


def _global_error(integrator: int, dt: float, horizon: float = 2.0) -> float:
    q0 = np.array([0.2, -0.1, 0.3])
    u = np.array([1.0, 1.5])
    q = q0.copy()
    for _ in range(round(horizon / dt)):
        q = km.step(q, u, dt, integrator)
    exact = km.step(q0, u, horizon, EXACT)  # one exact arc over the whole horizon
    return float(np.linalg.norm(q - exact))


@pytest.mark.parametrize(
    ("integrator", "order", "dts"),
    [
        # RK4: errors from ~4e-6 down to ~1e-9, far above rounding (~1e-16 * 80 steps)
        pytest.param(RK4, 4.0, (0.2, 0.1, 0.05, 0.025), id="rk4"),
        pytest.param(EULER, 1.0, (0.02, 0.01, 0.005, 0.0025), id="euler"),
    ],
)
def test_integrator_order(integrator, order, dts):
    errors = [_global_error(integrator, dt) for dt in dts]
    slope = np.polyfit(np.log(dts), np.log(errors), 1)[0]
    # the asymptotic constant is reached up to O(dt) corrections: 0.3 on the slope is generous
    # for RK4 (measured 4.0); Euler's first-order term dominates even more cleanly
    assert abs(slope - order) < 0.3, (slope, errors)
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert_allclose(ratios, 2.0**order, rtol=0.15)  # ~16x (RK4) or ~2x (Euler) per halving


def test_exact_step_composes():
    """The exact ZOH flow is a semigroup: n steps of dt equal one step of n dt (to rounding)."""
    q0 = np.array([0.2, -0.1, 0.3])
    u = np.array([1.0, 1.5])
    q = q0.copy()
    for _ in range(100):
        q = km.step(q, u, 0.02, EXACT)
    assert_allclose(q, km.step(q0, u, 2.0, EXACT), rtol=0, atol=1e-13)


# --- Jacobians against central differences -------------------------------------------------------


def _central_differences(q, u, dt, integrator):
    F = np.empty((3, 3))
    G = np.empty((3, 2))
    for j in range(3):
        dq = np.zeros(3)
        dq[j] = FD_STEP
        F[:, j] = (km.step(q + dq, u, dt, integrator) - km.step(q - dq, u, dt, integrator)) / (
            2 * FD_STEP
        )
    for j in range(2):
        du = np.zeros(2)
        du[j] = FD_STEP
        G[:, j] = (km.step(q, u + du, dt, integrator) - km.step(q, u - du, dt, integrator)) / (
            2 * FD_STEP
        )
    return F, G


_q, _u, _dt = _random_points(seed=2, n=12)
JACOBIAN_POINTS = [pytest.param(_q[i], _u[i], _dt[i], id=f"random{i}") for i in range(len(_q))] + [
    pytest.param(np.array([1.0, 2.0, math.pi]), np.array([0.8, 1.2]), 0.05, id="θ=π"),
    pytest.param(np.array([1.0, 2.0, -math.pi]), np.array([0.8, -1.2]), 0.05, id="θ=-π"),
    pytest.param(np.array([1.0, 2.0, 0.7]), np.array([0.0, 1.2]), 0.05, id="v=0"),
    pytest.param(np.array([1.0, 2.0, 0.7]), np.array([0.8, 0.0]), 0.05, id="w=0"),
    pytest.param(np.array([1.0, 2.0, 0.7]), np.array([0.0, 0.0]), 0.05, id="v=0,w=0"),
    pytest.param(np.array([-3.0, 4.0, 2.0]), np.array([1.5, 2e-3]), 0.1, id="w-on-series-side"),
    pytest.param(np.array([-3.0, 4.0, 2.0]), np.array([-1.5, 40.0]), 0.2, id="large-w-dt"),
]


@pytest.mark.parametrize("integrator", INTEGRATOR_PARAMS)
@pytest.mark.parametrize(("q", "u", "dt"), JACOBIAN_POINTS)
def test_step_jacobians_match_central_differences(q, u, dt, integrator):
    F, G = km.step_jacobians(q, u, dt, integrator)
    F_fd, G_fd = _central_differences(q, u, dt, integrator)
    assert F.shape == (3, 3) and G.shape == (3, 2)
    assert_allclose(F, F_fd, rtol=0, atol=FD_ATOL)
    assert_allclose(G, G_fd, rtol=0, atol=FD_ATOL)


def test_euler_jacobians_are_the_linearised_rhs():
    """Euler: F = I + dt A, G = dt B(theta) exactly, with B = the input matrix of eq. (1)."""
    q = np.array([0.5, 0.5, 1.1])
    u = np.array([0.9, -0.4])
    dt = 0.03
    F, G = km.step_jacobians(q, u, dt, EULER)
    A = np.zeros((3, 3))
    A[0, 2] = -u[0] * math.sin(q[2])
    A[1, 2] = u[0] * math.cos(q[2])
    assert_allclose(F, np.eye(3) + dt * A, rtol=0, atol=1e-16)
    assert_allclose(G, dt * km.input_matrix(q[2]), rtol=0, atol=1e-16)


def test_rhs_is_input_matrix_times_input():
    q, u, _ = _random_points(seed=3, n=20)
    for qi, ui in zip(q, u, strict=True):
        assert_allclose(km.unicycle_rhs(qi, ui), km.input_matrix(qi[2]) @ ui, rtol=0, atol=1e-15)


def test_integrator_code():
    assert km.integrator_code("exact") == EXACT
    assert km.integrator_code("euler") == EULER
    assert km.integrator_code("rk4") == RK4
    assert km.integrator_code(RK4) == RK4
    for bad in ("midpoint", 7, None, ["rk4"]):
        with pytest.raises(ValueError, match="unknown integrator"):
            km.integrator_code(bad)


# --- the error rotation (eqs. 4/6) and the tracking error ----------------------------------------

THETAS = np.concatenate(
    (np.linspace(-2 * math.pi, 2 * math.pi, 73), [math.pi / 4, -math.pi / 4, 3 * math.pi / 4])
)


@pytest.mark.parametrize("theta", THETAS, ids=lambda t: f"θ={t:.4f}")
def test_corrected_rotation_is_orthogonal_with_det_one(theta):
    T = km.rotation(theta)
    assert_allclose(T @ T.T, np.eye(3), rtol=0, atol=1e-15)
    assert np.linalg.det(T) == pytest.approx(1.0, abs=1e-15)


@pytest.mark.parametrize("theta", THETAS, ids=lambda t: f"θ={t:.4f}")
def test_printed_rotation_has_det_cos_2theta(theta):
    T = km.rotation(theta, True)
    assert np.linalg.det(T) == pytest.approx(math.cos(2 * theta), abs=1e-15)


@pytest.mark.parametrize("theta", [math.pi / 4, -math.pi / 4, 3 * math.pi / 4], ids=str)
def test_printed_rotation_is_singular_at_45_degrees(theta):
    T = km.rotation(theta, True)
    # rows [c, s] and [s, c] coincide (or are opposite) when |c| = |s|
    assert abs(np.linalg.det(T)) < 1e-15
    assert np.linalg.matrix_rank(T[:2, :2], tol=1e-12) == 1


def test_wrap_angle_interval():
    assert km.wrap_angle(-math.pi) == math.pi
    assert km.wrap_angle(math.pi) == math.pi
    assert km.wrap_angle(3 * math.pi) == pytest.approx(math.pi, abs=1e-15)  # 3pi is rounded
    assert km.wrap_angle(-math.pi - 1e-15) == pytest.approx(math.pi - 1e-15, abs=1e-15)
    assert km.wrap_angle(0.0) == 0.0
    rng = np.random.default_rng(4)
    for a in rng.uniform(-50, 50, 500):
        w = km.wrap_angle(a)
        assert -math.pi < w <= math.pi
        # same angle: an integer number of turns apart (rounding of a/2pi ~ 1e-14 here)
        turns = (a - w) / (2 * math.pi)
        assert abs(turns - round(turns)) < 1e-12


def test_tracking_error_is_the_rotated_world_error_with_wrapped_heading():
    rng = np.random.default_rng(5)
    for _ in range(300):
        q = np.array([*rng.uniform(-3, 3, 2), rng.uniform(-20, 20)])
        q_r = np.array([*rng.uniform(-3, 3, 2), rng.uniform(-20, 20), 0.5, 0.1])  # a full sample
        e = km.tracking_error(q, q_r)
        d = q_r[:3] - q
        assert_allclose(e[:2], (km.rotation(q[2]) @ d)[:2], rtol=0, atol=1e-14)
        assert -math.pi < e[2] <= math.pi
        turns = (d[2] - e[2]) / (2 * math.pi)
        assert abs(turns - round(turns)) < 1e-12
        # the rotation keeps distances: e1^2 + e2^2 is the world squared distance
        assert e[0] ** 2 + e[1] ** 2 == pytest.approx(d[0] ** 2 + d[1] ** 2, rel=1e-13, abs=1e-15)
        # the printed matrix does not: |e|^2 = |d|^2 + 2 sin(2 theta) dx dy
        ep = km.tracking_error(q, q_r, True)
        assert_allclose(ep[:2], (km.rotation(q[2], True) @ d)[:2], rtol=0, atol=1e-14)
        expected = d[0] ** 2 + d[1] ** 2 + 2 * math.sin(2 * q[2]) * d[0] * d[1]
        assert ep[0] ** 2 + ep[1] ** 2 == pytest.approx(expected, rel=1e-12, abs=1e-13)
        assert ep[2] == e[2]


def test_printed_error_differs_from_the_distance():
    """A concrete case: theta = 45 deg, target straight ahead-left; the printed form doubles it."""
    q = np.array([0.0, 0.0, math.pi / 4])
    q_r = np.array([1.0, 1.0, math.pi / 4])
    e = km.tracking_error(q, q_r)
    ep = km.tracking_error(q, q_r, True)
    assert_allclose(e, [math.sqrt(2), 0.0, 0.0], atol=1e-15)  # target dead ahead, sqrt(2) m
    assert_allclose(ep, [math.sqrt(2), math.sqrt(2), 0.0], atol=1e-15)  # |ep|^2 = 4 != 2


def test_heading_error_across_the_branch_cut():
    q = np.array([0.0, 0.0, math.pi - 0.1])
    q_r = np.array([0.0, 0.0, -math.pi + 0.1])
    assert km.tracking_error(q, q_r)[2] == pytest.approx(0.2, abs=1e-14)  # the short way round
    q_r = np.array([0.0, 0.0, q[2] + math.pi])
    assert km.tracking_error(q, q_r)[2] == pytest.approx(math.pi, abs=1e-14)


# --- the allocation-free forms ---------------------------------------------------------------


@pytest.mark.parametrize("integrator", INTEGRATOR_PARAMS)
def test_step_into_may_advance_the_pose_in_place(integrator):
    """``step_into(q, u, dt, i, q)`` (the loop's form: the pose overwritten as it is read) gives
    the bits of ``step`` into a separate array, for every integrator (an aliasing bug -- a
    coordinate read after it was written -- would move x or y)."""
    q, u, dt = _random_points(seed=7, n=50)
    for qi, ui, h in zip(q, u, dt, strict=True):
        expected = km.step(qi, ui, h, integrator)
        inplace = qi.copy()
        km.step_into(inplace, ui, h, integrator, inplace)
        assert_array_equal(inplace, expected)


@pytest.mark.parametrize("integrator", INTEGRATOR_PARAMS)
def test_step_jacobians_into_computes_the_one_asked_for(integrator):
    """With ``F`` or ``G`` None only the other is written (the laws need G, the filter F); each
    equals ``step_jacobians``'s, and a stale buffer is fully overwritten."""
    q, u, dt = _random_points(seed=8, n=20)
    for qi, ui, h in zip(q, u, dt, strict=True):
        F, G = km.step_jacobians(qi, ui, h, integrator)
        Fo, Go = np.full((3, 3), np.nan), np.full((3, 2), np.nan)
        km.step_jacobians_into(qi, ui, h, integrator, Fo, None)
        km.step_jacobians_into(qi, ui, h, integrator, None, Go)
        assert_array_equal(Fo, F)
        assert_array_equal(Go, G)


def test_tracking_error_parts_are_the_tracking_error():
    """The scalar form (the laws') and the array form give the same bits, rotation and printed."""
    q, _, _ = _random_points(seed=9, n=100)
    q_r = q[::-1] + 0.3
    for a, b in zip(q, q_r, strict=True):
        for printed in (False, True):
            assert km.tracking_error_parts(a, b, printed) == tuple(km.tracking_error(a, b, printed))
