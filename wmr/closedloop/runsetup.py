"""A run's inputs: :func:`prepare`, set up once per scenario, shared by its seeds and controllers.

:func:`prepare` turns ``(scenario, controller, seed, settings)`` into everything the loop
(``wmr.closedloop.step``) reads: the controller's packed parameters and state, the noise stream, the
pose filter's matrices, which pose the controller acts on, the disturbance arrays, the limits, the
plant.  What depends only on the scenario -- the reference table, the pose filter's matrices, the
noise scale, the disturbance windows, the plant's parameter table, the controller's settings -- is
built once per process and scenario (:data:`SHARED`, keyed by the scenario's parts: a sweep's seeds
and controllers share them) and only read by the runs; each run gets its own mutable state.

The reference is one table of rows ``0 .. N`` per scenario (up to :data:`TABLE_ROWS` rows; a
longer run samples it chunk by chunk); noise is drawn in chunks of :data:`CHUNK` steps into a
buffer reused across chunks and runs (:meth:`Prepared.chunks`), so a run keeps O(1) memory and
its numbers depend neither on how it is split nor on what ran before it in the process.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from wmr import controllers
from wmr._jit import njit
from wmr._shared import SHARED
from wmr.closedloop import metrics
from wmr.closedloop.seeding import generators, seed_sequences
from wmr.model.kinematics import integrator_code
from wmr.model.references import ReferenceSampler
from wmr.robots import plant
from wmr.scenario import Plant, Scenario

__all__ = [
    "CHUNK",
    "TABLE_ROWS",
    "JIT_NOISE_ROWS",
    "draw_noise",
    "PLANT_IDEAL",
    "PLANT_TABLE",
    "PLANT_PYTHON",
    "SHARED",
    "Prepared",
    "prepare",
    "seed_sequences",
    "reference_table",
]

#: Steps simulated per kernel call (noise is drawn per chunk).
CHUNK = 8192
#: From this many steps on, a chunk's noise is drawn by :func:`draw_noise` (compiled, ~4x faster
#: per draw than numpy's ``standard_normal``, but ~10 us to hand it the generator); shorter chunks
#: by numpy.  The two give the same draws, bit for bit (``tests/test_runsetup.py``).
JIT_NOISE_ROWS = 512
#: The longest reference table kept for a scenario (rows: one chunk's, 328 kB): a longer run
#: samples its reference chunk by chunk instead, so its memory does not grow with its length.
TABLE_ROWS = CHUNK + 1
#: What drives the true robot (a compile-time constant of each copy of the loop's step): the
# ideal plant (``wmr.model.kinematics.step`` with the scenario's integrator), the parameter table of
# ``wmr.robots.plant`` (gains, coupling, lag, slip, lagged velocity loop, changes), or a
# Python-level
#: plant (``wmr.robots.pyplant.PyPlant``: the MuJoCo robot, a user's robot).
PLANT_IDEAL, PLANT_TABLE, PLANT_PYTHON = 0, 1, 2


def reference_table(scenario: Scenario) -> np.ndarray | None:
    """The reference rows ``0 .. N`` of ``scenario`` (shape (N + 1, 5); shared: do not write),
    or None when the run is longer than :data:`TABLE_ROWS`.  The longest table asked for is
    kept per reference and sample period; a shorter run reads its first rows (a row depends on
    its ``k`` only: ``wmr.model.references.ReferenceSampler``)."""
    sc = scenario
    rows = sc.n_steps + 1
    if rows > TABLE_ROWS:
        return None
    holder = SHARED.get("reference", (sc.reference,), sc.dt, lambda: [np.empty((0, 5))])
    if holder[0].shape[0] < rows:
        holder[0] = ReferenceSampler(sc.reference.kind, sc.reference.params, sc.dt).rows(0, rows)
    return holder[0]


@dataclass(frozen=True)
class _Fixed:
    """The scenario's shared arrays (read only): pose filter ``Qp``, ``Rp``, noise ``std``,
    disturbance windows, integrator code and ``wmr.robots.plant.arrays`` (table, change times, and
    the
    initial integer state, velocities and delay line, which each run copies)."""

    Qp: np.ndarray
    Rp: np.ndarray
    std: np.ndarray
    disturbance: np.ndarray
    integrator: int
    plant: tuple
    quiet: bool  # the noise cannot overflow (finite std < 1e300): no np.errstate needed


def _fixed(sc: Scenario, python_robot: bool) -> _Fixed:
    """The shared :class:`_Fixed` of ``sc``; with a ``python_robot`` (``wmr.robots.pyplant``) the
    compiled plant's arrays are those of the ideal plant with the scenario's delay line (the loop
    keeps only the delay line of them), unless the scenario's model is itself a compiled one."""

    def build():
        Qp, Rp = sc.estimator.matrices(sc.noise)
        dist = np.array([(x.start, x.stop, *x.velocity) for x in sc.disturbances],
                        dtype=float).reshape(-1, 4)  # fmt: skip
        std = np.array(sc.noise.pose_std)
        quiet = bool(np.all(np.abs(std) < 1e300))  # a normal deviate is far below 1e8
        compiled = (sc.plant if not python_robot or sc.plant.model in plant.MODEL_CODES
                    else Plant(delay_steps=sc.plant.delay_steps))  # fmt: skip
        return _Fixed(Qp, Rp, std, dist, integrator_code(sc.integrator),
                      plant.arrays(compiled, sc.dt), quiet)  # fmt: skip

    parts = (sc.estimator, sc.noise, sc.disturbances, sc.plant)
    return SHARED.get("fixed", parts, (sc.dt, sc.integrator, python_robot), build)


