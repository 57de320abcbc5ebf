"""The sampled-data closed loop (DESIGN §3.1) and its run result.

One step ``k`` (``t_k = k dt``, ``k = 0 .. N-1``):

1. the pose ``q_k`` is measured with additive Gaussian noise, ``z_k = q_k + n_k``;
2. the estimator gives ``q_hat_k``: the raw measurement, or the pose EKF (errata E9, reading A);
3. the controller law computes ``u_k`` from ``q_hat_k`` and the reference at ``t_k``;
4. ``u_k`` is saturated to the actuator limits, then the disturbance active at ``t_k`` is added;
5. the plant is integrated over ``[t_k, t_k + dt]`` with that input held (zero-order hold);
6. the EKF (if used) predicts with the commanded ``u_k`` (it does not know the disturbance).

The RMSE of eq. (64) is accumulated on the fly over the true poses ``q_0 .. q_N`` against the
reference at the same instants, so a run keeps O(1) memory unless its trajectory is asked for.
A run stops at the first non-finite value or when the position error exceeds the scenario's
``divergence_bound``; the result records when and why (``diverged_at``, ``cause``).

The whole loop is one numba kernel, specialised per controller law (the law is passed in as a
first-class jitted function); noise and reference are produced in fixed-size chunks so results do
not depend on memory or on how a run is split.
"""

from __future__ import annotations

import math
import types
from dataclasses import dataclass, field

import numpy as np

from wmr import controllers
from wmr._jit import njit
from wmr.ekf import pose_predict, pose_update
from wmr.kinematics import integrator_code, step, wrap_angle
from wmr.references import ReferenceSampler
from wmr.scenario import Scenario

__all__ = ["RunResult", "simulate", "kernel", "seed_sequences", "CAUSES", "CHUNK", "TRANSIENT"]

#: Steps simulated per kernel call (noise and reference are generated per chunk).
CHUNK = 8192
#: Divergence causes recorded by the kernel.
CAUSES = {0: None, 1: "non-finite value", 2: "position error exceeded divergence_bound"}
#: Start [s] of the post-transient window of ``RunResult.rmse_after_transient`` (notes §5.5).
TRANSIENT = 5.0
# sums of squares x, y, theta (world), e1, e2 (robot frame), the count; then x, y, theta and the
# count again over the poses with t >= TRANSIENT
_N_ACC = 10


@dataclass
class RunResult:
    """One closed-loop run.

    Arrays are row-per-instant: ``t``, ``q``, ``ref`` have ``n + 1`` rows (``q_0 .. q_n``), the
    per-step signals ``q_hat``, ``u``, ``state`` have ``n`` rows, where ``n`` is the number of
    steps simulated (``n_steps`` unless the run diverged).  They are ``None`` when the run was
    made with ``keep_trajectory=False``.

    Attributes
    ----------
    rmse : dict
        ``{"x", "y", "theta", "position"}`` over ``q_0 .. q_N`` (eq. 64, theta wrapped); NaN
        when the run diverged.
    rmse_robot_frame : dict
        RMSE of ``e1``, ``e2`` (robot frame) — their squares sum to the position error.
    rmse_after_transient : dict
        The RMSE of ``rmse`` over the poses with ``t >= TRANSIENT`` only (NaN if none, or
        diverged): the initial pose error dominates the full-run figure.
    diverged, diverged_at, cause
        Whether the run stopped early, at which time [s], and why.
    """

    scenario: str
    controller: str
    seed: int
    dt: float
    n_steps: int
    rmse: dict[str, float]
    rmse_robot_frame: dict[str, float]
    rmse_after_transient: dict[str, float] = field(default_factory=dict)
    diverged: bool = False
    diverged_at: float | None = None
    cause: str | None = None
    state_names: tuple[str, ...] = ()
    t: np.ndarray | None = None
    q: np.ndarray | None = None
    ref: np.ndarray | None = None
    q_hat: np.ndarray | None = None
    u: np.ndarray | None = None
    state: np.ndarray | None = None
    extra: dict = field(default_factory=dict)  # final controller state: W, P, s; pose-EKF P

    def summary(self) -> dict:
        """The JSON record of DESIGN §3.2 (``null`` for the RMSE of a diverged run)."""

        def num(x):
            return None if x is None or not math.isfinite(x) else float(x)

        return {
            "controller": self.controller,
            "rmse": {k: num(v) for k, v in self.rmse.items()},
            "diverged": self.diverged,
            "diverged_at": num(self.diverged_at),
        }


