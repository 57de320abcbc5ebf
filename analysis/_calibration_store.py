"""Evaluation of calibration points through the execution engine, cached in a resumable store.

A :class:`Task` is a list of runs (``Scenario``, controller, settings) over a list of seeds,
named by a deterministic ``key`` (a hash of what defines it).  :class:`Evaluator` runs the tasks
it has not seen before on ``wmr.study.engine`` (serial, or Dask: batches of a few seconds, explicit
task keys, retries, a bounded window) and keeps every result in a store:

- ``manifest.json``: the store's digest (wmr's sources and the calibration's own code) and
  counts;
- ``rows/part-*.parquet``: immutable shards, one row per (task, seed, run): ``key``, ``seed``,
  ``i_seed``, ``case``, ``scenario``, ``controller``, the metrics of :data:`METRICS` and
  ``status`` (0 ok, 1 diverged, 2 error), written atomically at least every ``flush_seconds``.

Every stage of the study (screening, design, Sobol matrices, the fit's generations, the fair
tuning) goes through :meth:`Evaluator.evaluate`, so an interrupted study resumes where it
stopped: a rerun finds its finished tasks in the store (the fit's optimiser is seeded, so it asks
for the same points again and replays them from the store).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["METRICS", "Task", "task_key", "run_task", "Evaluator", "store_digest", "read_store"]

#: Metrics of a run, in the order of a result's last axis (then ``status``).
METRICS = ("x", "y", "theta", "position", "tail_position", "effort")
OK, DIVERGED, ERROR = 0, 1, 2
#: Tasks per batch sent to a worker (a task is 12 runs x seeds: ~0.2-0.5 s).
TASKS_PER_BATCH = 6


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


def run_task(task: Task) -> tuple[str, np.ndarray]:
    """Run a task here: ``(key, array)``, the array of shape ``(len(seeds), len(cases),
    len(METRICS) + 1)`` holding the metrics and the status; a diverged run or one that raised
    has NaN metrics (effort too) and status 1 or 2."""
    from wmr.sim import simulate

    out = np.full((len(task.seeds), len(task.cases), len(METRICS) + 1), np.nan)
    for j, (sc, controller, settings) in enumerate(task.cases):
        for i, seed in enumerate(task.seeds):
            try:
                r = simulate(sc, controller, seed, settings=settings, keep_trajectory=False)
            except Exception:  # noqa: BLE001 - a run that raises is a result (status 2)
                out[i, j, -1] = ERROR
                continue
            if r.diverged:
                out[i, j, -1] = DIVERGED
                continue
            m, t = r.rmse, r.rmse_after_transient
            out[i, j, :-1] = (m["x"], m["y"], m["theta"], m["position"], t["position"],
                              r.effort)  # fmt: skip
            out[i, j, -1] = OK
    return task.key, out


def store_digest(extra: str = "") -> str:
    """What the runs of a task depend on: wmr's sources, the prior (settings to scenarios,
    ``_calibration_prior.py``), the fair tuning's trajectories and gain ranges
    (``_calibration_fair.py``), :func:`run_task` and :data:`METRICS`; and ``extra``.  The
    stages that only summarise runs are not in it: changing them reuses the store."""
    import inspect

    from wmr._jit import source_digest

    h = hashlib.sha256(source_digest().encode())
    here = Path(__file__).resolve().parent
    for name in ("_calibration_prior.py", "_calibration_fair.py"):
        h.update((here / name).read_bytes())
    h.update(inspect.getsource(run_task).encode())
    h.update(repr(METRICS).encode())
    h.update(extra.encode())
    return h.hexdigest()[:16]


def read_store(folder: str | Path) -> dict[str, np.ndarray]:
    """Every finished task of the store ``folder``: key -> array (as :func:`run_task`)."""
    import pyarrow.parquet as pq

    shards = sorted((Path(folder) / "rows").glob("part-*.parquet"))
    out: dict[str, np.ndarray] = {}
    for path in shards:
        t = pq.read_table(path).to_pydict()
        keys, i_seed, case = t["key"], t["i_seed"], t["case"]
        cols = np.column_stack([np.asarray(t[m], dtype=float) for m in (*METRICS, "status")])
        groups: dict[str, list[int]] = {}
        for row, k in enumerate(keys):
            groups.setdefault(k, []).append(row)
        for k, rows in groups.items():
            n_s = max(i_seed[r] for r in rows) + 1
            n_c = max(case[r] for r in rows) + 1
            arr = np.full((n_s, n_c, len(METRICS) + 1), np.nan)
            for r in rows:
                arr[i_seed[r], case[r]] = cols[r]
            out[k] = arr
    return out


class Evaluator:
    """Runs tasks on the engine, caching them in the store at ``folder``.

    Parameters
    ----------
    folder : path
        The store (created if absent; a store of another digest is refused).
    digest : str
        The store's digest (:func:`store_digest`).
    workers, scheduler
        The engine (``wmr.study.engine``): 1 = serial here; None = the usable cores.
    flush_seconds : float [s]
        Finished rows are written as a shard at least this often.
    progress : bool or None
        ``wmr.study.Progress`` (None: a bar on a terminal, lines otherwise).
    """

    def __init__(self, folder: str | Path, digest: str, workers: int | None = None,
                 scheduler: str | None = None, flush_seconds: float = 30.0,
                 progress: bool | None = None):  # fmt: skip
        self.folder, self.digest = Path(folder), digest
        self.workers, self.scheduler = workers, scheduler
        self.flush_seconds, self.progress = flush_seconds, progress
        self.manifest = self.folder / "manifest.json"
        old = json.loads(self.manifest.read_text()) if self.manifest.exists() else {}
        if old and old.get("digest") != digest:
            raise ValueError(f"{self.folder} holds a calibration store of another version "
                             f"({old.get('digest')} != {digest}): give another folder")  # fmt: skip
        (self.folder / "rows").mkdir(parents=True, exist_ok=True)
        #: every invocation's runs and seconds of running, summed (the study's whole cost)
        self.totals = {"runs": int(old.get("runs_total", 0)),
                       "seconds_running": float(old.get("seconds_running_total", 0.0))}
        self._write_manifest()
        self.cache = read_store(self.folder)
        self.loaded = len(self.cache)
        self.runs_this_time, self.seconds, self.engine_name = 0, 0.0, "none (all from the store)"
        self._engine, self._warm = None, set()

    # -- the engine, started on first need ------------------------------------------------------
    def _eng(self):
        from wmr import study

        if self._engine is None:
            self._engine = study.engine(self.workers, self.scheduler)
            self.engine_name = self._engine.name
        return self._engine

    def _warm_up(self, tasks: Sequence[Task]) -> None:
        from wmr import study

        pairs = {}
        for t in tasks:
            for sc, c, _ in t.cases:
                if (c, sc.plant.ideal) not in self._warm:
                    pairs[(c, sc.plant.ideal)] = (sc, c)
        if pairs:
            self._eng().run_everywhere(study.warm_up, list(pairs.values()))
            self._warm |= set(pairs)

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
        """The result of each task (:func:`run_task`), running only those not in the store."""
        from wmr.study import Progress

        todo = list({t.key: t for t in tasks if t.key not in self.cache}.values())
        if todo:
            t0 = time.perf_counter()
            self._warm_up(todo)
            eng = self._eng()
            batches = [todo[i:i + TASKS_PER_BATCH] for i in range(0, len(todo), TASKS_PER_BATCH)]
            keys = [f"wmr-calibration-{b[0].key}-{len(b)}" for b in batches]
            n_runs = sum(len(t.cases) * len(t.seeds) for t in todo)
            bar = Progress(n_runs, desc, self.progress)
            buffer: list[tuple[Task, np.ndarray]] = []
            last = time.perf_counter()
            by_key = {t.key: t for t in todo}
            try:
                for _, results in eng.map_batches(run_task, batches, keys):
                    for key, arr in results:
                        self.cache[key] = arr
                        buffer.append((by_key[key], arr))
                        bar.update(arr.shape[0] * arr.shape[1])
                    if time.perf_counter() - last >= self.flush_seconds:
                        self._write(buffer)
                        buffer, last = [], time.perf_counter()
            finally:
                self._write(buffer)  # what is finished is kept, even on an interrupt
                bar.close()
            self.runs_this_time += n_runs
            self.seconds += time.perf_counter() - t0
            self.totals["runs"] += n_runs
            self.totals["seconds_running"] += time.perf_counter() - t0
            self._write_manifest()
        return [self.cache[t.key] for t in tasks]

    def _write_manifest(self) -> None:
        from wmr.io import write_json

        write_json(self.manifest, {"digest": self.digest, "kind": "wmr calibration store",
                                   "runs_total": self.totals["runs"],
                                   "seconds_running_total": self.totals["seconds_running"]})

    def _write(self, done: list[tuple[Task, np.ndarray]]) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        if not done:
            return
        cols: dict[str, list] = {k: [] for k in ("key", "seed", "i_seed", "case", "scenario",
                                                  "controller", *METRICS, "status")}  # fmt: skip
        for task, arr in done:
            for i, seed in enumerate(task.seeds):
                for j, (sc, c, _) in enumerate(task.cases):
                    cols["key"].append(task.key)
                    cols["seed"].append(int(seed))
                    cols["i_seed"].append(i)
                    cols["case"].append(j)
                    cols["scenario"].append(sc.name)
                    cols["controller"].append(c)
                    for m, x in zip((*METRICS, "status"), arr[i, j], strict=True):
                        cols[m].append(int(x) if m == "status" else float(x))
        table = pa.table(cols)
        name = f"part-{time.time_ns():020d}-{os.getpid()}.parquet"
        tmp = self.folder / "rows" / f".{name}.tmp"
        pq.write_table(table, tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, self.folder / "rows" / name)

    def runs_in_store(self) -> int:
        """Runs held by the store (tasks x seeds x cases)."""
        return int(sum(a.shape[0] * a.shape[1] for a in self.cache.values()))


def finite_or(x: float, default=None):
    """``x`` as a float, or ``default`` when it is not finite (for JSON)."""
    return float(x) if x is not None and math.isfinite(float(x)) else default
