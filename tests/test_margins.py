"""Tests of analysis/margins.py: the linearisation, the loops, the margins and their cross-checks.

Oracles: central differences of the **simulator's own** step (``wmr.kinematics.step`` and
``tracking_error``, and the jitted PID law), margins of loops computed by hand, closed-form
stability conditions (Jury), ``exp(A dt)`` for the sampled backstepping loop, and the
nonlinear simulation.
"""

from __future__ import annotations

import dataclasses
import math

import control as ct
import numpy as np
import pytest
from numpy.testing import assert_allclose
from oracles import central_fd as _central_fd

from analysis import margins as M
from wmr import kinematics as kin
from wmr import scenario as scn
from wmr import symbolic as sym
from wmr.controllers import pid
from wmr.controllers.pid import S_INT, S_PREV, S_STARTED

SEED = 20240251
DT = 0.01
# Central differences, step 1e-6, of maps whose entries reach Kd/dt ~ 50: rounding
# ~eps*50/1e-6 ~ 1e-8, truncation ~1e-12; 1e-6 is two decades above.
FD_STEP = 1e-6
FD_TOL = 1e-6
# Two exact computations of the same matrix in a different order of operations.
EXACT_TOL = 1e-12
# Margins from the refined frequency response vs closed forms: limited by brentq/minimize
# tolerances (~1e-10 relative) and by round-off in (zI - A)^-1 near z = 1.
MARGIN_TOL = 1e-8

OPS = [M.OperatingPoint(0.61, 0.0, DT, label="straight"),
       M.OperatingPoint(0.5, 0.5, DT, label="left turn"),
       M.OperatingPoint(0.21, -0.5, DT, label="slow right turn")]  # fmt: skip
OP_IDS = [op.label for op in OPS]


def central_fd(fun, x, step=FD_STEP):
    return _central_fd(fun, x, step)


def _robot_pose(e, q_r):
    """Robot pose whose corrected error (eq. 6) to the reference pose ``q_r`` is ``e``."""
    th = q_r[2] - e[2]
    c, s = math.cos(th), math.sin(th)
    return np.array([q_r[0] - (c * e[0] - s * e[1]), q_r[1] - (s * e[0] + c * e[1]), th])


