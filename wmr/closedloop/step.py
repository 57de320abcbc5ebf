"""The closed-loop step, written once: its phases, the two drivers built from it, and ``prepare``.

One step ``k`` (``t_k = k dt``, ``k = 0 .. N-1``; DESIGN §3.1, §3.3), as phases:

1. :func:`sense` -- the pose ``q_k`` is measured with additive Gaussian noise, ``z_k = q_k + n_k``,
   and the estimator gives ``q_hat_k``: the raw measurement, or the pose EKF (errata E9, reading
   A; at ``k = 0`` the first estimate is the first measurement, ``P = R``);
2. the controller's ``law`` computes ``u_k`` from ``q_hat_k`` and the reference at ``t_k``, and
   :func:`saturate` clips it to the actuator limits;
3. the plant half -- the command is delayed (``[plant] delay_steps``, ``wmr.robots.plant.delayed``),
   the
   disturbance active at ``t_k`` is added (:func:`disturb`) and the true robot is driven over
   ``[t_k, t_k + dt]`` with that input held (zero-order hold): the ideal unicycle, the parameter
   table of ``wmr.robots.plant``, or a Python-level plant (``wmr.robots.pyplant``: the MuJoCo
   robot); the pose EKF (if used) predicts with the commanded ``u_k`` and its nominal model;
4. :func:`score` -- the RMSE of eq. (64) is accumulated over the true poses
   (``wmr.closedloop.metrics``) and
   the run is checked: a non-finite value or a position error beyond ``divergence_bound`` stops it.

The order is written once, as the body of the loop of :func:`_advance_template` (the plant half in
:func:`_plant_template`).  Two drivers run it: the compiled kernel (:func:`kernel`, numba; a copy of
the loop per controller law and plant kind, the law a global of the copy) and the Python driver
(:func:`python_step`; the same loop as plain Python, calling the same jitted phases), which runs
what numba cannot compile -- a Python-level controller (``wmr.controllers.PyController``: an
optimiser in the loop, a plugin prototype), a Python-level plant, per-step probes
(``wmr.closedloop.probes``) -- and the python-control comparator (``wmr.linear.nlsys``). :func:`run`
picks the driver; either way the numbers are the same, bit for bit.

:func:`prepare` (``wmr.closedloop.runsetup``, re-exported here) turns ``(scenario, controller, seed,
settings)`` into everything the loop reads, with what depends only on the scenario (the reference
table, the filter's matrices, the plant's table) built once per process and shared; noise is drawn
in chunks of :data:`CHUNK` steps (:meth:`Prepared.chunks`), so a run keeps O(1) memory and its
numbers do not depend on how it is split.

No phase allocates: they work on scalars and on buffers made once per kernel call (the command, the
measurement, the pose filter's scratch ``wmr.estimation.ekf.pose_work``), and what only some runs
need -- the logs of a kept trajectory, the probe's hooks, the oracle's true pose -- is a
compile-time constant of each copy of the step (``KEEP``, ``PROBE``, ``ORACLE``), so the other
kernels carry none of it.
"""

from __future__ import annotations

import hashlib
import marshal
import math
import threading
import types
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from wmr._borrow import borrowed
from wmr._jit import njit
from wmr.closedloop import metrics
from wmr.closedloop.runsetup import (
    CHUNK,
    PLANT_IDEAL,
    PLANT_PYTHON,
    PLANT_TABLE,
    Prepared,
    prepare,
    seed_sequences,
)
from wmr.estimation.ekf import pose_predict, pose_update, pose_work
from wmr.model.kinematics import step_into
from wmr.robots import plant

__all__ = [
    "CHUNK",
    "CAUSES",
    "Prepared",
    "prepare",
    "seed_sequences",
    "sense",
    "measure",
    "estimate",
    "saturate",
    "disturb",
    "score",
    "PLANT_IDEAL",
    "PLANT_TABLE",
    "PLANT_PYTHON",
    "kernel",
    "python_step",
    "step_scratch",
    "plant_step",
    "plant_half",
    "law_digest",
    "Logs",
    "run",
]

