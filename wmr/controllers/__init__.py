"""The tracking controllers and their registry.

A controller is a pure jitted law plus explicit state (STYLE §7)::

    law(p, s, W, P, q_hat, ref, dt, u) -> None

``p`` are its frozen parameters (a namedtuple or float vector), ``s`` its small mutable state
(integrals, gains, previous signals...), ``W`` and ``P`` its weight vector and covariance (empty
for controllers without a network); it writes the input ``(v, w)`` into ``u``.
``pack(settings, scenario, rng) -> (p, s, W, P)`` builds them from the validated settings (``rng``
initialises network weights); the simulator owns and advances them.  The first
``len(state_names)`` entries of ``s`` are logged along a run.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from wmr.controllers import adaptive_nn, backstepping, iapid_nn_dekf, pid

__all__ = ["Controller", "REGISTRY", "NAMES", "PAPER_NAMES", "get"]


@dataclass(frozen=True)
class Controller:
    """A registered controller."""

    name: str
    Settings: type
    pack: Callable
    law: Callable
    state_names: tuple[str, ...] = ()
    uses_estimator: bool = False  # True: consumes the pose-EKF estimate under pose_source="paper"
    label: str = ""


REGISTRY: dict[str, Controller] = {
    c.name: c
    for c in (
        Controller("iapid-nn-dekf", iapid_nn_dekf.Settings, iapid_nn_dekf.pack,
                   iapid_nn_dekf.law, iapid_nn_dekf.STATE_NAMES, uses_estimator=True,
                   label="IAPID-NN-DEKF"),
        Controller("backstepping", backstepping.Settings, backstepping.pack, backstepping.law,
                   backstepping.STATE_NAMES, label="BSC"),
        Controller("adaptive-nn", adaptive_nn.Settings, adaptive_nn.pack, adaptive_nn.law,
                   adaptive_nn.STATE_NAMES, label="DA-NN"),
        Controller("adaptive-pid", pid.Settings, pid.pack, pid.law, pid.STATE_NAMES,
                   label="APID"),
        Controller("pid", pid.FixedSettings, pid.pack, pid.law, pid.GAIN_NAMES,
                   label="PID (fixed)"),
    )
}  # fmt: skip
#: Controller names in table order.
NAMES: tuple[str, ...] = tuple(REGISTRY)
#: The four controllers of the paper's tables.
PAPER_NAMES: tuple[str, ...] = ("iapid-nn-dekf", "backstepping", "adaptive-nn", "adaptive-pid")


def get(name: str) -> Controller:
    """The registered controller ``name``; ``KeyError`` with the known names otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown controller {name!r}; known: {', '.join(NAMES)}") from None
