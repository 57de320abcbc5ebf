"""A sweep spec (``wmr.engine.sweep``) run on the engine into its store (``wmr sweep``, DESIGN
§3.5).

The store (``wmr.engine.store.ShardStore``) is the sweep's folder: ``spec.toml`` (a copy),
``manifest.json`` and ``rows/part-*.parquet``, with the columns of :func:`schema`.  Its digests
are the spec's (the spec and every scenario file it names, ``Spec.digest``) and wmr's code
(:func:`code_digest`).  Rerunning the same command resumes: jobs with a row are skipped, none
runs twice; ``retry_errors`` reruns the jobs whose row is an error (the new rows supersede
them).  A different spec in a non-empty folder is refused (:func:`check_out`, exit 2 at the
CLI), unless ``stale="set-aside"`` (the studies' stores under the cache folder): then it is set
aside and rebuilt, as a store of the same spec made by other code always is.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Sequence
from pathlib import Path

from wmr.engine.jobs import COLUMN_TYPES, COLUMNS, job_row, measure_columns
from wmr.engine.store import ShardStore
from wmr.engine.sweep import Factor, Spec, SweepError, jobs, summarise

__all__ = ["KIND", "schema", "code_digest", "digests", "open_store", "check_out", "run_sweep",
           "read_rows", "finished_jobs", "error_jobs", "write_shard"]  # fmt: skip

KIND = "wmr sweep store"


def _factor_type(f: Factor):
    import pyarrow as pa

    if f.levels is None:
        return pa.float64()
    if all(isinstance(v, bool) for v in f.levels):
        return pa.bool_()
    if all(isinstance(v, int) and not isinstance(v, bool) for v in f.levels):
        return pa.int64()
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in f.levels):
        return pa.float64()
    return pa.string()


def schema(spec: Spec):
    """The Parquet schema of the store's rows (DESIGN §3.5): the job's columns, one per factor,
    the results (``wmr.engine.jobs.COLUMNS``) and the measures' columns."""
    import pyarrow as pa

    cols = [("job_id", pa.int64()), ("point", pa.int64()), ("scenario", pa.string()),
            ("controller", pa.string()), ("seed", pa.int64())]  # fmt: skip
    cols += [(f.path, _factor_type(f)) for f in spec.factors]
    cols += [(c, getattr(pa, COLUMN_TYPES[c])()) for c in COLUMNS]
    cols += [(c, pa.float64()) for c in measure_columns(spec.measures)]
    return pa.schema(cols)


def code_digest() -> str:
    """What the runs read besides the spec: wmr's sources (``wmr._jit.source_digest``)."""
    from wmr._jit import source_digest

    return source_digest()


def digests(spec: Spec) -> dict[str, str]:
    """The store's digests: ``spec_digest`` (the spec and its scenario files) and
    ``code_digest``."""
    return {"spec_digest": spec.digest, "code_digest": code_digest()}


def open_store(out: str | Path, spec: Spec) -> ShardStore:
    """The store of ``spec`` at ``out``, resumed, or created (a stale one set aside first)."""
    return ShardStore.open(out, schema(spec), digests(spec), kind=KIND, name=spec.name)


def check_out(out: Path, spec: Spec) -> None:
    """``out`` is empty, or holds a store of this very spec (then the sweep resumes)."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise SweepError(spec.source, "--out", str(out), "exists and is not a directory")
    if not out.exists() or not any(out.iterdir()):
        return
    try:
        stored = json.loads((out / "manifest.json").read_text())["spec_digest"]
    except (OSError, ValueError, KeyError, TypeError):
        stored = None
    if stored != spec.digest:
        raise SweepError(spec.source, "--out", str(out),
                         "is not empty and holds no store of this spec (a different spec, or "
                         "not a sweep store): give another folder")  # fmt: skip


def read_rows(out: str | Path, columns: Sequence[str] | None = None):
    """The current rows of the store ``out`` as a ``pyarrow.Table`` (None if it has none yet):
    a row superseded by a newer shard's row of the same ``job_id`` is left out."""
    return ShardStore(out).read(columns)


def finished_jobs(out: str | Path) -> set[int]:
    """The ``job_id`` of every row in the store."""
    return ShardStore(out).ids()


def error_jobs(out: str | Path) -> set[int]:
    """The ``job_id`` of every current error row (``status = "error"``)."""
    return ShardStore(out).ids("error")