def _simulator_error_step(e, u, ref, dt):
    """e_{k+1} with the simulator's functions: move the pose and the reference one step."""
    q = _robot_pose(e, ref[:3])
    q_next = kin.step(q, np.asarray(u, dtype=float), dt, kin.EXACT)
    q_r_next = kin.step(ref[:3].copy(), ref[3:5].copy(), dt, kin.EXACT)
    return kin.tracking_error(q_next, q_r_next)


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
def test_plant_linearisation_equals_finite_differences_of_the_simulator_step(op):
    """E, B of error_plant (CasADi AD) vs central differences of kinematics.step + tracking_error,
    at reference poses anywhere in the plane (the corrected error is SE(2)-invariant)."""
    rng = np.random.default_rng(SEED)
    P = M.error_plant(op)
    for _ in range(5):
        ref = np.array([*rng.uniform(-5, 5, 2), rng.uniform(-math.pi, math.pi), op.v_r, op.w_r])
        E = central_fd(lambda e, r=ref: _simulator_error_step(e, op.u_r, r, op.dt), np.zeros(3))
        B = central_fd(lambda u, r=ref: _simulator_error_step(np.zeros(3), u, r, op.dt), op.u_r)
        assert_allclose(P.A, E, atol=FD_TOL)
        assert_allclose(P.B, B, atol=FD_TOL)
    assert_allclose(P.C, np.eye(3))
    assert P.dt == op.dt


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
def test_pid_closed_loop_equals_finite_differences_of_the_simulator_law_and_step(op):
    """The python-control closed loop (plant + eq. 7 as an LTI system) vs central differences of
    one step of the simulator's jitted PID law followed by kinematics.step, about x*."""
    sc = scn.load(scn.builtin("sinusoid"))
    K = (5.0, 5.0, 0.3, 10.0, 2.0, 0.2)  # non-zero Kd exercises the derivative states
    settings = pid.FixedSettings(gains=K)
    ref = np.array([1.0, -2.0, 0.7, op.v_r, op.w_r])

    def step(x):
        p, s, W, P = pid.pack(settings, sc, np.random.default_rng(0))
        s[S_INT], s[S_INT + 1], s[S_PREV], s[S_PREV + 1] = x[3:7]
        s[S_STARTED] = 1.0
        q = _robot_pose(x[:3], ref[:3])
        u = np.zeros(2)
        pid.law(p, s, W, P, q, ref, op.dt, u)
        e_next = kin.tracking_error(
            kin.step(q, u, op.dt), kin.step(ref[:3].copy(), ref[3:5].copy(), op.dt)
        )
        return np.concatenate((e_next, s[S_INT : S_INT + 2], s[S_PREV : S_PREV + 2]))

    xs = M.pid_equilibrium(op, K)
    assert_allclose(step(xs), xs, atol=1e-14)  # the equilibrium of the literal eq. 7
    A_fd = central_fd(step, xs)
    loops = M.pid_loops(op, K)
    assert_allclose(M.closed_loop_matrix(loops["v"]), A_fd, atol=FD_TOL)
    assert_allclose(M.closed_loop_matrix(loops["w"]), A_fd, atol=FD_TOL)


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
def test_loops_close_to_casadis_jacobian_of_the_whole_closed_loop(op):
    K = (5.0, 5.0, 0.3, 10.0, 2.0, 0.2)
    A = np.asarray(
        sym.pid_closed_loop_jacobian_function()(M.pid_equilibrium(op, K), op.u_r, K, op.dt)
    )
    loops = M.pid_loops(op, K)
    for ch in M.CHANNELS:
        assert_allclose(M.closed_loop_matrix(loops[ch]), A, atol=EXACT_TOL)
    E, B = M.error_plant(op).A, M.error_plant(op).B
    assert_allclose(M.pid_closed_loop_matrix(E, B, K, op.dt), A, atol=EXACT_TOL)
    Ab = np.asarray(sym.backstepping_step_jacobian_function()(*op.u_r, *M.BSC_GAINS, op.dt))
    assert_allclose(M.closed_loop_matrix(M.backstepping_loops(op)["w"]), Ab, atol=EXACT_TOL)


# ---- margins of hand-computable loops ------------------------------------------------------


def _check_against_eigen(L, m):
    e = M.eigen_margins(L)
    assert e["gain_margin"] == pytest.approx(m.gain_margin, rel=1e-6)
    assert e["phase_margin_deg"] == pytest.approx(m.phase_margin_deg, rel=1e-6)
    assert e["disk_margin"] == pytest.approx(m.disk_margin, rel=1e-6)


@pytest.mark.parametrize("a", [0.05, 0.5, 1.2])
def test_margins_of_an_integrator_loop(a):
    """L(z) = a/(z - 1) (a = K dt: proportional control of e_{k+1} = e_k - dt u_k), 0 < a < 2.

    By hand, with z = exp(j theta), theta = w dt:
    - z - 1 = 2j sin(theta/2) exp(j theta/2), so arg L = -(pi/2 + theta/2): L is real negative
      only at theta = pi (z = -1), L(-1) = -a/2, hence GM = 2/a at the Nyquist frequency
      (closed-loop pole 1 - g a leaves the unit disc at g = 2/a); no lower gain margin.
    - |L| = a/(2 sin(theta/2)) = 1 at sin(theta_c/2) = a/2; PM = 180 + arg L = 90 - theta_c/2,
      i.e. PM = 90 deg - asin(a/2).
    - S - T = (1 - L)/(1 + L) = (z - 1 - a)/(z - 1 + a), the ratio of the distances from z to
      1 + a and to 1 - a, largest on the circle at z = -1: (2 + a)/(2 - a).  So
      alpha = 2/max|S - T| = 2(2 - a)/(2 + a), the disk gain margin (1 + alpha/2)/(1 - alpha/2)
      = 2/a equals the classical one (the worst point is on the real axis), and the disk phase
      margin is 2 atan(alpha/2) = 2 atan((2 - a)/(2 + a)).
    """
    L = ct.ss([[1.0]], [[1.0]], [[a]], [[0.0]], DT)
    m = M.loop_margins(L)
    assert m.stable
    assert m.gain_margin == pytest.approx(2 / a, rel=MARGIN_TOL)
    assert m.phase_crossover_rad_s == pytest.approx(math.pi / DT, rel=1e-12)
    assert m.gain_margin_lower == 0.0 and m.gain_margin_lower_db == -math.inf
    assert m.phase_margin_deg == pytest.approx(90 - math.degrees(math.asin(a / 2)), rel=MARGIN_TOL)
    alpha = 2 * (2 - a) / (2 + a)
    assert m.disk_margin == pytest.approx(alpha, rel=MARGIN_TOL)
    assert m.disk_gain_margin_db == pytest.approx(20 * math.log10(2 / a), rel=MARGIN_TOL)
    assert m.disk_phase_margin_deg == pytest.approx(
        math.degrees(2 * math.atan((2 - a) / (2 + a))), rel=MARGIN_TOL)  # fmt: skip
    _check_against_eigen(L, m)