#: Entries of a reference row: ``(x_r, y_r, theta_r, v_r, w_r)`` (``wmr.model.references``).
REF_COLUMNS = 5
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
    here = Path(__file__).resolve().parents[1]  # the package wmr/
    try:
        Path(path).resolve().relative_to(here)
    except ValueError:
        return False
    return True


# ---------------------------------------------------------------------------------------------
# The phases


@njit(inline="always")
def measure(q, noise, i, z):
    """Phase 1a: the measurement ``z = q + noise[i]`` (in place)."""
    for j in range(3):
        z[j] = q[j] + noise[i, j]


@njit
def sense(k, q, noise, i, q_hat, Pq, use_ekf, Rp, z, work):
    """Phase 1: measure ``z = q + noise[i]`` (:func:`measure`) and estimate ``q_hat`` in place
    (:func:`estimate`); returns the pose filter's NIS (NaN without the filter or at ``k = 0``).
    The loop calls the two halves itself (see :func:`_advance_template`)."""
    measure(q, noise, i, z)
    return estimate(k, z, q_hat, Pq, use_ekf, Rp, work)


@njit
def estimate(k, z, q_hat, Pq, use_ekf, Rp, work):
    """Phase 1b: the estimate ``q_hat`` from the measurement ``z``, in place: ``z`` itself, or the
    pose filter's update (errata E9, reading A; at ``k = 0`` the estimate is the measurement and
    ``Pq = Rp``: no prior); returns the filter's NIS (NaN without a filter update).  ``work``:
    the filter's scratch (``wmr.estimation.ekf.pose_work``).  A call of its own, not inlined: its
    branches
    would keep the loop's reference counts on its arrays (measured)."""
    if not use_ekf:
        q_hat[:] = z
        return math.nan
    if k == 0:
        q_hat[:] = z
        Pq[:, :] = Rp
        return math.nan
    return pose_update(q_hat, Pq, z, Rp, work)


@njit
def step_scratch(n_ref):
    """The buffers of one caller of the step (``scratch`` of :func:`_advance_template`): the
    command, the applied command, the measurement, the pose filter's scratch and a reference row
    of ``n_ref`` entries."""
    return np.zeros(2), np.zeros(2), np.zeros(3), pose_work(), np.zeros(n_ref)


@njit(inline="always")
def row_into(table, i, r):
    """Copy the row ``table[i]`` into ``r`` (the loop hands the laws a buffer, not a view of the
    row: a view is made with its parent's reference count incremented, and released, every
    step)."""
    for j in range(r.shape[0]):
        r[j] = table[i, j]


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


@njit
def score(k, dt, q, r, u, acc, t_tail, bound):
    """Phase 4: accumulate the errors of the pose at ``t_{k+1}`` against the reference row ``r``
    and the command ``u`` that led there (``wmr.closedloop.metrics.accumulate``), then check the
    pose; returns the cause code (0: go on)."""
    d2 = metrics.accumulate(acc, q, r, (k + 1) * dt >= t_tail, u)
    finite = math.isfinite(q[0]) & math.isfinite(q[1]) & math.isfinite(q[2])  # no branch
    return 1 if not finite else (2 if d2 > bound * bound else 0)


# ---------------------------------------------------------------------------------------------
# The step, written once, and the two drivers built from it

