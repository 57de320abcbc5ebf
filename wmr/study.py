"""Many runs at once: jobs, batches, and the execution engine (serial, or Dask distributed).

A study is a list of :class:`Job`; :func:`run_jobs` executes them and returns one
``wmr.result.Row`` per job in job order.  Each run is deterministic in its (scenario,
controller, settings, seed), so the rows do not depend on the engine, the number of workers or
how the jobs are batched.  Only summaries are kept (memory O(jobs), not O(jobs x steps)).

The engine (:func:`engine`) is the one way work leaves this process:

- ``workers=1`` (no scheduler): :class:`SerialEngine`, everything in this process;
- otherwise :class:`DaskEngine` on Dask distributed: a ``LocalCluster`` of ``workers`` worker
  processes (one thread each), or an existing cluster (``scheduler="tcp://host:port"``).

Work goes out in **batches** (a task costs ~1 ms in Dask and a scheduler slows beyond ~1e6
tasks, so a task must hold seconds of runs), under **explicit task keys**, with **retries**,
through a **bounded submission window** (a few batches per worker in flight, so a sweep of any
size never floods the scheduler).  numba's machine code is not pickled: workers import ``wmr``
and load the kernels from the on-disk cache, which :func:`warm_up` fills in this process first
(so no two workers race to write it).  Progress: a bar on a terminal, plain lines otherwise.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import time
import uuid
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from typing import Any

from wmr.result import Row
from wmr.scenario import Scenario

__all__ = [
    "Job",
    "Row",
    "ROW_HEADER",
    "run_job",
    "run_batch",
    "run_jobs",
    "default_workers",
    "Engine",
    "SerialEngine",
    "DaskEngine",
    "engine",
    "warm_up",
    "Progress",
    "LoopbackCluster",
]

#: Columns of ``paper/results/rmse.csv``.
ROW_HEADER = Row.CSV_HEADER
#: Batches in flight per worker (the submission window).
WINDOW_PER_WORKER = 3
#: Retries of a failed batch (a worker lost mid-batch is rescheduled by Dask besides).
RETRIES = 2
#: Environment of Dask worker processes: one BLAS thread each (a process per core already).
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}

#: Dask configuration under which a ``LocalCluster`` starts its workers.  Dask's nanny sets
#: ``MALLOC_TRIM_THRESHOLD_=65536`` in a worker's environment before it starts; with any such
#: setting glibc stops adapting its mmap threshold, so every large numpy array becomes a fresh
#: mmap (page faults on each allocation): numpy-heavy code measured 3-4x slower in such a
#: worker than in the driver, and the sweep's set-up per run (the reference's columns) with it.
#: ``None`` leaves glibc's default (docs/scaling.md: the same for a nanny on a real cluster).
LOCAL_CLUSTER_CONFIG = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}


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


def run_batch(fn: Callable, items: Sequence) -> list:
    """``[fn(item) for item in items]``: the unit of work sent to a worker."""
    return [fn(item) for item in items]


def default_workers() -> int:
    """Worker processes by default: the cores this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


