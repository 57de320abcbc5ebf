"""The closed-loop step, written once: its phases, the two drivers built from it, and ``prepare``.

One step ``k`` (``t_k = k dt``, ``k = 0 .. N-1``; DESIGN §3.1, §3.3), as phases:

1. :func:`sense` -- the pose ``q_k`` is measured with additive Gaussian noise, ``z_k = q_k + n_k``,
   and the estimator gives ``q_hat_k``: the raw measurement, or the pose EKF (errata E9, reading
   A; at ``k = 0`` the first estimate is the first measurement, ``P = R``);
2. the controller's ``law`` computes ``u_k`` from ``q_hat_k`` and the reference at ``t_k``, and
   :func:`saturate` clips it to the actuator limits;
3. the plant half -- the command is delayed (``[plant] delay_steps``, ``wmr.plant.delayed``), the
   disturbance active at ``t_k`` is added (:func:`disturb`) and the true robot is driven over
   ``[t_k, t_k + dt]`` with that input held (zero-order hold): the ideal unicycle, the parameter
   table of ``wmr.plant``, or a Python-level plant (``wmr.pyplant``: the MuJoCo robot); the pose
   EKF (if used) predicts with the commanded ``u_k`` and its nominal model;
4. :func:`score` -- the RMSE of eq. (64) is accumulated over the true poses (``wmr.metrics``) and
   the run is checked: a non-finite value or a position error beyond ``divergence_bound`` stops it.

The order is written once, in :func:`_step_template`.  Two drivers run it: the compiled kernel
(:func:`kernel`, numba; a copy of the step per controller law and plant kind, the law a global of
the copy) and the Python driver (:func:`python_step`; the same step as plain Python, calling the
same jitted phases), which runs what numba cannot compile -- a Python-level controller
(``wmr.controllers.PyController``: an optimiser in the loop, a plugin prototype), a Python-level
plant, per-step probes (``wmr.probes``) -- and the python-control comparator (``wmr.nlsys``).
:func:`run` picks the driver; either way the numbers are the same, bit for bit.

:func:`prepare` turns ``(scenario, controller, seed, settings)`` into everything the loop reads:
the controller's packed parameters and state, the noise stream, the pose filter's matrices, which
pose the controller acts on, the disturbance arrays, the limits, the plant.  Noise and reference
are made in chunks of :data:`CHUNK` steps (:meth:`Prepared.chunks`), so a run keeps O(1) memory
and its numbers do not depend on how it is split.
"""

from __future__ import annotations

import hashlib
import marshal
import math
import types
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wmr import controllers, metrics, plant
from wmr._jit import njit
from wmr.ekf import pose_predict, pose_update
from wmr.kinematics import integrator_code, step
from wmr.references import ReferenceSampler
from wmr.scenario import Plant, Scenario

__all__ = [
    "CHUNK",
    "CAUSES",
    "Prepared",
    "prepare",
    "seed_sequences",
    "sense",
    "saturate",
    "disturb",
    "score",
    "PLANT_IDEAL",
    "PLANT_TABLE",
    "PLANT_PYTHON",
    "kernel",
    "python_step",
    "plant_step",
    "law_digest",
    "Logs",
    "run",
]

#: Steps simulated per kernel call (noise and reference are generated per chunk).
CHUNK = 8192
#: Why a run stopped: the codes the phases return.
CAUSES = {0: None, 1: "non-finite value", 2: "position error exceeded divergence_bound"}


def law_digest(law) -> str:
    """A digest (12 hex digits) of the source file of a law defined outside ``wmr`` (a plugin),
    "" for wmr's own laws (their source is covered by the package's cache folder; ``wmr._jit``).
    """
    fn = getattr(law, "py_func", law)
    path = getattr(getattr(fn, "__code__", None), "co_filename", None)
    if path is None or _within_wmr(path):
        return ""
    try:
        data = Path(path).read_bytes()
    except OSError:  # defined in an interactive session: digest its code object instead
        data = marshal.dumps(fn.__code__)
    return hashlib.sha256(data).hexdigest()[:12]


def _within_wmr(path: str) -> bool:
    here = Path(__file__).resolve().parent
    try:
        Path(path).resolve().relative_to(here)
    except ValueError:
        return False
    return True


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
    (``wmr.metrics``); ``status = (step, cause)`` once the run stopped (``(-1, 0)`` before);
    ``plant_kind`` one of ``PLANT_IDEAL, PLANT_TABLE, PLANT_PYTHON`` and ``pyplant`` the
    Python-level robot (``wmr.pyplant.PyPlant``) of the last kind.
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
    plant_kind: int = 0
    pyplant: Any = None

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


