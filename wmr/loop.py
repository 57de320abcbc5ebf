"""The closed-loop step, written once: its phases, the kernel built from them, and ``prepare``.

One step ``k`` (``t_k = k dt``, ``k = 0 .. N-1``; DESIGN §3.1), as phases:

1. :func:`sense` -- the pose ``q_k`` is measured with additive Gaussian noise, ``z_k = q_k + n_k``,
   and the estimator gives ``q_hat_k``: the raw measurement, or the pose EKF (errata E9, reading
   A; at ``k = 0`` the first estimate is the first measurement, ``P = R``);
2. the controller's ``law`` computes ``u_k`` from ``q_hat_k`` and the reference at ``t_k``, and
   :func:`saturate` clips it to the actuator limits;
3. :func:`actuate` -- the command is delayed (``[plant] delay_steps``), the disturbance active at
   ``t_k`` is added and the true robot (``wmr.plant``) is driven over ``[t_k, t_k + dt]`` with
   that input held (zero-order hold); the pose EKF (if used) predicts with the commanded ``u_k``
   and its nominal model (it knows neither the delay, the disturbance nor the true plant);
4. :func:`score` -- the RMSE of eq. (64) is accumulated over the true poses (``wmr.metrics``) and
   the run is checked: a non-finite value or a position error beyond ``divergence_bound`` stops it.

:func:`kernel` composes the phases into one numba loop per controller law (the law is a global of
the compiled copy); ``wmr.sim.simulate`` runs that kernel, or, when it is given a probe, the same
phases one by one from Python with hooks between them (:func:`run_probed`).  Either way the
numbers are the same, bit for bit.

:func:`prepare` turns ``(scenario, controller, seed, settings)`` into everything the loop reads:
the controller's packed parameters and state, the noise stream, the pose filter's matrices, which
pose the controller acts on, the disturbance arrays, the limits.  Noise and reference are made
in chunks of :data:`CHUNK` steps (:meth:`Prepared.chunks`), so a run keeps O(1) memory and its
numbers do not depend on how it is split.
"""

from __future__ import annotations

import math
import types
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from wmr import controllers, metrics, plant
from wmr._jit import njit
from wmr.ekf import pose_predict, pose_update
from wmr.kinematics import integrator_code, step
from wmr.references import ReferenceSampler
from wmr.scenario import Scenario

__all__ = [
    "CHUNK",
    "CAUSES",
    "Prepared",
    "prepare",
    "seed_sequences",
    "sense",
    "saturate",
    "disturb",
    "actuate",
    "score",
    "kernel",
    "run_kernel",
    "run_probed",
]

#: Steps simulated per kernel call (noise and reference are generated per chunk).
CHUNK = 8192
#: Why a run stopped: the codes the phases return.
CAUSES = {0: None, 1: "non-finite value", 2: "position error exceeded divergence_bound"}


def seed_sequences(seed: int | np.random.SeedSequence):
    """The run's two independent streams: measurement noise and controller initialisation.

    The noise stream depends on the seed only, so every controller of a comparison sees the same
    noise draws (common random numbers).
    """
    ss = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    return ss.spawn(2)