class Progress:
    """Progress of ``total`` units: a tqdm bar on a terminal, plain lines otherwise (at most one
    per ``every`` seconds, so a log file does not fill with carriage-return bars), or nothing.

    ``enabled=None``: a bar on a terminal, lines otherwise; ``True``: the same; ``False``: off.
    """

    def __init__(self, total: int, desc: str, enabled: bool | None = None, every: float = 10.0,
                 stream=None):  # fmt: skip
        self.total, self.desc, self.every, self.done = total, desc, every, 0
        self.stream = stream if stream is not None else sys.stderr
        self.bar = None
        self.lines = enabled is not False and not _isatty(self.stream)
        if enabled is not False and _isatty(self.stream):
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit="run", leave=False, file=self.stream)
        self.t0 = self.last = time.perf_counter()

    def update(self, n: int = 1) -> None:
        self.done += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.lines:
            now = time.perf_counter()
            if now - self.last >= self.every or self.done >= self.total:
                self.last = now
                self.stream.write(self.line(now) + "\n")
                self.stream.flush()

    def line(self, now: float | None = None) -> str:
        """``desc: done/total runs (p %), r runs/s, ETA s``."""
        elapsed = (time.perf_counter() if now is None else now) - self.t0
        rate = self.done / elapsed if elapsed > 0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else math.inf
        pct = 100.0 * self.done / self.total if self.total else 100.0
        return (f"{self.desc}: {self.done}/{self.total} runs ({pct:.0f} %), {rate:.1f} runs/s, "
                f"ETA {eta:.0f} s")  # fmt: skip

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _isatty(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


# ---------------------------------------------------------------------------------------------
# Engines


class Engine:
    """Runs ``fn(item)`` for batches of items and yields the results as they complete."""

    workers: int = 1
    name: str = "engine"

    def map_batches(self, fn: Callable, batches: Sequence[Sequence], keys: Sequence[str]
                    ) -> Iterator[tuple[int, list]]:  # fmt: skip
        """Yield ``(batch index, [fn(item) for item in batch])`` in completion order."""
        raise NotImplementedError

    def run_everywhere(self, fn: Callable, *args) -> None:
        """Call ``fn(*args)`` in every worker process (and here)."""
        fn(*args)

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
            yield i, run_batch(fn, batch)


class DaskEngine(Engine):
    """Dask distributed: a ``LocalCluster`` of ``workers`` processes, or the cluster at
    ``scheduler`` (its workers must import the same ``wmr``)."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None):
        import dask
        from distributed import Client, LocalCluster

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
        self.workers = max(1, len(self.client.scheduler_info(n_workers=-1)["workers"]))

    def map_batches(self, fn, batches, keys):
        from distributed import as_completed

        window = max(1, WINDOW_PER_WORKER * self.workers)
        pending = iter(range(len(batches)))
        index = {}

        def submit(i):
            fut = self.client.submit(run_batch, fn, batches[i], key=keys[i], retries=RETRIES,
                                     pure=False)  # fmt: skip
            index[fut.key] = i
            return fut

        first = [submit(i) for _, i in zip(range(window), pending, strict=False)]
        done = as_completed(first, loop=self.client.loop)
        for fut in done:
            i = index.pop(fut.key)
            result = fut.result()
            fut.release()
            nxt = next(pending, None)
            if nxt is not None:
                done.add(submit(nxt))
            yield i, result

    def run_everywhere(self, fn, *args):
        fn(*args)
        self.client.run(fn, *args)

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def engine(workers: int | None = None, scheduler: str | None = None) -> Engine:
    """The engine for ``workers`` processes (``1``: serial in this process; None: the usable
    cores) or for the Dask cluster at ``scheduler``."""
    if scheduler:
        return DaskEngine(scheduler=scheduler)
    n = default_workers() if workers is None else int(workers)
    if n < 1:
        raise ValueError(f"workers must be >= 1, got {n}")
    return SerialEngine() if n == 1 else DaskEngine(workers=n)


def warm_up(pairs: Iterable[tuple[Scenario, str]]) -> None:
    """Compile (or load from the disk cache) the loop kernel of each (scenario, controller):
    a one-step run each, so that workers only ever read the cache."""
    from wmr.sim import simulate

    seen = set()
    for sc, controller in pairs:
        key = (controller, sc.plant.ideal)
        if key not in seen:
            seen.add(key)
            simulate(replace(sc, duration=sc.dt), controller, 0, keep_trajectory=False)


def _batches(n: int, workers: int, per_worker: int = 8) -> list[range]:
    """``n`` items in contiguous batches, about ``per_worker`` per worker."""
    size = max(1, math.ceil(n / (workers * per_worker)))
    return [range(a, min(a + size, n)) for a in range(0, n, size)]


def run_jobs(
    jobs: Sequence[Job],
    workers: int | None = None,
    *,
    progress: bool | None = None,
    desc: str = "runs",
    fn: Callable[[Job], Any] = run_job,
    scheduler: str | None = None,
) -> list:
    """Run ``jobs`` with ``fn`` on :func:`engine` ``(workers, scheduler)``; results in job order.

    ``workers=None`` uses all available cores; ``1`` runs serially in this process.  Progress:
    :class:`Progress` (``progress=None``: a bar on a terminal, plain lines otherwise).
    """
    jobs = list(jobs)
    with engine(1 if len(jobs) <= 1 and not scheduler else workers, scheduler) as eng:
        if isinstance(eng, DaskEngine):
            pairs = {(j.controller, j.scenario.plant.ideal): (j.scenario, j.controller)
                     for j in jobs}  # fmt: skip
            eng.run_everywhere(warm_up, list(pairs.values()))
        batches = [[jobs[i] for i in r] for r in _batches(len(jobs), eng.workers)]
        tag = uuid.uuid4().hex[:12]
        keys = [f"wmr-jobs-{tag}-{b}" for b in range(len(batches))]
        out: list = [None] * len(batches)
        bar = Progress(len(jobs), desc, progress)
        try:
            for i, results in eng.map_batches(fn, batches, keys):
                out[i] = results
                bar.update(len(results))
        finally:
            bar.close()
    return [r for batch in out for r in batch]


class LoopbackCluster:
    """A Dask scheduler and ``workers`` worker processes started as separate programs on
    127.0.0.1, as on a real cluster (``dask scheduler`` and ``dask worker``: one process of one
    thread each, no nanny); ``address`` is the scheduler's.  For tests and benchmarks; on a real
    cluster start them by hand (docs/scaling.md).  Use as a context manager."""

    def __init__(self, folder, workers: int = 2, timeout: float = 120.0):
        import json
        import subprocess
        from pathlib import Path

        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        self.file = folder / "scheduler.json"
        env = {**os.environ, **WORKER_ENV}
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL, "env": env}
        py = sys.executable
        self.scheduler = subprocess.Popen(
            [py, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1", "--port", "0",
             "--no-dashboard", "--scheduler-file", str(self.file)], **quiet)  # fmt: skip
        self.workers = []
        try:
            t0 = time.monotonic()
            while not (self.file.exists() and self.file.read_text().strip()):
                if time.monotonic() - t0 > timeout or self.scheduler.poll() is not None:
                    raise RuntimeError("the Dask scheduler did not start")
                time.sleep(0.1)
            self.address = json.loads(self.file.read_text())["address"]
            self.workers = [subprocess.Popen(
                [py, "-m", "distributed.cli.dask_worker", "--scheduler-file", str(self.file),
                 "--nthreads", "1", "--no-nanny", "--no-dashboard", "--host", "127.0.0.1",
                 "--local-directory", str(folder / f"worker-{i}")], **quiet)
                for i in range(workers)]  # fmt: skip
            from distributed import Client

            with Client(self.address, timeout=timeout) as client:
                client.wait_for_workers(workers, timeout=timeout)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