def _advance_template(
    p, s, theta, P,
    k0, k1, dt, integrator,
    q, q_hat, ref, noise, use_ekf, Pq, Qp, Rp,
    disturbance, v_max, w_max, bound,
    plant_table, plant_at, plant_ints, plant_vel, plant_buffer,
    acc, t_tail, status, q_log, qhat_log, u_log, s_log, vel_log, z_log, scratch=None,
):  # fmt: skip
    """Steps ``k = k0 .. k1-1`` of the loop (DESIGN §3.1, §3.3), each in its one order: sense ->
    law -> saturate -> delay -> disturb -> plant -> pose predict -> score.  Returns True when the
    run stopped (``status = (step, cause)`` written), at once.

    The control half is phases 1-2 (:func:`sense`, the controller's ``law``, :func:`saturate`),
    the plant half phase 3 (``plant_half``, a copy of :func:`_plant_template`), then the pose
    filter's prediction with the commanded ``u`` (which knows neither the delay, the disturbance
    nor the true plant) and :func:`score`.  ``ref`` holds the reference rows ``k0 .. k1``
    (``ref[i]`` at ``t_k``, ``i = k - k0``; the last row is where the last pose is scored) and
    ``noise`` the measurement noise of the steps; ``*_log`` are the arrays of :class:`Logs`
    (written only by a copy with ``KEEP``).  ``scratch = (u, ua, z, work, r)``: the command, the
    applied command, the measurement, the pose filter's scratch
    (``wmr.estimation.ekf.pose_work``) and the reference row the law and the score read (a copy of
    ``ref[i]``, then of ``ref[i + 1]``), made here once per call when not given (a caller that steps
    one ``k`` at a time, the python-control comparator, hands in its own).

    This function is never called as written: :func:`_bind` makes copies of it whose globals fix
    what varies -- ``law`` (the controller), ``PLANT`` (one of the ``PLANT_*`` kinds) and
    ``pyplant``, ``ORACLE`` (the loop writes the true pose into ``p.truth``), ``KEEP`` (the logs
    of a kept trajectory are written), ``PROBE`` and ``probe`` (per-step hooks).  The compiled
    kernel (:func:`kernel`) jits such a copy with ``PROBE = False`` and a non-Python plant, so
    the unused branches are pruned at compile time; the Python driver runs a copy as plain
    Python, calling the same jitted phases, with a Python-level law or plant where needed.  Same
    inputs, same numbers.

    The step is the body of this loop, not a function the loop calls: numba's inlining of a
    callee increments and decrements the reference count of every array it is handed, at every
    call, unless its body is simple enough for the pruning pass (measured: a third of the
    backstepping kernel's time).  For the same reason the inlined phases are branch-free and the
    branching ones (:func:`estimate`, the pose filter) are called from the loop's body.
    """
    # every array of the loop borrowed for the call (wmr._borrow: no reference counts per step);
    # the caller owns them all for the call's duration -- the scratch too when it hands it in
    # (made here, it stays owned: borrowing it would let numba free it under its views)
    p, s, theta, P, q, q_hat, ref, noise = borrowed((p, s, theta, P, q, q_hat, ref, noise))
    Pq, Qp, Rp, disturbance, acc, status = borrowed((Pq, Qp, Rp, disturbance, acc, status))
    plant_arrays = borrowed((plant_table, plant_at, plant_ints, plant_vel, plant_buffer))
    q_log, qhat_log, u_log, s_log, vel_log, z_log = borrowed(
        (q_log, qhat_log, u_log, s_log, vel_log, z_log))
    if scratch is None:
        u, ua, z, work, r = step_scratch(ref.shape[1])
    else:
        u, ua, z, work, r = borrowed(scratch)
    row_into(ref, 0, r)
    for k in range(k0, k1):
        i = k - k0
        measure(q, noise, i, z)  # sense, in two parts (see below)
        if use_ekf:
            nis = estimate(k, z, q_hat, Pq, use_ekf, Rp, work)
        else:  # the raw measurement: no call (a call passes its arrays with their counts)
            for j in range(3):
                q_hat[j] = z[j]
            nis = math.nan
        if PROBE:  # noqa: F821 - the globals of this template are bound per copy by _bind()
            if probe.after_estimate is not None:  # noqa: F821
                probe.after_estimate(k, q, q_hat, Pq, nis)  # noqa: F821
            if probe.before_law is not None:  # noqa: F821
                probe.before_law(k, p, s, theta, P, q_hat)  # noqa: F821
        if ORACLE:  # noqa: F821 - a diagnostic arm reads the true pose
            p.truth[0] = q[0]
            p.truth[1] = q[1]
            p.truth[2] = q[2]
        law(p, s, theta, P, q_hat, r, dt, u)  # noqa: F821 - r: the row ref[i]
        finite = saturate(u, v_max, w_max)
        if PROBE:  # noqa: F821
            if probe.after_law is not None:  # noqa: F821
                probe.after_law(k, p, s, theta, P, q_hat, u)  # noqa: F821
        if KEEP:  # noqa: F821
            z_log[k, :] = z
            qhat_log[k, :] = q_hat
            u_log[k, :] = u
            s_log[k, :] = s[: s_log.shape[1]]
        if not finite:
            status[0] = k
            status[1] = 1
            return True
        plant_half(k, dt, integrator, u, ua, q, disturbance, plant_arrays, vel_log)  # noqa: F821
        if use_ekf:  # the filter predicts with the commanded u: it knows no delay, disturbance
            pose_predict(q_hat, Pq, u, dt, integrator, Qp, work)  # or true plant
        if KEEP:  # noqa: F821
            q_log[k + 1, :] = q
        row_into(ref, i + 1, r)  # the row ref[i + 1]: scored now, the next step's reference
        cause = score(k, dt, q, r, u, acc, t_tail, bound)
        if cause != 0:
            status[0] = k + 1
            status[1] = cause
            return True
    return False