@dataclass
class Prepared:
    """The inputs and the mutable state of one run, as the phases read and write them.

    ``p, s, theta, P`` are the controller's parameters, small state, flat weight vector and its
    covariance (``wmr.controllers``); ``q``, ``q_hat`` (3,) the true pose and its estimate;
    ``Pq`` (3, 3) the pose filter's covariance with process and measurement noise ``Qp``, ``Rp``;
    ``use_ekf`` whether the controller acts on the filtered pose; ``disturbance`` the windows
    ``(start, stop, dv, dw)``, one per row; ``plant_*`` the true robot's
    parameter table, change times, integer state, actual velocities and delay line
    (``wmr.plant.arrays``); ``acc`` the RMSE accumulators
    (``wmr.metrics``); ``status = (step, cause)`` once the run stopped (``(-1, 0)`` before).
    """

    scenario: Scenario
    controller: controllers.Controller
    settings: Any
    seed: int
    p: Any
    s: np.ndarray
    theta: np.ndarray
    P: np.ndarray
    q: np.ndarray
    q_hat: np.ndarray
    Pq: np.ndarray
    Qp: np.ndarray
    Rp: np.ndarray
    use_ekf: bool
    std: np.ndarray
    disturbance: np.ndarray
    integrator: int
    plant_table: np.ndarray
    plant_at: np.ndarray
    plant_ints: np.ndarray
    plant_vel: np.ndarray
    plant_buffer: np.ndarray
    acc: np.ndarray
    status: np.ndarray
    rng_noise: np.random.Generator

    @property
    def dt(self) -> float:
        return self.scenario.dt

    @property
    def n_steps(self) -> int:
        return self.scenario.n_steps

    def chunks(self, ref0: np.ndarray | None = None) -> Iterator[tuple[int, int, np.ndarray,
                                                                        np.ndarray]]:  # fmt: skip
        """``(k0, k1, ref, noise)`` for consecutive chunks of at most :data:`CHUNK` steps.

        ``ref`` holds the reference rows ``k0 .. k1`` (one more than the steps: the last row is
        where the step's pose is scored), ``noise`` the measurement noise of steps ``k0 .. k1-1``.
        """
        sc = self.scenario
        sampler = ReferenceSampler(sc.reference.kind, sc.reference.params, sc.dt)
        prev = sampler.rows(0, 1)
        n = sc.n_steps
        for k0 in range(0, n, CHUNK):
            k1 = min(k0 + CHUNK, n)
            ref = np.vstack((prev[-1:], sampler.rows(k0 + 1, k1 + 1)))
            with np.errstate(over="ignore", invalid="ignore"):  # extreme scenarios diverge
                noise = self.rng_noise.standard_normal((k1 - k0, 3)) * self.std
            yield k0, k1, ref, noise
            prev = ref

    def first_reference(self) -> np.ndarray:
        """The reference row at ``t_0`` (where the initial pose is scored)."""
        sc = self.scenario
        return ReferenceSampler(sc.reference.kind, sc.reference.params, sc.dt).rows(0, 1)[0]


def prepare(scenario: Scenario, controller: str, seed: int | None = None, settings=None
            ) -> Prepared:  # fmt: skip
    """Everything one run of ``controller`` on ``scenario`` reads, set up once.

    ``seed`` defaults to the scenario's; ``settings`` to the scenario's settings of the
    controller.  The same inputs give the same ``Prepared``, draw for draw.
    """
    ctrl = controllers.get(controller)
    settings = settings if settings is not None else scenario.settings(controller)
    seed = scenario.seed if seed is None else seed
    noise_ss, init_ss = seed_sequences(seed)
    p, s, theta, P = ctrl.pack(settings, scenario, np.random.default_rng(init_ss))
    std = np.array(scenario.noise.pose_std)
    Qp, Rp = scenario.estimator.matrices(scenario.noise)
    d = scenario.disturbances
    table, at, ints, vel, buffer = plant.arrays(scenario.plant, scenario.dt)
    return Prepared(
        scenario=scenario, controller=ctrl, settings=settings,
        seed=int(seed) if np.isscalar(seed) else -1,
        p=p, s=s, theta=theta, P=P,
        q=np.array(scenario.initial_pose, dtype=float), q_hat=np.zeros(3), Pq=Rp.copy(),
        Qp=Qp, Rp=Rp, use_ekf=scenario.estimator.filters(controller), std=std,
        disturbance=np.array([(x.start, x.stop, *x.velocity) for x in d],
                             dtype=float).reshape(-1, 4),
        integrator=integrator_code(scenario.integrator),
        plant_table=table, plant_at=at, plant_ints=ints, plant_vel=vel, plant_buffer=buffer,
        acc=np.zeros(metrics.N_ACC), status=np.array([-1, 0], dtype=np.int64),
        rng_noise=np.random.default_rng(noise_ss),
    )  # fmt: skip


# ---------------------------------------------------------------------------------------------
# The phases


