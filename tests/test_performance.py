"""The fast path (one numba kernel) against a straightforward reference, and the benchmark.

The reference below is the closed loop of ``wmr.closedloop.sim`` written out in plain Python/numpy,
from the equations (docs/conventions.md, the module docstrings), without any of the library's jitted
functions: noise drawn as ``wmr.closedloop.sim`` draws it, the exact-arc plant, the pose EKF and the
weight EKF as dense textbook Joseph updates (``np.linalg.solve``, O(n^3)), the network and its
Jacobians as numpy matrices, the SGD gain step and the PID of eq. (7).  It reads only settings and
the reference samples (``wmr.model.references.sample``, plain numpy) from the library.

The benchmark (``analysis/performance/``): its floor is a correct EKF update, and the
study shape (``run`` writes the record, table and figure; ``check`` asserts the ratio and
correctness targets only).  No timing is asserted here: timings belong to the benchmark's record.
The python-control comparator is tested against ``simulate`` in ``tests/test_nlsys.py``.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose

from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.model.references import sample
from wmr.scenario import Disturbance, Limits

STEPS = 200
#: Agreement asked by issue 6.  Differences come from the order of floating-point operations:
#: the library's O(n^2 m) Joseph expansion (with fastmath reassociation) against the dense
#: textbook products here.
RTOL = 1e-12
ATOL = 1e-12


# ---------------------------------------------------------------------------------------------
# reference closed loop


def wrap(a: float) -> float:
    r = math.atan2(math.sin(a), math.cos(a))
    return math.pi if r == -math.pi else r


def sinc_and_derivative(a: float) -> tuple[float, float]:
    if abs(a) < 1e-4:
        return 1.0 - a * a / 6.0 + a**4 / 120.0, -a / 3.0 + a**3 / 30.0
    s = math.sin(a) / a
    return s, (math.cos(a) - s) / a


def plant_step(q, u, dt):
    """Exact arc under zero-order hold and its Jacobians ``F = dq+/dq``, ``G = dq+/du``."""
    v, w = u
    a = 0.5 * w * dt
    s, ds = sinc_and_derivative(a)
    phi = q[2] + a
    c, sn = math.cos(phi), math.sin(phi)
    q_next = np.array([q[0] + v * dt * s * c, q[1] + v * dt * s * sn, q[2] + w * dt])
    F = np.eye(3)
    F[0, 2], F[1, 2] = -v * dt * s * sn, v * dt * s * c
    G = np.array([[dt * s * c, 0.5 * v * dt * dt * (ds * c - s * sn)],
                  [dt * s * sn, 0.5 * v * dt * dt * (ds * sn + s * c)],
                  [0.0, dt]])  # fmt: skip
    return q_next, F, G


def rotation(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def tracking_error(q_hat, ref) -> np.ndarray:
    e = rotation(q_hat[2]) @ (ref[:3] - q_hat)
    e[2] = wrap(ref[2] - q_hat[2])
    return e


def joseph(x, P, H, nu, R):
    """Dense textbook Kalman update with the Joseph covariance form."""
    S = H @ P @ H.T + R
    K = np.linalg.solve(S, H @ P).T  # P H^T S^-1 (P and S symmetric)
    IKH = np.eye(x.size) - K @ H
    return x + K @ nu, IKH @ P @ IKH.T + K @ R @ K.T


class Network:
    """One hidden tanh layer, linear outputs; flat weights ``[V, b_v, W, b_w]`` (row-major)."""

    def __init__(self, n_in: int, n_h: int, n_out: int):
        self.n_in, self.n_h, self.n_out = n_in, n_h, n_out
        self.n = n_h * n_in + n_h + n_out * n_h + n_out

    def init(self, rng, output_scale: float) -> np.ndarray:
        V = rng.standard_normal((self.n_h, self.n_in)) * math.sqrt(2.0 / (self.n_in + self.n_h))
        W = rng.standard_normal((self.n_out, self.n_h)) * output_scale / math.sqrt(self.n_h)
        return np.concatenate((V.ravel(), np.zeros(self.n_h), W.ravel(), np.zeros(self.n_out)))

    def split(self, theta):
        i1 = self.n_h * self.n_in
        i2 = i1 + self.n_h
        i3 = i2 + self.n_out * self.n_h
        return (theta[:i1].reshape(self.n_h, self.n_in), theta[i1:i2],
                theta[i2:i3].reshape(self.n_out, self.n_h), theta[i3:])  # fmt: skip

    def forward(self, theta, x):
        V, b_v, W, b_w = self.split(theta)
        h = np.tanh(V @ x + b_v)
        return W @ h + b_w, h

    def input_jacobian(self, theta, x):
        V, _, W, _ = self.split(theta)
        _, h = self.forward(theta, x)
        return W @ np.diag(1.0 - h * h) @ V

    def weight_jacobian(self, theta, x):
        """``dz/dtheta`` built entry by entry from its definition."""
        V, _, W, _ = self.split(theta)
        _, h = self.forward(theta, x)
        H = np.zeros((self.n_out, self.n))
        i1 = self.n_h * self.n_in
        i2 = i1 + self.n_h
        i3 = i2 + self.n_out * self.n_h
        for i in range(self.n_out):
            for j in range(self.n_h):
                d = W[i, j] * (1.0 - h[j] ** 2)
                for k in range(self.n_in):
                    H[i, j * self.n_in + k] = d * x[k]
                H[i, i1 + j] = d
                H[i, i2 + i * self.n_h + j] = h[j]
            H[i, i3 + i] = 1.0
        return H


class PID:
    """Eq. (7) with the SGD gain step of eqs. (8)-(17) (Jacobian supplied by the caller)."""

    def __init__(self, st):
        self.st = st
        self.K = np.array(st.gains, dtype=float)
        self.J = np.zeros((3, 2))
        self.limits = (math.inf, math.inf)  # (v_max, w_max): the law saturates its own output
        self.integral = np.zeros(2)
        self.prev = np.zeros(2)
        self.phi = np.zeros(6)
        self.started = False

    def sgd(self, J, e, theta):
        te = rotation(theta).T @ (np.array(self.st.alpha) * e)
        g = J.T @ te  # (dF/du_v, dF/du_w) up to sign
        for i in range(6):
            k = self.K[i] + self.st.mu[i] * g[0 if i < 3 else 1] * self.phi[i]
            self.K[i] = min(max(k, self.st.gain_min[i]), self.st.gain_max[i])

    def output(self, e, ref, dt):
        x, sw = e[0], e[2] + e[1]
        self.integral += dt * np.array([x, sw])
        d = (np.array([x, sw]) - self.prev) / dt if self.started else np.zeros(2)
        self.prev = np.array([x, sw])
        self.phi = np.array([x, self.integral[0], d[0], sw, self.integral[1], d[1]])
        u = np.array([self.K[:3] @ self.phi[:3], self.K[3:] @ self.phi[3:]])
        if self.st.feed_forward:
            u += (ref[3] * math.cos(e[2]), ref[4])
        for c, limit in enumerate(self.limits):  # saturated channel: no gradient through it
            if abs(u[c]) > limit:
                u[c] = min(max(u[c], -limit), limit)
                self.phi[3 * c : 3 * c + 3] = 0.0
        return u


class IapidReference:
    """IAPID-NN-DEKF: identify (weight EKF), Jacobian of the network, SGD, eq. (7)."""

    uses_estimator = True

    def __init__(self, st, rng):
        self.st, self.pid = st, PID(st)
        self.net = Network(4, st.hidden, 3)
        self.theta = self.net.init(rng, st.output_scale)
        self.P = st.p0 * np.eye(self.net.n)
        self.nn_error = 0.0
        self.repairs = 0.0

    def __call__(self, q_hat, ref, dt):
        e = tracking_error(q_hat, ref)
        pid = self.pid
        if pid.started:
            x = np.array([self.u_prev[0], self.u_prev[1], math.cos(self.q_prev[2]),
                          math.sin(self.q_prev[2])])  # fmt: skip
            z, _ = self.net.forward(self.theta, x)
            d = (q_hat - self.q_prev) / dt
            d[2] = wrap(q_hat[2] - self.q_prev[2]) / dt
            nu = d - z
            self.nn_error = math.sqrt(nu @ nu)
            H = self.net.weight_jacobian(self.theta, x)
            P = self.P + self.st.q * np.eye(self.net.n)
            self.theta, self.P = joseph(self.theta, P, H, nu, self.st.r * np.eye(3))
            if np.any(~(np.diag(self.P) > 1e-12)):
                self.P = 0.5 * (self.P + self.P.T)
                np.fill_diagonal(self.P, np.maximum(np.diag(self.P), 1e-12))
                self.repairs += 1.0
            J = dt * self.net.input_jacobian(self.theta, x)[:, :2]
            pid.J = J
            pid.sgd(J, e, q_hat[2])
        u = pid.output(e, ref, dt)
        self.u_prev, self.q_prev, pid.started = u.copy(), q_hat.copy(), True
        return u

    def logged(self):
        return np.concatenate((self.pid.K, self.pid.J.ravel(), [self.nn_error, self.repairs]))


class AdaptivePidReference:
    """APID: the SGD step with the exact ZOH Jacobian of the plant at the previous (q, u)."""

    uses_estimator = False

    def __init__(self, st, rng):
        self.st, self.pid = st, PID(st)

    def __call__(self, q_hat, ref, dt):
        e = tracking_error(q_hat, ref)
        pid = self.pid
        if pid.started:
            _, _, J = plant_step(self.q_prev, self.u_prev, dt)
            pid.J = J
            pid.sgd(J, e, q_hat[2])
        u = pid.output(e, ref, dt)
        self.u_prev, self.q_prev, pid.started = u.copy(), q_hat.copy(), True
        return u

    def logged(self):
        return np.concatenate((self.pid.K, self.pid.J.ravel()))


class BacksteppingReference:
    """Kanayama's law."""

    uses_estimator = False

    def __init__(self, st, rng):
        self.k1, self.k2, self.k3 = st.gains

    def __call__(self, q_hat, ref, dt):
        e = tracking_error(q_hat, ref)
        v_r, w_r = ref[3], ref[4]
        return np.array([v_r * math.cos(e[2]) + self.k1 * e[0],
                         w_r + v_r * (self.k2 * e[1] + self.k3 * math.sin(e[2]))])  # fmt: skip

    def logged(self):
        return np.zeros(0)


