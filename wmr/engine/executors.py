"""The execution engines: the one way work leaves this process (serial, or Dask distributed).

- ``workers=1`` (no scheduler): :class:`SerialEngine`, everything in this process;
- otherwise :class:`DaskEngine` on Dask distributed: a ``LocalCluster`` of ``workers`` worker
  processes (one thread each), or an existing cluster (``scheduler="tcp://host:port"``).

An engine runs ``fn(item)`` for batches of items (:meth:`Engine.map_batches`) under **explicit
task keys**, through a **bounded submission window** (a few batches per worker in flight, so a
sweep of any size never floods the scheduler), and **retries** a batch that failed with a
transient error (``wmr.engine.faults``: a worker killed, MemoryError, OSError) up to
``faults.RETRIES`` times, under a new key each time; then ``faults.RetriesExhausted``.
Any other exception of a batch propagates at once (the job functions turn a run's own errors
into rows where the caller keeps them).  A worker lost mid-batch is first rescheduled by Dask
itself (up to ``distributed.scheduler.allowed-failures`` times, then ``KilledWorker``, one
transient failure here).  :meth:`Engine.run_everywhere` calls a function in every worker
process and here (the kernels' warm-up; files a plugin needs).
"""

from __future__ import annotations

import gc
import logging
import os
from collections.abc import Callable, Iterator, Sequence

from wmr.engine import faults

__all__ = ["Engine", "SerialEngine", "DaskEngine", "engine", "default_workers", "run_batch",
           "WINDOW_PER_WORKER", "WORKER_ENV", "LOCAL_CLUSTER_CONFIG"]  # fmt: skip

log = logging.getLogger("wmr.engine")

#: Batches in flight per worker (the submission window).
WINDOW_PER_WORKER = 3
#: Environment of Dask worker processes: one BLAS thread each (a process per core already).
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

#: Dask configuration under which a ``LocalCluster`` starts its workers.  Dask's nanny sets
#: ``MALLOC_TRIM_THRESHOLD_=65536`` in a worker's environment before it starts; with any such
#: setting glibc stops adapting its mmap threshold, so every large numpy array becomes a fresh
#: mmap (page faults on each allocation): numpy-heavy code measured 3-4x slower in such a
#: worker than in the driver, and the sweep's set-up per run (the reference's columns) with it.
#: ``None`` leaves glibc's default (docs/scaling.md: the same for a nanny on a real cluster).
#: The rest quiets the machinery's own clocks, which a batch sweep does not need: the workers'
#: statistical profiler (a stack sample every 10 ms), the event-loop health tick (20 ms), the
#: system and memory monitors (0.5 s, 0.1 s).  Measured on an idle 2-worker cluster: 9 % of a
#: core with Dask's defaults, 1.5 % with these (``analysis.performance.sweep.idle_cost``), capacity
#: that a machine of two cores gives back to the runs.
LOCAL_CLUSTER_CONFIG = {
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.memory.monitor-interval": "1s",
}


def run_batch(fn: Callable, items: Sequence) -> list:
    """``[fn(item) for item in items]``: the unit of work sent to a worker, with Python's cyclic
    garbage collector paused for the batch (the runs' objects are freed by their reference
    counts; a batch's results, kept until it returns, would otherwise trigger full collections
    over every object of the worker, a tenth of its time in a sweep of short runs)."""
    paused = gc.isenabled()
    gc.disable()
    try:
        return [fn(item) for item in items]
    finally:
        if paused:
            gc.enable()


