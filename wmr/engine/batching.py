"""The one batcher: consecutive jobs in batches of about a given amount of work.

A Dask task costs about a millisecond of scheduling and a scheduler slows beyond ~1e6 tasks, so
a task must hold seconds of runs (docs/scaling.md).  A job's work is estimated as its steps
times the measured seconds per step of its (controller, plant kind) (:func:`step_costs`, a short
run in the driver after the kernels are warm); on the serial engine, where batches only pace the
progress bar and the store's flushes, :data:`NOMINAL_STEP_SECONDS` stands in.  Rows never depend
on the batching.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import replace

__all__ = ["NOMINAL_STEP_SECONDS", "COST_STEPS", "step_costs", "job_loads", "batches"]

#: Seconds per step assumed when none was measured (about the IAPID's on one core).
NOMINAL_STEP_SECONDS = 1e-5
#: Steps of the short run that measures a kernel's cost.
COST_STEPS = 500


def step_costs(pairs: Iterable) -> dict[tuple[str, bool], float]:
    """Seconds per step of each ``(scenario, controller)`` on this machine, keyed by
    ``(controller, plant is ideal)``: a run of at most :data:`COST_STEPS` steps each (after the
    warm-up, so no compilation is timed)."""
    from wmr.closedloop.sim import simulate

    out: dict = {}
    for sc, controller in pairs:
        key = (controller, sc.plant.ideal)
        if key not in out:
            short = replace(sc, duration=min(sc.n_steps, COST_STEPS) * sc.dt)
            t0 = time.perf_counter()
            simulate(short, controller, 0, keep_trajectory=False)
            out[key] = (time.perf_counter() - t0) / short.n_steps
    return out


def job_loads(jobs: Iterable, costs: Mapping[tuple[str, bool], float] | None) -> list[float]:
    """Estimated seconds of each job (``wmr.engine.jobs.Job``): its steps times the cost per
    step of its kernel (``costs``; None or a missing kernel: :data:`NOMINAL_STEP_SECONDS`)."""
    costs = costs or {}
    return [j.scenario.n_steps * costs.get((j.controller, j.scenario.plant.ideal),
                                           NOMINAL_STEP_SECONDS) for j in jobs]  # fmt: skip


def batches(loads: Sequence[float], seconds: float, workers: int = 1) -> list[range]:
    """Consecutive items (their estimated ``loads`` [s]) in batches of about ``seconds`` of
    work each, shrinking toward the end (guided scheduling: a batch holds at most a
    ``1 / (2 workers)`` share of the work left, so the last batches are short and no worker idles
    long while another finishes).  A batch is closed before the item that would take it past the
    limit, so a batch is over the limit only when it is one item; ``seconds = 0`` gives one item
    per batch."""
    left = float(sum(loads))
    share = 1.0 / (2 * max(1, int(workers)))
    out, start, acc = [], 0, 0.0
    for i, cost in enumerate(loads):
        if i > start and acc + cost > min(seconds, share * left):
            out.append(range(start, i))
            left -= acc
            start, acc = i, 0.0
        acc += cost
    if len(loads) > start:
        out.append(range(start, len(loads)))
    return out
