"""The suite's closed loop as a python-control discrete-time nonlinear system (``nlsys``).

``closed_loop(scenario, controller, seed)`` wraps the step of ``wmr.closedloop.step`` -- the same
jitted
phases the kernel is built from, called in the kernel's order -- as the update function of a
``control.NonlinearIOSystem`` with sample time ``dt``, so that the loop can be stepped by
``control.input_output_response`` or connected to other python-control systems (a reference
generator, a noise model) through its inputs.  Nothing of the step is written here: the update
function unpacks the loop's state from the nlsys state vector and runs the loop for that one step
(``wmr.closedloop.step.python_step``: sense, law, saturate, disturb, plant, pose-filter prediction,
in the kernel's order, the oracle's true pose included), so its trajectory is
``wmr.closedloop.sim.simulate``'s, bit for bit (``tests/test_nlsys.py``).

Signals (python-control's names in brackets)

- state ``x`` (1-D, :class:`Layout`): the true pose ``q`` (3) [``q[i]``], its estimate ``q_hat``
  (3) [``q_hat[i]``], the pose filter's covariance ``Pq`` (3 x 3, row-major) [``Pq[i]``], the
  controller's state ``s`` [``s[i]``], flat weight vector ``theta`` (n) [``theta[i]``] and its
  covariance ``P`` (n x n, row-major) [``P[i]``];
- input ``u_k`` (8): the measurement noise ``n_k`` (3) [``noise[i]``] added to the pose, and the
  reference row at ``t_k`` [``x_r, y_r, theta_r, v_r, w_r``] (``docs/conventions.md``);
- output ``y_k``: the true pose ``q_k`` [``x, y, theta``] (m, m, rad).

The step index is ``k = round(t / dt)``: it selects the disturbance windows and the first-step
rule of ``sense`` (at ``k = 0`` the estimate is the measurement and ``Pq = Rp``).  The
controller's packed parameters ``p`` (and the scratch arrays in them) are constants of the
system, not states.

What the nlsys does not do is score the run: ``simulate`` also stops a run whose pose becomes
non-finite or leaves ``divergence_bound``; the nlsys goes on, so compare the two up to
``diverged_at``.  A non-finite command, where the kernel stops, makes the next state NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from wmr.closedloop import metrics
from wmr.closedloop import step as loop
from wmr.scenario import Scenario

__all__ = ["INPUTS", "OUTPUTS", "Layout", "ClosedLoop", "closed_loop", "inputs", "update_function"]

#: Input names: the measurement noise (3) and the reference row (5) at ``t_k``.
INPUTS: tuple[str, ...] = ("noise[0]", "noise[1]", "noise[2]", "x_r", "y_r", "theta_r", "v_r",
                           "w_r")  # fmt: skip
#: Output names: the true pose ``q_k``.
OUTPUTS: tuple[str, ...] = ("x", "y", "theta")

_POSE = 3  # q, q_hat
_PQ = 9  # the pose filter's covariance, 3 x 3


@dataclass(frozen=True)
class Layout:
    """Where the loop's state sits in the nlsys state vector ``x``.

    ``x = [q (3), q_hat (3), Pq (9), s (n_s), theta (n_theta), P (n_theta**2)]``, matrices
    row-major.

    Attributes
    ----------
    n_s : int
        Length of the controller's small state ``s``.
    n_theta : int
        Length of its flat weight vector ``theta`` (0 without a network).
    """

    n_s: int
    n_theta: int

    @property
    def n_states(self) -> int:
        """Length of ``x``."""
        return 2 * _POSE + _PQ + self.n_s + self.n_theta * (1 + self.n_theta)

    def split(self, x: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(q, q_hat, Pq, s, theta, P)``: views into ``x`` (shapes (3,), (3,), (3, 3),
        (n_s,), (n_theta,), (n_theta, n_theta)); writing them writes ``x``."""
        i_s = 2 * _POSE + _PQ
        i_theta = i_s + self.n_s
        i_P = i_theta + self.n_theta
        return (x[0:_POSE], x[_POSE : 2 * _POSE], x[2 * _POSE : i_s].reshape(3, 3),
                x[i_s:i_theta], x[i_theta:i_P],
                x[i_P:].reshape(self.n_theta, self.n_theta))  # fmt: skip

    def pack(self, q, q_hat, Pq, s, theta, P) -> np.ndarray:
        """The state vector ``x`` of the loop's state (copies)."""
        parts = (q, q_hat, Pq, s, theta, P)
        return np.concatenate([np.asarray(a, dtype=float).ravel() for a in parts])

    def labels(self) -> list[str]:
        """python-control's state names, in the order of ``x``."""
        n = self.n_theta
        blocks = (("q", _POSE), ("q_hat", _POSE), ("Pq", _PQ), ("s", self.n_s),
                  ("theta", n), ("P", n * n))  # fmt: skip
        return [f"{name}[{i}]" for name, size in blocks for i in range(size)]