@njit(inline="always")
def sense(k, q, noise, i, q_hat, Pq, use_ekf, Rp, z):
    """Phase 1: measure ``z = q + noise[i]`` and estimate ``q_hat`` in place; returns the pose
    filter's NIS (NaN without the filter or at ``k = 0``, where the estimate is the measurement
    and ``Pq = Rp``: no prior)."""
    for j in range(3):
        z[j] = q[j] + noise[i, j]
    if not use_ekf:
        q_hat[:] = z
        return math.nan
    if k == 0:
        q_hat[:] = z
        Pq[:, :] = Rp
        return math.nan
    return pose_update(q_hat, Pq, z, Rp)


@njit(inline="always")
def saturate(u, v_max, w_max):
    """Phase 2 (after the law): clip ``u = (v, w)`` to ``|v| <= v_max``, ``|w| <= w_max``;
    returns whether the command is finite (a run with a non-finite command stops)."""
    u[0] = min(max(u[0], -v_max), v_max)
    u[1] = min(max(u[1], -w_max), w_max)
    return math.isfinite(u[0]) and math.isfinite(u[1])


@njit(inline="always")
def disturb(t, ua, disturbance):
    """Phase 3a: add to ``ua`` the ``(dv, dw)`` of every disturbance window containing ``t``
    (``disturbance`` rows ``(start, stop, dv, dw)``, active for ``start <= t < stop``)."""
    for d in range(disturbance.shape[0]):
        if disturbance[d, 0] <= t < disturbance[d, 1]:
            ua[0] += disturbance[d, 2]
            ua[1] += disturbance[d, 3]


def actuate(run: Prepared, k: int, u, ua, q, q_hat, Pq) -> None:
    """Phase 3 from Python (the probed loop, ``wmr.nlsys``), as :func:`_advance_template` runs it:
    the saturated command ``u`` is delayed (``wmr.plant.delayed``), disturbed (:func:`disturb`)
    and drives the true robot over one period (``wmr.kinematics.step`` for the ideal plant,
    ``wmr.plant.apply`` otherwise); the pose filter predicts with ``u`` and the nominal model
    (it knows neither the delay, the disturbance nor the true plant)."""
    dt = run.dt
    ua[:] = u
    ideal = run.scenario.plant.ideal
    if not ideal:
        plant.delayed(ua, run.plant_ints, run.plant_buffer)
    disturb(k * dt, ua, run.disturbance)
    if ideal:
        q[:] = step(q, ua, dt, run.integrator)
    else:
        plant.apply(k, dt, ua, q, run.plant_table, run.plant_at, run.plant_ints, run.plant_vel)
    if run.use_ekf:
        pose_predict(q_hat, Pq, u, dt, run.integrator, run.Qp)


@njit(inline="always")
def score(k, dt, q, r, u, acc, t_tail, bound):
    """Phase 4: accumulate the errors of the pose at ``t_{k+1}`` against the reference row ``r``
    and the command ``u`` that led there (``wmr.metrics.accumulate``), then check the pose;
    returns the cause code (0: go on)."""
    d2 = metrics.accumulate(acc, q, r, (k + 1) * dt >= t_tail, u)
    if not (math.isfinite(q[0]) and math.isfinite(q[1]) and math.isfinite(q[2])):
        return 1
    if d2 > bound * bound:
        return 2
    return 0


# ---------------------------------------------------------------------------------------------
# The kernel: the phases composed in one compiled loop per controller law


