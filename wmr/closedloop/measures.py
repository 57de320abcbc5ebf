"""Measures of a run beyond its RMSEs, for sweeps (``measures = [...]`` in a spec, DESIGN §3.5).

A measure is one row of :data:`MEASURES`: the columns it adds to a sweep's rows and a function
``(run, scenario) -> {column: value}`` of a run made *with* its trajectory.  A sweep that asks
for any measure keeps each run's trajectory in the worker (memory O(steps) per worker, not per
sweep) and stores only the measures' numbers.

- ``jacobian``: the quality of the plant Jacobian the SGD step used
  (``wmr.estimation.identification.jacobian_quality`` against the *true* robot's one-step Jacobian,
  ``wmr.estimation.identification.plant_jacobian``), averaged over the last half of the run, every
  :data:`JACOBIAN_EVERY`-th step; NaN for a controller that uses none (no SGD step) and where the
  true Jacobian is zero (an input delay: the command does not reach the robot within the step).
- ``recovery``: after the first event of the run (a plant change or a disturbance window's
  start, at ``t_c``), the position RMSE over ``[t_c, t_c + RECOVERY_WINDOW)`` and the largest
  position error there; NaN for a run without an event.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["Measure", "MEASURES", "JACOBIAN_EVERY", "RECOVERY_WINDOW", "measure", "event_time"]

#: Steps between evaluations of the Jacobian's quality (an estimate of the run's averages).
JACOBIAN_EVERY = 10
#: Length [s] of the window after an event over which the recovery is measured.
RECOVERY_WINDOW = 5.0
_JACOBIAN_COLUMNS = ("jac_rel_error", "jac_norm_ratio", "jac_sign_v", "jac_sign_w")


@dataclass(frozen=True)
class Measure:
    """A measure: its ``columns`` (float) and ``fn(run, scenario) -> {column: value}``."""

    name: str
    columns: tuple[str, ...]
    fn: Callable


def _jacobian(run, scenario) -> dict:
    from wmr.estimation import identification as idf

    if "J_xv" not in run.state_names:
        return dict.fromkeys(_JACOBIAN_COLUMNS, math.nan)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        q = idf.jacobian_quality(run, idf.plant_jacobian(scenario, run), every=JACOBIAN_EVERY)
        half = slice(len(q.t) // 2, None)
        defined = np.isfinite(q.norm_ratio[half])  # steps where the true Jacobian is not zero
        means = {}
        for key in ("rel_error", "norm_ratio", "sign_v", "sign_w"):
            x = getattr(q, key)[half][defined]
            x = x[np.isfinite(x)]
            means[key] = float(np.mean(x)) if x.size else math.nan
    return {f"jac_{k}": v for k, v in means.items()}


def event_time(scenario) -> float | None:
    """``t_c``: the first plant change or disturbance start of ``scenario`` (None: none)."""
    times = [c.at for c in scenario.plant.changes] + [d.start for d in scenario.disturbances]
    return min(times) if times else None


def _recovery(run, scenario) -> dict:
    t_c = event_time(scenario)
    if t_c is None or run.diverged:
        return {"recovery_rmse": math.nan, "recovery_peak": math.nan}
    window = (run.t >= t_c) & (run.t < t_c + RECOVERY_WINDOW)
    err2 = np.sum((run.ref[window, :2] - run.q[window, :2]) ** 2, axis=1)
    if not err2.size:
        return {"recovery_rmse": math.nan, "recovery_peak": math.nan}
    return {"recovery_rmse": float(np.sqrt(np.mean(err2))),
            "recovery_peak": float(np.sqrt(np.max(err2)))}  # fmt: skip


#: The measures, by name.
MEASURES: dict[str, Measure] = {
    m.name: m
    for m in (
        Measure("jacobian", _JACOBIAN_COLUMNS, _jacobian),
        Measure("recovery", ("recovery_rmse", "recovery_peak"), _recovery),
    )
}


def measure(names, run, scenario) -> dict:
    """The columns of the measures ``names`` for ``run`` of ``scenario`` (NaN if diverged)."""
    out = {}
    for name in names:
        m = MEASURES[name]
        out.update(dict.fromkeys(m.columns, math.nan) if run.diverged else m.fn(run, scenario))
    return out
