"""Tests of wmr/linear/loops.py: the linearisation, the loops, the closed loops and the closed
forms.

Oracles: central differences of the **simulator's own** step (``wmr.model.kinematics.step`` and
``tracking_error``, and the jitted PID law), CasADi's Jacobian of the whole nonlinear closed loop,
closed-form stability conditions (Jury, Routh), ``exp(A dt)`` for the sampled backstepping loop,
and two constructions of the same closed loop (``control.interconnect`` vs block matrices).
"""

from __future__ import annotations

import dataclasses
import math

import control as ct
import numpy as np
import pytest
from numpy.testing import assert_allclose
from oracles import central_fd as _central_fd

from wmr import scenario as scn
from wmr.controllers import pid
from wmr.controllers.pid import S_INT, S_PREV, S_STARTED
from wmr.linear import loops as lp
from wmr.model import kinematics as kin
from wmr.model import symbolic as sym
from wmr.model.references import sample

SEED = 20240251
DT = 0.01
# Central differences, step 1e-6, of maps whose entries reach Kd/dt ~ 50: rounding
# ~eps*50/1e-6 ~ 1e-8, truncation ~1e-12; 1e-6 is two decades above.
FD_STEP = 1e-6
FD_TOL = 1e-6
# Two exact computations of the same matrix in a different order of operations.
EXACT_TOL = 1e-12
#: Gains with non-zero Kd (exercise the derivative states).
K_D = (5.0, 5.0, 0.3, 10.0, 2.0, 0.2)

OPS = [lp.OperatingPoint(0.61, 0.0, DT, label="straight"),
       lp.OperatingPoint(0.5, 0.5, DT, label="left turn"),
       lp.OperatingPoint(0.21, -0.5, DT, label="slow right turn")]  # fmt: skip
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
    P = lp.error_plant(op)
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
    one step of the simulator's jitted PID law followed by kinematics.step, about x*.

    The PID's memory (integrals, previous signals) has no public setter: the state offsets
    ``S_INT``, ``S_PREV``, ``S_STARTED`` put the law at a chosen closed-loop state."""
    sc = scn.load(scn.builtin("sinusoid"))
    settings = pid.FixedSettings(gains=K_D)
    ref = np.array([1.0, -2.0, 0.7, op.v_r, op.w_r])

    def step(x):
        p, s, theta, P = pid.pack(settings, sc, np.random.default_rng(0))
        s[S_INT], s[S_INT + 1], s[S_PREV], s[S_PREV + 1] = x[3:7]
        s[S_STARTED] = 1.0
        q = _robot_pose(x[:3], ref[:3])
        u = np.zeros(2)
        pid.law(p, s, theta, P, q, ref, op.dt, u)
        e_next = kin.tracking_error(
            kin.step(q, u, op.dt), kin.step(ref[:3].copy(), ref[3:5].copy(), op.dt)
        )
        return np.concatenate((e_next, s[S_INT : S_INT + 2], s[S_PREV : S_PREV + 2]))

    xs = lp.pid_equilibrium(op, K_D)
    assert_allclose(step(xs), xs, atol=1e-14)  # the equilibrium of the literal eq. 7
    A_fd = central_fd(step, xs)
    loops = lp.pid_loops(op, K_D)
    assert_allclose(lp.closed_loop_matrix(loops["v"]), A_fd, atol=FD_TOL)
    assert_allclose(lp.closed_loop_matrix(loops["w"]), A_fd, atol=FD_TOL)


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
def test_loops_close_to_casadis_jacobian_of_the_whole_closed_loop(op):
    A = np.asarray(
        sym.pid_closed_loop_jacobian_function()(lp.pid_equilibrium(op, K_D), op.u_r, K_D, op.dt)
    )
    loops = lp.pid_loops(op, K_D)
    for ch in lp.CHANNELS:
        assert_allclose(lp.closed_loop_matrix(loops[ch]), A, atol=EXACT_TOL)
    assert_allclose(lp.pid_closed_loop_matrix(lp.error_plant(op), K_D), A, atol=EXACT_TOL)
    Ab = np.asarray(sym.backstepping_step_jacobian_function()(*op.u_r, *lp.BSC_GAINS, op.dt))
    assert_allclose(lp.closed_loop_matrix(lp.backstepping_loops(op)["w"]), Ab, atol=EXACT_TOL)


def _delayed_plant(op: lp.OperatingPoint) -> ct.StateSpace:
    """The kinematic error plant behind a one-sample delay of both inputs (states: e, then the
    held input), named like error_plant's: a plant with more states than outputs."""
    P = lp.error_plant(op)
    A = np.block([[P.A, P.B], [np.zeros((2, 3)), np.zeros((2, 2))]])
    B = np.vstack((np.zeros((3, 2)), np.eye(2)))
    C = np.hstack((np.eye(3), np.zeros((3, 2))))
    return ct.ss(A, B, C, np.zeros((3, 2)), op.dt, inputs=("v", "w"),
                 outputs=("e1", "e2", "e3"), name="plant")  # fmt: skip


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
def test_closed_loops_handle_plants_with_more_states_than_the_error(op):
    """The block-matrix closed loop (gain grids) equals the interconnected one for a plant whose
    error is C x with extra states (as actuator lag or delay make it), and the start map puts
    those states at rest."""
    P = _delayed_plant(op)
    L = lp.loop_transfer(P, lp.pid_controller(K_D, op.dt), "v")
    assert_allclose(lp.pid_closed_loop_matrix(P, K_D), lp.closed_loop_matrix(L), atol=EXACT_TOL)
    M = lp.start_state_map("pid", P)
    assert M.shape == (9, 3)
    assert_allclose(M[3:5], 0.0)
    assert_allclose(M[:3], np.eye(3))