@dataclass(frozen=True)
class ClosedLoop:
    """One run of the loop as a python-control system and the inputs ``simulate`` would see.

    Attributes
    ----------
    system : control.NonlinearIOSystem
        The discrete-time closed loop (sample time ``dt``).
    T : ndarray, shape (N + 1,)
        The instants ``t_0 .. t_N`` [s].
    U : ndarray, shape (8, N + 1)
        The inputs at those instants (:func:`inputs`).
    X0 : ndarray, shape (layout.n_states,)
        The initial state (initial pose, the controller's packed state).
    layout : Layout
        Where each part of the loop's state sits in ``x``.
    """

    system: Any
    T: np.ndarray
    U: np.ndarray
    X0: np.ndarray
    layout: Layout

    def response(self):
        """``control.input_output_response(system, T, U, X0)``: its ``states`` hold
        ``x_0 .. x_N`` and its ``outputs`` the true poses ``q_0 .. q_N`` (``simulate``'s ``q``)."""
        import control as ct

        return ct.input_output_response(self.system, self.T, self.U, self.X0)


def closed_loop(scenario: Scenario, controller: str, seed: int | None = None, *, settings=None,
                name: str | None = None) -> ClosedLoop:  # fmt: skip
    """The closed loop of ``controller`` on ``scenario`` as a python-control ``nlsys``.

    Parameters
    ----------
    scenario, controller, seed, settings
        As for ``wmr.closedloop.sim.simulate``: the noise in ``U`` and the controller's initial
        state in
        ``X0`` are those of ``simulate`` with the same arguments.
    name : str, optional
        The system's name (default ``"<controller>-closed-loop"``).

    Returns
    -------
    ClosedLoop
        ``system``, the inputs ``T``, ``U``, the initial state ``X0`` and the state ``layout``;
        ``ClosedLoop.response()`` steps it over the scenario.
    """
    import control as ct

    if not scenario.plant.ideal:
        raise ValueError(f"{scenario.name}: the python-control loop models the ideal plant only "
                         "(the true robot's state would live outside the nlsys state)")
    run = loop.prepare(scenario, controller, seed, settings)
    layout = Layout(n_s=run.s.size, n_theta=run.theta.size)
    system = ct.nlsys(update_function(run, layout), _output, dt=scenario.dt,
                      states=layout.labels(), inputs=list(INPUTS), outputs=list(OUTPUTS),
                      name=name or f"{controller}-closed-loop")  # fmt: skip
    X0 = layout.pack(run.q, run.q_hat, run.Pq, run.s, run.theta, run.P)
    T, U = inputs(run)
    return ClosedLoop(system=system, T=T, U=U, X0=X0, layout=layout)


def inputs(run: loop.Prepared) -> tuple[np.ndarray, np.ndarray]:
    """``(T, U)``: the instants ``t_0 .. t_N`` and the inputs at them, from ``run``'s streams.

    ``U[0:3, k]`` is the measurement noise of step ``k`` and ``U[3:8, k]`` the reference row at
    ``t_k``, drawn exactly as the kernel draws them (``Prepared.chunks``; this consumes the run's
    noise stream).  The noise column at ``t_N`` is zero: python-control evaluates one update
    after the last stored state, and its result is discarded.
    """
    refs, noises = [], []
    for k0, _, ref, noise in run.chunks():
        refs.append(ref if k0 == 0 else ref[1:])
        noises.append(noise)
    noises.append(np.zeros((1, 3)))
    U = np.vstack((np.vstack(noises).T, np.vstack(refs).T))
    return np.arange(run.n_steps + 1) * run.dt, U


def update_function(run: loop.Prepared, layout: Layout):
    """The nlsys update ``f(t, x, u, params) -> x_next`` of ``run``'s loop (see the module).

    The state handed in is not modified (python-control stores it): ``f`` works on a copy.  The
    loop's scoring runs too, into scratch accumulators: its verdict is not the nlsys's (the
    module's last paragraph), but a non-finite command makes the next state NaN.
    """
    sc = run.scenario
    advance = loop.python_step(run)
    dt, p, integrator = sc.dt, run.p, run.integrator
    v_max, w_max, bound = sc.limits.v_max, sc.limits.w_max, math.inf
    scratch = loop.step_scratch(loop.REF_COLUMNS)  # the kernel's buffers
    acc, status, none = np.zeros(metrics.N_ACC), np.zeros(2, dtype=np.int64), np.zeros((0, 0))

    def update(t, x, u, params=None):
        x = x.copy()
        q, q_hat, Pq, s, theta, P = layout.split(x)
        k = round(t / dt)
        ref = np.vstack((u[3:8], u[3:8]))  # the row at t_k (the second is only scored)
        stopped = advance(p, s, theta, P, k, k + 1, dt, integrator, q, q_hat, ref,
                          u[0:3].reshape(1, 3), run.use_ekf, Pq, run.Qp, run.Rp,
                          run.disturbance, v_max, w_max, bound, run.plant_table, run.plant_at,
                          run.plant_ints, run.plant_vel, run.plant_buffer, acc,
                          metrics.TRANSIENT, status, *(none,) * 6, scratch)  # fmt: skip
        if stopped and status[1] == 1:
            x[:] = np.nan  # the kernel stops the run here
        return x

    return update


def _output(t, x, u, params=None) -> np.ndarray:
    """The true pose ``q_k``: the first three states."""
    return x[0:_POSE]
