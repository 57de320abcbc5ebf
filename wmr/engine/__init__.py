"""The run engine: one job type, one batcher, one shard store, one driver (DESIGN §4).

========================  =========================================================================
``wmr.engine.jobs``       :class:`Job`, the run-to-row mapping (``run_job``, ``job_row``), warm-up
``wmr.engine.batching``   the batcher (guided, by measured cost per step)
``wmr.engine.executors``  the engines: serial, Dask ``LocalCluster``, an existing scheduler
``wmr.engine.faults``     which failures are transient; retries; ``RetriesExhausted``
``wmr.engine.store``      the shard store: atomic Parquet shards, resume, digests, stale stores
``wmr.engine.driver``     ``execute``: the loop every driver of many runs uses
``wmr.engine.progress``   the progress bar / lines
``wmr.engine.cluster``    ``LoopbackCluster``: a scheduler and workers as separate programs
``wmr.engine.sweeps``     a sweep spec (``wmr.engine.sweep``) run into its store (``wmr sweep``)
========================  =========================================================================

``wmr.engine.study`` keeps the names of the earlier single module (``Job``, ``run_jobs``,
``engine``, ``Engine.map_batches``, ``Engine.run_everywhere``, ``LoopbackCluster``...). Importing
this package imports none of its modules; the names below load theirs on first use.
"""

from __future__ import annotations

import importlib

_NAMES = {
    "Job": "jobs", "run_job": "jobs", "job_row": "jobs", "warm_up": "jobs",
    "batches": "batching", "step_costs": "batching",
    "Engine": "executors", "SerialEngine": "executors", "DaskEngine": "executors",
    "engine": "executors", "default_workers": "executors",
    "RetriesExhausted": "faults", "is_transient": "faults",
    "ShardStore": "store", "execute": "driver", "Progress": "progress",
    "LoopbackCluster": "cluster",
}  # fmt: skip

__all__ = sorted(_NAMES)


def __getattr__(name: str):
    if name in _NAMES:
        return getattr(importlib.import_module(f"wmr.engine.{_NAMES[name]}"), name)
    raise AttributeError(f"module 'wmr.engine' has no attribute {name!r}")
