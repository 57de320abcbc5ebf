"""Simulate one closed-loop run: ``simulate(scenario, controller, seed) -> RunResult``.

The step and its phases live in ``wmr.closedloop.step`` (DESIGN §3.1, §4); this module prepares a
run, runs the compiled kernel (or, with a ``probe``, the same phases from Python with per-step
hooks), and turns the result into the typed record ``wmr.closedloop.result.RunResult``.

The RMSE of eq. (64) is accumulated on the fly over the true poses ``q_0 .. q_N`` against the
reference at the same instants, so a run keeps O(1) memory unless its trajectory is asked for.
A run stops at the first non-finite value or when the position error exceeds the scenario's
``divergence_bound``; the result records when and why (``diverged_at``, ``cause``).
"""

from __future__ import annotations

import numpy as np

from wmr.closedloop import metrics
from wmr.closedloop import step as loop
from wmr.closedloop.result import RunResult
from wmr.scenario import Scenario

__all__ = ["simulate"]


def simulate(
    scenario: Scenario,
    controller: str,
    seed: int | None = None,
    *,
    settings=None,
    keep_trajectory: bool = True,
    probe=None,
    driver: str | None = None,
    robot=None,
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
    probe : optional
        An object with per-step hooks ``after_estimate(k, q, q_hat, Pq, nis)``,
        ``before_law(k, p, s, theta, P, q_hat)``, ``after_law(k, p, s, theta, P, q_hat, u)``
        (each optional; arrays are live views, copy what you keep): the run goes through the
        Python driver (slower, same numbers).
    driver : {None, "compiled", "python"}
        Which driver runs the step (``wmr.closedloop.step.run``): by default the compiled kernel
        unless the controller, the plant or a probe is Python-level.  Both give the same numbers.
    robot : callable, optional
        ``robot(scenario) -> wmr.robots.pyplant.PyPlant``: drive this Python-level robot instead of
        the
        scenario's (its delay and disturbance still apply).
    """
    run = loop.prepare(scenario, controller, seed, settings, robot=robot)
    n = scenario.n_steps
    logs = loop.Logs.empty(n, len(run.controller.state_names), True) if keep_trajectory else None
    loop.run(run, logs, probe=probe, driver=driver)
    return _result(run, logs)


def _result(run: loop.Prepared, logs: loop.Logs | None) -> RunResult:
    status = run.status
    diverged = bool(status[0] >= 0)
    steps = int(status[0]) if diverged else run.n_steps
    rmse, rmse_rf, rmse_tail, effort = metrics.reduce(run.acc, diverged)
    ctrl = run.controller
    result = RunResult(
        scenario=run.scenario.name, controller=ctrl.name, seed=run.seed, dt=run.dt,
        n_steps=run.n_steps, rmse=rmse, rmse_robot_frame=rmse_rf, rmse_after_transient=rmse_tail,
        effort=effort,
        diverged=diverged, diverged_at=steps * run.dt if diverged else None,
        cause=_cause(run), state_names=ctrl.state_names, settings=run.settings,
        final=ctrl.final_state(run.p, run.s, run.theta, run.P),
        pose_estimate=run.q_hat.copy(), pose_covariance=run.Pq.copy() if run.use_ekf else None,
    )  # fmt: skip
    if logs is not None:
        result.t = np.arange(steps + 1) * run.dt
        result.q = logs.q[: steps + 1]
        result.ref = logs.ref[: steps + 1]
        result.q_hat = logs.q_hat[:steps]
        result.u = logs.u[:steps]
        result.state = logs.state[:steps]
        result.z = logs.z[:steps]
        result.disturbance = _disturbance(run, steps)
        if run.plant_kind != loop.PLANT_IDEAL:
            result.plant_velocity = logs.vel[:steps]
    return result


def _disturbance(run: loop.Prepared, steps: int) -> np.ndarray:
    """The ``(dv, dw)`` in force at ``t_0 .. t_{steps-1}``: the sum over the windows with
    ``start <= t_k < stop``, ``t_k = k dt`` as the loop computes it
    (``wmr.closedloop.step.disturb``)."""
    t = np.arange(steps) * run.dt
    out = np.zeros((steps, 2))
    for start, stop, dv, dw in run.disturbance:
        on = (start <= t) & (t < stop)
        out[on, 0] += dv
        out[on, 1] += dw
    return out


def _cause(run: loop.Prepared) -> str | None:
    """Why the run stopped: the loop's cause, or the message of a Python-level controller that
    stopped it (``wmr.controllers.ControllerStopped``)."""
    stopped = None if run.controller.compiled else run.controller.stopped(run.p)
    if stopped is not None and run.status[0] >= 0:
        return f"controller stopped: {stopped}"
    return loop.CAUSES[int(run.status[1])]