@pytest.mark.parametrize("dt", [0.02, 0.01])
def test_backstepping_discrete_eigenvalues_approach_exp_of_continuous(dt):
    """A_d = I + A dt + O(dt^2) (the ZOH step and the sampled law agree to first order), so
    eig(A_d) - exp(eig(A) dt) = O(dt^2): halving dt divides the difference by ~4."""
    for op in OPS:
        A = np.asarray(sym.backstepping_jacobian_function()(*op.u_r, *lp.BSC_GAINS))
        lam = np.linalg.eigvals(A)
        diffs = []
        for h in (dt, dt / 2):
            L = lp.backstepping_loops(dataclasses.replace(op, dt=h))["v"]
            diffs.append(lp.eigenvalue_distance(np.linalg.eigvals(lp.closed_loop_matrix(L)),
                                                np.exp(lam * h)))  # fmt: skip
        assert diffs[0] < 5 * dt**2, diffs
        assert 3.5 < diffs[0] / diffs[1] < 4.5, diffs


def test_frequency_response_equals_the_transfer_function():
    """The state-space response equals python-control's own evaluation of the loop."""
    L = lp.pid_loops(OPS[1])["w"]
    w = np.array([0.05, 1.0, 30.0, math.pi / DT])
    assert_allclose(lp.frequency_response(L, w), L(np.exp(1j * w * DT)), rtol=1e-9)


def test_stability_region_matches_jury_on_a_straight_line():
    op = OPS[0]
    reg = lp.stability_region(op, "v", n=25, log_range=(-1.0, 3.5))
    P, I = np.meshgrid(reg["kp"], reg["ki"])
    away = np.abs(reg["rho"] - 1.0) > 1e-6
    assert np.array_equal((reg["rho"] < 1.0)[away], lp.jury_v_loop_stable(P, I, op.dt)[away])
    assert not np.all(reg["rho"] < 1.0) and np.any(reg["rho"] < 1.0)  # both sides are sampled


