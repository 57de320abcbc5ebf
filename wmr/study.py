"""Many runs at once: jobs, parallel execution on the local cores, per-run summary rows.

A study is a list of :class:`Job`; :func:`run_jobs` executes them in worker processes (or
serially with ``workers=1``) and returns one :class:`Row` per job in job order.  Each run is
deterministic in its (scenario, controller, settings, seed), so the rows do not depend on the
number of workers.  Only summaries are kept (memory O(jobs), not O(jobs x steps)).
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from typing import Any

from wmr.result import Row
from wmr.scenario import Scenario

__all__ = ["Job", "Row", "run_job", "run_jobs", "default_workers", "ROW_HEADER"]

#: Columns of ``paper/results/rmse.csv``.
ROW_HEADER = Row.CSV_HEADER


@dataclass(frozen=True)
class Job:
    """One run: ``controller`` on ``scenario`` with ``settings`` (None: the scenario's) and
    ``seed``."""

    scenario: Scenario
    controller: str
    seed: int
    variant: str = "default"
    settings: Any = None


def run_job(job: Job) -> Row:
    """Run one job (no trajectory kept) and summarise it."""
    from wmr.sim import simulate

    r = simulate(job.scenario, job.controller, job.seed, settings=job.settings,
                 keep_trajectory=False)  # fmt: skip
    return Row.of(r, job.variant)


def default_workers() -> int:
    """Worker processes by default: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


def _progress(total: int, desc: str, enabled: bool | None):
    from tqdm import tqdm

    if enabled is None:
        enabled = sys.stderr.isatty()
    return tqdm(total=total, desc=desc, disable=not enabled, unit="run", leave=False)


def run_jobs(
    jobs: Sequence[Job],
    workers: int | None = None,
    *,
    progress: bool | None = None,
    desc: str = "runs",
    fn: Callable[[Job], Any] = run_job,
) -> list:
    """Run ``jobs`` with ``fn`` on ``workers`` processes; results in job order.

    ``workers=None`` uses all available cores; ``1`` runs serially in this process.  A progress
    bar is shown on a terminal (``progress=None``), always (True) or never (False).
    """
    workers = default_workers() if workers is None else int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    bar = _progress(len(jobs), desc, progress)
    try:
        if workers == 1 or len(jobs) <= 1:
            out = []
            for job in jobs:
                out.append(fn(job))
                bar.update()
            return out
        chunk = max(1, math.ceil(len(jobs) / (workers * 8)))
        with ProcessPoolExecutor(max_workers=workers) as pool:
            out = []
            for result in pool.map(fn, jobs, chunksize=chunk):
                out.append(result)
                bar.update()
            return out
    finally:
        bar.close()