REFERENCES = {"iapid-nn-dekf": IapidReference, "adaptive-pid": AdaptivePidReference,
              "backstepping": BacksteppingReference}  # fmt: skip


def reference_run(sc, controller: str, seed: int) -> dict:
    """The closed loop of ``wmr.closedloop.sim`` (DESIGN §3.1) in plain Python, for ``sc.n_steps``
    steps."""
    n, dt = sc.n_steps, sc.dt
    noise_ss, init_ss = np.random.SeedSequence(seed).spawn(2)  # the two streams of a run
    std = np.array(sc.noise.pose_std)
    noise = np.random.default_rng(noise_ss).standard_normal((n, 3)) * std  # one chunk (n <= 8192)
    law = REFERENCES[controller](sc.settings(controller), np.random.default_rng(init_ss))
    if hasattr(law, "pid"):
        law.pid.limits = (sc.limits.v_max, sc.limits.w_max)
    ref = sample(sc.reference.kind, sc.reference.params, dt, n + 1)
    est = sc.estimator
    use_ekf = est.pose_source == "filtered" or (est.pose_source == "paper" and law.uses_estimator)
    Qp = np.diag(np.square(est.process_std))
    Rp = np.diag(np.square(np.maximum(std, est.min_measurement_std)))
    q = np.array(sc.initial_pose, dtype=float)
    q_hat, Pq = np.zeros(3), Rp.copy()
    qs, q_hats, us, states = [q.copy()], [], [], []
    for k in range(n):
        z = q + noise[k]
        if not use_ekf or k == 0:
            q_hat, Pq = z.copy(), Rp.copy()
        else:
            nu = z - q_hat
            nu[2] = wrap(nu[2])
            q_hat, Pq = joseph(q_hat, Pq, np.eye(3), nu, Rp)
        u = law(q_hat, ref[k], dt)
        u = np.clip(u, (-sc.limits.v_max, -sc.limits.w_max), (sc.limits.v_max, sc.limits.w_max))
        q_hats.append(q_hat.copy())
        us.append(u.copy())
        states.append(law.logged())
        ua = u.copy()
        for d in sc.disturbances:
            if d.start <= k * dt < d.stop:
                ua += d.velocity
        q, _, _ = plant_step(q, ua, dt)
        if use_ekf:
            q_hat, F, _ = plant_step(q_hat, u, dt)
            Pq = F @ Pq @ F.T + Qp
        qs.append(q.copy())
    q_arr = np.array(qs)
    err = ref[:, :3] - q_arr
    err[:, 2] = [wrap(a) for a in err[:, 2]]
    rmse = {"x": math.sqrt(np.mean(err[:, 0] ** 2)), "y": math.sqrt(np.mean(err[:, 1] ** 2)),
            "theta": math.sqrt(np.mean(err[:, 2] ** 2)),
            "position": math.sqrt(np.mean(err[:, 0] ** 2 + err[:, 1] ** 2))}  # fmt: skip
    return {"q": q_arr, "q_hat": np.array(q_hats), "u": np.array(us), "state": np.array(states),
            "ref": ref, "rmse": rmse}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# tests