def test_margins_of_a_two_step_delay():
    """L(z) = k z^-2, k = 1/2.  arg L = -2 theta = -pi at theta = pi/2 (z = j), L(j) = -k, so
    GM = 1/k = 2 at w = pi/(2 dt) (closed loop z^2 + g k: |z| = sqrt(g k) = 1 at g = 1/k);
    |L| = k < 1 everywhere, so no gain crossover: PM = inf.  S - T = (z^2 - k)/(z^2 + k) is
    largest at z^2 = -1: (1 + k)/(1 - k), so alpha = 2(1 - k)/(1 + k) = 2/3, disk GM = 1/k
    (6.02 dB) and disk PM = 2 atan(1/3) = 36.87 deg."""
    k = 0.5
    L = ct.ss([[0.0, 0.0], [1.0, 0.0]], [[1.0], [0.0]], [[0.0, k]], [[0.0]], DT)  # k z^-2
    m = M.loop_margins(L)
    assert m.gain_margin == pytest.approx(1 / k, rel=MARGIN_TOL)
    assert m.phase_crossover_rad_s == pytest.approx(math.pi / (2 * DT), rel=1e-9)
    assert m.phase_margin_deg == math.inf
    assert m.disk_margin == pytest.approx(2 * (1 - k) / (1 + k), rel=MARGIN_TOL)
    assert m.disk_gain_margin_db == pytest.approx(20 * math.log10(1 / k), rel=MARGIN_TOL)
    assert m.disk_phase_margin_deg == pytest.approx(
        math.degrees(2 * math.atan(1 / 3)), rel=MARGIN_TOL
    )
    assert m.to_json()["phase_margin_deg"] == "inf"
    e = M.eigen_margins(L)
    assert e["gain_margin"] == pytest.approx(1 / k, rel=1e-6)
    assert e["phase_margin_deg"] == math.inf
    assert e["disk_margin"] == pytest.approx(m.disk_margin, rel=1e-6)


