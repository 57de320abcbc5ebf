"""wmr: adaptive trajectory tracking of wheeled mobile robots.

The names most scripts need, importable from the package itself (``from wmr import simulate``).
Importing ``wmr`` compiles and starts nothing: each name is imported from its module on first
use.

- scenarios: :func:`load` (a TOML file), :func:`loads`, :func:`builtin` (a shipped scenario's
  path), :class:`Scenario`, :class:`ScenarioError`;
- one run: :func:`simulate` -> :class:`RunResult`;
- controllers: :class:`Controller` (a compiled law), :class:`PyController` (a Python-level one),
  :class:`ControllerStopped`, :func:`njit` (wmr's JIT decorator for laws), :mod:`plugins`;
- true robots: :class:`PyPlant` (the interface of a Python-level robot);
- many runs: :class:`Job`, :func:`run_jobs`.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "load": ("wmr.scenario", "load"),
    "loads": ("wmr.scenario", "loads"),
    "builtin": ("wmr.scenario", "builtin"),
    "Scenario": ("wmr.scenario", "Scenario"),
    "ScenarioError": ("wmr.scenario", "ScenarioError"),
    "simulate": ("wmr.closedloop.sim", "simulate"),
    "RunResult": ("wmr.closedloop.result", "RunResult"),
    "Controller": ("wmr.controllers", "Controller"),
    "PyController": ("wmr.controllers", "PyController"),
    "ControllerStopped": ("wmr.controllers", "ControllerStopped"),
    "njit": ("wmr._jit", "njit"),
    "PyPlant": ("wmr.robots.pyplant", "PyPlant"),
    "Job": ("wmr.engine.study", "Job"),
    "run_jobs": ("wmr.engine.study", "run_jobs"),
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'wmr' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
