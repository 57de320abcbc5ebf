"""The tracking controllers and their registry.

A controller is a pure jitted law plus explicit state (STYLE §7)::

    law(p, s, W, P, q_hat, ref, dt, u) -> None

``p`` are its frozen parameters (float vector), ``s`` its small mutable state (integrals, gains,
previous signals...), ``W`` and ``P`` its weight vector and covariance (empty for controllers
without a network); it writes the input ``(v, w)`` into ``u``.  ``pack(settings, n_steps, dt, rng)``
builds ``(p, s, W, P)`` from the validated settings; the simulator owns and advances them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from types import ModuleType

from wmr.controllers import backstepping

__all__ = ["Controller", "REGISTRY", "NAMES", "get"]


@dataclass(frozen=True)
class Controller:
    """A registered controller: its name, settings class, packer, law and logged state names."""

    name: str
    module: ModuleType
    uses_estimator: bool = False  # True: consumes the pose-EKF estimate by default (the paper's scheme)

    @property
    def Settings(self) -> type:  # noqa: N802 - a class
        return self.module.Settings

    @property
    def pack(self) -> Callable:
        return self.module.pack

    @property
    def law(self) -> Callable:
        return self.module.law

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.module.STATE_NAMES


REGISTRY: dict[str, Controller] = {
    "backstepping": Controller("backstepping", backstepping),
}
#: Controller names in the order tables list them.
NAMES: tuple[str, ...] = tuple(REGISTRY)


def get(name: str) -> Controller:
    """The registered controller ``name``; ``KeyError`` with the known names otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown controller {name!r}; known: {', '.join(NAMES)}") from None
