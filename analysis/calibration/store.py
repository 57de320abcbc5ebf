"""Evaluation of calibration points on the run engine, cached in its shard store.

A :class:`Task` is a list of runs (``Scenario``, controller, settings) over a list of seeds,
named by a deterministic ``key`` (a hash of what defines it); its result is an array of shape
``(seeds, cases, len(METRICS) + 1)`` (:func:`task_array`).  :class:`Evaluator` runs the tasks it
has not seen before as jobs of the one engine (``wmr.engine``: one ``Job`` per run, the engine's
batches, retries and store) and keeps every run's row in a ``wmr.engine.store.ShardStore``:

- ``manifest.json``: the store's digest (:func:`store_digest`: wmr's sources, the calibration's
  own code, the shipped scenario files it reads) and counts;  the fair tuning's held-out runs
  have a store of their own (``<folder>-fair``), whose digest adds the fair tuning's code, so
  that changing it does not set aside the other stages' runs;
- ``rows/part-*.parquet``: immutable shards, one row per (task, seed, run), the engine's row
  (``wmr.engine.jobs.job_row``) with ``job_id = "<key>/<seed index>/<case>"`` and the labels
  ``key``, ``i_seed``, ``case``.

A store of another digest is stale: it is set aside (renamed ``<folder>.stale-<time>``, one
line on stderr) and rebuilt.  Every stage of the study (screening, design, Sobol matrices, the
fit's generations, the fair tuning) goes through :meth:`Evaluator.evaluate`, so an interrupted
study resumes where it stopped: a rerun finds its finished tasks in the store (the fit's
optimiser is seeded, so it asks for the same points again and replays them from the store).
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["METRICS", "COLUMNS", "Task", "task_key", "task_jobs", "task_array", "run_task",
           "Evaluator", "store_digest", "read_store", "KIND"]  # fmt: skip

#: Metrics of a run, in the order of a result's last axis (then ``status``).
METRICS = ("x", "y", "theta", "position", "tail_position", "effort")
#: The engine's row column of each metric.
COLUMNS = ("rmse_x", "rmse_y", "rmse_theta", "rmse_position", "tail_position", "effort")
OK, DIVERGED, ERROR = 0, 1, 2
KIND = "wmr calibration store"


def task_key(spec) -> str:
    """A deterministic name for the task defined by the JSON-able ``spec`` (20 hex digits)."""
    text = json.dumps(spec, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


@dataclass(frozen=True)
class Task:
    """Runs ``cases`` (``(Scenario, controller, settings)``) for every seed of ``seeds``."""

    key: str
    cases: tuple
    seeds: tuple[int, ...]


def task_jobs(task: Task, which: np.ndarray | None = None) -> list:
    """The task's runs as engine jobs, seed-major, ``job_id = "<key>/<i_seed>/<case>"``; only
    those where the (seeds, cases) mask ``which`` is true, if given."""
    from wmr.engine.jobs import Job

    return [Job(sc, c, int(seed), settings=st, job_id=f"{task.key}/{i}/{j}",
                labels=(("key", task.key), ("i_seed", i), ("case", j)))
            for i, seed in enumerate(task.seeds)
            for j, (sc, c, st) in enumerate(task.cases)
            if which is None or which[i, j]]  # fmt: skip


def task_array(task: Task, rows: Sequence[dict]) -> np.ndarray:
    """The result of ``task`` from its runs' rows (any order): shape ``(len(seeds),
    len(cases), len(METRICS) + 1)``, the metrics then the status; a diverged run or one that
    raised has NaN metrics (effort too) and status 1 or 2."""
    out = np.full((len(task.seeds), len(task.cases), len(METRICS) + 1), np.nan)
    for r in rows:
        i, j = r["i_seed"], r["case"]
        if r["status"] == "error":
            out[i, j, -1] = ERROR
        elif r["diverged"]:
            out[i, j, -1] = DIVERGED
        else:
            out[i, j, :-1] = [r[c] for c in COLUMNS]
            out[i, j, -1] = OK
    return out


def run_task(task: Task) -> tuple[str, np.ndarray]:
    """Run a task here: ``(key, array)`` (:func:`task_array` of the engine's rows)."""
    from wmr.engine.jobs import job_row

    return task.key, task_array(task, [job_row(j) for j in task_jobs(task)])


def _schema():
    import pyarrow as pa

    from wmr.engine.jobs import COLUMN_TYPES
    from wmr.engine.jobs import COLUMNS as RESULT

    cols = [("job_id", pa.string()), ("key", pa.string()), ("seed", pa.int64()),
            ("i_seed", pa.int64()), ("case", pa.int64()), ("scenario", pa.string()),
            ("controller", pa.string())]  # fmt: skip
    return pa.schema(cols + [(c, getattr(pa, COLUMN_TYPES[c])()) for c in RESULT])


def digest_inputs(fair: bool = False) -> list[Path]:
    """The files a store's runs depend on besides wmr's sources: the prior (settings to
    scenarios, ``prior.py``) and the shipped scenario files it reads
    (``wmr/scenarios/<paper scenario>.toml``); for the fair tuning's store (``fair``) also its
    arms and held-out runs (``fair.py``), the tuning stage (``analysis/tuning.py``), the
    regime study's ``design.py`` (the held-out and training documents) and the MuJoCo robot's
    scenario files whose ``[plant]`` blocks those documents copy (``design.MUJOCO``).  The
    screening, design, planted truths, waves, fit and verdict run only what the prior defines,
    so a change to the fair tuning leaves their store as it is."""
    from analysis.calibration import prior
    from wmr import scenario as scn

    here = Path(__file__).resolve().parent
    files = [here / "prior.py", *(scn.builtin(name) for name in prior.SCENARIOS)]
    if fair:
        from analysis.regimes import design

        files += [here / "fair.py", here.parent / "tuning.py",
                  here.parent / "regimes" / "design.py",
                  *(scn.builtin(name) for name in sorted(set(design.MUJOCO.values())))]
    return files


def store_digest(extra: str = "", fair: bool = False) -> str:
    """What the runs of a store's tasks depend on: wmr's sources, :func:`digest_inputs`,
    :func:`task_jobs` and :func:`task_array` (a task's runs and its result from their rows),
    :data:`METRICS`; and ``extra``.  The stages that only summarise runs are not in it:
    changing them reuses the store."""
    import inspect

    from wmr._jit import source_digest
    from wmr.engine.store import digest_files

    code = "".join(inspect.getsource(f) for f in (task_jobs, task_array))
    parts = (source_digest(), code, repr((METRICS, COLUMNS)), extra, "fair" if fair else "")
    return digest_files(digest_inputs(fair), "\0".join(parts))


def _arrays(table, tasks: dict[str, Task] | None = None) -> dict[str, np.ndarray]:
    """Task key -> result array from a table of rows (a task's shape from its rows when it is
    not in ``tasks``)."""
    if table is None:
        return {}
    t = table.to_pydict()
    rows = [dict(zip(t, values, strict=True)) for values in zip(*t.values(), strict=True)]
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(r["key"], []).append(r)
    out = {}
    for k, rs in groups.items():
        task = (tasks or {}).get(k)
        if task is None:
            seeds = {r["i_seed"]: r["seed"] for r in rs}
            n_c = max(r["case"] for r in rs) + 1
            task = Task(k, (None,) * n_c, tuple(seeds[i] for i in range(max(seeds) + 1)))
        out[k] = task_array(task, rs)
    return out


def read_store(folder: str | Path) -> dict[str, np.ndarray]:
    """Every finished task of the store ``folder``: key -> array (as :func:`run_task`)."""
    from wmr.engine.store import ShardStore

    return _arrays(ShardStore(folder).read())


def _missing(task: Task, stored: np.ndarray | None) -> np.ndarray:
    """Which runs of ``task`` (seed x case, bool) the ``stored`` array (None: none) lacks."""
    miss = np.ones((len(task.seeds), len(task.cases)), dtype=bool)
    if stored is not None:
        a, b = min(stored.shape[0], miss.shape[0]), min(stored.shape[1], miss.shape[1])
        miss[:a, :b] = np.isnan(stored[:a, :b, -1])
    return miss


class Evaluator:
    """Runs tasks on the engine, caching them in the store at ``folder``.

    Parameters
    ----------
    folder : path
        The store (created if absent; a store of another digest is set aside and rebuilt).
    digest : str
        The store's digest (:func:`store_digest`).
    workers, scheduler
        The engine (``wmr.engine.executors.engine``): 1 = serial here; None = the usable cores.
    flush_seconds : float [s]
        Finished rows are written as a shard at least this often.
    progress : bool or None
        ``wmr.engine.progress.Progress`` (None: a bar on a terminal, lines otherwise).
    """

    def __init__(self, folder: str | Path, digest: str, workers: int | None = None,
                 scheduler: str | None = None, flush_seconds: float = 30.0,
                 progress: bool | None = None):  # fmt: skip
        from wmr.engine.store import ShardStore

        self.folder, self.digest = Path(folder), digest
        self.workers, self.scheduler = workers, scheduler
        self.flush_seconds, self.progress = flush_seconds, progress
        self.store = ShardStore.open(self.folder, _schema(), {"digest": digest}, kind=KIND)
        old = self.store.manifest
        #: every invocation's runs and seconds of running, summed (the study's whole cost)
        self.totals = {"runs": int(old.get("runs_total", 0)),
                       "seconds_running": float(old.get("seconds_running_total", 0.0))}
        self._write_manifest()
        self.cache = _arrays(self.store.read())
        self.loaded = len(self.cache)
        self.runs_this_time, self.seconds, self.engine_name = 0, 0.0, "none (all from the store)"
        self._engine = None

    # -- the engine, started on first need ------------------------------------------------------
    def engine(self):
        """The engine (started on first need; closed with the evaluator)."""
        from wmr.engine.executors import engine

        if self._engine is None:
            self._engine = engine(self.workers, self.scheduler)
            self.engine_name = self._engine.name
        return self._engine

    def close(self) -> None:
        if self._engine is not None:
            self._engine.close()
            self._engine = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- evaluation -----------------------------------------------------------------------------
    def evaluate(self, tasks: Sequence[Task], desc: str = "calibration") -> list[np.ndarray]:
        """The result of each task (:func:`run_task`), running only the runs not in the store
        (a task cut by an interruption runs its missing runs only)."""
        from wmr.engine.driver import execute
        from wmr.engine.jobs import job_row

        todo = {t.key: t for t in tasks if _missing(t, self.cache.get(t.key)).any()}
        if todo:
            t0 = time.perf_counter()
            jobs = [j for t in todo.values()
                    for j in task_jobs(t, _missing(t, self.cache.get(t.key)))]  # fmt: skip
            try:
                rows = execute(jobs, self.engine(), job_row, store=self.store, keep=True,
                               flush_seconds=self.flush_seconds, progress=self.progress,
                               desc=desc)  # fmt: skip
            finally:
                self.seconds += time.perf_counter() - t0
                self.totals["seconds_running"] += time.perf_counter() - t0
            by_key: dict[str, list[dict]] = {}
            for r in rows:
                by_key.setdefault(r["key"], []).append(r)
            for k, t in todo.items():
                arr = task_array(t, by_key.get(k, []))
                old = self.cache.get(k)
                if old is not None:  # the runs stored before
                    a, b = min(old.shape[0], arr.shape[0]), min(old.shape[1], arr.shape[1])
                    kept = ~np.isnan(old[:a, :b, -1])
                    arr[:a, :b][kept] = old[:a, :b][kept]
                self.cache[k] = arr
            self.runs_this_time += len(jobs)
            self.totals["runs"] += len(jobs)
            self._write_manifest()
        return [self.cache[t.key] for t in tasks]

    def _write_manifest(self) -> None:
        self.store.write_manifest({"digest": self.digest, "kind": KIND,
                                   "runs_total": self.totals["runs"],
                                   "seconds_running_total": self.totals["seconds_running"]})

    def runs_in_store(self) -> int:
        """Runs held by the store (tasks x seeds x cases)."""
        return int(sum(a.shape[0] * a.shape[1] for a in self.cache.values()))


def finite_or(x: float, default=None):
    """``x`` as a float, or ``default`` when it is not finite (for JSON)."""
    return float(x) if x is not None and math.isfinite(float(x)) else default