def _plant_template(k, dt, integrator, u, ua, q, disturbance, plant_arrays, vel_log):
    """The plant half of step ``k`` (phase 3): the saturated command ``u`` is delayed
    (``wmr.robots.plant.delayed``), disturbed (:func:`disturb`) into ``ua`` and drives the true
    robot over ``[t_k, t_k + dt]`` -- the ideal unicycle, the parameter table or the Python-level
    ``pyplant`` (``PLANT``, bound per copy as in :func:`_advance_template`).  Mutates ``q`` (the
    true pose) and the plant's arrays ``plant_arrays = (table, at, ints, vel, buffer)``
    (``wmr.robots.plant.arrays``); logs the actual ``(v, w)`` at ``t_k`` into ``vel_log`` when
    ``KEEP``.  (The pose filter's prediction follows it in the loop.)"""
    plant_table, plant_at, plant_ints, plant_vel, plant_buffer = plant_arrays
    ua[0] = u[0]
    ua[1] = u[1]
    if PLANT != PLANT_IDEAL:  # noqa: F821
        if KEEP:  # noqa: F821
            if PLANT == PLANT_PYTHON:  # noqa: F821
                pyplant.velocity(plant_vel)  # noqa: F821
            vel_log[k, 0] = plant_vel[0]  # the actual (v, w) at t_k, before the step
            vel_log[k, 1] = plant_vel[1]
        plant.delayed(ua, plant_ints, plant_buffer)
    disturb(k * dt, ua, disturbance)
    if PLANT == PLANT_IDEAL:  # noqa: F821
        step_into(q, ua, dt, integrator, q)
    elif PLANT == PLANT_TABLE:  # noqa: F821
        plant.apply(k, dt, ua, q, plant_table, plant_at, plant_ints, plant_vel)
    else:
        pyplant.advance(k, ua)  # noqa: F821
        pyplant.pose(q)  # noqa: F821


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


def _bind(name: str, law, plant_kind: int, oracle: bool, *, compiled: bool, keep: bool = False,
          pyplant=None, probe=None):  # fmt: skip
    """``(plant_half, advance)``: copies of the two templates with their globals bound (see
    :func:`_advance_template`); jitted when ``compiled`` (the plant half and the law inlined into
    the loop)."""
    if compiled:
        law = _inlined(law)
    glb = {"law": law, "PLANT": int(plant_kind), "ORACLE": bool(oracle), "KEEP": bool(keep),
           "PROBE": probe is not None, "probe": _Hooks(probe) if probe is not None else _NoProbe,
           "pyplant": pyplant}  # fmt: skip
    half = _copy(_plant_template, f"_plant_{name}", glb)
    if compiled:
        half = njit(inline="always")(half)
    adv = _copy(_advance_template, f"_advance_{name}", {**glb, "plant_half": half})
    return half, (njit(adv) if compiled else adv)