def default_workers() -> int:
    """Worker processes by default: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class Engine:
    """Runs ``fn(item)`` for batches of items and yields the results as they complete.

    Attributes
    ----------
    workers : int
        Worker processes (1 for the serial engine).
    parallel : bool
        Whether batches leave this process (then the kernels are warmed up everywhere first).
    retries : int
        Retries of a batch that failed with a transient error.
    retried : int
        Batches retried so far after a transient error.
    costs : dict
        Seconds per step of each ``(controller, plant is ideal)`` whose kernel this engine's
        workers have loaded (filled by ``wmr.engine.driver``; reused by later calls).
    """

    workers: int = 1
    name: str = "engine"
    parallel: bool = False

    def __init__(self, retries: int = faults.RETRIES):
        self.retries = int(retries)
        self.retried = 0
        self.costs: dict = {}

    def map_batches(self, fn: Callable, batches: Sequence[Sequence], keys: Sequence[str]
                    ) -> Iterator[tuple[int, list]]:  # fmt: skip
        """Yield ``(batch index, [fn(item) for item in batch])`` in completion order."""
        raise NotImplementedError

    def run_everywhere(self, fn: Callable, *args) -> None:
        """Call ``fn(*args)`` in every worker process (and here)."""
        fn(*args)

    def _failed(self, key: str, runs: int, attempt: int, err: BaseException) -> None:
        """After a batch's ``attempt``-th failure (counting from 1): raise if ``err`` is not
        transient or the retries are spent; else note the retry."""
        if not faults.is_transient(err):
            raise err
        if attempt > self.retries:
            raise faults.RetriesExhausted(key, runs, attempt, err) from err
        self.retried += 1
        log.warning("wmr: batch %s failed with a transient error (%s): attempt %d of %d",
                    key, faults.describe(err), attempt + 1, self.retries + 1)

    def close(self) -> None:
        """Release the workers."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class SerialEngine(Engine):
    """Everything in this process, batch after batch, in order."""

    name = "serial"

    def map_batches(self, fn, batches, keys):
        for i, batch in enumerate(batches):
            attempt = 0
            while True:
                try:
                    result = run_batch(fn, batch)
                    break
                except Exception as err:  # noqa: BLE001 - sorted by Engine._failed
                    attempt += 1
                    self._failed(keys[i], len(batch), attempt, err)
            yield i, result


class DaskEngine(Engine):
    """Dask distributed: a ``LocalCluster`` of ``workers`` processes, or the cluster at
    ``scheduler`` (its workers must import the same ``wmr``)."""

    parallel = True

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 retries: int = faults.RETRIES):  # fmt: skip
        import dask
        from distributed import Client, LocalCluster

        super().__init__(retries)
        self.cluster = None
        if scheduler:
            self.client = Client(scheduler, set_as_default=False)
            self.name = f"dask scheduler {scheduler}"
        else:
            n = default_workers() if workers is None else int(workers)
            with dask.config.set(LOCAL_CLUSTER_CONFIG):
                self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                            dashboard_address=":0", silence_logs=logging.ERROR,
                                            env=dict(WORKER_ENV))  # fmt: skip
            self.client = Client(self.cluster, set_as_default=False)
            self.name = f"dask LocalCluster ({n} worker processes)"
        from wmr.engine.plugins_dask import ship

        ship(self.client)  # the driver's plugin controllers, on every worker (DESIGN §3.8)
        self.workers = max(1, len(self.client.scheduler_info(n_workers=-1)["workers"]))

    def map_batches(self, fn, batches, keys):
        from distributed import as_completed

        window = max(1, WINDOW_PER_WORKER * self.workers)
        pending = iter(range(len(batches)))
        index: dict[str, int] = {}
        attempts = [0] * len(batches)

        live: dict = {}  # key -> future, until its result is taken

        def submit(i):
            key = keys[i] if not attempts[i] else f"{keys[i]}-retry{attempts[i]}"
            fut = self.client.submit(run_batch, fn, batches[i], key=key, pure=False)
            index[fut.key], live[fut.key] = i, fut
            return fut

        try:
            first = [submit(i) for _, i in zip(range(window), pending, strict=False)]
            done = as_completed(first, loop=self.client.loop)
            for fut in done:
                i = index.pop(fut.key)
                del live[fut.key]
                try:
                    result = fut.result()
                except Exception as err:  # noqa: BLE001 - sorted by Engine._failed
                    fut.release()
                    attempts[i] += 1
                    self._failed(keys[i], len(batches[i]), attempts[i], err)
                    done.add(submit(i))
                    continue
                fut.release()
                nxt = next(pending, None)
                if nxt is not None:
                    done.add(submit(nxt))
                yield i, result
        finally:  # stopped early (an error, an interrupt): nothing left running for nothing
            if live:
                self.client.cancel(list(live.values()))

    def run_everywhere(self, fn, *args):
        fn(*args)
        self.client.run(fn, *args)

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def engine(workers: int | None = None, scheduler: str | None = None,
           retries: int = faults.RETRIES) -> Engine:  # fmt: skip
    """The engine for ``workers`` processes (``1``: serial in this process; None: the usable
    cores) or for the Dask cluster at ``scheduler``; ``retries`` of a batch that failed with a
    transient error."""
    if scheduler:
        return DaskEngine(scheduler=scheduler, retries=retries)
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise ValueError(f"workers must be >= 1, got {n}")
    return SerialEngine(retries) if n == 1 else DaskEngine(workers=n, retries=retries)