def _advance_template(
    p, s, W, P,
    k0, k1, dt, integrator,
    q, q_hat, ref, noise, use_ekf, Pq, Qp, Rp,
    dist_start, dist_stop, dist_v, dist_w, v_max, w_max, bound,
    acc, t_tail, status, keep, q_log, qhat_log, u_log, s_log,
):  # fmt: skip
    """Advance the loop over steps ``k0 .. k1-1``; ``ref`` holds rows ``k0 .. k1``.

    Compiled once per controller law by :func:`kernel` (``law`` is a global of the copy).

    Mutates ``q``, ``q_hat``, the controller state ``s, W, P``, the accumulators ``acc`` and,
    when ``keep``, the logs.  On divergence writes ``status = (step, cause)`` and returns early.
    """
    u = np.zeros(2)
    ua = np.zeros(2)
    z = np.zeros(3)
    for k in range(k0, k1):
        i = k - k0
        for j in range(3):
            z[j] = q[j] + noise[i, j]
        if not use_ekf:
            q_hat[:] = z
        elif k == 0:  # no prior: the first estimate is the first measurement, P = R
            q_hat[:] = z
            Pq[:, :] = Rp
        else:
            pose_update(q_hat, Pq, z, Rp)
        law(p, s, W, P, q_hat, ref[i], dt, u)  # noqa: F821 - bound per controller by kernel()
        u[0] = min(max(u[0], -v_max), v_max)
        u[1] = min(max(u[1], -w_max), w_max)
        if keep:
            qhat_log[k, :] = q_hat
            u_log[k, :] = u
            s_log[k, :] = s[: s_log.shape[1]]
        if not (math.isfinite(u[0]) and math.isfinite(u[1])):
            status[0] = k
            status[1] = 1
            return
        t = k * dt
        ua[0] = u[0]
        ua[1] = u[1]
        for d in range(dist_start.size):
            if dist_start[d] <= t < dist_stop[d]:
                ua[0] += dist_v[d]
                ua[1] += dist_w[d]
        q[:] = step(q, ua, dt, integrator)
        if use_ekf:  # predicts with the commanded input: the disturbance is unknown to it
            pose_predict(q_hat, Pq, u, dt, integrator, Qp)
        if keep:
            q_log[k + 1, :] = q
        r = ref[i + 1]
        dx = r[0] - q[0]
        dy = r[1] - q[1]
        dth = wrap_angle(r[2] - q[2])
        c = math.cos(q[2])
        sn = math.sin(q[2])
        e1 = c * dx + sn * dy
        e2 = -sn * dx + c * dy
        acc[0] += dx * dx
        acc[1] += dy * dy
        acc[2] += dth * dth
        acc[3] += e1 * e1
        acc[4] += e2 * e2
        acc[5] += 1.0
        if (k + 1) * dt >= t_tail:
            acc[6] += dx * dx
            acc[7] += dy * dy
            acc[8] += dth * dth
            acc[9] += 1.0
        if not (math.isfinite(q[0]) and math.isfinite(q[1]) and math.isfinite(q[2])):
            status[0] = k + 1
            status[1] = 1
            return
        if dx * dx + dy * dy > bound * bound:
            status[0] = k + 1
            status[1] = 2
            return


_KERNELS: dict = {}


def kernel(name: str, law):
    """The loop of ``_advance_template`` compiled for one controller ``law`` (cached on disk).

    Each controller gets its own copy of the template function with ``law`` bound as a global
    and its own qualified name, so numba caches one kernel per controller (a jitted function
    taking the law as a first-class argument cannot be cached reliably).
    """
    key = (name, law)
    if key not in _KERNELS:
        template = _advance_template
        fn = types.FunctionType(template.__code__, {**template.__globals__, "law": law},
                                f"_advance_{name}", template.__defaults__,
                                template.__closure__)  # fmt: skip
        fn.__qualname__ = f"_advance_{name.replace('-', '_')}"
        fn.__module__ = template.__module__
        fn.__doc__ = template.__doc__
        _KERNELS[key] = njit(fn)
    return _KERNELS[key]


def _accumulate_initial(q, ref0, acc):
    dx, dy = ref0[0] - q[0], ref0[1] - q[1]
    dth = math.atan2(math.sin(ref0[2] - q[2]), math.cos(ref0[2] - q[2]))
    c, s = math.cos(q[2]), math.sin(q[2])
    acc[:6] = (dx * dx, dy * dy, dth * dth, (c * dx + s * dy) ** 2, (-s * dx + c * dy) ** 2, 1.0)
    acc[6:] = 0.0  # t_0 = 0 < TRANSIENT


def seed_sequences(seed: int | np.random.SeedSequence):
    """The run's two independent streams: measurement noise and controller initialisation.

    The noise stream depends on the seed only, so every controller of a comparison sees the same
    noise draws (common random numbers).
    """
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return ss.spawn(2)


