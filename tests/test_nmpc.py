"""Nonlinear MPC (``wmr.controllers.nmpc``, issue 21 item 1): the pieces that need no closed loop.

Oracles: ipopt converged tightly on the same problem (the first command of the other solvers),
an independent evaluation of the cost (M1) with the library's jitted ZOH step
(``wmr.kinematics.step``), the reference sampler the loop reads, a fine-grid time average for the
warm-start shift, and the limits themselves.  The closed-loop checks (tracking to the solver's
tolerance, RMSE against the fixed PID) wait for the Python driver of issue 21: no test here runs
a loop of its own.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from wmr import references
from wmr import scenario as scn
from wmr._settings import SettingError, from_table
from wmr.controllers import nmpc
from wmr.kinematics import integrator_code, step
from wmr.sim import simulate

#: ipopt's tolerance for the oracle solution, and the agreement issue 21 asks of the first
#: command (both converge to the same KKT point; 1e-10 leaves four orders of margin).
ORACLE_TOL, SAME_SOLUTION = 1e-12, 1e-6


@pytest.fixture(scope="module")
def lemniscate():
    return scn.load(scn.builtin("lemniscate"))


@pytest.fixture(scope="module")
def poses(lemniscate):
    """Pose estimates along a backstepping run that starts 0.7 m off the reference (a realistic
    sequence to feed ``step``; its transient saturates any tight limit)."""
    r = simulate(dataclasses.replace(lemniscate, duration=3.0), "backstepping", 0)
    return r.q_hat


@pytest.fixture(scope="module")
def on_track(lemniscate):
    """The lemniscate started on its reference, with limits just above the reference's peak
    speeds (0.444 m/s, 0.498 rad/s): the feedback on the noise makes them active at times."""
    sc = dataclasses.replace(lemniscate, duration=3.0, initial_pose=(0.0, 0.0, math.pi / 4),
                             limits=scn.Limits(v_max=0.45, w_max=0.5))  # fmt: skip
    return sc, simulate(sc, "backstepping", 0).q_hat


def _oracle(c: nmpc.NMPC, q_hat, rows, guess) -> np.ndarray:
    """ipopt, converged to ORACLE_TOL, on the problem ``c`` solves at this step."""
    ipopt = nmpc.problem(c.settings.horizon, "exact", "ipopt", ORACLE_TOL, 3000)
    p = nmpc.Problem.parameters(q_hat, rows, c.weights, c.settings.terminal_weight, c.h)
    x, _, ok, status = ipopt.solve(guess.ravel(), p, c.lbx, c.ubx, np.zeros(c.lbx.size))
    assert ok, status
    return x.reshape(-1, 2)


# --- settings -----------------------------------------------------------------------------------


@pytest.mark.parametrize(("table", "key"), [
    ({"horizon": 0}, "horizon"),
    ({"weights": [10.0, 0.0, 0.1, 0.1]}, "weights"),
    ({"weights": [-1.0, 1.0, 0.1, 0.1]}, "weights"),
    ({"terminal_weight": 0.0}, "terminal_weight"),
    ({"prediction_step": 0.0}, "prediction_step"),
    ({"solver": "acados"}, "solver"),
    ({"max_failures": 0}, "max_failures"),
    ({"tolerance": -1e-8}, "tolerance"),
], ids=lambda x: x if isinstance(x, str) else None)  # fmt: skip
def test_bad_settings_are_errors_naming_the_key(table, key):
    with pytest.raises(SettingError) as err:
        from_table(nmpc.Settings, table, "controllers.nmpc")
    assert err.value.key == f"controllers.nmpc.{key}" and "\n" not in str(err.value)


@pytest.mark.parametrize("h", [0.015, 0.005, 0.1 + 1e-6])
def test_a_prediction_step_that_is_not_a_multiple_of_dt_is_an_error(lemniscate, h):
    with pytest.raises(SettingError, match="whole multiple of dt = 0.01") as err:
        nmpc.make(nmpc.Settings(prediction_step=h), lemniscate)
    assert err.value.key == "controllers.nmpc.prediction_step"


def test_the_problem_is_built_once_per_structure(lemniscate):
    a = nmpc.make(nmpc.Settings(), lemniscate)
    b = nmpc.make(nmpc.Settings(weights=(1.0, 2.0, 3.0, 4.0), prediction_step=0.05), lemniscate)
    assert a.problem is b.problem  # weights and h are parameters, not structure
    assert nmpc.make(nmpc.Settings(horizon=7), lemniscate).problem is not a.problem


# --- the problem --------------------------------------------------------------------------------


def test_cost_is_M1_evaluated_independently(lemniscate):
    """The CasADi cost against (M1) written out with the jitted ZOH step of wmr.kinematics."""
    st = nmpc.Settings(horizon=6, weights=(3.0, 0.7, 0.2, 0.05), terminal_weight=4.0)
    c = nmpc.make(st, lemniscate)
    rng = np.random.default_rng(1)
    rows = c.preview(0)
    q0 = np.array([0.1, -0.5, 1.2 + 2 * math.pi])  # a turn away: the heading term is wrapped
    U = rng.normal(scale=0.5, size=(6, 2)) + rows[:-1, 3:5]
    qp, qt, rv, rw = st.weights
    want, q = 0.0, q0.copy()
    for j in range(6):
        want += rv * (U[j, 0] - rows[j, 3]) ** 2 + rw * (U[j, 1] - rows[j, 4]) ** 2
        q = step(q, U[j], c.h, integrator_code("exact"))
        cj = st.terminal_weight if j == 5 else 1.0
        d = q[2] - rows[j + 1, 2]
        want += cj * (qp * ((q[0] - rows[j + 1, 0]) ** 2 + (q[1] - rows[j + 1, 1]) ** 2)
                      + qt * 2.0 * (1.0 - math.cos(d)))  # fmt: skip
    p = nmpc.Problem.parameters(q0, rows, c.weights, st.terminal_weight, c.h)
    got = float(c.problem.cost(U.ravel(), p))
    assert got == pytest.approx(want, rel=1e-12)


def test_the_preview_is_the_loops_reference_at_the_prediction_times(lemniscate):
    c = nmpc.make(nmpc.Settings(horizon=5, prediction_step=0.03), lemniscate)
    grid = references.sample(lemniscate.reference.kind, lemniscate.reference.params,
                             lemniscate.dt, 10_000)  # fmt: skip
    for k in (0, 1, 2, 500, 9000):
        assert np.array_equal(c.preview(k), grid[k : k + 16 : 3])


@pytest.mark.parametrize("case", ["transient-unconstrained", "on-track-limits"])
def test_first_command_equals_converged_ipopt(lemniscate, poses, on_track, case):
    """Issue 21: the first command of a step of the ``"sqp"`` solver equals ipopt's, converged on
    the same problem (same pose, reference preview, bounds and warm start), within 1e-6, over
    40 steps: from the 0.7 m initial error without limits, and on the reference with limits that
    are active at times (some steps are checked to have them active).  (With a large error and
    saturated inputs the Gauss-Newton SQP converges only linearly and stops at its iteration
    limit: a stated failure, tested below; ipopt's exact Hessian does not have that problem.)"""
    sc, qs = (lemniscate, poses) if case.startswith("transient") else on_track
    c = nmpc.make(nmpc.Settings(solver="sqp"), sc)
    worst, active = 0.0, 0
    for k in range(40):
        rows = c.preview(k).copy()
        guess = c._U if c._U is not None else np.clip(rows[:-1, 3:5], c.lbx[:2], c.ubx[:2])
        want = _oracle(c, qs[k], rows, guess)
        got = c.step(qs[k], rows[0], sc.dt)
        worst = max(worst, float(np.abs(np.subtract(got, want[0])).max()))
        active += bool(np.isclose(np.abs(want), c.ubx.reshape(-1, 2), atol=1e-9).any())
    assert worst < SAME_SOLUTION and c.final()["failures"] == 0
    assert case.startswith("transient") or active > 0


def test_rti_takes_gauss_newton_steps_of_the_same_problem(lemniscate, poses):
    """The real-time iteration's QP is the Gauss-Newton step of (M1)-(M2): iterated from the warm
    start it converges to ipopt's solution, and the converged point is its fixed point."""
    c = nmpc.make(nmpc.Settings(solver="rti"), lemniscate)
    rows = c.preview(0)
    guess = rows[:-1, 3:5].copy()
    want = _oracle(c, poses[0], rows, guess)
    p = nmpc.Problem.parameters(poses[0], rows, c.weights, c.settings.terminal_weight, c.h)
    x = guess.ravel()
    for _ in range(30):
        x, _, ok, _ = c.problem.solve(x, p, c.lbx, c.ubx, None)
        assert ok
    assert np.abs(x - want.ravel()).max() < SAME_SOLUTION
    fixed, _, _, _ = c.problem.solve(want.ravel(), p, c.lbx, c.ubx, None)
    assert np.abs(fixed - want.ravel()).max() < 1e-8


def test_a_full_turn_of_heading_changes_nothing(lemniscate, poses):
    """The wrapped heading term: the same pose with theta + 2 pi gets the same command."""
    cmds = []
    for turn in (0.0, 2 * math.pi, -4 * math.pi):
        c = nmpc.make(nmpc.Settings(), lemniscate)
        q = poses[3] + (0.0, 0.0, turn)
        cmds.append(c.step(q, c.preview(0)[0], lemniscate.dt))
    assert np.allclose(cmds[0], cmds[1], atol=1e-9) and np.allclose(cmds[0], cmds[2], atol=1e-9)


# --- the controller object ----------------------------------------------------------------------


@pytest.mark.parametrize("solver", nmpc.SOLVERS)
def test_limits_are_never_exceeded(lemniscate, poses, solver):
    """With [limits] every returned command is within them, and some are at them (the poses of a
    BSC run that starts 0.7 m off the reference ask for more)."""
    sc = dataclasses.replace(lemniscate, limits=scn.Limits(v_max=0.35, w_max=0.8))
    c = nmpc.make(nmpc.Settings(solver=solver, max_failures=1000), sc)
    u = np.array([c.step(q, c.preview(k)[0], sc.dt) for k, q in enumerate(poses[:100])])
    assert np.all(np.abs(u[:, 0]) <= 0.35) and np.all(np.abs(u[:, 1]) <= 0.8)
    assert np.isclose(np.abs(u).max(axis=0), (0.35, 0.8)).any()


@pytest.mark.parametrize("fraction", [1.0, 0.5, 0.1])
def test_shift_is_the_time_average_of_the_previous_solution(fraction):
    """``shift`` against the piecewise-constant previous solution averaged over each new
    interval on a fine grid (its last input held beyond the horizon)."""
    rng = np.random.default_rng(2)
    U = rng.normal(size=(6, 2))
    got = nmpc.shift(U, fraction)
    fine = 10_000
    for j in range(6):
        s = fraction + j + (np.arange(fine) + 0.5) / fine  # old-step units
        idx = np.minimum(np.floor(s).astype(int), 5)
        assert np.allclose(got[j], U[idx].mean(axis=0), atol=1e-3)
    if fraction == 1.0:
        assert np.array_equal(got, np.vstack((U[1:], U[-1:])))


def test_the_warm_start_is_the_shifted_solution(lemniscate, poses):
    c = nmpc.make(nmpc.Settings(solver="sqp", prediction_step=0.04), lemniscate)
    c.step(poses[0], c.preview(0)[0], lemniscate.dt)
    rows = c.preview(1).copy()
    p = nmpc.Problem.parameters(poses[1], rows, c.weights, c.settings.terminal_weight, c.h)
    guess = c._U.copy()
    x, _, ok, _ = c.problem.solve(guess.ravel(), p, c.lbx, c.ubx, c._lam)
    assert ok
    c.step(poses[1], rows[0], lemniscate.dt)
    assert np.array_equal(c._U, nmpc.shift(x.reshape(-1, 2), 0.25))


def test_solver_failures_fall_back_then_stop_the_run(lemniscate, poses):
    """An SQP allowed one iteration does not converge: each step falls back to the shifted
    previous solution (at k = 0 the reference's inputs), and the third failure in a row stops
    the run with its cause."""
    st = nmpc.Settings(solver="sqp", max_iterations=1, max_failures=3)
    c = nmpc.make(st, lemniscate)
    rows0 = c.preview(0).copy()
    assert c.step(poses[0], rows0[0], lemniscate.dt) == tuple(rows0[0, 3:5])
    c.step(poses[1], c.preview(1)[0], lemniscate.dt)
    with pytest.raises(nmpc.ControllerStopped, match=r"failed 3 times in a row .* t = 0.02 s"):
        c.step(poses[2], c.preview(2)[0], lemniscate.dt)
    assert c.final()["failures"] == 3 and c.signals()[1] == 1.0


def test_deterministic_and_records_its_solve_times(lemniscate, poses):
    runs = []
    for _ in range(2):
        c = nmpc.make(nmpc.Settings(), lemniscate)
        runs.append([c.step(q, c.preview(k)[0], lemniscate.dt) for k, q in enumerate(poses[:50])])
    assert runs[0] == runs[1]
    final = c.final()
    assert final["steps"] == 50 and final["failures"] == 0 and final["solver"] == "rti"
    assert 0 < final["solve_time_median"] <= final["solve_time_p95"] <= final["solve_time_max"]
    assert c.signals()[0] > 0 and c.signals()[1] == 0.0


@pytest.mark.parametrize("seed", range(12))
def test_box_qp_is_the_kkt_point(seed):
    """:func:`box_qp` against scipy's bounded minimiser, and its KKT conditions: the gradient
    vanishes on the free entries and points out of the box on the held ones.  Half the cases
    start with entries at their bounds (``lo = 0`` or ``hi = 0``: the warm start's)."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(seed)
    n = 12
    A = rng.normal(size=(n, n))
    H = A @ A.T + 0.1 * np.eye(n)
    g = rng.normal(scale=3.0, size=n)
    lo, hi = -rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.0, n)
    lo[rng.random(n) < 0.2] = -np.inf
    if seed % 2:
        lo[:3] = 0.0
        hi[3:5] = 0.0
    d, ok = nmpc.box_qp(H, g, lo, hi)
    assert ok and np.all(d >= lo) and np.all(d <= hi)
    grad = H @ d + g
    free = (d > lo) & (d < hi)
    assert np.abs(grad[free]).max(initial=0.0) < 1e-9
    assert np.all(grad[d <= lo] >= -1e-9) and np.all(grad[d >= hi] <= 1e-9)
    ref = minimize(lambda x: 0.5 * x @ H @ x + g @ x, np.zeros(n), jac=lambda x: H @ x + g,
                   bounds=list(zip(lo, hi, strict=True)), method="L-BFGS-B",
                   options={"ftol": 1e-15, "gtol": 1e-12, "maxiter": 10_000})  # fmt: skip
    assert np.allclose(d, ref.x, atol=1e-5)


def test_box_qp_without_finite_bounds_is_the_newton_step():
    rng = np.random.default_rng(0)
    A = rng.normal(size=(6, 6))
    H, g = A @ A.T + np.eye(6), rng.normal(size=6)
    d, ok = nmpc.box_qp(H, g, np.full(6, -np.inf), np.full(6, np.inf))
    assert ok and np.allclose(H @ d, -g, atol=1e-12)
