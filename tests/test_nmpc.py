"""Nonlinear MPC (``wmr.controllers.nmpc``, issue 21 item 1): the pieces that need no closed loop.

Oracles: ipopt converged tightly on the same problem (the first command of the other solvers), an
independent evaluation of the cost (M1) with the library's jitted ZOH step
(``wmr.model.kinematics.step``), the reference sampler the loop reads, a fine-grid time average for
the warm-start shift, and the limits themselves.  The closed-loop checks run through ``simulate``
(the loop's Python driver; no test here runs a loop of its own): the noise-free circle tracked to
rounding, the real-time iteration's gap to a converged ipopt along a run, a forced solver failure as
the run's stated cause, the solve-time record, and the fixed PID as the bar on the paper's
scenarios.
"""

from __future__ import annotations

import dataclasses
import math
import os

import numpy as np
import pytest

from wmr import cli, controllers
from wmr import scenario as scn
from wmr._settings import SettingError, from_table
from wmr.closedloop.sim import simulate
from wmr.controllers import nmpc
from wmr.model import references
from wmr.model.kinematics import integrator_code, step

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
    """The CasADi cost against (M1) written out with the jitted ZOH step of wmr.model.kinematics."""
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
    assert worst < SAME_SOLUTION and c.final().failures == 0
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
    assert c.final().failures == 3 and c.signals()[1] == 1.0


def test_deterministic_and_records_its_solve_times(lemniscate, poses):
    runs = []
    for _ in range(2):
        c = nmpc.make(nmpc.Settings(), lemniscate)
        runs.append([c.step(q, c.preview(k)[0], lemniscate.dt) for k, q in enumerate(poses[:50])])
    assert runs[0] == runs[1]
    final = c.final()
    assert final.steps == 50 and final.failures == 0 and final.solver == "rti"
    assert 0 < final.solve_time_median <= final.solve_time_p95 <= final.solve_time_max
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


# --- registered, and bad input at the command line ---------------------------------------------


def test_registered_with_its_own_label_and_colour():
    row = controllers.get("nmpc")
    assert row.label == "NMPC" and "nmpc" in controllers.NAMES and not row.compiled
    assert row.colour not in [c.colour for n, c in controllers.REGISTRY.items() if n != "nmpc"]
    assert row.Settings is nmpc.Settings and not row.uses_estimator


@pytest.mark.parametrize(("table", "key", "reason"), [
    ("horizon = 0", "horizon", "must be an integer >= 1"),
    ("weights = [10.0, 1.0, 0.0, 0.1]", "weights", "entries must be > 0"),
    ("weights = [10.0, -1.0, 0.1, 0.1]", "weights", "entries must be > 0"),
    ("terminal_weight = -2.0", "terminal_weight", "must be > 0"),
    ("prediction_step = 0.015", "prediction_step", "must be a whole multiple of dt = 0.01"),
    ("prediction_step = 0.005", "prediction_step", "must be a whole multiple of dt = 0.01"),
], ids=["horizon-0", "weight-0", "weight-negative", "terminal-negative", "h-1.5-dt",
        "h-half-dt"])  # fmt: skip