def simulate(
    scenario: Scenario,
    controller: str,
    seed: int | None = None,
    *,
    settings=None,
    keep_trajectory: bool = True,
) -> RunResult:
    """Run ``controller`` on ``scenario``.

    Parameters
    ----------
    scenario : Scenario
        The validated scenario.
    controller : str
        A registered controller name (``wmr.controllers.NAMES``).
    seed : int, optional
        Seed of the run (default: the scenario's).  Same scenario and seed give identical results.
    settings : optional
        Controller settings overriding those of the scenario file.
    keep_trajectory : bool
        Keep the logged signals (memory O(N)); otherwise only the metrics (memory O(1)).
    """
    ctrl = controllers.get(controller)
    settings = settings if settings is not None else scenario.settings(controller)
    seed = scenario.seed if seed is None else seed
    noise_ss, init_ss = seed_sequences(seed)
    rng_noise = np.random.default_rng(noise_ss)
    n = scenario.n_steps
    dt = scenario.dt
    p, s, W, P = ctrl.pack(settings, scenario, np.random.default_rng(init_ss))
    state_names = ctrl.state_names

    q = np.array(scenario.initial_pose, dtype=float)
    q_hat = np.zeros(3)
    std = np.array(scenario.noise.pose_std)
    d = scenario.disturbances
    dist = [np.array([getattr(x, f) for x in d], dtype=float) for f in ("start", "stop")]
    dist_v = np.array([x.velocity[0] for x in d], dtype=float)
    dist_w = np.array([x.velocity[1] for x in d], dtype=float)
    integ = integrator_code(scenario.integrator)
    est = scenario.estimator
    use_ekf = est.pose_source == "filtered" or (est.pose_source == "paper" and ctrl.uses_estimator)
    with np.errstate(over="ignore"):  # an absurd std gives an infinite covariance, not a warning
        Qp = np.diag(np.square(est.process_std))
        Rp = np.diag(np.square(np.maximum(std, est.min_measurement_std)))
    Pq = Rp.copy()
    acc = np.zeros(_N_ACC)
    status = np.array([-1, 0], dtype=np.int64)

    keep = bool(keep_trajectory)
    rows = n + 1 if keep else 1
    q_log = np.full((rows, 3), np.nan)
    qhat_log = np.full((rows - 1 if keep else 0, 3), np.nan)
    u_log = np.full((rows - 1 if keep else 0, 2), np.nan)
    s_log = np.full((rows - 1 if keep else 0, len(state_names)), np.nan)
    ref_log = np.empty((rows, 5)) if keep else None

    advance = kernel(controller, ctrl.law)
    sampler = ReferenceSampler(scenario.reference.kind, scenario.reference.params, dt)
    ref_prev = sampler.rows(0, 1)
    with np.errstate(over="ignore", invalid="ignore"):  # extreme scenarios diverge, not warn
        _accumulate_initial(q, ref_prev[0], acc)
    if keep:
        q_log[0] = q
        ref_log[0] = ref_prev[0]
    for k0 in range(0, n, CHUNK):
        k1 = min(k0 + CHUNK, n)
        ref = np.vstack((ref_prev[-1:], sampler.rows(k0 + 1, k1 + 1)))
        with np.errstate(over="ignore", invalid="ignore"):
            noise = rng_noise.standard_normal((k1 - k0, 3)) * std
        advance(
            p, s, W, P, k0, k1, dt, integ, q, q_hat, ref, noise, use_ekf, Pq, Qp, Rp,
            dist[0], dist[1], dist_v, dist_w,
            scenario.limits.v_max, scenario.limits.w_max, scenario.divergence_bound,
            acc, TRANSIENT, status, keep, q_log, qhat_log, u_log, s_log,
        )  # fmt: skip
        if keep:
            ref_log[k0 + 1 : k1 + 1] = ref[1:]
        ref_prev = ref
        if status[0] >= 0:
            break

    diverged = status[0] >= 0
    steps = int(status[0]) if diverged else n
    rmse_tail = dict.fromkeys(("x", "y", "theta", "position"), math.nan)
    if diverged:
        rmse = dict.fromkeys(("x", "y", "theta", "position"), math.nan)
        rmse_rf = {"e1": math.nan, "e2": math.nan}
    else:
        if acc[9] > 0:
            m_t = acc[9]
            rmse_tail = {"x": math.sqrt(acc[6] / m_t), "y": math.sqrt(acc[7] / m_t),
                         "theta": math.sqrt(acc[8] / m_t),
                         "position": math.sqrt((acc[6] + acc[7]) / m_t)}  # fmt: skip
        m = acc[5]
        rmse = {
            "x": math.sqrt(acc[0] / m),
            "y": math.sqrt(acc[1] / m),
            "theta": math.sqrt(acc[2] / m),
            "position": math.sqrt((acc[0] + acc[1]) / m),
        }
        rmse_rf = {"e1": math.sqrt(acc[3] / m), "e2": math.sqrt(acc[4] / m)}
    result = RunResult(
        scenario=scenario.name, controller=controller, seed=int(seed) if np.isscalar(seed) else -1,
        dt=dt, n_steps=n, rmse=rmse, rmse_robot_frame=rmse_rf, rmse_after_transient=rmse_tail,
        diverged=bool(diverged),
        diverged_at=steps * dt if diverged else None, cause=CAUSES[int(status[1])],
        state_names=state_names,
        extra={"W": W, "P": P, "s": s, "q_hat": q_hat, "P_pose": Pq if use_ekf else None},
    )  # fmt: skip
    if keep:
        result.t = np.arange(steps + 1) * dt
        result.q = q_log[: steps + 1]
        result.ref = ref_log[: steps + 1]
        result.q_hat = qhat_log[:steps]
        result.u = u_log[:steps]
        result.state = s_log[:steps]
    return result
