"""The performance study's measurement of the Python-level controllers (``PyController`` rows,
e.g. ``nmpc``): the cost of their own step with its percentiles, and of the loop around them.

A Python-level controller's run goes through the loop's Python driver and costs ~1-2 s (against
~10 ms for a compiled one), so it is timed on a few full lemniscate runs of its own, not in the
interleaved rounds of the compiled controllers.  A controller that logs its step's wall time as
the signal ``solve_time`` [s] (``nmpc``: the whole ``step``, preview and solve) gets that
signal's distribution pooled over the runs; every one gets the loop's wall and CPU time per step.
"""

from __future__ import annotations

import numpy as np

from analysis.performance.bench import clocks, per_step, steps_done
from wmr import controllers
from wmr.closedloop import sim

__all__ = ["ROUNDS", "STEP_SIGNAL", "names", "measure", "table_lines", "NOTE"]

#: Full lemniscate runs per Python-level controller (quick: 2).
ROUNDS = 3
#: The signal a controller's own step time is read from [s].
STEP_SIGNAL = "solve_time"
_US, _MS = 1e6, 1e3

NOTE = ("python_controllers: each Python-level controller runs through the loop's Python "
        f"driver on {ROUNDS} full lemniscate runs of its own after the warm-up (quick: 2), not "
        "interleaved with the compiled ones. The loop's us_per_step is the whole loop per step "
        "(min over the runs, median beside it). Its step_ms is the distribution of the "
        f"controller's own step, its logged {STEP_SIGNAL!r} (nmpc's preview, solve and "
        "bookkeeping), pooled over every step of the runs.")  # fmt: skip


def names() -> tuple[str, ...]:
    """The registered Python-level controllers, in table order."""
    return tuple(n for n in controllers.NAMES if not controllers.get(n).compiled)


def measure(lem, quick: bool = False) -> dict:
    """``{name: {us_per_step, us_per_step_median, cpu_us_per_step, runs, steps, step_ms}}`` for
    each Python-level controller on the scenario ``lem`` (``step_ms``: ``median``, ``p95``,
    ``max`` [ms], or None without a :data:`STEP_SIGNAL` signal)."""
    out = {}
    for name in names():
        has_signal = STEP_SIGNAL in controllers.get(name).state_names
        walls, cpus, times, steps = [], [], [], 0
        for _ in range(2 if quick else ROUNDS):
            t0 = clocks()
            r = sim.simulate(lem, name, 0, keep_trajectory=has_signal)
            wall, cpu = per_step(t0, steps_done(r))
            walls.append(wall)
            cpus.append(cpu)
            steps += steps_done(r)
            if has_signal:
                times.append(r.signal(STEP_SIGNAL))
        t = np.concatenate(times) * _MS if times else None
        out[name] = {
            "us_per_step": min(walls) * _US, "us_per_step_median": float(np.median(walls)) * _US,
            "cpu_us_per_step": min(cpus) * _US, "runs": len(walls), "steps": steps,
            "step_ms": None if t is None else {"median": float(np.median(t)),
                                               "p95": float(np.percentile(t, 95)),
                                               "max": float(t.max())},
        }  # fmt: skip
    return out


def table_lines(rec: dict) -> list[str]:
    """The Markdown table of :func:`measure`'s record (empty without Python-level controllers)."""
    pcs = rec.get("python_controllers") or {}
    if not pcs:
        return []
    lines = ["| Python-level controller | loop µs/step (min) | loop µs/step (median) "
             "| its step [ms]: median | p95 | max | runs |",
             "|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for name, v in pcs.items():
        s = v["step_ms"] or {"median": float("nan"), "p95": float("nan"), "max": float("nan")}
        lines.append(f"| {name} | {v['us_per_step']:.1f} | {v['us_per_step_median']:.1f} "
                     f"| {s['median']:.3f} | {s['p95']:.3f} | {s['max']:.2f} | {v['runs']} |")
    return lines + [""]
