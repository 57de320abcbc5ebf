"""The one job type, and the one mapping of a run to a row.

A :class:`Job` is one closed-loop run: ``controller`` on ``scenario`` with ``settings`` (None:
the scenario's) and ``seed``, plus what its row carries besides the run (``job_id``, the
``labels`` of a sweep's design point or of a calibration task, the ``measures`` to take).
Every driver of many runs (``wmr.engine.study.run_jobs``, ``wmr sweep``, the calibration, the
studies) builds jobs of this type and runs them on the one engine (``wmr.engine.driver.execute``).

The run-to-row mapping is ``wmr.closedloop.result.Row.of`` (the run's RMSEs, after-transient RMSEs,
effort and divergence); :func:`run_job` returns that ``Row``, :func:`job_row` the store's row:
the job's columns, the ``Row``'s result fields (:data:`RESULT_FIELDS`), the measures and
``status``/``error``.  A run that raises a non-transient exception gives an error row
(``status = "error"``, NaN results); a transient one (``wmr.engine.faults``) propagates, to be
retried, and is never a row.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any

from wmr.closedloop.result import Row
from wmr.engine.faults import describe, is_transient
from wmr.scenario import Scenario

__all__ = ["Job", "RESULT_FIELDS", "COLUMNS", "COLUMN_TYPES", "OK", "ERROR", "run_job",
           "job_row", "result_columns", "measure_columns", "kernel_pairs", "warm_up"]  # fmt: skip

#: The fields of ``wmr.closedloop.result.Row`` that describe the run's outcome (not the job).
RESULT_FIELDS = ("rmse_x", "rmse_y", "rmse_theta", "rmse_position", "tail_x", "tail_y",
                 "tail_theta", "tail_position", "effort", "diverged", "diverged_at", "cause")
#: Result columns of a store's row, in the order of DESIGN §3.5.
COLUMNS = (*RESULT_FIELDS, "status", "error")
#: Arrow type names of :data:`COLUMNS` (``pyarrow.<name>()``).
COLUMN_TYPES = {**dict.fromkeys(RESULT_FIELDS[:9], "float64"), "diverged": "bool_",
                "diverged_at": "float64", "cause": "string", "status": "string",
                "error": "string"}  # fmt: skip
OK, ERROR = "ok", "error"
#: Longest error message kept in a row [characters].
ERROR_CHARS = 500

assert set(RESULT_FIELDS) <= {f.name for f in dataclasses.fields(Row)}


@dataclass(frozen=True)
class Job:
    """One run, as sent to a worker (everything it needs, nothing more).

    Attributes
    ----------
    scenario, controller, seed
        The run: ``controller`` (a registry name) on ``scenario`` with noise seed ``seed``.
    variant : str
        The row's variant label (``wmr.closedloop.result.Row.variant``).
    settings
        The controller's settings (None: the scenario's).
    measures : tuple of str
        ``wmr.closedloop.measures.MEASURES`` to take on the run (their columns join the row).
    job_id : int or str or None
        The row's identity in a store (a newer row of the same ``job_id`` supersedes it).
    labels : tuple of (str, value)
        Columns the row carries besides the run's (a sweep's point and factor values, a
        calibration task's key, seed index and case).
    """

    scenario: Scenario
    controller: str
    seed: int
    variant: str = "default"
    settings: Any = None
    measures: tuple[str, ...] = ()
    job_id: int | str | None = None
    labels: tuple[tuple[str, Any], ...] = ()


def _simulate(job: Job, keep_trajectory: bool):
    from wmr.closedloop.sim import simulate  # looked up at call time (tests replace it)

    return simulate(job.scenario, job.controller, job.seed, settings=job.settings,
                    keep_trajectory=keep_trajectory)  # fmt: skip


def run_job(job: Job) -> Row:
    """Run one job (no trajectory kept) and summarise it: ``wmr.closedloop.result.Row.of``.
    Whatever the run raises propagates."""
    return Row.of(_simulate(job, keep_trajectory=False), job.variant)


def result_columns(row: Row) -> dict:
    """The result columns (:data:`RESULT_FIELDS`) of a run's ``Row``."""
    return {name: getattr(row, name) for name in RESULT_FIELDS}


def measure_columns(names: Iterable[str]) -> tuple[str, ...]:
    """Columns the measures ``names`` add to a row (``wmr.closedloop.measures``)."""
    from wmr.closedloop.measures import MEASURES

    return tuple(c for n in names for c in MEASURES[n].columns)


def job_row(job: Job) -> dict:
    """Run ``job`` and return its store row: ``job_id``, the labels, ``scenario``,
    ``controller``, ``seed``, the result columns, the measures' columns, ``status`` and
    ``error``.  A run that raises a non-transient exception is an error row (NaN results,
    ``status = "error"``, the exception's type and message in ``error``); a transient one
    (``wmr.engine.faults.is_transient``) propagates."""
    row = {"job_id": job.job_id, **dict(job.labels), "scenario": job.scenario.name,
           "controller": job.controller, "seed": job.seed}  # fmt: skip
    try:
        r = _simulate(job, keep_trajectory=bool(job.measures))
        extra: Mapping = {}
        if job.measures:
            from wmr.closedloop.measures import measure

            extra = measure(job.measures, r, job.scenario)
        result = result_columns(Row.of(r, job.variant))
    except Exception as err:  # the contract: an error row, the sweep goes on
        if is_transient(err):
            raise
        row.update(dict.fromkeys(RESULT_FIELDS[:9] + measure_columns(job.measures), math.nan),
                   diverged=False, diverged_at=None, cause=None, status=ERROR,
                   error=describe(err, ERROR_CHARS))  # fmt: skip
        return row
    row.update(extra)
    row.update(result, status=OK, error=None)
    return row


def kernel_pairs(jobs: Iterable[Job]) -> dict[tuple[str, bool], tuple[Scenario, str]]:
    """One ``(scenario, controller)`` per compiled kernel the jobs need, keyed by
    ``(controller, plant is ideal)``."""
    out: dict = {}
    for j in jobs:
        out.setdefault((j.controller, j.scenario.plant.ideal), (j.scenario, j.controller))
    return out


def warm_up(pairs: Iterable[tuple[Scenario, str]]) -> None:
    """Compile (or load from the disk cache) the loop kernel of each (scenario, controller):
    a one-step run each, so that workers only ever read the cache."""
    from wmr.closedloop.sim import simulate

    seen = set()
    for sc, controller in pairs:
        key = (controller, sc.plant.ideal)
        if key not in seen:
            seen.add(key)
            simulate(replace(sc, duration=sc.dt), controller, 0, keep_trajectory=False)