@njit
def draw_noise(rng, std, out):
    """Fill ``out`` (n, 3) with ``std * rng.standard_normal((n, 3))``, row by row: the draws of
    numpy's ``Generator.standard_normal`` (numba's implementation is numpy's ziggurat over the same
    bit generator, whose state it advances), each times its axis' deviation as numpy's broadcast
    multiplies it."""
    for i in range(out.shape[0]):
        for j in range(3):
            out[i, j] = rng.standard_normal() * std[j]


_LOCAL = threading.local()


def _noise_buffer(n: int) -> np.ndarray:
    """This thread's noise buffer, ``n`` (<= :data:`CHUNK`) rows of it: reused across chunks and
    runs (a kernel reads a chunk's noise before the next chunk is drawn)."""
    buf = getattr(_LOCAL, "noise", None)
    if buf is None:
        buf = _LOCAL.noise = np.empty((CHUNK, 3))
    return buf[:n]


@dataclass
class Prepared:
    """The inputs and the mutable state of one run, as the phases read and write them.

    ``p, s, theta, P`` are the controller's parameters, small state, flat weight vector and its
    covariance (``wmr.controllers``); ``q``, ``q_hat`` (3,) the true pose and its estimate;
    ``Pq`` (3, 3) the pose filter's covariance with process and measurement noise ``Qp``, ``Rp``;
    ``use_ekf`` whether the controller acts on the filtered pose; ``disturbance`` the windows
    ``(start, stop, dv, dw)``, one per row; ``plant_*`` the true robot's
    parameter table, change times, integer state, actual velocities and delay line
    (``wmr.robots.plant.arrays``); ``acc`` the RMSE accumulators (``wmr.closedloop.metrics``);
    ``status = (step, cause)`` once the run stopped (``(-1, 0)`` before);
    ``plant_kind`` one of ``PLANT_IDEAL, PLANT_TABLE, PLANT_PYTHON`` and ``pyplant`` the
    Python-level robot (``wmr.robots.pyplant.PyPlant``) of the last kind; ``reference`` the
    scenario's shared reference table (None for a run longer than :data:`TABLE_ROWS`); ``quiet``
    whether the noise cannot overflow (no warnings to silence).  ``Qp``, ``Rp``,
    ``std``, ``disturbance``, ``plant_table``, ``plant_at`` and ``reference`` are shared by the
    scenario's runs (:data:`SHARED`): read only.
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
    reference: np.ndarray | None = None
    quiet: bool = False

    @property
    def dt(self) -> float:
        return self.scenario.dt

    @property
    def n_steps(self) -> int:
        return self.scenario.n_steps

    def chunks(self, ref0: np.ndarray | None = None, *, reuse: bool = False
               ) -> Iterator[tuple[int, int, np.ndarray, np.ndarray]]:  # fmt: skip
        """``(k0, k1, ref, noise)`` for consecutive chunks of at most :data:`CHUNK` steps.

        ``ref`` holds the reference rows ``k0 .. k1`` (one more than the steps: the last row is
        where the step's pose is scored), ``noise`` the measurement noise of steps ``k0 .. k1-1``.
        Fresh arrays by default; with ``reuse`` (the compiled kernel's use: no other run can
        start on this thread before it has read the chunk) ``ref`` is a view of the shared
        table and ``noise`` the thread's buffer, overwritten by the next chunk.
        """
        sc = self.scenario
        n = sc.n_steps
        table = self.reference
        if table is None:
            sampler = ReferenceSampler(sc.reference.kind, sc.reference.params, sc.dt)
            prev = sampler.rows(0, 1)
        for k0 in range(0, n, CHUNK):
            k1 = min(k0 + CHUNK, n)
            if table is not None:
                ref = table[k0 : k1 + 1] if reuse else table[k0 : k1 + 1].copy()
            else:
                ref = np.vstack((prev[-1:], sampler.rows(k0 + 1, k1 + 1)))
                prev = ref
            if reuse and k1 - k0 >= JIT_NOISE_ROWS:
                noise = _noise_buffer(k1 - k0)
                draw_noise(self.rng_noise, self.std, noise)  # no warnings to silence: compiled
            elif reuse:
                noise = _noise_buffer(k1 - k0)
                self.rng_noise.standard_normal(out=noise)
                if self.quiet:
                    np.multiply(noise, self.std, out=noise)
                else:
                    with np.errstate(over="ignore", invalid="ignore"):  # extreme scenarios
                        np.multiply(noise, self.std, out=noise)  # diverge, not warn
            else:
                with np.errstate(over="ignore", invalid="ignore"):
                    noise = self.rng_noise.standard_normal((k1 - k0, 3)) * self.std
            yield k0, k1, ref, noise

    def first_reference(self) -> np.ndarray:
        """The reference row at ``t_0`` (where the initial pose is scored)."""
        if self.reference is not None:
            return self.reference[0].copy()
        sc = self.scenario
        return ReferenceSampler(sc.reference.kind, sc.reference.params, sc.dt).rows(0, 1)[0]


def _settings(scenario: Scenario, controller: str):
    """``scenario.settings(controller)``, shared by the scenario's runs (frozen dataclasses)."""
    row = controllers.get(controller)
    return SHARED.get("settings", (scenario.controllers, row), controller,
                      lambda: scenario.settings(controller))  # fmt: skip


def prepare(scenario: Scenario, controller: str, seed: int | None = None, settings=None,
            robot=None) -> Prepared:  # fmt: skip
    """Everything one run of ``controller`` on ``scenario`` reads, set up once.

    ``seed`` defaults to the scenario's; ``settings`` to the scenario's settings of the
    controller.  ``robot``: a factory ``robot(scenario) -> wmr.robots.pyplant.PyPlant`` that
    replaces the scenario's robot by a Python-level one (default: the scenario's; ``model =
    "mujoco"`` is
    one).  The same inputs give the same ``Prepared``, draw for draw.
    """
    from wmr.robots import pyplant

    ctrl = controllers.get(controller)
    settings = settings if settings is not None else _settings(scenario, controller)
    seed = scenario.seed if seed is None else seed
    # a pack that says it draws nothing (``pack.uses_rng = False``) is handed no generator (its
    # stream is not even made: the noise stream is the first child either way)
    rng_noise, rng_init = generators(seed, getattr(ctrl.pack, "uses_rng", True))
    p, s, theta, P = ctrl.pack(settings, scenario, rng_init)
    make = robot if robot is not None else pyplant.factory(scenario.plant)
    fx = _fixed(scenario, make is not None)
    table, at, ints, vel, buffer = fx.plant
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
        q=np.array(scenario.initial_pose, dtype=float), q_hat=np.zeros(3), Pq=fx.Rp.copy(),
        Qp=fx.Qp, Rp=fx.Rp, use_ekf=scenario.estimator.filters(controller), std=fx.std,
        disturbance=fx.disturbance, integrator=fx.integrator,
        plant_table=table, plant_at=at, plant_ints=ints.copy(), plant_vel=vel.copy(),
        plant_buffer=buffer.copy(), acc=np.zeros(metrics.N_ACC),
        status=np.array([-1, 0], dtype=np.int64), rng_noise=rng_noise,
        plant_kind=kind, pyplant=robot, reference=reference_table(scenario), quiet=fx.quiet,
    )  # fmt: skip