def short_lemniscate():
    return dataclasses.replace(scn.load(scn.builtin("lemniscate")), duration=STEPS * 0.01)


def short_perturbed():
    """The perturbed sinusoid cut to STEPS steps, with the perturbation and saturation inside."""
    sc = scn.load(scn.builtin("sinusoid-perturbed"))
    return dataclasses.replace(sc, duration=STEPS * sc.dt,
                               disturbances=(Disturbance(0.5, 1.2, (0.1, 0.3)),),
                               limits=Limits(v_max=0.6, w_max=1.5))  # fmt: skip


SCENARIOS = {"lemniscate": short_lemniscate, "perturbed-saturated": short_perturbed}


def max_rel_error(a, b) -> float:
    if a.size == 0:
        return 0.0
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), ATOL / RTOL)))


@pytest.mark.parametrize("scenario", list(SCENARIOS))
@pytest.mark.parametrize("controller", list(REFERENCES))
def test_fast_path_matches_reference(controller, scenario):
    sc = SCENARIOS[scenario]()
    fast = simulate(sc, controller, 3, keep_trajectory=True)
    ref = reference_run(sc, controller, 3)
    assert not fast.diverged
    assert fast.q.shape == (STEPS + 1, 3)
    for name in ("q", "q_hat", "u", "state", "ref"):
        got, want = getattr(fast, name), ref[name]
        assert got.shape == want.shape, name
        msg = f"{name}: max rel error {max_rel_error(got, want):.2e}"
        assert_allclose(got, want, rtol=RTOL, atol=ATOL, err_msg=msg)
    for key, value in ref["rmse"].items():
        assert fast.rmse[key] == pytest.approx(value, rel=RTOL, abs=ATOL), key
    if scenario == "perturbed-saturated":  # the case exercises the limits
        assert np.any(np.abs(fast.u) == [0.6, 1.5])


