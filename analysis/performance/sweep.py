"""The sweep engine's throughput for the benchmark (issue 13): serial, a local Dask cluster and a
loopback scheduler with worker processes, side by side on the same spec; and a large sweep.

Parallel efficiency = (runs/s on W workers) / (W x runs/s of the serial engine on the same
jobs), each rate over the sweep's run phase (``manifest.run_seconds``: after the engine is up
and the kernels are warm, as a long sweep spends nearly all its time).
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from wmr.engine import study, sweep

__all__ = ["SPEC", "throughput", "large_sweep"]

#: A sweep of one scenario over the seeds only; ``{controller}``, ``{seeds}`` filled in.
SPEC = """\
name = "bench-{controller}"
scenarios = ["scenario.toml"]
controllers = ["{controller}"]
seeds = {seeds}
"""


def _spec(folder: Path, controller: str, seeds: int, duration: float,
          scenario: str = "lemniscate") -> sweep.Spec:  # fmt: skip
    from wmr import scenario as scn

    text = scn.builtin(scenario).read_text()
    if "duration = 40.0" not in text:
        raise ValueError(f"scenario {scenario!r} has no 'duration = 40.0' line to cut")
    (folder / "scenario.toml").write_text(text.replace("duration = 40.0", f"duration = {duration}"))
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


def _process_cpu(procs) -> float:
    """User + system CPU seconds of ``procs`` (psutil processes; one gone meanwhile adds 0)."""
    import psutil

    total = 0.0
    for p in procs:
        try:
            t = p.cpu_times()
        except psutil.Error:
            continue
        total += t.user + t.system
    return total


def idle_cost(workers: int = 2, seconds: float = 5.0) -> dict:
    """CPU used by an idle ``LocalCluster`` of ``workers`` processes over ``seconds``, in cores:
    the driver (which hosts the scheduler, the nannies and the client) and the workers (their
    event loops, heartbeats, memory monitor).  A fixed cost of the machinery, whatever the
    sweep: on a machine of few cores a visible share of its capacity."""
    import psutil  # a dependency of distributed

    with study.engine(workers) as eng:
        time.sleep(1.0)  # past the start-up
        me = psutil.Process()
        kids = [p for p in me.children(recursive=True)
                if "resource_tracker" not in " ".join(p.cmdline())]  # fmt: skip
        d0, w0, t0 = _process_cpu([me]), _process_cpu(kids), time.perf_counter()
        time.sleep(seconds)
        wall = time.perf_counter() - t0
        driver, work = (_process_cpu([me]) - d0) / wall, (_process_cpu(kids) - w0) / wall
        name = eng.name
    return {"engine": name, "seconds": seconds, "driver_cores": driver, "worker_cores": work,
            "cores": driver + work, "share_of_machine": (driver + work) / workers}


def throughput(controllers=("iapid-nn-dekf", "pid"), workers: int = 2, quick: bool = False,
               repeats: int = 2, scenario: str = "lemniscate", runs: dict | None = None
               ) -> dict:  # fmt: skip
    """Runs/s of the serial engine, a LocalCluster of ``workers`` and a loopback scheduler with
    ``workers`` worker processes, for each controller, ``repeats`` times interleaved (the best
    rate of each engine is kept); rows checked equal across engines.  ``scenario``: a shipped
    scenario's name (its 40 s runs); ``runs``: runs per controller (default: ~10 s per parallel
    sweep on the lemniscate).  The engine's own costs (an empty task, an idle cluster) are
    measured with the default scenario only."""
    # each parallel sweep runs ~10 s (a 4-5 s one measured 0.82-1.0 from run to run: noise)
    runs = runs or {"iapid-nn-dekf": 30 if quick else 600, "pid": 300 if quick else 10000}
    machinery = scenario == "lemniscate"
    out = {"workers": workers, "repeats": repeats, "scenario": scenario, "controllers": {}}
    with tempfile.TemporaryDirectory(prefix="wmr-sweep-bench-") as tmp:
        tmp = Path(tmp)
        with study.LoopbackCluster(tmp / "cluster", workers=workers) as cluster:
            for c in controllers:
                spec = _spec(tmp, c, runs.get(c, 400), 40.0, scenario)
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
            if machinery:
                out["task_seconds"] = task_cost(cluster.address)
    if machinery:
        out["local_idle"] = idle_cost(workers, 2.0 if quick else 5.0)
    per = out["controllers"].values()
    out["local"] = {"efficiency": min(v["local_efficiency"] for v in per)}
    out["dask"] = {"efficiency": min(v["dask_efficiency"] for v in per)}
    out["rows_equal"] = all(v["rows_equal"] for v in per)
    return out


def large_sweep(runs: int = 100_000, controller: str = "pid", workers: int = 2,
                duration: float = 10.0) -> dict:  # fmt: skip
    """A sweep of ``runs`` runs (the lemniscate cut to ``duration`` s, one controller, over
    seeds) on a LocalCluster of ``workers``: its wall time and runs/s, and that the store holds
    every run once."""
    with tempfile.TemporaryDirectory(prefix="wmr-sweep-large-") as tmp:
        tmp = Path(tmp)
        spec = _spec(tmp, controller, runs, duration)
        m = sweep.run_sweep(spec, tmp / "out", workers=workers, progress=False)
        ids = sweep.read_rows(tmp / "out", ["job_id"]).column("job_id").to_pylist()
    return {"runs": spec.n_jobs, "controller": controller, "workers": workers,
            "steps_per_run": spec.runs[0][0].n_steps, "seconds": m["seconds"],
            "run_seconds": m["run_seconds"], "runs_per_s": spec.n_jobs / m["seconds"],
            "batches": m["batches"], "complete": sorted(ids) == list(range(spec.n_jobs))}


def scaling_paragraph(rec: dict) -> str:
    """The measured paragraph of docs/scaling.md, from a performance record (``rec["sweep"]``):
    every number in it computed here (``tests/test_scaling_doc.py`` keeps the doc current)."""
    s = rec["sweep"]
    iapid, pid = s["controllers"]["iapid-nn-dekf"], s["controllers"]["pid"]
    w = s["workers"]
    large = s.get("large_sweep")
    rate = iapid["local_runs_per_s"]
    cores = 256
    per_task = s["task_seconds"]
    batch = 2.0
    tasks_1e6 = 1e6 / (rate / w) / batch  # a worker does rate/w runs per second
    text = (
        f"On this {w}-core machine one run of the 40 s lemniscate ({iapid['steps_per_run']:,} "
        f"steps) costs {1 / iapid['serial_runs_per_s']:.4f} s for iapid-nn-dekf and "
        f"{1 / pid['serial_runs_per_s']:.4f} s for the fixed PID (serial engine, per run "
        f"including the simulation's set-up).  Two worker processes ran iapid-nn-dekf sweeps at "
        f"{iapid['local_runs_per_s']:.1f} runs/s (local cluster) and "
        f"{iapid['dask_runs_per_s']:.1f} runs/s (loopback scheduler), efficiencies "
        f"{iapid['local_efficiency']:.2f} and {iapid['dask_efficiency']:.2f} of twice the serial "
        f"rate; the PID at {pid['local_runs_per_s']:.0f} and {pid['dask_runs_per_s']:.0f} runs/s "
        f"(efficiencies {pid['local_efficiency']:.2f} and {pid['dask_efficiency']:.2f}).  A task "
        f"of the engine costs {1e3 * per_task:.1f} ms when it does nothing.")
    idle = s.get("local_idle")
    if idle:
        text += (f"  An idle local cluster of {w} workers uses {100 * idle['cores']:.1f} % of a "
                 f"core ({100 * idle['driver_cores']:.1f} % in the driver, which hosts the "
                 f"scheduler and the nannies; {100 * idle['worker_cores']:.1f} % in the workers' "
                 f"event loops): {100 * idle['share_of_machine']:.1f} % of this machine before "
                 "any run, a fixed cost that a machine of many cores does not notice.")
    if large:
        text += (f"  A sweep of {large['runs']:,} {large['controller']} runs of "
                 f"{large['steps_per_run']:,} steps took {large['seconds']:.0f} s "
                 f"({large['runs_per_s']:.0f} runs/s).")
    text += (
        f"  At these rates 10⁶ iapid-nn-dekf runs take {1e6 / rate / 3600:.1f} h on this machine "
        f"and 10⁷ take {1e7 / rate / 3600:.0f} h; on {cores} cores ({cores // w}x, if every core "
        f"keeps this rate: not measured here), "
        f"{1e6 / rate / (cores / w) / 60:.1f} min and {1e7 / rate / (cores / w) / 60:.0f} min; "
        f"the PID is {pid['serial_runs_per_s'] / iapid['serial_runs_per_s']:.0f}x cheaper.  With "
        f"{batch:g} s batches a sweep of 10⁶ iapid-nn-dekf runs is {tasks_1e6:,.0f} tasks and "
        f"10⁷ is {10 * tasks_1e6:,.0f}, below the millions at which a scheduler slows, and the "
        f"{1e3 * per_task:.1f} ms per task is {100 * per_task / batch:.1f} % of a batch.")
    return text


def update_scaling_doc(path, rec: dict) -> None:
    """Rewrite the measured paragraph (between the ``measured`` markers) of docs/scaling.md."""
    import textwrap

    path = Path(path)
    doc = path.read_text()
    head, rest = doc.split("<!-- measured -->\n", 1)
    _, tail = rest.split("<!-- /measured -->", 1)
    body = textwrap.fill(scaling_paragraph(rec), 98, break_on_hyphens=False)
    path.write_text(f"{head}<!-- measured -->\n{body}\n<!-- /measured -->{tail}")