@pytest.mark.parametrize(("Kp", "Ki"), [(5.0, 5.0), (50.0, 1.0), (1.0, 200.0)])
def test_gain_margin_of_the_pi_double_integrator(Kp, Ki):
    """The v loop on a straight line: e1_{k+1} = e1_k - dt dv_k with the PI of eq. (7) gives
    L(z) = dt((Kp + Ki dt) z - Kp)/(z - 1)^2 =: a (z - b)/(z - 1)^2.  With gain g the closed
    loop is z^2 + (g a - 2) z + (1 - g a b); Jury: g a b < 2, g a (1 - b) > 0 and
    4 - g a (1 + b) > 0.  Since b < 1 the last binds: GM = 4/(a (1 + b)) = 1/|L(-1)|; there is
    no lower gain margin (the phase tends to -180 deg only as w -> 0, where python-control
    0.10.2's polynomial method reports a spurious crossover)."""
    a = DT * (Kp + Ki * DT)
    b = Kp / (Kp + Ki * DT)
    L = ct.ss([[2.0, -1.0], [1.0, 0.0]], [[1.0], [0.0]], [[a, -a * b]], [[0.0]], DT)
    m = M.loop_margins(L)
    assert m.gain_margin == pytest.approx(4 / (a * (1 + b)), rel=MARGIN_TOL)
    assert m.gain_margin_lower == 0.0
    _check_against_eigen(L, m)
    # The same loop from the library: the v loop of the PID on a straight line.
    op = M.OperatingPoint(0.61, 0.0, DT)
    Lv = M.pid_loops(op, (Kp, Ki, 0.0, 10.0, 2.0, 0.0))["v"]
    assert M.loop_margins(Lv, python_control=False).gain_margin == pytest.approx(
        m.gain_margin, rel=1e-9
    )


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
@pytest.mark.parametrize("which", ["pid", "backstepping"])
def test_frequency_margins_agree_with_closed_loop_eigenvalues(op, which):
    loops = M.pid_loops(op) if which == "pid" else M.backstepping_loops(op)
    for ch in M.CHANNELS:
        m = M.loop_margins(loops[ch])
        e = M.eigen_margins(loops[ch])
        checks = M._channel_checks(m, e)
        assert checks["gain_margin_rel_diff"] < 1e-6, checks
        assert checks["gain_margin_lower_rel_diff"] < 1e-6, checks
        assert checks["phase_margin_abs_diff_deg"] < 1e-6, checks
        assert checks["disk_margin_rel_diff"] < 1e-6, checks
        assert checks["disk_gm_below_classical"] and checks["disk_pm_below_classical"]
        # python-control's own disk margin and the formula used along runs agree.
        fast = M.loop_margins(loops[ch], python_control=False)
        assert fast.disk_margin == pytest.approx(m.disk_margin, rel=1e-9)
        assert fast.disk_phase_margin_deg == pytest.approx(m.disk_phase_margin_deg, rel=1e-9)


def test_margins_are_mirror_symmetric_in_w_r():
    """Reflecting the plane (y -> -y) maps (v_r, w_r) to (v_r, -w_r), e2, e3, w to their negatives
    and s = e3 + e2 to -s: same loops, same margins."""
    op = OPS[1]
    for ch in M.CHANNELS:
        a = M.loop_margins(M.pid_loops(op)[ch], python_control=False)
        b = M.loop_margins(
            M.pid_loops(dataclasses.replace(op, w_r=-op.w_r))[ch], python_control=False
        )
        assert a.phase_margin_deg == pytest.approx(b.phase_margin_deg, rel=1e-9)
        assert a.disk_margin == pytest.approx(b.disk_margin, rel=1e-9)


def test_an_unstable_loop_gets_zero_margins():
    L = ct.ss([[1.0]], [[1.0]], [[2.5]], [[0.0]], DT)  # closed-loop pole 1 - 2.5 = -1.5
    m = M.loop_margins(L)
    assert not m.stable and m.disk_margin == 0.0 and m.gain_margin_db == 0.0


@pytest.mark.parametrize("dt", [0.02, 0.01])
def test_backstepping_discrete_eigenvalues_approach_exp_of_continuous(dt):
    """A_d = I + A dt + O(dt^2) (the ZOH step and the sampled law agree to first order), so
    eig(A_d) - exp(eig(A) dt) = O(dt^2): halving dt divides the difference by ~4."""
    for op in OPS:
        A = np.asarray(sym.backstepping_jacobian_function()(*op.u_r, *M.BSC_GAINS))
        lam = np.linalg.eigvals(A)
        diffs = []
        for h in (dt, dt / 2):
            L = M.backstepping_loops(dataclasses.replace(op, dt=h))["v"]
            diffs.append(M._match(np.linalg.eigvals(M.closed_loop_matrix(L)), np.exp(lam * h)))
        assert diffs[0] < 5 * dt**2, diffs
        assert 3.5 < diffs[0] / diffs[1] < 4.5, diffs