def prepare(scenario: Scenario, controller: str, seed: int | None = None, settings=None,
            robot=None) -> Prepared:  # fmt: skip
    """Everything one run of ``controller`` on ``scenario`` reads, set up once.

    ``seed`` defaults to the scenario's; ``settings`` to the scenario's settings of the
    controller.  ``robot``: a factory ``robot(scenario) -> wmr.pyplant.PyPlant`` that replaces
    the scenario's robot by a Python-level one (default: the scenario's; ``model = "mujoco"`` is
    one).  The same inputs give the same ``Prepared``, draw for draw.
    """
    from wmr import pyplant

    ctrl = controllers.get(controller)
    settings = settings if settings is not None else scenario.settings(controller)
    seed = scenario.seed if seed is None else seed
    noise_ss, init_ss = seed_sequences(seed)
    p, s, theta, P = ctrl.pack(settings, scenario, np.random.default_rng(init_ss))
    std = np.array(scenario.noise.pose_std)
    Qp, Rp = scenario.estimator.matrices(scenario.noise)
    d = scenario.disturbances
    make = robot if robot is not None else pyplant.factory(scenario.plant)
    # a Python-level robot keeps only the loop's delay line from the compiled plant's arrays
    compiled = (scenario.plant if make is None or scenario.plant.model in plant.MODEL_CODES
                else Plant(delay_steps=scenario.plant.delay_steps))  # fmt: skip
    table, at, ints, vel, buffer = plant.arrays(compiled, scenario.dt)
    robot = make(scenario) if make is not None else None
    if robot is not None:
        robot.reset(np.array(scenario.initial_pose, dtype=float))
        kind = PLANT_PYTHON
    else:
        kind = PLANT_IDEAL if scenario.plant.ideal else PLANT_TABLE
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
        rng_noise=np.random.default_rng(noise_ss), plant_kind=kind, pyplant=robot,
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
# The step, written once, and the two drivers built from it

#: What drives the true robot (a compile-time constant of each copy of the step): the ideal
#: plant (``wmr.kinematics.step`` with the scenario's integrator), the parameter table of
#: ``wmr.plant`` (gains, coupling, lag, slip, lagged velocity loop, changes), or a Python-level
#: plant (``wmr.pyplant.PyPlant``: the MuJoCo robot, a user's robot).
PLANT_IDEAL, PLANT_TABLE, PLANT_PYTHON = 0, 1, 2


def _step_template(
    k, i, dt, integrator, p, s, theta, P,
    q, q_hat, ref, noise, use_ekf, Pq, Qp, Rp,
    disturbance, v_max, w_max, bound, plant_arrays, acc, t_tail, status, scratch, keep, logs,
):  # fmt: skip
    """One step ``k`` of the loop (DESIGN §3.1, §3.3), in its one order: sense -> law ->
    saturate -> delay -> disturb -> plant -> pose predict -> score.  Returns True when the run
    stops (``status = (step, cause)`` written).

    The control half is phases 1-2 (:func:`sense`, the controller's ``law``, :func:`saturate`),
    the plant half phase 3 (``wmr.plant.delayed``, :func:`disturb`, the true robot, the pose
    filter's prediction with the commanded ``u``, which knows neither the delay, the disturbance
    nor the true plant), then :func:`score`.  ``ref`` holds the reference rows of the chunk and
    ``noise`` its measurement noise (row ``i = k - k0``).  Tuples keep the call under CPython's
    30 arguments (beyond them a call is compiled as ``f(*args)``, which numba cannot inline):
    ``plant_arrays = (table, at, ints, vel, buffer)`` of ``wmr.plant.arrays``, ``scratch = (u,
    ua, z)`` and ``logs = (q, q_hat, u, state, vel, z)`` of :class:`Logs`.

    This function is never called as written: :func:`_bind` makes copies of it whose globals fix
    what varies -- ``law`` (the controller), ``PLANT`` (one of the ``PLANT_*`` kinds) and
    ``pyplant``, ``ORACLE`` (the loop writes the true pose into ``p.truth``), ``PROBE`` and
    ``probe`` (per-step hooks).  The compiled kernel (:func:`kernel`) jits such a copy with
    ``PROBE = False`` and a non-Python plant, so the unused branches are pruned at compile time;
    the Python driver (:func:`python_step`) runs a copy as plain Python, calling the same jitted
    phases, with a Python-level law or plant where needed.  Same inputs, same numbers.
    """
    u, ua, z = scratch
    q_log, qhat_log, u_log, s_log, vel_log, z_log = logs
    nis = sense(k, q, noise, i, q_hat, Pq, use_ekf, Rp, z)
    if PROBE:  # noqa: F821 - the globals of this template are bound per copy by _bind()
        if probe.after_estimate is not None:  # noqa: F821
            probe.after_estimate(k, q, q_hat, Pq, nis)  # noqa: F821
        if probe.before_law is not None:  # noqa: F821
            probe.before_law(k, p, s, theta, P, q_hat)  # noqa: F821
    if ORACLE:  # noqa: F821 - a diagnostic arm reads the true pose
        p.truth[0] = q[0]
        p.truth[1] = q[1]
        p.truth[2] = q[2]
    law(p, s, theta, P, q_hat, ref[i], dt, u)  # noqa: F821
    finite = saturate(u, v_max, w_max)
    if PROBE:  # noqa: F821
        if probe.after_law is not None:  # noqa: F821
            probe.after_law(k, p, s, theta, P, q_hat, u)  # noqa: F821
    if keep:
        z_log[k, :] = z
        qhat_log[k, :] = q_hat
        u_log[k, :] = u
        s_log[k, :] = s[: s_log.shape[1]]
    if not finite:
        status[0] = k
        status[1] = 1
        return True
    plant_half(k, dt, integrator, u, ua, q, q_hat, Pq, Qp, use_ekf, disturbance,  # noqa: F821
               plant_arrays, keep, vel_log)  # fmt: skip
    if keep:
        q_log[k + 1, :] = q
    cause = score(k, dt, q, ref[i + 1], u, acc, t_tail, bound)
    if cause != 0:
        status[0] = k + 1
        status[1] = cause
        return True
    return False


