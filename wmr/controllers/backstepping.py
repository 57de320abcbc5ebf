"""Backstepping (Kanayama et al. 1990) tracking law, the paper's BSC baseline.

With the tracking error ``e = T_e(theta)(q_r - q)`` of eq. (6)::

    v = v_r cos(e3) + k1 e1
    w = w_r + v_r (k2 e2 + k3 sin(e3))

It is locally exponentially stable for ``k1, k2, k3 > 0`` and ``v_r > 0`` (Lyapunov function
``V = (e1^2 + e2^2)/2 + (1 - cos e3)/k2``); ``k3 = 2 sqrt(k2)`` is critical damping of the
linearised lateral loop.  The paper gives no gains; reproduction-notes §4.1 lists published ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from wmr._jit import njit
from wmr._settings import check
from wmr.model.kinematics import tracking_error_parts

__all__ = ["Settings", "State", "STATE_NAMES", "pack", "final_state", "law", "command"]

#: Controller-state entries logged along a run (none: the law is static).
STATE_NAMES: tuple[str, ...] = ()


@dataclass(frozen=True)
class Settings:
    """Backstepping settings.

    Attributes
    ----------
    gains : tuple of float [1/s, 1/m^2, 1/m]
        ``(k1, k2, k3)``, each > 0.  Default ``(2, 10, 4)``: of the order of
        published values (notes §4.1); damping ``zeta = k3 / (2 sqrt(k2)) = 0.63`` of the
        linearised lateral loop (critical damping would need ``k3 = 2 sqrt(k2) = 6.3``).
    printed_rotation : bool [-]
        Use the paper's printed (wrong) error rotation of eqs. 4/6 instead of the rotation.
    """

    gains: tuple[float, ...] = (2.0, 10.0, 4.0)
    printed_rotation: bool = False

    def __post_init__(self):
        for name, g in zip(("k1", "k2", "k3"), self.gains, strict=True):
            check(math.isfinite(g) and g > 0, "gains", self.gains, f"{name} must be > 0")


def pack(settings: Settings, scenario, rng: np.random.Generator):
    """Parameter vector and initial state: ``p = (k1, k2, k3, printed)``; no state."""
    p = np.array([*settings.gains, float(settings.printed_rotation)])
    return p, np.zeros(0), np.zeros(0), np.zeros((0, 0))


pack.uses_rng = False  # it draws nothing: the loop need not make the initialisation stream


@dataclass(frozen=True)
class State:
    """Backstepping has no controller state: the law is static."""


def final_state(p, s, theta, P) -> State:
    """The (empty) controller state."""
    return State()


@njit(inline="always")
def command(p, e, ref, u):
    """Write Kanayama's command ``u = (v, w)`` for the tracking error ``e = (e1, e2, e3)`` (eq. 6;
    a tuple of scalars or an array) and the reference sample ``ref``, gains ``p[:3]`` (the law
    below, and ``adaptive_bsc``)."""
    v_r = ref[3]
    w_r = ref[4]
    u[0] = v_r * math.cos(e[2]) + p[0] * e[0]
    u[1] = w_r + v_r * (p[1] * e[1] + p[2] * math.sin(e[2]))


@njit
def law(p, s, theta, P, q_hat, ref, dt, u):
    """Write the backstepping input ``u = (v, w)`` for estimate ``q_hat`` and sample ``ref``."""
    command(p, tracking_error_parts(q_hat, ref, p[3] != 0.0), ref, u)
