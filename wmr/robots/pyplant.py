"""Python-level true robots (DESIGN §3.7, §4): the plant half of the step run from Python.

The compiled kernel drives the built-in plants of ``wmr.robots.plant`` (the ideal unicycle and the
parameter table: gains, coupling, lag, slip, the lagged velocity loop).  A robot numba cannot
compile -- a physics engine such as MuJoCo (``model = "mujoco"``), or a user's own -- is a
:class:`PyPlant`, and its runs go through the loop's Python driver
(``wmr.closedloop.step.python_step``), which calls, at every control step ``k``, after the command
was saturated, delayed and disturbed:

1. ``velocity(vel)`` -- only when the run is logged: the actual body velocities ``(v, w)`` at
   ``t_k``, before the step, into ``vel`` (2,) [m/s, rad/s];
2. ``advance(k, a)`` -- hold the command ``a = (v, w)`` (2,) over ``[t_k, t_k + dt]`` (the
   robot's own input map, its ``[[plant.change]]`` events in force at ``t_k``);
3. ``pose(q)`` -- write the true pose at ``t_{k+1}`` into ``q`` (3,) [m, m, rad], the heading
   unwrapped (continuous).

``reset(q0)`` puts the robot at rest at ``q0`` at ``t = 0`` (``wmr.closedloop.step.prepare`` calls
it).
Delay and disturbance stay in the loop (``wmr.robots.plant.delayed``,
``wmr.closedloop.step.disturb``), so every robot sees them the same way.

:class:`TablePlant` wraps the built-in step (``wmr.model.kinematics.step`` for the ideal plant,
``wmr.robots.plant.apply`` otherwise) as a PyPlant: the Python driver with it gives the compiled
kernel's numbers bit for bit (a test checks it), which is what makes a PyPlant trustworthy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np

from wmr.model.kinematics import integrator_code, step
from wmr.robots import plant

__all__ = ["PyPlant", "TablePlant", "factory", "MODELS"]


@runtime_checkable
class PyPlant(Protocol):
    """The interface of a Python-level true robot (see the module)."""

    def reset(self, q0: np.ndarray) -> None:
        """Rest at pose ``q0`` (3,) at ``t = 0``."""

    def advance(self, k: int, a: np.ndarray) -> None:
        """Hold the command ``a = (v, w)`` over ``[t_k, t_k + dt]``."""

    def pose(self, q: np.ndarray) -> None:
        """Write the true pose (x, y, theta unwrapped) into ``q`` (3,)."""

    def velocity(self, vel: np.ndarray) -> None:
        """Write the actual body velocities ``(v, w)`` into ``vel`` (2,)."""


class TablePlant:
    """The built-in plant of a scenario (``wmr.robots.plant``) as a :class:`PyPlant` (the same
    jitted step as the kernel's: bit for bit)."""

    def __init__(self, scenario):
        self.dt = scenario.dt
        self.spec = scenario.plant
        self.integrator = integrator_code(scenario.integrator)

    def reset(self, q0):
        self.q = np.array(q0, dtype=float)
        self.table, self.at, self.ints, self.vel, _ = plant.arrays(self.spec, self.dt)

    def advance(self, k, a):
        if self.spec.ideal:
            self.q[:] = step(self.q, a, self.dt, self.integrator)
            self.vel[:] = a
        else:
            plant.apply(k, self.dt, a, self.q, self.table, self.at, self.ints, self.vel)

    def pose(self, q):
        q[:] = self.q

    def velocity(self, vel):
        vel[:] = self.vel


def _mujoco(scenario) -> PyPlant:
    """``model = "mujoco"`` (DESIGN §3.7): the MuJoCo robot of ``[plant.mujoco]`` with the
    scenario's ``[[plant.change]]`` events (mass, centre-of-mass offset, friction)."""
    from wmr.robots.mujoco_robot import MujocoRobot

    spec = scenario.plant
    return MujocoRobot(spec.model_table, scenario.dt, [(c.at, c.values) for c in spec.changes])


#: Plant models driven from Python: ``[plant] model`` -> ``factory(scenario) -> PyPlant``.
MODELS: dict[str, Callable] = {"mujoco": _mujoco}


def factory(spec) -> Callable | None:
    """The PyPlant factory of a ``[plant]`` spec, or None for the built-in (compiled) plants."""
    return MODELS.get(spec.model)