def _plant_template(k, dt, integrator, u, ua, q, q_hat, Pq, Qp, use_ekf, disturbance,
                    plant_arrays, keep, vel_log):  # fmt: skip
    """The plant half of step ``k`` (phase 3): the saturated command ``u`` is delayed
    (``wmr.plant.delayed``), disturbed (:func:`disturb`) into ``ua`` and drives the true robot
    over ``[t_k, t_k + dt]`` -- the ideal unicycle, the parameter table or the Python-level
    ``pyplant`` (``PLANT``, bound per copy as in :func:`_step_template`) -- then the pose filter
    predicts with ``u`` and its nominal model.  Mutates ``q`` (the true pose), ``q_hat``, ``Pq``
    and the plant's arrays; logs the actual ``(v, w)`` at ``t_k`` when ``keep``."""
    plant_table, plant_at, plant_ints, plant_vel, plant_buffer = plant_arrays
    ua[0] = u[0]
    ua[1] = u[1]
    if PLANT != PLANT_IDEAL:  # noqa: F821
        if keep:
            if PLANT == PLANT_PYTHON:  # noqa: F821
                pyplant.velocity(plant_vel)  # noqa: F821
            vel_log[k, 0] = plant_vel[0]  # the actual (v, w) at t_k, before the step
            vel_log[k, 1] = plant_vel[1]
        plant.delayed(ua, plant_ints, plant_buffer)
    disturb(k * dt, ua, disturbance)
    if PLANT == PLANT_IDEAL:  # noqa: F821
        q[:] = step(q, ua, dt, integrator)
    elif PLANT == PLANT_TABLE:  # noqa: F821
        plant.apply(k, dt, ua, q, plant_table, plant_at, plant_ints, plant_vel)
    else:
        pyplant.advance(k, ua)  # noqa: F821
        pyplant.pose(q)  # noqa: F821
    if use_ekf:
        pose_predict(q_hat, Pq, u, dt, integrator, Qp)


def _advance_template(
    p, s, theta, P,
    k0, k1, dt, integrator,
    q, q_hat, ref, noise, use_ekf, Pq, Qp, Rp,
    disturbance, v_max, w_max, bound,
    plant_table, plant_at, plant_ints, plant_vel, plant_buffer,
    acc, t_tail, status, keep, q_log, qhat_log, u_log, s_log, vel_log, z_log,
):  # fmt: skip
    """Advance the loop over steps ``k0 .. k1-1`` (``ref`` holds rows ``k0 .. k1``) by the bound
    copy of :func:`_step_template` (``one_step``, a global of each copy); returns early once the
    run stopped."""
    scratch = (np.zeros(2), np.zeros(2), np.zeros(3))
    plant_arrays = (plant_table, plant_at, plant_ints, plant_vel, plant_buffer)
    logs = (q_log, qhat_log, u_log, s_log, vel_log, z_log)
    for k in range(k0, k1):
        if one_step(k, k - k0, dt, integrator, p, s, theta, P,  # noqa: F821 - bound by _bind()
                    q, q_hat, ref, noise, use_ekf, Pq, Qp, Rp, disturbance, v_max, w_max, bound,
                    plant_arrays, acc, t_tail, status, scratch, keep, logs):  # fmt: skip
            return