def write_shard(out: Path, spec: Spec, rows: list[dict]) -> Path | None:
    """Write ``rows`` as a new shard of the store ``out`` (``ShardStore.write``)."""
    return ShardStore(out, schema(spec)).write(rows)


def run_sweep(spec: Spec, out: str | Path, *, workers: int | None = None,
              scheduler: str | None = None, batch_seconds: float = 2.0,
              flush_seconds: float = 30.0, progress: bool | None = None,
              retry_errors: bool = False, stale: str = "refuse", fn=job_row,
              eng=None) -> dict:  # fmt: skip
    """Run (or resume) the sweep ``spec`` into the store ``out``; returns the manifest.

    ``workers``/``scheduler`` choose the engine (``wmr.engine.executors.engine``: 1 = serial
    here, N = a local Dask cluster of N processes, or the cluster at ``scheduler``).  Jobs with a
    row in ``out/rows`` are skipped (with ``retry_errors``, those whose row is an error are run
    again); completed rows are written as a new shard at least every ``flush_seconds``, so an
    interruption, even SIGKILL, loses at most that much work.  ``stale``: ``"refuse"`` a different
    spec in a non-empty ``out`` (:class:`~wmr.engine.sweep.SweepError`) or ``"set-aside"``.
    ``fn`` maps a job to its row (``wmr.engine.jobs.job_row``; a wrapper of it in tests).
    ``eng``: an engine already running to use instead (left running).

    Raises
    ------
    wmr.engine.faults.RetriesExhausted
        A batch kept failing with a transient error; the finished rows are stored.
    """
    from wmr.engine.driver import execute
    from wmr.engine.executors import engine
    from wmr.io import atomic_write_text

    if stale not in ("refuse", "set-aside"):
        raise ValueError(f"stale must be 'refuse' or 'set-aside', not {stale!r}")
    out = Path(out)
    if stale == "refuse":
        check_out(out, spec)
    t0 = time.perf_counter()
    store = open_store(out, spec)
    if not (out / "spec.toml").exists():
        atomic_write_text(out / "spec.toml", Path(spec.source).read_text(encoding="utf-8"))
    done = store.ids()
    redo = store.ids("error") if retry_errors else set()
    todo = [j for j in range(spec.n_jobs) if j not in done or j in redo]
    before = store.manifest
    total = float(before.get("run_seconds_total", 0.0))
    manifest = {**before, **_counts(spec, store), "started": time.time()}
    store.write_manifest(manifest)
    stats: dict = {}
    try:
        with contextlib.nullcontext(eng) if eng is not None else engine(workers, scheduler) as eng:
            t_run = time.perf_counter()
            execute(jobs(spec, todo), eng, fn, store=store, keep=False,
                    batch_seconds=batch_seconds, flush_seconds=flush_seconds, progress=progress,
                    desc=f"sweep {spec.name}", tag=f"sweep-{spec.digest[:12]}",
                    stats=stats)  # fmt: skip
            run_s = time.perf_counter() - t_run  # the engine's start and stop: in ``seconds``
            name, n_workers = eng.name, eng.workers
    except BaseException:
        store.write_manifest({**manifest, **_counts(spec, store)})  # the counts of what is stored
        raise
    manifest.update(_counts(spec, store), engine=name, workers=n_workers,
                    seconds=round(time.perf_counter() - t0, 3), run_seconds=round(run_s, 3),
                    run_seconds_total=round(total + run_s, 3), runs_this_time=len(todo),
                    runs_per_s=round(len(todo) / run_s, 3) if run_s > 0 and todo else None,
                    retried_errors=len(redo), retried_batches=stats["retries"],
                    batch_seconds=batch_seconds, flush_seconds=flush_seconds,
                    batches=stats["batches"], finished=time.time())  # fmt: skip
    store.write_manifest(manifest)
    summarise(out, spec)
    return manifest


def _counts(spec: Spec, store: ShardStore) -> dict:
    import wmr

    done, errors = store.ids(), store.ids("error")
    return {"kind": KIND, "name": spec.name, **digests(spec), "wmr_version": wmr.__version__,
            "design": dict(spec.design), "factors": [f.path for f in spec.factors],
            "points": len(spec.points), "scenarios": list(spec.scenarios),
            "controllers": list(spec.controllers), "seeds": len(spec.seeds),
            "jobs": spec.n_jobs, "done": len(done), "errors": len(errors),
            "complete": len(done) == spec.n_jobs}  # fmt: skip
