"""The sweep engine's throughput for the benchmark (issue 13): serial, a local Dask cluster and a
loopback scheduler with worker processes, side by side on the same spec; and a large sweep.

Parallel efficiency = (runs/s on W workers) / (W x runs/s of the serial engine on the same
jobs), each rate over the sweep's run phase (``manifest.run_seconds``: after the engine is up
and the kernels are warm, as a long sweep spends nearly all its time).
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from wmr import study, sweep

__all__ = ["SPEC", "throughput", "large_sweep"]

#: A lemniscate sweep over the seeds only; ``{controller}``, ``{seeds}``, ``{duration}`` filled in.
SPEC = """\
name = "bench-{controller}"
scenarios = ["lemniscate.toml"]
controllers = ["{controller}"]
seeds = {seeds}
"""


def _spec(folder: Path, controller: str, seeds: int, duration: float) -> sweep.Spec:
    from wmr import scenario as scn

    text = scn.builtin("lemniscate").read_text().replace("duration = 40.0",
                                                         f"duration = {duration}")  # fmt: skip
    (folder / "lemniscate.toml").write_text(text)
    path = folder / f"{controller}.toml"
    path.write_text(SPEC.format(controller=controller, seeds=seeds))
    return sweep.load_spec(path)


def _rate(spec, out, **engine) -> tuple[float, dict]:
    m = sweep.run_sweep(spec, out, progress=False, batch_seconds=2.0, **engine)
    return m["runs_this_time"] / m["run_seconds"], m


def _noop(x):
    return x


def task_cost(address: str, tasks: int = 500) -> float:
    """Seconds per task of the engine (explicit keys, the bounded window) for tasks that do
    nothing, on the cluster at ``address``: the floor under any batch."""
    import time
    import uuid

    tag = uuid.uuid4().hex[:8]
    with study.engine(scheduler=address) as eng:
        t0 = time.perf_counter()
        for _ in eng.map_batches(_noop, [[i] for i in range(tasks)],
                                 [f"noop-{tag}-{i}" for i in range(tasks)]):  # fmt: skip
            pass
        return (time.perf_counter() - t0) / tasks


def throughput(controllers=("iapid-nn-dekf", "pid"), workers: int = 2, quick: bool = False,
               repeats: int = 2) -> dict:  # fmt: skip
    """Runs/s of the serial engine, a LocalCluster of ``workers`` and a loopback scheduler with
    ``workers`` worker processes, for each controller, ``repeats`` times interleaved (the best
    rate of each engine is kept); rows checked equal across engines."""
    runs = {"iapid-nn-dekf": 60 if quick else 400, "pid": 600 if quick else 6000}
    out = {"workers": workers, "repeats": repeats, "controllers": {}}
    with tempfile.TemporaryDirectory(prefix="wmr-sweep-bench-") as tmp:
        tmp = Path(tmp)
        with study.LoopbackCluster(tmp / "cluster", workers=workers) as cluster:
            for c in controllers:
                spec = _spec(tmp, c, runs.get(c, 400), 40.0)
                rates: dict = {"serial": [], "local": [], "dask": []}
                for rep in range(repeats):  # interleaved; the best rate of each (least disturbed)
                    rates["serial"].append(_rate(spec, tmp / f"{c}-serial-{rep}", workers=1))
                    rates["local"].append(_rate(spec, tmp / f"{c}-local-{rep}", workers=workers))
                    rates["dask"].append(_rate(spec, tmp / f"{c}-dask-{rep}",
                                               scheduler=cluster.address))  # fmt: skip
                (serial, _), (local, ml), (dask, md) = (max(rates[e], key=lambda x: x[0])
                                                        for e in ("serial", "local", "dask"))
                rows = [sweep.read_rows(tmp / f"{c}-{e}-0").to_pandas().sort_values("job_id")
                        .reset_index(drop=True) for e in ("serial", "local", "dask")]  # fmt: skip
                out["controllers"][c] = {
                    "runs": spec.n_jobs, "steps_per_run": spec.runs[0][0].n_steps,
                    "serial_runs_per_s": serial,
                    "local_runs_per_s": local, "local_batches": ml["batches"],
                    "dask_runs_per_s": dask, "dask_batches": md["batches"],
                    "local_efficiency": local / (workers * serial),
                    "dask_efficiency": dask / (workers * serial),
                    "rows_equal": bool(rows[0].equals(rows[1]) and rows[0].equals(rows[2])),
                }  # fmt: skip
            out["task_seconds"] = task_cost(cluster.address)
    per = out["controllers"].values()
    out["local"] = {"efficiency": min(v["local_efficiency"] for v in per)}
    out["dask"] = {"efficiency": min(v["dask_efficiency"] for v in per)}
    out["rows_equal"] = all(v["rows_equal"] for v in per)
    return out


def large_sweep(runs: int = 100_000, controller: str = "pid", workers: int = 2) -> dict:
    """A sweep of ``runs`` runs (the lemniscate, one controller, over seeds) on a LocalCluster
    of ``workers``: its wall time and runs/s, and that the store holds every run once."""
    with tempfile.TemporaryDirectory(prefix="wmr-sweep-large-") as tmp:
        tmp = Path(tmp)
        spec = _spec(tmp, controller, runs, 40.0)
        m = sweep.run_sweep(spec, tmp / "out", workers=workers, progress=False)
        ids = sweep.read_rows(tmp / "out", ["job_id"]).column("job_id").to_pylist()
    return {"runs": spec.n_jobs, "controller": controller, "workers": workers,
            "steps_per_run": spec.runs[0][0].n_steps, "seconds": m["seconds"],
            "run_seconds": m["run_seconds"], "runs_per_s": spec.n_jobs / m["seconds"],
            "batches": m["batches"], "complete": sorted(ids) == list(range(spec.n_jobs))}
