"""The exception a Python-level controller raises to stop its run with a stated cause.

In a module of its own so that the controller modules (``wmr.controllers.nmpc``) and the
registry (``wmr.controllers``, which imports them) share one class without an import cycle.
"""

from __future__ import annotations

__all__ = ["ControllerStopped"]


class ControllerStopped(RuntimeError):
    """Raised by a :class:`~wmr.controllers.PyController`'s ``step`` to stop the run with a
    stated cause (e.g. an optimiser that failed too often in a row): the run is recorded as
    stopped at that step with ``cause = "controller stopped: <message>"``, like a divergence,
    never as a crash."""
