"""Job functions that fail on purpose, for the engine's fault tests (tests/test_engine.py).

Each calls the engine's real row (``wmr.engine.jobs.job_row``) and, for the jobs of ``ids``
only, makes the run itself raise (``wmr.closedloop.sim.simulate`` replaced for that one call, in the
process that runs it: the error goes through the row mapping's own handling) or kills the
worker process.  "Once" is kept in a marker file per job in ``folder``, so that it holds across
worker processes (a LocalCluster's workers import this module: they inherit the driver's
``sys.path``).  Bind the arguments with ``functools.partial``, which pickles.
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import wmr.closedloop.sim
from wmr.engine.jobs import job_row

__all__ = ["once", "oserror_once", "exit_once", "oserror_always", "value_error_while"]


@contextlib.contextmanager
def _run_raises(err: BaseException):
    """``wmr.closedloop.sim.simulate`` raises ``err`` inside this block (this process only)."""
    real = wmr.closedloop.sim.simulate

    def failing(*args, **kwargs):
        raise err

    wmr.closedloop.sim.simulate = failing
    try:
        yield
    finally:
        wmr.closedloop.sim.simulate = real


def _row(job, err: BaseException | None):
    if err is None:
        return job_row(job)
    with _run_raises(err):
        return job_row(job)

def once(folder: str, job_id) -> bool:
    """True the first time it is asked about ``job_id`` (a marker file in ``folder``), false
    afterwards, in any process."""
    marker = Path(folder) / f"attempted-{job_id}"
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        return False
    os.close(fd)
    return True


def oserror_once(folder: str, ids: frozenset, job):
    """An ``OSError`` (transient) on the first attempt of each job of ``ids``."""
    hit = job.job_id in ids and once(folder, job.job_id)
    return _row(job, OSError(5, "injected I/O error") if hit else None)


def exit_once(folder: str, ids: frozenset, job):
    """The worker process dies (``os._exit``) on the first attempt of each job of ``ids``."""
    if job.job_id in ids and once(folder, job.job_id):
        os._exit(3)
    return job_row(job)


def oserror_always(ids: frozenset, job):
    """An ``OSError`` on every attempt of each job of ``ids`` (the retries run out)."""
    hit = job.job_id in ids
    return _row(job, OSError(28, "injected: no space left on device") if hit else None)


def value_error_while(cause: str, ids: frozenset, job):
    """A ``ValueError`` (not transient: an error row) for the jobs of ``ids`` while the file
    ``cause`` exists, the true row once it is gone (the cause fixed)."""
    hit = job.job_id in ids and Path(cause).exists()
    return _row(job, ValueError(f"injected: job {job.job_id} cannot run") if hit else None)