class _NoProbe:
    """The hooks of a run without a probe (never read: ``PROBE`` is False)."""

    after_estimate = before_law = after_law = None


class _Hooks:
    """A probe's optional hooks, looked up once (None where it does not define one)."""

    def __init__(self, probe):
        self.after_estimate = getattr(probe, "after_estimate", None)
        self.before_law = getattr(probe, "before_law", None)
        self.after_law = getattr(probe, "after_law", None)


def _copy(template, name: str, glb: dict):
    """A copy of ``template`` with extra globals ``glb`` and qualified name ``name``."""
    fn = types.FunctionType(template.__code__, {**template.__globals__, **glb}, name,
                            template.__defaults__, template.__closure__)  # fmt: skip
    fn.__qualname__ = name
    fn.__module__ = template.__module__
    fn.__doc__ = template.__doc__
    return fn


def _bind(name: str, law, plant_kind: int, oracle: bool, *, compiled: bool, pyplant=None,
          probe=None):  # fmt: skip
    """``(plant_half, step, advance)``: copies of the three templates with their globals bound
    (see :func:`_step_template`); jitted when ``compiled`` (the halves inlined into the loop)."""
    jit = njit(inline="always") if compiled else (lambda f: f)
    glb = {"law": law, "PLANT": int(plant_kind), "ORACLE": bool(oracle),
           "PROBE": probe is not None, "probe": _Hooks(probe) if probe is not None else _NoProbe,
           "pyplant": pyplant}  # fmt: skip
    half = jit(_copy(_plant_template, f"_plant_{name}", glb))
    one = jit(_copy(_step_template, f"_step_{name}", {**glb, "plant_half": half}))
    adv = _copy(_advance_template, f"_advance_{name}", {**glb, "one_step": one})
    return half, one, (njit(adv) if compiled else adv)


_KERNELS: dict = {}


def _kernel_name(name: str, law, plant_kind: int, oracle: bool) -> str:
    """The kernel's qualified name: controller, plant kind, oracle, and -- for a law defined
    outside ``wmr`` (a plugin) -- a digest of the law's source file, so that numba's on-disk
    cache (keyed by the name) never serves a kernel compiled from an earlier version of it."""
    suffix = {PLANT_IDEAL: "", PLANT_TABLE: "_plant"}[plant_kind] + ("_oracle" if oracle else "")
    digest = law_digest(law)
    return f"{name.replace('-', '_')}{suffix}" + (f"_{digest}" if digest else "")


def kernel(name: str, law, plant_kind: int = PLANT_IDEAL, oracle: bool = False):
    """The loop compiled for one controller ``law`` and plant kind (``PLANT_IDEAL`` or
    ``PLANT_TABLE``; cached on disk).

    Each (controller, plant kind, oracle) gets its own copy of the templates with those bound as
    globals (compile-time constants: the ideal plant's kernel carries no branch of the true
    robot, and no kernel carries the probe's hooks) and its own qualified name, so numba caches
    one kernel each (a jitted function taking the law as a first-class argument cannot be cached
    reliably).  ``plant_kind`` also accepts a bool, ``True`` meaning the ideal plant.
    """
    if isinstance(plant_kind, bool):
        plant_kind = PLANT_IDEAL if plant_kind else PLANT_TABLE
    if plant_kind == PLANT_PYTHON:
        raise ValueError("a Python-level plant runs through the Python driver (python_step)")
    key = (name, law, plant_kind, bool(oracle))
    if key not in _KERNELS:
        _KERNELS[key] = _bind(_kernel_name(name, law, plant_kind, oracle), law, plant_kind,
                              oracle, compiled=True)[2]  # fmt: skip
    return _KERNELS[key]


def python_step(run: Prepared, probe=None):
    """The step of ``run`` as plain Python (the Python driver's, :func:`_step_template`), with
    ``run``'s law, plant and oracle bound and ``probe``'s hooks called: for the probes, the
    python-control comparator (``wmr.nlsys``) and what numba cannot compile."""
    c = run.controller
    return _bind(c.name, c.law, run.plant_kind, c.oracle, compiled=False, pyplant=run.pyplant,
                 probe=probe)[1]  # fmt: skip


