"""The one loop that runs many jobs: warm-up, batches, the engine, the store's flushes, progress.

:func:`execute` serves every driver of many runs: ``wmr.engine.study.run_jobs`` (results in job
order), ``wmr sweep`` and the calibration (rows into a ``wmr.engine.store.ShardStore``) and the
studies.  On a parallel engine it first loads every kernel the jobs need in every worker
(``wmr.engine.jobs.warm_up``: numba's machine code is not pickled; workers load it from the
disk cache, which the driver fills first so no two workers race to write it) and measures each
kernel's cost per step (``wmr.engine.batching``), once per engine.  Each job is deterministic in
its inputs, so the results do not depend on the engine, the number of workers or the batching.
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable, Sequence
from typing import Any

from wmr.engine.batching import batches, job_loads, step_costs
from wmr.engine.executors import Engine
from wmr.engine.jobs import Job, kernel_pairs, run_job, warm_up
from wmr.engine.progress import Progress

__all__ = ["execute", "prepare"]


def prepare(eng: Engine, jobs: Sequence[Job]) -> dict | None:
    """On a parallel engine: warm up every kernel of ``jobs`` not yet loaded in its workers and
    measure its cost per step (kept in ``eng.costs``); returns the costs (None on the serial
    engine, where the first run compiles and batches only pace the progress and the flushes)."""
    if not eng.parallel:
        return None
    new = {k: v for k, v in kernel_pairs(jobs).items() if k not in eng.costs}
    if new:
        eng.run_everywhere(warm_up, list(new.values()))
        eng.costs.update(step_costs(new.values()))
    return eng.costs


def execute(jobs: Sequence[Job], eng: Engine, fn: Callable[[Job], Any] = run_job, *,
            store=None, keep: bool = True, batch_seconds: float = 2.0,
            flush_seconds: float = 30.0, progress: bool | None = None, desc: str = "runs",
            tag: str | None = None, stats: dict | None = None) -> list | None:  # fmt: skip
    """Run ``fn(job)`` for every job on ``eng``.

    Parameters
    ----------
    jobs : sequence of wmr.engine.jobs.Job
    eng : wmr.engine.executors.Engine
    fn : callable
        Job -> result (``run_job``: a ``Row``; ``wmr.engine.jobs.job_row``: a store row).
        Module-level, so that it pickles to the workers.
    store : wmr.engine.store.ShardStore, optional
        Where results (rows) are written, as a shard at least every ``flush_seconds`` of work
        and once more at the end, even when the run stops on an error or an interrupt.
    keep : bool
        Return the results in job order (else None: a large sweep keeps nothing in memory).
    batch_seconds : float [s]
        Estimated work per batch (``wmr.engine.batching.batches``; 0: one job per batch).
    flush_seconds : float [s]
    progress : bool or None
        ``wmr.engine.progress.Progress`` (None: a bar on a terminal, lines otherwise).
    desc : str
        The progress label.
    tag : str, optional
        The batches' task keys are ``wmr-<tag>-<first job>-<last job>-<count>`` (default: a
        random tag).
    stats : dict, optional
        Filled with ``batches`` (their count) and ``retries`` (batches retried after a
        transient error).

    Raises
    ------
    wmr.engine.faults.RetriesExhausted
        A batch failed with a transient error on every attempt (what finished is stored).
    """
    jobs = list(jobs)
    stats = {} if stats is None else stats
    stats.update(batches=0, retries=0)
    if not jobs:
        return [] if keep else None
    groups = batches(job_loads(jobs, prepare(eng, jobs)), batch_seconds, eng.workers)
    stats["batches"], retried = len(groups), eng.retried
    tag = tag or uuid.uuid4().hex[:12]

    def name(k: int):
        return jobs[k].job_id if jobs[k].job_id is not None else k

    keys = [f"wmr-{tag}-{name(g[0])}-{name(g[-1])}-{len(g)}" for g in groups]
    out: list = [None] * len(groups)
    bar = Progress(len(jobs), desc, progress)
    buffer: list = []
    last = time.perf_counter()
    try:
        work = [[jobs[k] for k in g] for g in groups]
        for i, results in eng.map_batches(fn, work, keys):
            if keep:
                out[i] = results
            if store is not None:
                buffer.extend(results)
                if time.perf_counter() - last >= flush_seconds:
                    store.write(buffer)
                    buffer, last = [], time.perf_counter()
            bar.update(len(results))
    finally:
        if store is not None:
            store.write(buffer)  # what is complete is kept, even on an error or an interrupt
        bar.close()
        stats["retries"] = eng.retried - retried
    return [r for batch in out for r in batch] if keep else None