def test_bad_settings_in_a_scenario_file_exit_2_with_one_line(tmp_path, capsys, table, key,
                                                              reason):  # fmt: skip
    """Issue 21 item 5: ``wmr run`` exits 2 with one line naming the file, key and reason, and
    runs nothing (the prediction step is checked against the file's ``dt`` when it loads)."""
    path = tmp_path / "bad.toml"
    path.write_text(scn.builtin("lemniscate").read_text() + f"\n[controllers.nmpc]\n{table}\n")
    code = cli.main(["run", str(path), "--controller", "nmpc", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1, err
    assert str(path) in err and f"controllers.nmpc.{key}" in err and reason in err
    assert not (tmp_path / "out").exists()


def test_a_prediction_step_that_fits_dt_loads():
    text = scn.builtin("lemniscate").read_text() + "\n[controllers.nmpc]\nprediction_step = 0.05\n"
    assert scn.loads(text).settings("nmpc").prediction_step == 0.05


# --- closed loop (through simulate: the loop's Python driver) -----------------------------------

#: The circle of the tracking-to-tolerance check: 0.1 m and 0.1 rad off its start, no noise.
_CIRCLE = {"radius": 1.0, "period": 20.0}
#: Weights of that check: a lighter input penalty and a heavier terminal cost than the defaults
#: (with which the error falls only ~6x per 10 s at h = dt, N = 20: a 0.2 s horizon), so the decay
#: reaches rounding within the 30 s run (measured: 1e-1 -> 7e-12 m by 20 s, 2e-16 m at 30 s).
_FAST = {"weights": (10.0, 1.0, 0.001, 0.001), "terminal_weight": 100.0}
#: The circle's error from t = 25 s on [m, rad]: the converged solvers' default tolerance
#: (1e-10) on the KKT conditions, here on the pose; RTI's fixed point is the exact optimum, so the
#: error goes to rounding (measured <= 3e-14 from 25 s).
SETTLED_TOL = 1e-10


def _circle_scenario(duration: float) -> scn.Scenario:
    r0 = references.sample("circle", _CIRCLE, 0.01, 1)[0]
    return scn.from_dict({"name": "circle", "duration": duration, "dt": 0.01,
                          "initial_pose": [r0[0] + 0.1, r0[1], r0[2] + 0.1],
                          "reference": {"kind": "circle", **_CIRCLE},
                          "noise": {"pose_std": [0.0, 0.0, 0.0]}})  # fmt: skip


def test_the_noise_free_circle_is_tracked_to_the_solver_tolerance():
    """Issue 21: the prediction model is the plant's exact ZOH step and h = dt, so on the
    noise-free ideal circle (constant inputs: the reference is a trajectory of the model) the
    optimum at the reference is the reference's own inputs and the error decays to the solver's
    tolerance, not to a floor.  (A wrong preview time, model or heading term leaves an offset.)"""
    sc = _circle_scenario(30.0)
    r = simulate(sc, "nmpc", 0, settings=nmpc.Settings(prediction_step=sc.dt, **_FAST))
    pos = np.hypot(*(r.q[:, :2] - r.ref[:, :2]).T)
    head = np.abs(np.angle(np.exp(1j * (r.q[:, 2] - r.ref[:, 2]))))
    late = r.t >= 25.0
    assert pos[0] > 0.09 and not r.diverged and r.final.failures == 0
    assert pos[late].max() < SETTLED_TOL and head[late].max() < SETTLED_TOL
    assert np.abs(r.u[r.t[:-1] >= 25.0] - r.ref[:-1][r.t[:-1] >= 25.0, 3:5]).max() < 1e-8


def test_limits_hold_along_a_closed_loop_run(lemniscate):
    """[limits] tighter than the 0.7 m initial error asks for: the run's commands stay within
    them and sit at them during the transient, with no solver failure.  (The loop saturates
    again, so this is a consistency check of the run; the controller's own commands are checked
    against the limits above.)"""
    sc = dataclasses.replace(lemniscate, duration=10.0, limits=scn.Limits(v_max=0.6, w_max=1.0))
    r = simulate(sc, "nmpc", 0)
    assert np.all(np.abs(r.u[:, 0]) <= 0.6) and np.all(np.abs(r.u[:, 1]) <= 1.0)
    assert np.isclose(np.abs(r.u).max(axis=0), (0.6, 1.0)).all() and r.final.failures == 0
    assert not r.diverged


#: The real-time iteration's first command against the converged one along a run (issue 21: "for
#: RTI, the gap over a run is measured and reported").  Measured on the lemniscate, seed 0, noise,
#: 10 s, every 4th step: median 2.2e-3 m/s / 2.5e-3 rad/s, 95th percentile 1.3e-2 / 1.6e-2, the
#: same in every stretch of the run (the measurement noise moves the optimum by about one
#: Gauss-Newton step each sample); the largest, 0.11 m/s / 1.03 rad/s, at k = 0 (the cold start
#: from the reference's inputs, 0.7 m off).  Bounds: about 2.5x the measured figures.
RTI_GAP_MEDIAN, RTI_GAP_P95 = 5e-3, 4e-2


def test_rti_gap_to_converged_ipopt_along_a_run(lemniscate):
    """Replaying the run's pose estimates through a fresh controller gives the run's commands
    bit for bit (the loop hands ``step`` its pose and reference in order); at every 4th step the
    first command is compared with ipopt converged on the same problem (same pose, preview,
    warm start); the gap's median and 95th percentile stay within the measured figures, and the
    first step (no warm start) is the worst."""
    sc = dataclasses.replace(lemniscate, duration=10.0)
    r = simulate(sc, "nmpc", 0)
    c = nmpc.make(nmpc.Settings(), sc)
    gaps = []
    for k in range(len(r.u)):
        rows = c.preview(k).copy()
        if k % 4 == 0:
            guess = c._U if c._U is not None else np.clip(rows[:-1, 3:5], c.lbx[:2], c.ubx[:2])
            want = _oracle(c, r.q_hat[k], rows, guess)[0]
        got = c.step(r.q_hat[k], r.ref[k], sc.dt)
        assert got == tuple(r.u[k])
        if k % 4 == 0:
            gaps.append(np.abs(np.subtract(got, want)))
    gaps = np.array(gaps)
    med, p95 = np.median(gaps, axis=0), np.percentile(gaps, 95, axis=0)
    assert np.all(med < RTI_GAP_MEDIAN) and np.all(p95 < RTI_GAP_P95), (med, p95)
    assert np.all(gaps[0] == gaps.max(axis=0))


def test_a_forced_solver_failure_is_the_runs_stated_cause(lemniscate):
    """An SQP allowed one iteration never converges: after ``max_failures`` = 3 failures in a row
    the run stops at that step, recorded like a divergence with the controller's message."""
    st = nmpc.Settings(solver="sqp", max_iterations=1, max_failures=3)
    r = simulate(dataclasses.replace(lemniscate, duration=2.0), "nmpc", 0, settings=st)
    assert r.diverged and r.diverged_at == pytest.approx(2 * lemniscate.dt)
    assert r.cause.startswith("controller stopped: nmpc: the sqp solver failed 3 times in a row")
    assert r.cause.endswith("at t = 0.02 s")
    assert r.final.failures == 3 and np.all(r.signal("solver_failed") == 1.0)


def test_the_run_record_holds_the_solve_time_distribution(lemniscate):
    """RunResult.final: median <= p95 <= max of the per-step time over every step, the logged
    ``solve_time`` signal being those times (its median and maximum are the record's)."""
    r = simulate(dataclasses.replace(lemniscate, duration=2.0), "nmpc", 0)
    f, times = r.final, r.signal("solve_time")
    assert isinstance(f, nmpc.SolveRecord) and f.steps == len(r.u) == len(times)
    assert f.solver == "rti" and f.failures == 0
    assert 0 < f.solve_time_median <= f.solve_time_p95 <= f.solve_time_max
    assert f.solve_time_max == times.max()
    assert f.solve_time_median == pytest.approx(np.median(times), rel=BIN_HALF_WIDTH)
    assert f.solve_time_p95 == pytest.approx(np.percentile(times, 95), rel=BIN_HALF_WIDTH)


#: Half the relative width of a :class:`nmpc.TimeHistogram` bin (10^(1/200) - 1 = 1.16 %), plus
#: rounding: how far its quantiles may be from numpy's on the exact times.
BIN_HALF_WIDTH = 0.5 * (10 ** (1 / nmpc.TimeHistogram.PER_DECADE) - 1) + 1e-12


@pytest.mark.parametrize("n", [1, 2, 7, 200, 20_000])
def test_time_histogram_quantiles_are_numpys_within_half_a_bin(n):
    """Against numpy.percentile of the exact times (lognormal around 0.2 ms, a tail to 0.1 s,
    values outside the binned range clamped to it), for the record's quantiles and others."""
    rng = np.random.default_rng(n)
    t = np.exp(rng.normal(math.log(2e-4), 0.8, n))
    t[: n // 50] = rng.uniform(1e-2, 1e-1, n // 50)
    h = nmpc.TimeHistogram()
    for x in t:
        h.add(float(x))
    assert h.n == n and h.max == t.max() and h.counts.sum() == n
    for q in (0.0, 0.05, 0.5, 0.95, 0.99, 1.0):
        assert h.quantile(q) == pytest.approx(np.percentile(t, 100 * q), rel=BIN_HALF_WIDTH), q
    assert math.isnan(nmpc.TimeHistogram().quantile(0.5))


#: Seeds of the comparison with the fixed PID (issue 21: 20; each nmpc run ~2 s, so the default
#: suite runs 4 and WMR_LONG_TESTS=1 the 20).
PID_SEEDS = 20 if os.environ.get("WMR_LONG_TESTS") else 4


@pytest.mark.parametrize("name", scn.PAPER_SCENARIOS)
def test_tracks_the_paper_scenarios_better_than_the_fixed_pid(name):
    """Issue 21 "Done when": on the ideal plant (the paper's scenarios as shipped, measurement
    noise included), the position RMSE after the transient is below the fixed PID's on every
    seed (common noise), and the mean paired difference's 95% interval is below zero.  Measured
    (20 seeds, paper/results/reproduction.json): the report's table."""
    from scipy import stats

    sc = scn.load(scn.builtin(name))
    a = [simulate(sc, "nmpc", s, keep_trajectory=False).rmse_after_transient["position"]
         for s in range(PID_SEEDS)]  # fmt: skip
    b = [simulate(sc, "pid", s, keep_trajectory=False).rmse_after_transient["position"]
         for s in range(PID_SEEDS)]  # fmt: skip
    d = np.subtract(a, b)
    assert np.all(d < 0), (a, b)
    half = stats.t.ppf(0.975, d.size - 1) * d.std(ddof=1) / math.sqrt(d.size)
    assert d.mean() + half < 0