def plant_step(run: Prepared):
    """The plant half of ``run``'s step (:func:`_plant_template`) as plain Python: ``f(k, dt,
    integrator, u, ua, q, q_hat, Pq, Qp, use_ekf, disturbance, plant_arrays, keep, vel_log)``,
    for tests and tools that drive the true robot with given commands."""
    c = run.controller
    return _bind(c.name, c.law, run.plant_kind, c.oracle, compiled=False,
                 pyplant=run.pyplant)[0]  # fmt: skip


@dataclass
class Logs:
    """Per-step signals of a run (``keep_trajectory``): ``q`` and ``ref`` have ``n + 1`` rows,
    ``q_hat``, ``u``, ``state`` and ``z`` ``n`` rows (``state``: the controller's logged entries;
    ``z``: the measured pose, true pose plus noise, the estimator's input)."""

    q: np.ndarray
    ref: np.ndarray
    q_hat: np.ndarray
    u: np.ndarray
    state: np.ndarray
    vel: np.ndarray  # the true robot's actual (v, w) at t_k (a non-ideal plant only)
    z: np.ndarray  # the measured pose at t_k

    @classmethod
    def empty(cls, n: int, n_state: int, keep: bool) -> Logs:
        rows = n + 1 if keep else 1
        per_step = rows - 1 if keep else 0
        return cls(q=np.full((rows, 3), np.nan), ref=np.empty((rows, 5)),
                   q_hat=np.full((per_step, 3), np.nan), u=np.full((per_step, 2), np.nan),
                   state=np.full((per_step, n_state), np.nan),
                   vel=np.full((per_step, 2), np.nan),
                   z=np.full((per_step, 3), np.nan))  # fmt: skip


def _start(run: Prepared, logs: Logs | None) -> None:
    """Score the initial pose at ``t_0`` (and log it)."""
    r0 = run.first_reference()
    with np.errstate(over="ignore", invalid="ignore"):  # extreme scenarios diverge, not warn
        metrics.accumulate_initial(run.acc, run.q, r0)
    if logs is not None:
        logs.q[0] = run.q
        logs.ref[0] = r0


def run(run: Prepared, logs: Logs | None, probe=None, driver: str | None = None) -> None:
    """Run the whole loop of ``run`` (logging into ``logs`` if given).

    ``driver``: ``"compiled"`` (the kernel), ``"python"`` (the same step as plain Python), or
    None: compiled unless something of the run cannot be (a ``probe``, a Python-level controller
    or plant).  Either gives the same numbers, bit for bit.
    """
    sc = run.scenario
    can_compile = run.controller.compiled and run.plant_kind != PLANT_PYTHON and probe is None
    if driver is None:
        driver = "compiled" if can_compile else "python"
    if driver not in ("compiled", "python"):
        raise ValueError(f"driver must be 'compiled' or 'python', not {driver!r}")
    if driver == "compiled" and not can_compile:
        raise ValueError("this run has a Python-level controller, plant or probe: "
                         "it needs driver='python'")  # fmt: skip
    keep = logs is not None
    if logs is None:
        logs = Logs.empty(0, len(run.controller.state_names), False)
    if driver == "compiled":
        advance = kernel(run.controller.name, run.controller.law, run.plant_kind,
                         run.controller.oracle)  # fmt: skip
    else:
        c = run.controller
        advance = _bind(c.name, c.law, run.plant_kind, c.oracle, compiled=False,
                        pyplant=run.pyplant, probe=probe)[2]  # fmt: skip
    _start(run, logs if keep else None)
    for k0, k1, ref, noise in run.chunks():
        advance(
            run.p, run.s, run.theta, run.P, k0, k1, sc.dt, run.integrator, run.q, run.q_hat,
            ref, noise, run.use_ekf, run.Pq, run.Qp, run.Rp, run.disturbance,
            sc.limits.v_max, sc.limits.w_max, sc.divergence_bound,
            run.plant_table, run.plant_at, run.plant_ints, run.plant_vel, run.plant_buffer,
            run.acc, metrics.TRANSIENT, run.status, keep, logs.q, logs.q_hat, logs.u, logs.state,
            logs.vel, logs.z,
        )  # fmt: skip
        if keep:
            logs.ref[k0 + 1 : k1 + 1] = ref[1:]
        if run.status[0] >= 0:
            break
