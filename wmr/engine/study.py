"""Many runs at once: :func:`run_jobs`, and the names of the run engine (``wmr.engine``).

A study is a list of :class:`Job`; :func:`run_jobs` executes them on the one engine
(``wmr.engine.driver.execute``) and returns one ``wmr.closedloop.result.Row`` per job in job order.
Each run is deterministic in its (scenario, controller, settings, seed), so the rows do not depend
on the engine, the number of workers or how the jobs are batched.  Only summaries are kept (memory
O(jobs), not O(jobs x steps)).

The engine (:func:`engine`) is the one way work leaves this process: ``workers=1`` (no
scheduler) runs serially here; otherwise Dask distributed, a ``LocalCluster`` of ``workers``
processes or an existing cluster (``scheduler="tcp://host:port"``).  Work goes out in batches of
seconds, under explicit task keys, through a bounded window; a batch that fails with a transient
error (``wmr.engine.faults``: a worker killed, MemoryError, OSError) is retried a bounded number
of times, then ``RetriesExhausted`` stops the call.  This module keeps the names it has always
exported; they live in ``wmr.engine``'s modules.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from wmr.closedloop.result import Row
from wmr.engine.batching import batches
from wmr.engine.cluster import LoopbackCluster
from wmr.engine.driver import execute
from wmr.engine.executors import (
    LOCAL_CLUSTER_CONFIG,
    WINDOW_PER_WORKER,
    WORKER_ENV,
    DaskEngine,
    Engine,
    SerialEngine,
    default_workers,
    engine,
    run_batch,  # fmt: skip
)
from wmr.engine.faults import RETRIES, RetriesExhausted
from wmr.engine.jobs import Job, run_job, warm_up
from wmr.engine.progress import Progress

__all__ = [
    "Job",
    "Row",
    "ROW_HEADER",
    "run_job",
    "run_batch",
    "run_jobs",
    "batches",
    "default_workers",
    "Engine",
    "SerialEngine",
    "DaskEngine",
    "engine",
    "warm_up",
    "Progress",
    "LoopbackCluster",
    "RetriesExhausted",
    "RETRIES",
    "WINDOW_PER_WORKER",
    "WORKER_ENV",
    "LOCAL_CLUSTER_CONFIG",
]

#: Columns of ``paper/results/rmse.csv``.
ROW_HEADER = Row.CSV_HEADER


def run_jobs(
    jobs: Sequence[Job],
    workers: int | None = None,
    *,
    progress: bool | None = None,
    desc: str = "runs",
    fn: Callable[[Job], Any] = run_job,
    scheduler: str | None = None,
    batch_seconds: float = 2.0,
) -> list:
    """Run ``jobs`` with ``fn`` on :func:`engine` ``(workers, scheduler)``; results in job order.

    ``workers=None`` uses all available cores; ``1`` runs serially in this process (so does a
    single job).  ``fn`` (module-level, picklable) maps a job to its result (default: its
    ``Row``); ``batch_seconds`` is the estimated work per batch (0: one job per batch, for jobs
    of seconds each).  Progress: :class:`Progress` (``progress=None``: a bar on a terminal,
    plain lines otherwise).  A job that raises stops the call (after the retries of a transient
    error: ``RetriesExhausted``).
    """
    jobs = list(jobs)
    with engine(1 if len(jobs) <= 1 and not scheduler else workers, scheduler) as eng:
        return execute(jobs, eng, fn, progress=progress, desc=desc, batch_seconds=batch_seconds)