def test_gain_limits_equal_jurys_closed_forms_on_a_straight_line():
    """w_r = 0, Kdv = 0: Jury's conditions (jury_v_loop_stable) bound Kpv by
    min(2/dt, (4 - dt^2 Kiv)/(2 dt)) and Kiv by (4 - 2 dt Kpv)/dt^2."""
    op = OPS[0]
    Kpv, Kiv = lp.PID_GAINS[:2]
    kpv_max, kiv_max = lp.jury_v_gain_limits(Kpv, Kiv, DT)
    assert kpv_max == min(2 / DT, (4 - DT * DT * Kiv) / (2 * DT))
    assert kiv_max == (4 - 2 * DT * Kpv) / DT**2
    assert lp.stable_gain_interval(op, 0)[1] == pytest.approx(kpv_max, rel=1e-10)
    assert lp.stable_gain_interval(op, 1)[1] == pytest.approx(kiv_max, rel=1e-10)
    lo, hi = lp.stable_gain_interval(op, 3)
    # The continuous-time Routh bound Kpw^2 v_r + Kpw Kiw - Kiw v_r > 0, to O(dt).
    Kiw = lp.PID_GAINS[4]
    routh = (-Kiw + math.sqrt(Kiw**2 + 4 * op.v_r**2 * Kiw)) / (2 * op.v_r)
    assert lo == pytest.approx(routh, rel=0.05)
    assert not lp.routh_w_loop_stable(0.99 * routh, Kiw, op.v_r)
    assert lp.routh_w_loop_stable(1.01 * routh, Kiw, op.v_r)
    assert 1.9 / DT < hi < 2 / DT


def test_slow_mode_error_cancels_the_next_mode():
    op = OPS[1]
    A = lp.closed_loop_matrix(lp.backstepping_loops(op)["v"])
    e0 = lp.slow_mode_error(A, lp.start_state_map("backstepping", lp.error_plant(op)))
    z, V = np.linalg.eig(A)
    c = np.abs(np.linalg.solve(V, e0))
    order = np.argsort(-np.abs(z))
    assert np.linalg.norm(e0) == pytest.approx(1e-3)
    assert c[order[-1]] < 1e-15 * np.max(c) + 1e-18  # the third (fastest) mode is not excited


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
def test_constant_reference_scenario_starts_at_the_error(op):
    e0 = np.array([0.01, -0.02, 0.03])
    sc = lp.constant_reference_scenario(op, 1.0, e0)
    ref = sample(sc.reference.kind, sc.reference.params, sc.dt, 2)
    assert_allclose(kin.tracking_error(np.asarray(sc.initial_pose), ref[0]), e0, atol=1e-15)
    assert_allclose(ref[:, 3], op.v_r, atol=1e-12)
    assert_allclose(ref[:, 4], abs(op.w_r), atol=1e-12)
    assert sc.n_steps == 100 and sc.noise.pose_std == (0.0, 0.0, 0.0)


def test_operating_point_validation():
    with pytest.raises(ValueError, match="dt"):
        lp.OperatingPoint(0.5, 0.0, 0.0)
    with pytest.raises(ValueError, match="where"):
        lp.operating_point(scn.load(scn.builtin("sinusoid")), "median")
    with pytest.raises(ValueError, match="controller"):
        lp.start_state_map("adaptive-nn", lp.error_plant(OPS[0]))


# --- Input dynamics of the true robot in the linearised plant (issue 12) --------------------------


def _true_error_step(op, e, ua, u):
    """One step of the true robot (``wmr.robots.plant.lagged_step``, the simulator's own
    integration) in error coordinates about the constant reference of ``op``: ``(e_next,
    ua_next)``."""
    from wmr.model.kinematics import EXACT, rotation, step, tracking_error
    from wmr.robots import plant

    q_r = np.zeros(3)
    th = q_r[2] - e[2]
    q = np.array([*(q_r[:2] - rotation(th).T[:2, :2] @ e[:2]), th])
    row = plant.table_row(scn.Plant(actuator_tau=op.actuator_tau).row(), plant.KINEMATIC, op.dt, 1)
    vel = np.array(ua, dtype=float)
    plant.lagged_step(row, plant.KINEMATIC, q, vel, u[0], u[1], op.dt, 1)
    return tracking_error(q, step(q_r, op.u_r, op.dt, EXACT)), vel