def _advance_template(
    p, s, theta, P,
    k0, k1, dt, integrator,
    q, q_hat, ref, noise, use_ekf, Pq, Qp, Rp,
    disturbance, v_max, w_max, bound,
    plant_table, plant_at, plant_ints, plant_vel, plant_buffer,
    acc, t_tail, status, keep, q_log, qhat_log, u_log, s_log, vel_log,
):  # fmt: skip
    """Advance the loop over steps ``k0 .. k1-1``; ``ref`` holds rows ``k0 .. k1``.

    Compiled once per controller law and plant kind by :func:`kernel` (``law`` and
    ``IDEAL_PLANT`` are globals of the copy: the ideal plant's kernel has no branch of the true
    robot).  Mutates ``q``, ``q_hat``, the controller state ``s, theta, P``, the accumulators
    ``acc`` and, when ``keep``, the logs.  On divergence writes ``status = (step, cause)`` and
    returns early.  Phase 3 is :func:`actuate`'s sequence, spelt out here so that numba
    compiles it inline.
    """
    u = np.zeros(2)
    ua = np.zeros(2)
    z = np.zeros(3)
    for k in range(k0, k1):
        i = k - k0
        sense(k, q, noise, i, q_hat, Pq, use_ekf, Rp, z)
        if ORACLE:  # noqa: F821 - bound per kernel: a diagnostic arm reads the true pose
            p.truth[0] = q[0]
            p.truth[1] = q[1]
            p.truth[2] = q[2]
        law(p, s, theta, P, q_hat, ref[i], dt, u)  # noqa: F821 - bound per controller by kernel()
        finite = saturate(u, v_max, w_max)
        if keep:
            qhat_log[k, :] = q_hat
            u_log[k, :] = u
            s_log[k, :] = s[: s_log.shape[1]]
        if not finite:
            status[0] = k
            status[1] = 1
            return
        ua[0] = u[0]
        ua[1] = u[1]
        if not IDEAL_PLANT:  # noqa: F821 - bound per kernel
            if keep:
                vel_log[k, 0] = plant_vel[0]  # the actual (v, w) at t_k, before the step
                vel_log[k, 1] = plant_vel[1]
            plant.delayed(ua, plant_ints, plant_buffer)
        disturb(k * dt, ua, disturbance)
        if IDEAL_PLANT:  # noqa: F821
            q[:] = step(q, ua, dt, integrator)
        else:
            plant.apply(k, dt, ua, q, plant_table, plant_at, plant_ints, plant_vel)
        if use_ekf:
            pose_predict(q_hat, Pq, u, dt, integrator, Qp)
        if keep:
            q_log[k + 1, :] = q
        cause = score(k, dt, q, ref[i + 1], u, acc, t_tail, bound)
        if cause != 0:
            status[0] = k + 1
            status[1] = cause
            return


_KERNELS: dict = {}


def kernel(name: str, law, ideal: bool = True, oracle: bool = False):
    """The loop of ``_advance_template`` compiled for one controller ``law`` and plant kind
    (cached on disk).

    Each (controller, ideal plant or not) gets its own copy of the template function with
    ``law`` and ``IDEAL_PLANT`` bound as globals (compile-time constants: the ideal plant's
    kernel carries no branch of the true robot) and its own qualified name, so numba caches one
    kernel each (a jitted function taking the law as a first-class argument cannot be cached
    reliably).
    """
    key = (name, law, bool(ideal), bool(oracle))
    if key not in _KERNELS:
        template = _advance_template
        fn = types.FunctionType(template.__code__,
                                {**template.__globals__, "law": law, "IDEAL_PLANT": bool(ideal),
                                 "ORACLE": bool(oracle)},
                                f"_advance_{name}", template.__defaults__,
                                template.__closure__)  # fmt: skip
        suffix = "" if ideal else "_plant"
        fn.__qualname__ = f"_advance_{name.replace('-', '_')}{suffix}"
        fn.__module__ = template.__module__
        fn.__doc__ = template.__doc__
        _KERNELS[key] = njit(fn)
    return _KERNELS[key]


@dataclass
class Logs:
    """Per-step signals of a run (``keep_trajectory``): ``q`` and ``ref`` have ``n + 1`` rows,
    ``q_hat``, ``u`` and ``state`` ``n`` rows (``state``: the controller's logged entries)."""

    q: np.ndarray
    ref: np.ndarray
    q_hat: np.ndarray
    u: np.ndarray
    state: np.ndarray
    vel: np.ndarray  # the true robot's actual (v, w) at t_k (a non-ideal plant only)

    @classmethod
    def empty(cls, n: int, n_state: int, keep: bool) -> Logs:
        rows = n + 1 if keep else 1
        per_step = rows - 1 if keep else 0
        return cls(q=np.full((rows, 3), np.nan), ref=np.empty((rows, 5)),
                   q_hat=np.full((per_step, 3), np.nan), u=np.full((per_step, 2), np.nan),
                   state=np.full((per_step, n_state), np.nan),
                   vel=np.full((per_step, 2), np.nan))  # fmt: skip