def test_stability_region_matches_jury_on_a_straight_line():
    op = OPS[0]
    reg = M.stability_region(op, "v", n=25, log_range=(-1.0, 3.5))
    P, I = np.meshgrid(reg["kp"], reg["ki"])
    away = np.abs(reg["rho"] - 1.0) > 1e-6
    assert np.array_equal((reg["rho"] < 1.0)[away], M.jury_v_loop_stable(P, I, op.dt)[away])
    assert not np.all(reg["rho"] < 1.0) and np.any(reg["rho"] < 1.0)  # both sides are sampled


def test_slow_mode_error_cancels_the_next_mode():
    op = OPS[1]
    A = M.closed_loop_matrix(M.backstepping_loops(op)["v"])
    e0 = M.slow_mode_error(A, np.eye(3))
    z, V = np.linalg.eig(A)
    c = np.abs(np.linalg.solve(V, e0))
    order = np.argsort(-np.abs(z))
    assert np.linalg.norm(e0) == pytest.approx(1e-3)
    assert c[order[-1]] < 1e-15 * np.max(c) + 1e-18  # the third (fastest) mode is not excited


def test_decay_of_the_simulated_loop_follows_the_slowest_eigenvalue():
    """The nonlinear simulated loop from a small error follows its linearisation and decays at
    the rate of the slowest closed-loop eigenvalue."""
    d = M.decay_check("backstepping", OPS[1], M.BSC_GAINS, decades=4.0)
    assert not d["diverged"]
    assert d["rate_rel_error"] < 1e-3, d
    assert d["max_deviation_from_linear_rel"] < 1e-2, d


def test_json_numbers():
    assert M._num(math.inf) == "inf" and M._num(-math.inf) == "-inf" and M._num(math.nan) is None
    assert M._num(np.float64(1.5)) == 1.5


def test_operating_point_validation():
    with pytest.raises(ValueError, match="dt"):
        M.OperatingPoint(0.5, 0.0, 0.0)
    with pytest.raises(ValueError, match="where"):
        M.operating_point(scn.load(scn.builtin("sinusoid")), "median")


def test_gain_limits_equal_jurys_closed_forms_on_a_straight_line():
    """w_r = 0, Kdv = 0: Jury's conditions (jury_v_loop_stable) bound Kpv by
    min(2/dt, (4 - dt^2 Kiv)/(2 dt)) and Kiv by (4 - 2 dt Kpv)/dt^2."""
    op = OPS[0]
    Kpv, Kiv = M.PID_GAINS[:2]
    assert M.stable_gain_interval(op, 0)[1] == pytest.approx(
        min(2 / DT, (4 - DT * DT * Kiv) / (2 * DT)), rel=1e-10
    )
    assert M.stable_gain_interval(op, 1)[1] == pytest.approx((4 - 2 * DT * Kpv) / DT**2, rel=1e-10)
    lo, hi = M.stable_gain_interval(op, 3)
    # The continuous-time Routh bound Kpw^2 v_r + Kpw Kiw - Kiw v_r > 0, to O(dt).
    Kiw = M.PID_GAINS[4]
    routh = (-Kiw + math.sqrt(Kiw**2 + 4 * op.v_r**2 * Kiw)) / (2 * op.v_r)
    assert lo == pytest.approx(routh, rel=0.05)
    assert 1.9 / DT < hi < 2 / DT


@pytest.mark.parametrize("index", [2, 5], ids=["Kdv", "Kdw"])
def test_simulated_loop_crosses_the_derivative_gain_limit_where_the_eigenvalues_do(index):
    op = OPS[0]
    limit = M.stable_gain_interval(op, index)[1]
    inside, outside = M.gain_limit_check(op, index, limit, steps=1500)
    assert inside["spectral_radius"] < 1 < outside["spectral_radius"]
    assert inside["diverged_at"] is None and inside["tail_over_initial"] < 1
    assert outside["diverged_at"] is not None or outside["peak_over_initial"] > 10