@pytest.mark.parametrize("tau", [0.05, 0.3])
def test_lagged_plant_is_the_linearisation_of_the_true_robots_step(tau):
    """The exact sampled (e, u_a) step of error_plant equals central differences of the true
    robot's own step (``wmr.robots.plant``) at perfect tracking, to O(h^2)."""
    op = lp.OperatingPoint(0.5, 0.3, 0.01, actuator_tau=tau)
    P = lp.error_plant(op)
    x0 = np.concatenate((np.zeros(3), op.u_r))

    def f(x, u):
        e, ua = _true_error_step(op, x[:3], x[3:], u)
        return np.concatenate((e, ua))

    h = 1e-6
    A = np.column_stack([(f(x0 + h * d, op.u_r) - f(x0 - h * d, op.u_r)) / (2 * h)
                         for d in np.eye(5)])  # fmt: skip
    B = np.column_stack([(f(x0, op.u_r + h * d) - f(x0, op.u_r - h * d)) / (2 * h)
                         for d in np.eye(2)])  # fmt: skip
    assert_allclose(P.A, A, atol=1e-8)  # central differences: O(h^2) plus rounding 1e-16/h
    assert_allclose(P.B, B, atol=1e-8)
    assert P.nstates == 5 and np.array_equal(P.C, np.hstack((np.eye(3), np.zeros((3, 2)))))


def test_delay_line_shifts_the_impulse_response_by_whole_samples():
    op = lp.OperatingPoint(0.5, 0.2, 0.01, actuator_tau=0.1)
    base = lp.error_plant(op)
    for d in (1, 3):
        delayed = lp.error_plant(dataclasses.replace(op, delay_steps=d))
        assert delayed.nstates == base.nstates + 2 * d
        for ch in range(2):
            y0 = np.squeeze(ct.impulse_response(base[:, ch], T=np.arange(40) * op.dt).outputs)
            yd = np.squeeze(ct.impulse_response(delayed[:, ch],
                                                T=np.arange(40 + d) * op.dt).outputs)
            assert_allclose(yd[..., d:], y0, atol=1e-14)
            assert np.all(yd[..., :d] == 0.0) and np.any(y0 != 0.0)


@pytest.mark.parametrize("controller", ["pid", "backstepping"])
def test_max_stable_delay_matches_the_simulated_robot(controller):
    """Two samples below the linearised loop's delay limit the simulated robot (the nonlinear
    loop with the plant's delay line) settles; two above it, its error grows."""
    loops_of = lp.pid_loops if controller == "pid" else lp.backstepping_loops
    settings = pid.FixedSettings(feed_forward=True) if controller == "pid" else None
    op = lp.operating_point(scn.load(scn.builtin("sinusoid")), "mean")
    d_max = lp.max_stable_delay(op, loops_of)
    assert 0 < d_max < 400
    from wmr.closedloop.sim import simulate

    for d, grows in ((d_max - 2, False), (d_max + 2, True)):
        sc = lp.constant_reference_scenario(dataclasses.replace(op, delay_steps=d), 60.0,
                                            [0.0, 1e-3, 0.0])  # fmt: skip
        r = simulate(sc, controller, 0, settings=settings)
        e = np.hypot(*(r.ref[:, :2] - r.q[:, :2]).T)
        n = len(e)
        if r.diverged:
            assert grows
            continue
        late, later = e[n // 3 : 2 * n // 3].max(), e[2 * n // 3 :].max()
        assert (later > late) == grows, (d, late, later)