def _start(run: Prepared, logs: Logs | None) -> None:
    """Score the initial pose at ``t_0`` (and log it)."""
    r0 = run.first_reference()
    with np.errstate(over="ignore", invalid="ignore"):  # extreme scenarios diverge, not warn
        metrics.accumulate_initial(run.acc, run.q, r0)
    if logs is not None:
        logs.q[0] = run.q
        logs.ref[0] = r0


def run_kernel(run: Prepared, logs: Logs | None) -> None:
    """Run the whole loop of ``run`` in the compiled kernel (logging into ``logs`` if given)."""
    sc = run.scenario
    keep = logs is not None
    if logs is None:
        logs = Logs.empty(0, len(run.controller.state_names), False)
    advance = kernel(run.controller.name, run.controller.law, sc.plant.ideal,
                     run.controller.oracle)
    _start(run, logs if keep else None)
    for k0, k1, ref, noise in run.chunks():
        advance(
            run.p, run.s, run.theta, run.P, k0, k1, sc.dt, run.integrator, run.q, run.q_hat,
            ref, noise, run.use_ekf, run.Pq, run.Qp, run.Rp, run.disturbance,
            sc.limits.v_max, sc.limits.w_max, sc.divergence_bound,
            run.plant_table, run.plant_at, run.plant_ints, run.plant_vel, run.plant_buffer,
            run.acc, metrics.TRANSIENT, run.status, keep, logs.q, logs.q_hat, logs.u, logs.state,
            logs.vel,
        )  # fmt: skip
        if keep:
            logs.ref[k0 + 1 : k1 + 1] = ref[1:]
        if run.status[0] >= 0:
            break


def run_probed(run: Prepared, logs: Logs | None, probe) -> None:
    """Run the loop of ``run`` phase by phase from Python, calling ``probe``'s hooks.

    The same jitted phases and law as the kernel, in the same order, on the same chunks: the
    numbers are the kernel's, bit for bit (a test checks it).  ``probe`` may define any of
    (all optional; arrays are live views, copy what you keep):

    - ``after_estimate(k, q, q_hat, Pq, nis)``: after phase 1 (``q`` the true pose at ``t_k``;
      ``nis`` of the pose update, NaN at ``k = 0`` or without the pose filter);
    - ``before_law(k, p, s, theta, P, q_hat)``: before the controller law at step ``k``;
    - ``after_law(k, p, s, theta, P, q_hat, u)``: after it (``u`` saturated).
    """
    sc = run.scenario
    dt, law = sc.dt, run.controller.law
    v_max, w_max, bound = sc.limits.v_max, sc.limits.w_max, sc.divergence_bound
    on_estimate = getattr(probe, "after_estimate", None)
    before = getattr(probe, "before_law", None)
    after = getattr(probe, "after_law", None)
    _start(run, logs)
    p, s, theta, P, q, q_hat, Pq = run.p, run.s, run.theta, run.P, run.q, run.q_hat, run.Pq
    for k0, k1, ref, noise in run.chunks():
        u, ua, z = np.zeros(2), np.zeros(2), np.zeros(3)
        for k in range(k0, k1):
            i = k - k0
            nis = sense(k, q, noise, i, q_hat, Pq, run.use_ekf, run.Rp, z)
            if on_estimate is not None:
                on_estimate(k, q, q_hat, Pq, nis)
            if before is not None:
                before(k, p, s, theta, P, q_hat)
            if run.controller.oracle:
                p.truth[0:3] = q
            law(p, s, theta, P, q_hat, ref[i], dt, u)
            finite = saturate(u, v_max, w_max)
            if after is not None:
                after(k, p, s, theta, P, q_hat, u)
            if logs is not None:
                logs.q_hat[k], logs.u[k] = q_hat, u
                logs.state[k] = s[: logs.state.shape[1]]
            if not finite:
                run.status[:] = (k, 1)
                return
            if logs is not None and not run.scenario.plant.ideal:
                logs.vel[k] = run.plant_vel
            actuate(run, k, u, ua, q, q_hat, Pq)
            if logs is not None:
                logs.q[k + 1] = q
                logs.ref[k + 1] = ref[i + 1]
            cause = score(k, dt, q, ref[i + 1], u, run.acc, metrics.TRANSIENT, bound)
            if cause != 0:
                run.status[:] = (k + 1, cause)
                return