def test_iapid_adapts_in_the_compared_window():
    """The comparison is not vacuous: gains move and the network error is non-zero."""
    fast = simulate(short_lemniscate(), "iapid-nn-dekf", 3, keep_trajectory=True)
    assert np.ptp(fast.gains(), axis=0).max() > 1e-3
    assert fast.signal("nn_error")[1:].min() > 0.0


def test_floor_update_is_a_correct_ekf_update():
    from analysis.performance.floor import floor_update

    rng = np.random.default_rng(5)
    for n, m, specialise in ((83, 3, True), (83, 3, False), (20, 2, True), (7, 3, True)):
        A = rng.standard_normal((n, n))
        P0 = A @ A.T / n + np.eye(n)
        H = rng.standard_normal((m, n))
        nu, q, R = rng.standard_normal(m), np.full(n, 1e-3), 2.0 * np.eye(m)
        theta, P = np.zeros(n), P0.copy()
        floor_update(theta, P, H, nu, q, R, np.zeros((2, m, n)), specialise)
        Pp = P0 + np.diag(q)
        S = H @ Pp @ H.T + R
        K = Pp @ H.T @ np.linalg.inv(S)
        assert_allclose(theta, K @ nu, rtol=1e-12, atol=1e-14)
        assert_allclose(P, Pp - K @ H @ Pp, rtol=1e-10, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# the study

COMMITTED = Path(__file__).resolve().parents[1] / "paper" / "results" / "performance.json"


def committed_record() -> dict:
    return json.loads(COMMITTED.read_text())


@pytest.mark.slow
def test_quick_run_writes_the_study_and_passes_check(tmp_path):
    from analysis import common
    from analysis import performance as perf

    rec = perf.run(tmp_path, quick=True, workers=2)
    stored = common.load_record(tmp_path, perf.STEM)
    assert stored == json.loads(json.dumps(rec))
    perf.check(stored)
    assert (tmp_path / "tables" / "performance.md").read_text() == perf.table(stored)
    assert (tmp_path / "figures" / "performance_vs_weights.png").stat().st_size > 0
    section = perf.render(stored)
    assert section.startswith("## Performance\n") and perf.tables(stored).rstrip() in section
    note = perf.notes(stored)[0]
    assert section.count(note) == 1 and "\n# " not in section  # the notes once, no stray H1
    figure = "performance_vs_weights.png"
    assert section.rstrip().endswith(f"![{figure}](figures/{figure})")
    # the non-timing values
    assert stored["n_weights"] == 83 and stored["parallel_equals_serial"] is True
    assert stored["paper_runs_diverged"] == 0 and stored["monte_carlo_1000_s"] is None
    assert set(stored["python_control"]) == {"iapid-nn-dekf/jit", "backstepping/jit"}
    for v in stored["python_control"].values():  # the nlsys runs the kernel's phases
        assert v["max_abs_q_difference"] == 0.0
    assert stored["floor_check_max_rel_error"] <= perf.SAME_TOL
    # the >= 50x python-control target is retired: measured, not a target
    assert stored["ratios"]["python_control_over_iapid"] > 1.0
    assert "python_control_ratio_min" not in stored["targets"]
    recorded = {"paper_runs_one_seed", "monte_carlo_1000", "quick_under_2_min", "plant_overhead",
                "sweep_local_efficiency", "sweep_dask_efficiency", "large_sweep",
                "iapid_floor_ratio_25", "run_overhead_25",  # issue 25: recorded, not asserted
                *(f"us_per_step_{n}" for n in perf.TARGETS["us_per_step_max"]), "nmpc_step_median",
                "mujoco_plant", "mujoco_sweep_efficiency"}  # issue 20: recorded, not asserted
    sweep = stored["sweep"]  # issue 13: measured on a local cluster and a loopback scheduler
    assert sweep["rows_equal"] is True and set(sweep["controllers"]) == {"iapid-nn-dekf", "pid"}
    assert 0 < sweep["local"]["efficiency"] and 0 < sweep["dask"]["efficiency"]
    assert stored["targets_met"]["large_sweep"] is None  # quick: no large sweep
    assert set(stored["targets_met"]) == set(perf.CHECKED) | recorded
    nmpc = stored["python_controllers"]["nmpc"]  # issue 21: its own step, with percentiles
    assert nmpc["runs"] == 2 and nmpc["steps"] == 2 * 4000 and "nmpc" not in stored["us_per_step"]
    assert 0 < nmpc["step_ms"]["median"] <= nmpc["step_ms"]["p95"] <= nmpc["step_ms"]["max"]
    # the loop around the solve costs too; against the runs' median, not their minimum: the
    # solve's median pools both runs' steps, so a slower second run (a loaded machine) lifts it
    # above the faster run's mean (measured under make test: 75.3 vs a minimum of 69.3 us)
    assert nmpc["step_ms"]["median"] * 1e3 < nmpc["us_per_step_median"]
    for name in ("backstepping", "iapid-nn-dekf"):  # issue 12: the plant's cost is measured
        p = stored["plant"][name]
        assert p["ratio"] > 0.5
        assert p["plant_cpu_us_per_step"] > 0 and p["ideal_cpu_us_per_step"] > 0
    # issue 25: the step phase by phase (quick: two controllers), and each run's set-up
    assert set(stored["phases"]) == set(perf.QUICK_PHASES) < set(stored["us_per_step"])
    for v in stored["phases"].values():
        assert v["kernel"] > 0 and v["law"] > 0 and v["sum"] == pytest.approx(
            sum(v[k] for k in ("sense", "law", "plant", "predict", "score")))
    assert stored["phases"]["iapid-nn-dekf"]["predict"] > 0  # it acts on the filtered pose
    assert stored["phases"]["backstepping"]["predict"] == 0.0  # it does not
    assert set(stored["run_overhead_ms_by_controller"]) == set(stored["us_per_step"])
    # issue 20: the MuJoCo plant per control step at the shipped and the ladder's physics step
    mj = stored["mujoco"]
    assert [p["substeps"] for p in mj["plant"]] == [5, 20] and mj["sweep"] is None  # quick
    for p in mj["plant"]:
        assert 0 < p["p10_us"] <= p["median_us"] <= p["p90_us"] and p["steps_timed"] == 300
    assert mj["run"]["us_per_step"] > 0 and stored["targets_met"]["mujoco_sweep_efficiency"] is None
    assert "MuJoCo plant per 10 ms control step at 2 ms physics step" in section


@pytest.mark.parametrize(("n", "level", "j"), [(5, 0.9, 1), (9, 0.9, 2), (10, 0.9, 2),
                                                (20, 0.95, 6)])  # fmt: skip
def test_median_interval_is_the_binomial_order_statistic(n, level, j):
    """The interval of ``analysis.performance.against.median_interval`` is ``(x_(j), x_(n+1-j))``
    with the largest ``j`` of binomial(n, 1/2) coverage >= level: j from the closed form, checked on
    a permutation of 1..n (the k-th order statistic is k)."""
    from analysis.performance.against import median_interval

    cover = 1 - 2 * sum(math.comb(n, i) for i in range(j)) / 2**n
    assert cover >= level and (j == n // 2 or
                               1 - 2 * sum(math.comb(n, i) for i in range(j + 1)) / 2**n < level)
    x = np.random.default_rng(0).permutation(np.arange(1.0, n + 1))
    med, lo, hi = median_interval(x, level)
    assert (med, lo, hi) == (np.median(x), float(j), float(n + 1 - j))


def test_against_per_step_and_its_table_columns():
    """``analysis.performance.against``'s per-step figure is (run - set-up) / steps in us (a run of
    2 ms with 0.5 ms set-up over 3000 steps: 0.5 us), and the table shows it beside the run and
    set-up columns, a row the reference lacks the figure for as dashes (a tree predating it)."""
    from analysis.performance.against import _per_step, table

    rec = _per_step({"run_ms": {"a": 2.0}, "setup_ms": {"a": 0.5}, "steps": {"a": 3000}})
    assert rec["step_us"]["a"] == pytest.approx(0.5, rel=1e-12)
    cell = {"this": 0.5, "ref": 1.0, "ratio": 0.5, "ratio_low": 0.4, "ratio_high": 0.6}
    lines = table({"ref": "r", "pairs": 5, "runs_per_process": 10, "level": 0.9,
                   "controllers": {"a": {"run_ms": cell, "setup_ms": cell, "step_us": cell},
                                   "b": {"run_ms": cell, "setup_ms": cell}}})  # fmt: skip
    row_a = next(x for x in lines if x.startswith("| a |"))
    row_b = next(x for x in lines if x.startswith("| b |"))
    assert row_a.count("0.500 [0.400, 0.600]") == 3 and row_b.endswith("| — | — | — |")


def test_the_opening_counts_and_names_the_missed_targets():
    from analysis import performance as perf

    rec = copy.deepcopy(committed_record())
    rec["paper_runs_one_seed_s"] = 0.0  # met, whatever the committed timing
    before = perf.opening(rec)
    met = perf.targets_met(rec)
    judged = [k for k, v in met.items() if v is not None]
    assert f"meets {sum(met[k] for k in judged)} of its {len(judged)} measured" in before
    rec["paper_runs_one_seed_s"] = 99.0  # a recorded-only target now missed
    after = perf.opening(rec)
    assert "the paper's 12 runs in 1 s" in after and "the paper's 12 runs" not in before
    assert f"meets {sum(met[k] for k in judged) - 1} of" in after
    rec["ratios"]["iapid_over_floor"] = 4.5  # an asserted one
    assert "asserts fail: IAPID-NN-DEKF within 4x the floor" in perf.opening(rec)


def test_check_passes_on_the_committed_record():
    from analysis import performance as perf

    rec = committed_record()
    perf.check(rec)
    assert perf.render(rec).startswith("## Performance\n")


@pytest.mark.parametrize(
    ("path", "value", "fails"),
    [
        (("ratios", "iapid_over_floor"), 4.5, "floor_ratio"),
        (("parallel_equals_serial",), False, "parallel_equals_serial"),
        (("python_control", "backstepping/jit", "max_abs_q_difference"), 1e-6, "same_computation"),
        (("floor_check_max_rel_error",), 1e-6, "floor_correct"),
        (("ratios", "python_control_over_iapid"), 1.5, None),  # information, not a target
        (("paper_runs_one_seed_s",), 5.0, None),  # absolute wall times: recorded only
        (("monte_carlo_1000_s",), 99.0, None),
    ],
    ids=lambda x: x if isinstance(x, str) else None,
)
def test_check_asserts_ratios_and_correctness_only(path, value, fails):
    from analysis import performance as perf

    rec = copy.deepcopy(committed_record())
    node = rec
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    if fails is None:
        perf.check(rec)
    else:
        with pytest.raises(AssertionError, match=fails):
            perf.check(rec)
