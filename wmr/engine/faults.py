"""Which failures are transient, and what happens when their retries run out.

A run's result depends only on its inputs, so an exception a run raises is either part of the
result or an accident of the machine it ran on:

- **transient** (:func:`is_transient`): ``MemoryError``, ``OSError`` (its subclasses included:
  ``ConnectionError``, ``TimeoutError``, Dask's ``CommClosedError``, a full disk, a file a
  worker node cannot read) and Dask's ``KilledWorker`` (the batch's worker process died, more
  often than ``distributed.scheduler.allowed-failures`` allows).  Never stored as a result: the
  batch is run again, up to :data:`RETRIES` more times; then :class:`RetriesExhausted` stops the
  command (exit 1, one line) after what finished is stored, so that the same command resumes.
- **anything else** a run raises (``ValueError``, ``FloatingPointError``, a settings error...)
  would be raised again by the same inputs: a row with ``status = "error"`` where the caller
  keeps error rows (``wmr sweep``, the calibration), otherwise it propagates.
"""

from __future__ import annotations

from wmr._settings import one_line

__all__ = ["RETRIES", "TRANSIENT", "transient_types", "is_transient", "describe",
           "RetriesExhausted"]  # fmt: skip

#: Retries of a batch that failed with a transient error (so at most ``1 + RETRIES`` attempts).
RETRIES = 2
#: The transient exceptions that need no optional import (see :func:`transient_types`).
TRANSIENT: tuple[type[BaseException], ...] = (MemoryError, OSError)


def transient_types() -> tuple[type[BaseException], ...]:
    """:data:`TRANSIENT` and, when Dask distributed is installed, its ``KilledWorker``
    (``CommClosedError`` is an ``OSError``)."""
    try:
        from distributed import KilledWorker
    except ImportError:  # pragma: no cover - distributed is a dependency
        return TRANSIENT
    return (*TRANSIENT, KilledWorker)


def is_transient(err: BaseException) -> bool:
    """Whether ``err`` is an accident of the machine (retried, never a result row)."""
    return isinstance(err, transient_types())


def describe(err: BaseException, limit: int = 300) -> str:
    """``Type: message`` of ``err`` on one line, at most ``limit`` characters."""
    return one_line(f"{type(err).__name__}: {err}")[:limit]


class RetriesExhausted(RuntimeError):
    """A batch failed with a transient error on each of its ``attempts``: the command stops.

    Parameters
    ----------
    batch : str
        The batch's task key.
    runs : int
        Runs in the batch.
    attempts : int
        Attempts made (``1 + RETRIES``).
    last : BaseException
        The last attempt's error.
    """

    def __init__(self, batch: str, runs: int, attempts: int, last: BaseException):
        self.batch, self.runs, self.attempts, self.last = batch, runs, attempts, last
        super().__init__(
            f"a batch of {runs} run{'s' * (runs != 1)} ({batch}) failed {attempts} times with a "
            f"transient error ({describe(last)}); what finished before is stored: run the same "
            "command again to resume")