def _inlined(law):
    """The jitted ``law`` recompiled to be inlined into the kernel at numba's IR level (a call
    would pass its parameters, a namedtuple of arrays, by value with their reference counts)."""
    fn = getattr(law, "py_func", None)
    return law if fn is None else njit(inline="always")(fn)


_KERNELS: dict = {}


def _kernel_name(name: str, law, plant_kind: int, oracle: bool, keep: bool = False) -> str:
    """The kernel's qualified name: controller, plant kind, oracle, logs kept, and -- for a law
    defined outside ``wmr`` (a plugin) -- a digest of the law's source file, so that numba's
    on-disk cache (keyed by the name) never serves a kernel compiled from an earlier version."""
    suffix = ({PLANT_IDEAL: "", PLANT_TABLE: "_plant"}[plant_kind] + ("_oracle" if oracle else "")
              + ("_keep" if keep else ""))  # fmt: skip
    digest = law_digest(law)
    return f"{name.replace('-', '_')}{suffix}" + (f"_{digest}" if digest else "")


def kernel(name: str, law, plant_kind: int = PLANT_IDEAL, oracle: bool = False,
           keep: bool = False):  # fmt: skip
    """The loop compiled for one controller ``law`` and plant kind (``PLANT_IDEAL`` or
    ``PLANT_TABLE``; cached on disk), logging a trajectory when ``keep``.

    Each (controller, plant kind, oracle, keep) gets its own copy of the templates with those
    bound as globals (compile-time constants: the ideal plant's kernel carries no branch of the
    true robot, a kernel without ``keep`` no logging, and no kernel the probe's hooks) and its own
    qualified name, so numba caches one kernel each (a jitted function taking the law as a
    first-class argument cannot be cached reliably).  ``plant_kind`` also accepts a bool,
    ``True`` meaning the ideal plant.
    """
    if isinstance(plant_kind, bool):
        plant_kind = PLANT_IDEAL if plant_kind else PLANT_TABLE
    if plant_kind == PLANT_PYTHON:
        raise ValueError("a Python-level plant runs through the Python driver (python_step)")
    key = (name, law, plant_kind, bool(oracle), bool(keep))
    if key not in _KERNELS:
        _KERNELS[key] = _bind(_kernel_name(name, law, plant_kind, oracle, keep), law, plant_kind,
                              oracle, compiled=True, keep=keep)[1]  # fmt: skip
    return _KERNELS[key]


def python_step(run: Prepared, probe=None, keep: bool = False):
    """The loop of ``run`` as plain Python (the Python driver's copy of
    :func:`_advance_template`), with ``run``'s law, plant and oracle bound, ``probe``'s hooks
    called and the logs written when ``keep``: ``f(p, s, theta, P, k0, k1, ...)`` advances steps
    ``k0 .. k1-1`` (one at a time for the python-control comparator, ``wmr.linear.nlsys``); for the
    probes and what numba cannot compile."""
    c = run.controller
    return _bind(c.name, c.law, run.plant_kind, c.oracle, compiled=False, keep=keep,
                 pyplant=run.pyplant, probe=probe)[1]  # fmt: skip


def plant_step(run: Prepared, keep: bool = False):
    """The plant half of ``run``'s step (:func:`_plant_template`) as plain Python: ``f(k, dt,
    integrator, u, ua, q, disturbance, plant_arrays, vel_log)`` (``vel_log`` written when
    ``keep``), for tests and tools that drive the true robot with given commands."""
    c = run.controller
    return _bind(c.name, c.law, run.plant_kind, c.oracle, compiled=False, keep=keep,
                 pyplant=run.pyplant)[0]  # fmt: skip


