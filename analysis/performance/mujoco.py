"""The MuJoCo robot's cost for the benchmark (issue 20, item 6).

Two figures, measured as the issue states them:

- **the plant's cost per 10 ms control step**: the shipped lemniscate on the MuJoCo robot
  (``wmr/scenarios/mujoco/lemniscate.toml``), the command sequence of one fixed-PID run replayed
  through :meth:`wmr.robots.mujoco_robot.MujocoRobot.advance` and :meth:`~MujocoRobot.pose`, each
  control step timed on its own (``perf_counter_ns``); the median and the 10th/90th percentiles, at
  the shipped physics step (2 ms, 5 physics steps per control step) and at the robot ladder's 0.5 ms
  (20); beside it the whole run's cost per step through the loop's Python driver (controller, noise,
  the RMSE: everything but compilation);
- **the 2-worker sweep efficiency** of MuJoCo runs: ``analysis.performance.sweep.throughput`` on the
  same scenario (serial engine, a LocalCluster and a loopback scheduler with worker processes),
  rows checked equal across engines.
"""

from __future__ import annotations

import dataclasses
import os
import time

import mujoco
import numpy as np

from analysis.performance import sweep as _sweep_bench
from wmr import scenario as scn
from wmr.closedloop import sim
from wmr.robots.mujoco_robot import MujocoRobot

__all__ = ["SCENARIO", "TIMESTEPS", "plant_cost", "measure"]

#: The shipped scenario the figures are measured on.
SCENARIO = "mujoco/lemniscate"
#: Physics steps [s]: the shipped robot's and the robot ladder's (``analysis.robots.MJ_TIMESTEP``).
TIMESTEPS = (0.002, 0.0005)


def plant_cost(timestep: float, steps: int | None = None, repeats: int = 3) -> dict:
    """Wall µs per control step of the MuJoCo plant alone (``advance`` + ``pose``) at the physics
    step ``timestep`` [s], replaying one fixed-PID run's commands; ``repeats`` replays, every step
    of each timed.  Median and percentiles over all timed steps.

    Beside it, the physics alone: a twin robot in the same state, given the same wheel-speed
    setpoints, timed over its ``mujoco.mj_step`` call only, step by step alternating with the
    plant (which of the two goes first alternates too), so both see the same machine;
    ``python_us`` is the median of the paired differences (the plant's Python around the
    physics), and the load averages at the start and end say how busy the machine was."""
    sc = scn.load(scn.builtin(SCENARIO))
    res = sim.simulate(sc, "pid", keep_trajectory=True)
    u = np.asarray(res.u, dtype=float)[: steps or len(res.u)]
    spec = dataclasses.replace(sc.plant.model_table, timestep=timestep)
    samples, physics = np.empty(repeats * len(u)), np.empty(repeats * len(u))
    q = np.empty(3)
    q0 = np.asarray(sc.initial_pose, dtype=float)
    robot = MujocoRobot(spec, sc.dt)  # the firmware's setpoints of every step, for the twin
    setpoints = np.empty((len(u), robot.model.nu))
    robot.reset(q0)
    for k, a in enumerate(u):
        robot.advance(k, a)
        setpoints[k] = robot.data.ctrl
    load_start = os.getloadavg()[0]
    j = 0
    clock, step = time.perf_counter_ns, mujoco.mj_step
    for _ in range(repeats):
        robot, twin = MujocoRobot(spec, sc.dt), MujocoRobot(spec, sc.dt)
        robot.reset(q0)
        twin.reset(q0)
        m, d, n = twin.model, twin.data, twin.n_sub
        for k, a in enumerate(u):
            for plant_turn in ((True, False) if j % 2 == 0 else (False, True)):
                if plant_turn:
                    t0 = clock()
                    robot.advance(k, a)
                    robot.pose(q)
                    samples[j] = clock() - t0
                else:  # the twin: this step's setpoints as the plant's firmware wrote them
                    d.ctrl[:] = setpoints[k]
                    t0 = clock()
                    step(m, d, n)
                    physics[j] = clock() - t0
            j += 1
        if not np.array_equal(robot.data.qpos, twin.data.qpos):
            raise AssertionError("the twin's physics did not follow the plant's")
    us, ph = samples / 1e3, physics / 1e3
    return {"timestep": timestep, "substeps": robot.n_sub, "control_dt": sc.dt,
            "steps_timed": int(us.size), "median_us": float(np.median(us)),
            "p10_us": float(np.percentile(us, 10)), "p90_us": float(np.percentile(us, 90)),
            "median_us_per_physics_step": float(np.median(us)) / robot.n_sub,
            "physics_median_us": float(np.median(ph)),
            "python_us": float(np.median(us - ph)),
            "load_average": [load_start, os.getloadavg()[0]]}  # fmt: skip


def _run_cost(repeats: int) -> dict:
    """Wall µs per control step of whole fixed-PID runs on the MuJoCo lemniscate through the
    loop's Python driver (best of ``repeats``, after one warm-up run)."""
    sc = scn.load(scn.builtin(SCENARIO))
    sim.simulate(sc, "pid", keep_trajectory=False)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        sim.simulate(sc, "pid", keep_trajectory=False)
        best = min(best, time.perf_counter() - t0)
    return {"controller": "pid", "steps": sc.n_steps, "us_per_step": 1e6 * best / sc.n_steps}


def measure(quick: bool = False, workers: int = 2) -> dict:
    """The record's ``mujoco`` entry: the plant's cost per control step at each of
    :data:`TIMESTEPS`, a whole run's cost per step, and the sweep throughput on ``workers``
    (``None`` with ``quick``)."""
    steps, repeats = (300, 1) if quick else (None, 3)
    out = {"scenario": SCENARIO,
           "plant": [plant_cost(h, steps, repeats) for h in TIMESTEPS],
           "run": _run_cost(1 if quick else 3),
           # quick: no sweep (a few runs would measure the engine's start, not its rate; the
           # engines' equality on MuJoCo rows is tested in tests/test_mujoco_loop.py)
           "sweep": None if quick else _sweep_bench.throughput(
               ("pid",), workers=workers, repeats=2, scenario=SCENARIO, runs={"pid": 48})}
    return out