_HALVES: dict = {}


def plant_half(plant_kind: int = PLANT_TABLE):
    """The plant half (:func:`_plant_template`) jitted for a compiled plant kind (``PLANT_IDEAL``
    or ``PLANT_TABLE``) without logging: ``f(k, dt, integrator, u, ua, q, disturbance, plant_arrays,
    vel_log)`` (``vel_log`` is not written: any (0, 2) array), callable from Python and inlined into
    jitted callers -- ``wmr.estimation.identify`` replays a log's commands through it, so
    the order delay -> disturbance -> robot is written once, here."""
    if plant_kind not in (PLANT_IDEAL, PLANT_TABLE):
        raise ValueError("a Python-level plant has no compiled plant half (use plant_step)")
    if plant_kind not in _HALVES:
        name = {PLANT_IDEAL: "_plant_half_ideal", PLANT_TABLE: "_plant_half_table"}[plant_kind]
        glb = {"PLANT": int(plant_kind), "KEEP": False, "pyplant": None}
        _HALVES[plant_kind] = njit(inline="always")(_copy(_plant_template, name, glb))
    return _HALVES[plant_kind]


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


#: The logs a run without a trajectory hands the kernel (never written: ``KEEP`` is False).
_NO_LOGS = Logs.empty(0, 0, False)


def _start(run: Prepared, logs: Logs | None) -> None:
    """Score the initial pose at ``t_0`` (and log it)."""
    r0 = run.first_reference()
    q, big = run.q, 1e150  # below it the squares cannot overflow: no warning to silence
    if abs(r0[0]) < big and abs(r0[1]) < big and abs(q[0]) < big and abs(q[1]) < big:
        metrics.accumulate_initial(run.acc, q, r0)
    else:
        with np.errstate(over="ignore", invalid="ignore"):  # extreme scenarios diverge, not warn
            metrics.accumulate_initial(run.acc, run.q, r0)
    if logs is not None:
        logs.q[0] = run.q
        logs.ref[0] = r0


_LOCAL = threading.local()


def _thread_scratch() -> tuple:
    """This thread's kernel buffers (:func:`step_scratch`), made once."""
    scratch = getattr(_LOCAL, "scratch", None)
    if scratch is None:
        scratch = _LOCAL.scratch = step_scratch(REF_COLUMNS)
    return scratch


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
    c = run.controller
    if driver == "compiled":
        advance = kernel(c.name, c.law, run.plant_kind, c.oracle, keep)
    else:
        advance = python_step(run, probe, keep)
    _start(run, logs)
    if logs is None:
        logs = _NO_LOGS
    # the thread's noise buffer only for the kernel: Python code run by the Python driver (a
    # controller that simulates inside its step) could start another run on this thread
    # the kernel's buffers: this thread's, zeroed for each call as if made afresh (the kernel
    # borrows them, so they are owned here, see the template); the Python driver's are made by
    # each call (Python code run by it could start another run on this thread)
    scratch = _thread_scratch() if driver == "compiled" else None
    for k0, k1, ref, noise in run.chunks(reuse=driver == "compiled"):
        if scratch is not None:
            for buf in scratch:
                buf.fill(0.0)
        advance(
            run.p, run.s, run.theta, run.P, k0, k1, sc.dt, run.integrator, run.q, run.q_hat,
            ref, noise, run.use_ekf, run.Pq, run.Qp, run.Rp, run.disturbance,
            sc.limits.v_max, sc.limits.w_max, sc.divergence_bound,
            run.plant_table, run.plant_at, run.plant_ints, run.plant_vel, run.plant_buffer,
            run.acc, metrics.TRANSIENT, run.status, logs.q, logs.q_hat, logs.u, logs.state,
            logs.vel, logs.z, scratch,
        )  # fmt: skip
        if keep:
            logs.ref[k0 + 1 : k1 + 1] = ref[1:]
        if run.status[0] >= 0:
            break
