"""Sweeps (DESIGN §3.5): a spec file, its design, the jobs, and a resumable Parquet store.

```toml
name = "mismatch-vs-mu"
scenarios = ["lemniscate", "my-scenario.toml"]   # built-in names, or paths relative to this file
controllers = ["pid", "adaptive-pid", "iapid-nn-dekf"]
seeds = 20                                       # seeds 0..19, or a list [3, 7]
measures = ["jacobian", "recovery"]              # optional: wmr.measures (columns beyond RMSEs)

[design]
kind = "sobol"          # "grid" | "sobol" | "lhs" | "random"
samples = 256           # sobol/lhs/random; sobol needs a power of 2
seed = 0                # design seed

[factors]               # dotted paths into the scenario; "controllers.*.FIELD" sets FIELD on
                        # every selected controller whose settings have it
"plant.v_gain" = { low = 0.6, high = 1.4 }
"controllers.*.mu" = { low = 0.09, high = 90.0, log = true }
"plant.delay_steps" = [0, 1, 2]                  # a list: grid levels (or categorical)
```

:func:`load_spec` validates the whole spec, every design point's scenario included, before any
run: a :class:`SweepError` names the spec file, the key and the value.  One job is (design point,
scenario, controller, seed); its ``job_id`` is its index in that nested order, so jobs, rows and
seeds are independent of batching, workers and engine; the same seed gives every controller and
design point the same noise (common random numbers).

The store (:func:`run_sweep`) is a folder: ``spec.toml`` (a copy), ``manifest.json``, and
``rows/part-*.parquet``, immutable shards each written atomically and flushed at least every
``flush_seconds`` of work; rerunning the same command resumes (finished jobs are skipped, none
runs twice) and a different spec in a non-empty folder is refused.  ``summary.md`` and
``summary.png`` (main effects: mean position RMSE against each factor, per controller) close it.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import os
import time
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wmr import controllers
from wmr import scenario as scn
from wmr._settings import InputError, one_line

__all__ = ["SweepError", "Factor", "Spec", "SweepJob", "load_spec", "loads_spec", "design_points",
           "COLUMNS", "jobs", "run_sweep_job", "job_rows", "check_out", "run_sweep", "read_rows",
           "finished_jobs", "write_shard", "schema", "summarise"]  # fmt: skip

#: Design kinds.
KINDS = ("grid", "sobol", "lhs", "random")
#: Result columns of a row, after the job's and the factors' (DESIGN §3.5).
COLUMNS = ("rmse_x", "rmse_y", "rmse_theta", "rmse_position", "tail_x", "tail_y", "tail_theta",
           "tail_position", "effort", "diverged", "diverged_at", "cause", "status", "error")
_TOP_KEYS = {"name", "scenarios", "controllers", "seeds", "design", "factors", "measures"}


class SweepError(InputError):
    """An invalid spec: ``source`` file, dotted ``key``, ``value``, ``reason`` (one line)."""


@dataclass(frozen=True)
class Factor:
    """A factor: its dotted ``path`` and either ``levels`` (a list) or a range
    ``[low, high]`` (``log``: log-uniform)."""

    path: str
    levels: tuple | None = None
    low: float | None = None
    high: float | None = None
    log: bool = False

    def value(self, u: float):
        """The factor's value at the unit coordinate ``u`` in [0, 1) of a sampled design."""
        if self.levels is not None:  # categorical: equal-probability levels
            return self.levels[min(int(u * len(self.levels)), len(self.levels) - 1)]
        if self.log:
            lo, hi = math.log(self.low), math.log(self.high)
            return float(math.exp(lo + u * (hi - lo)))
        return float(self.low + u * (self.high - self.low))


@dataclass(frozen=True)
class Spec:
    """A validated sweep spec: its points' scenarios and the job layout."""

    name: str
    source: str
    scenarios: tuple[str, ...]  # as given (names or paths)
    controllers: tuple[str, ...]
    seeds: tuple[int, ...]
    design: Mapping[str, Any]
    factors: tuple[Factor, ...]
    points: tuple[tuple, ...]  # factor values per design point
    runs: tuple[tuple[scn.Scenario, ...], ...] = field(repr=False)  # [point][scenario]
    digest: str = ""
    measures: tuple[str, ...] = ()  # wmr.measures.MEASURES: columns beyond the RMSEs

    @property
    def n_jobs(self) -> int:
        return len(self.points) * len(self.scenarios) * len(self.controllers) * len(self.seeds)

    def job(self, job_id: int) -> tuple[int, int, int, int]:
        """``(point, scenario index, controller index, seed index)`` of ``job_id``."""
        rest, r = divmod(job_id, len(self.seeds))
        rest, c = divmod(rest, len(self.controllers))
        point, s = divmod(rest, len(self.scenarios))
        return point, s, c, r


def _err(source):
    def fail(ok: bool, key: str, value, reason: str):
        if not ok:
            raise SweepError(source, key, value, reason)

    return fail


#: Column names a factor may not take (the job's own).
_RESERVED = ("job_id", "point", "scenario", "controller", "seed", *COLUMNS, "jac_rel_error",
             "jac_norm_ratio", "jac_sign_v", "jac_sign_w", "recovery_rmse", "recovery_peak")


def _factor(path: str, spec: Any, kind: str, fail) -> Factor:
    key = f"factors.{path}"
    fail(path not in _RESERVED, key, spec, "is a column of every row, not a scenario key to vary")
    if isinstance(spec, list):
        fail(len(spec) > 0, key, spec, "needs at least one level")
        levels = []
        for v in spec:
            vector = isinstance(v, list) and len(v) > 0 and all(
                isinstance(x, int | float) and not isinstance(x, bool) for x in v)  # fmt: skip
            fail(isinstance(v, int | float | str | bool) or vector, key, spec,
                 "levels must be numbers, strings, booleans or arrays of numbers")  # fmt: skip
            levels.append(tuple(v) if vector else v)
        return Factor(path, levels=tuple(levels))
    fail(isinstance(spec, Mapping), key, spec, "must be a list of levels or {low, high[, log]}")
    fail(kind != "grid", key, dict(spec), "a grid needs a list of levels, not a range")
    fail(set(spec) <= {"low", "high", "log"} and {"low", "high"} <= set(spec), key, dict(spec),
         "a range has the keys low, high and optionally log")  # fmt: skip
    low, high, log = spec["low"], spec["high"], spec.get("log", False)
    for name, v in (("low", low), ("high", high)):
        ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
        fail(ok, f"{key}.{name}", v, "must be a finite number")
    fail(isinstance(log, bool), f"{key}.log", log, "must be true or false")
    fail(low <= high, f"{key}.low", low, f"must be <= high = {high}")
    fail(not log or low > 0, f"{key}.low", low, "must be > 0 for a log-uniform range")
    return Factor(path, low=float(low), high=float(high), log=log)


def design_points(factors: Sequence[Factor], design: Mapping[str, Any]) -> list[tuple]:
    """The design's points (factor values, one tuple per point): the full factorial of the
    levels (``grid``), or ``samples`` points of a scrambled Sobol sequence, a Latin hypercube
    or uniform random numbers mapped to the factors (``design.seed`` seeds them)."""
    if not factors:
        return [()]
    if design["kind"] == "grid":
        import itertools

        return list(itertools.product(*(f.levels for f in factors)))
    from scipy.stats import qmc

    n, d, seed = design["samples"], len(factors), design["seed"]
    if design["kind"] == "sobol":
        u = qmc.Sobol(d, scramble=True, seed=seed).random_base2(int(math.log2(n)))
    elif design["kind"] == "lhs":
        u = qmc.LatinHypercube(d, seed=seed).random(n)
    else:
        u = np.random.default_rng(seed).random((n, d))
    return [tuple(f.value(float(x)) for f, x in zip(factors, row, strict=True)) for row in u]


def _set(doc: dict, path: str, value, controller_names: Sequence[str], fail) -> None:
    """Set the factor ``path`` to ``value`` in the scenario document ``doc`` (in place)."""
    parts = path.split(".")
    if parts[0] == "controllers" and len(parts) == 3:
        _, who, name = parts
        targets = controller_names if who == "*" else [who]
        fail(who == "*" or who in controllers.REGISTRY, f"factors.{path}", value,
             f"unknown controller {who!r} (known: {', '.join(controllers.NAMES)})")
        hit = False
        for c in targets:
            fields = {f for f in controllers.get(c).Settings.__dataclass_fields__}
            if name in fields:
                doc.setdefault("controllers", {}).setdefault(c, {})[name] = value
                hit = True
        fail(hit, f"factors.{path}", value,
             f"no selected controller has the setting {name!r}")  # fmt: skip
        return
    node = doc
    for p in parts[:-1]:
        node = node.setdefault(p, {})
        fail(isinstance(node, dict), f"factors.{path}", value, f"{p!r} is not a table")
    node[parts[-1]] = value


def _scenario_doc(entry: Any, source: str, fail) -> tuple[dict, str]:
    """The TOML document and the file of a spec's ``scenarios`` entry."""
    fail(isinstance(entry, str) and entry != "", "scenarios", entry,
         "entries must be built-in names or file paths")  # fmt: skip
    base = Path(source).parent if not source.startswith("<") else Path(".")
    path = base / entry
    if not path.exists() and "/" not in entry and not entry.endswith(".toml"):
        try:
            path = scn.builtin(entry)
        except FileNotFoundError:
            fail(False, "scenarios", entry, f"no such file or built-in scenario "
                                            f"(built-in: {', '.join(scn.shipped())})")
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8")), str(path)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        fail(False, "scenarios", entry, f"cannot read {path}: {err}")
    raise AssertionError  # unreachable


def loads_spec(text: str, source: str = "<spec>") -> Spec:
    """Parse and validate a spec (see the module): :class:`SweepError` on any problem."""
    fail = _err(source)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SweepError(source, "(syntax)", None, f"invalid TOML: {err}") from None
    for key in data:
        fail(key in _TOP_KEYS, key, data[key],
             f"unknown key (known: {', '.join(sorted(_TOP_KEYS))})")  # fmt: skip
    name = data.get("name")
    fail(isinstance(name, str) and name.strip() != "", "name", name, "must be a non-empty string")
    names = data.get("controllers")
    fail(isinstance(names, list) and len(names) > 0, "controllers", names,
         "must be a non-empty list of controller names")  # fmt: skip
    for c in names:
        fail(c in controllers.REGISTRY, "controllers", c,
             f"unknown controller (known: {', '.join(controllers.NAMES)})")  # fmt: skip
    seeds = data.get("seeds")
    if isinstance(seeds, int) and not isinstance(seeds, bool):
        fail(seeds >= 1, "seeds", seeds, "must be >= 1 (or a list of seeds)")
        seeds = list(range(seeds))
    fail(isinstance(seeds, list) and len(seeds) > 0, "seeds", seeds,
         "must be a count >= 1 or a non-empty list of seeds")  # fmt: skip
    for s in seeds:
        fail(isinstance(s, int) and not isinstance(s, bool) and s >= 0, "seeds", s,
             "seeds must be integers >= 0")  # fmt: skip
    fail(len(set(seeds)) == len(seeds), "seeds", seeds, "must not repeat a seed")
    design = _design(data.get("design", {"kind": "grid"}), fail)
    from wmr.measures import MEASURES

    measures = data.get("measures", [])
    fail(isinstance(measures, list), "measures", measures, "must be a list of measure names")
    for m in measures:
        fail(m in MEASURES, "measures", m, f"unknown measure (known: {', '.join(MEASURES)})")
    table = data.get("factors", {})
    fail(isinstance(table, Mapping), "factors", table, "must be a table")
    factors = tuple(_factor(path, spec, design["kind"], fail) for path, spec in table.items())
    entries = data.get("scenarios")
    fail(isinstance(entries, list) and len(entries) > 0, "scenarios", entries,
         "must be a non-empty list")  # fmt: skip
    docs = [_scenario_doc(e, source, fail) for e in entries]
    points = design_points(factors, design)
    runs = tuple(tuple(_point_scenario(doc, src, factors, pt, names, source) for doc, src in docs)
                 for pt in points)  # fmt: skip
    digest = hashlib.sha256(json.dumps(
        {"spec": data, "scenarios": [d for d, _ in docs]}, sort_keys=True, default=str
    ).encode()).hexdigest()  # fmt: skip
    return Spec(name=name, source=source, scenarios=tuple(entries), controllers=tuple(names),
                seeds=tuple(seeds), design=design, factors=factors, points=tuple(points),
                runs=runs, digest=digest, measures=tuple(dict.fromkeys(measures)))  # fmt: skip


def _design(table: Any, fail) -> dict:
    fail(isinstance(table, Mapping), "design", table, "must be a table")
    for key in table:
        fail(key in ("kind", "samples", "seed"), f"design.{key}", table[key],
             "unknown key (known: kind, samples, seed)")  # fmt: skip
    kind = table.get("kind", "grid")
    fail(kind in KINDS, "design.kind", kind, f"must be one of {', '.join(KINDS)}")
    seed = table.get("seed", 0)
    fail(isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0, "design.seed",
         seed, "must be an integer >= 0")  # fmt: skip
    out = {"kind": kind, "seed": seed}
    if kind != "grid":
        n = table.get("samples")
        fail(isinstance(n, int) and not isinstance(n, bool) and n >= 1, "design.samples", n,
             "must be an integer >= 1")  # fmt: skip
        fail(kind != "sobol" or n & (n - 1) == 0, "design.samples", n,
             "must be a power of 2 for a Sobol design")  # fmt: skip
        out["samples"] = n
    else:
        fail("samples" not in table, "design.samples", table.get("samples"),
             "a grid's points are its levels' product: no samples")  # fmt: skip
    return out


def _point_scenario(doc: dict, source: str, factors, values, names, spec: str) -> scn.Scenario:
    """The scenario (file ``source``) of one design point, validated: a value that makes it
    invalid is an error of the spec (file ``spec``), naming the factor."""
    doc = copy.deepcopy(doc)
    for f, v in zip(factors, values, strict=True):
        _set(doc, f.path, v, names, _err(spec))
    try:
        return scn.from_dict(doc, source)
    except scn.ScenarioError as err:
        culprit = _culprit(factors, err.key)
        value = dict(zip((f.path for f in factors), values, strict=True))
        raise SweepError(spec, f"factors.{culprit}" if culprit else err.key,
                         value.get(culprit, err.value),
                         f"makes scenario {source} invalid: {err.key}: {err.reason}") from None


def _culprit(factors, key: str) -> str | None:
    """The factor whose path leads to the scenario key ``key`` (None if none does)."""
    parts = key.split(".")
    for f in factors:
        fp = f.path.split(".")
        if fp[:2] == ["controllers", "*"] and parts[0] == "controllers" and len(parts) > 2:
            if parts[2].split("[")[0] == fp[2]:
                return f.path
        elif key == f.path or key.startswith((f.path + ".", f.path + "[")):
            return f.path
    return None


def load_spec(path: str | Path) -> Spec:
    """Read and validate the spec file ``path``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise SweepError(str(path), "(file)", None, f"cannot read: {err}") from None
    return loads_spec(text, str(path))


# ---------------------------------------------------------------------------------------------
# Jobs and rows


@dataclass(frozen=True)
class SweepJob:
    """One job of a sweep, as sent to a worker (everything it needs, nothing more)."""

    job_id: int
    point: int
    scenario: scn.Scenario
    controller: str
    seed: int
    values: tuple  # the point's factor values
    measures: tuple[str, ...] = ()


def jobs(spec: Spec, job_ids) -> list[SweepJob]:
    """The :class:`SweepJob` of each of ``job_ids``."""
    out = []
    for j in job_ids:
        point, s, c, r = spec.job(j)
        out.append(SweepJob(j, point, spec.runs[point][s], spec.controllers[c], spec.seeds[r],
                            spec.points[point], spec.measures))  # fmt: skip
    return out


def _measure_columns(names) -> tuple[str, ...]:
    from wmr.measures import MEASURES

    return tuple(c for n in names for c in MEASURES[n].columns)


def run_sweep_job(job: SweepJob) -> dict:
    """Run one job; a run that raises becomes an error row (``status = "error"``)."""
    from wmr.sim import simulate

    row = {"job_id": job.job_id, "point": job.point, "scenario": job.scenario.name,
           "controller": job.controller, "seed": job.seed, "values": job.values}  # fmt: skip
    try:
        r = simulate(job.scenario, job.controller, job.seed, keep_trajectory=bool(job.measures))
        if job.measures:
            from wmr.measures import measure

            row.update(measure(job.measures, r, job.scenario))
    except Exception as err:  # noqa: BLE001 - the contract: an error row, the sweep goes on
        row.update(dict.fromkeys(COLUMNS[:9] + _measure_columns(job.measures), math.nan),
                   diverged=False, diverged_at=None, cause=None, status="error",
                   error=one_line(f"{type(err).__name__}: {err}")[:500])  # fmt: skip
        return row
    m, t = r.rmse, r.rmse_after_transient
    row.update(rmse_x=m["x"], rmse_y=m["y"], rmse_theta=m["theta"], rmse_position=m["position"],
               tail_x=t["x"], tail_y=t["y"], tail_theta=t["theta"], tail_position=t["position"],
               effort=r.effort, diverged=r.diverged, diverged_at=r.diverged_at, cause=r.cause,
               status="ok", error=None)  # fmt: skip
    return row


def job_rows(spec: Spec, job_ids) -> list[dict]:
    """The rows of ``job_ids``, run here (the serial path of :func:`run_sweep`)."""
    return [run_sweep_job(j) for j in jobs(spec, job_ids)]


# ---------------------------------------------------------------------------------------------
# The store


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
    """The Parquet schema of the store's rows (DESIGN §3.5)."""
    import pyarrow as pa

    cols = [("job_id", pa.int64()), ("point", pa.int64()), ("scenario", pa.string()),
            ("controller", pa.string()), ("seed", pa.int64())]  # fmt: skip
    cols += [(f.path, _factor_type(f)) for f in spec.factors]
    cols += [(c, pa.float64()) for c in COLUMNS[:9]]
    cols += [("diverged", pa.bool_()), ("diverged_at", pa.float64()), ("cause", pa.string()),
             ("status", pa.string()), ("error", pa.string())]  # fmt: skip
    cols += [(c, pa.float64()) for c in _measure_columns(spec.measures)]
    return pa.schema(cols)


def _table(spec: Spec, rows: list[dict]):
    import pyarrow as pa

    sch = schema(spec)
    paths = [f.path for f in spec.factors]
    cols = {name: [r[name] for r in rows] for name in sch.names if name not in paths}
    for i, path in enumerate(paths):
        as_text = sch.field(path).type == pa.string()
        cols[path] = [str(r["values"][i]) if as_text else r["values"][i] for r in rows]
    return pa.table({name: cols[name] for name in sch.names}, schema=sch)


def write_shard(out: Path, spec: Spec, rows: list[dict]) -> Path | None:
    """Write ``rows`` as a new immutable shard ``rows/part-<time>-<pid>.parquet``, atomically
    (a temporary file, then a rename: a reader never sees a half-written shard)."""
    import pyarrow.parquet as pq

    if not rows:
        return None
    folder = out / "rows"
    folder.mkdir(parents=True, exist_ok=True)
    name = f"part-{time.time_ns():020d}-{os.getpid()}.parquet"
    tmp = folder / f".{name}.tmp"
    pq.write_table(_table(spec, rows), tmp)
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, folder / name)
    return folder / name


def read_rows(out: str | Path, columns: Sequence[str] | None = None):
    """All rows of the store ``out`` as a ``pyarrow.Table`` (None if it has none yet)."""
    import pyarrow.parquet as pq

    shards = sorted((Path(out) / "rows").glob("part-*.parquet"))
    if not shards:
        return None
    import pyarrow as pa

    return pa.concat_tables([pq.read_table(p, columns=columns) for p in shards])


def finished_jobs(out: str | Path) -> set[int]:
    """The ``job_id`` of every row already in the store."""
    table = read_rows(out, ["job_id"])
    return set() if table is None else set(table.column("job_id").to_pylist())


# ---------------------------------------------------------------------------------------------
# The driver


def check_out(out: Path, spec: Spec) -> None:
    """``out`` is empty, or holds a store of this very spec (then the sweep resumes)."""
    if out.exists() and not out.is_dir():
        raise SweepError(spec.source, "--out", str(out), "exists and is not a directory")
    if not out.exists() or not any(out.iterdir()):
        return
    manifest = out / "manifest.json"
    try:
        stored = json.loads(manifest.read_text())["spec_digest"]
    except (OSError, ValueError, KeyError):
        stored = None
    if stored != spec.digest:
        raise SweepError(spec.source, "--out", str(out),
                         "is not empty and holds no store of this spec (a different spec, or "
                         "not a sweep store): give another folder")  # fmt: skip


def _costs(spec: Spec) -> dict:
    """Seconds per step of each (controller, plant kind) on this machine, measured by a short
    run after the warm-up (to size batches: a batch should take seconds)."""
    from wmr.sim import simulate

    out = {}
    for sc in (run for point in spec.runs for run in point):
        for c in spec.controllers:
            key = (c, sc.plant.ideal)
            if key not in out:
                short = replace_duration(sc, min(sc.n_steps, 500))
                t0 = time.perf_counter()
                simulate(short, c, 0, keep_trajectory=False)
                out[key] = (time.perf_counter() - t0) / short.n_steps
    return out


def replace_duration(sc: scn.Scenario, steps: int) -> scn.Scenario:
    """``sc`` cut to ``steps`` steps (its disturbances and plant changes left as they are)."""
    import dataclasses

    return dataclasses.replace(sc, duration=steps * sc.dt)


def batches(spec: Spec, todo: Sequence[int], costs: dict, seconds: float,
            workers: int = 1) -> list[list[int]]:  # fmt: skip
    """Consecutive ``todo`` jobs in batches of about ``seconds`` of work each (estimated from
    ``costs``), shrinking toward the end (guided scheduling: a batch holds at most a
    ``1 / (2 workers)`` share of the work left, so the last batches are short and no worker
    idles long while another finishes).  Rows do not depend on the batching."""
    load = [spec.runs[p][s].n_steps * costs[(spec.controllers[c], spec.runs[p][s].plant.ideal)]
            for p, s, c, _ in map(spec.job, todo)]  # fmt: skip
    left = float(sum(load))
    share = 1.0 / (2 * max(1, int(workers)))
    out, current, acc = [], [], 0.0
    for j, cost in zip(todo, load, strict=True):
        if current and acc + cost > min(seconds, share * left):
            out.append(current)
            left -= acc
            current, acc = [], 0.0
        current.append(j)
        acc += cost
    if current:
        out.append(current)
    return out


def run_sweep(spec: Spec, out: str | Path, *, workers: int | None = None,
              scheduler: str | None = None, batch_seconds: float = 2.0,
              flush_seconds: float = 30.0, progress: bool | None = None) -> dict:  # fmt: skip
    """Run (or resume) the sweep ``spec`` into the store ``out``; returns the manifest.

    ``workers``/``scheduler`` choose the engine (``wmr.study.engine``: 1 = serial here, N = a
    local Dask cluster of N processes, or the cluster at ``scheduler``).  Finished jobs (rows
    already in ``out/rows``) are skipped; completed rows are written as a new shard at least
    every ``flush_seconds``, so an interruption, even SIGKILL, loses at most that much work.
    """
    from wmr import study
    from wmr.io import atomic_write_text, write_json

    out = Path(out)
    check_out(out, spec)
    t0 = time.perf_counter()
    (out / "rows").mkdir(parents=True, exist_ok=True)
    if not (out / "spec.toml").exists():
        atomic_write_text(out / "spec.toml", Path(spec.source).read_text(encoding="utf-8"))
    done = finished_jobs(out)
    todo = [j for j in range(spec.n_jobs) if j not in done]
    before = out / "manifest.json"
    total = json.loads(before.read_text()).get("run_seconds_total", 0.0) if before.exists() else 0.0
    manifest = _manifest(spec, done, started=time.time())
    write_json(out / "manifest.json", {**manifest, "run_seconds_total": total})
    pairs = {(c, sc.plant.ideal): (sc, c) for point in spec.runs for sc in point
             for c in spec.controllers}  # fmt: skip
    with study.engine(workers, scheduler) as eng:
        eng.run_everywhere(study.warm_up, list(pairs.values()))
        groups = batches(spec, todo, _costs(spec), batch_seconds, eng.workers) if todo else []
        keys = [f"wmr-sweep-{spec.digest[:12]}-{g[0]}-{g[-1]}-{len(g)}" for g in groups]
        bar = study.Progress(len(todo), f"sweep {spec.name}", progress)
        buffer, last, t_run = [], time.perf_counter(), time.perf_counter()
        try:
            work = [jobs(spec, g) for g in groups]
            for _, rows in eng.map_batches(run_sweep_job, work, keys):
                buffer.extend(rows)
                bar.update(len(rows))
                if time.perf_counter() - last >= flush_seconds:
                    write_shard(out, spec, buffer)
                    buffer, last = [], time.perf_counter()
        finally:
            write_shard(out, spec, buffer)  # what is complete is kept, even on an interrupt
            bar.close()
        run_s = time.perf_counter() - t_run  # the engine's start and stop are in ``seconds``
        manifest.update(engine=eng.name, workers=eng.workers)
    done = finished_jobs(out)
    manifest.update(_manifest(spec, done, started=manifest["started"]),
                    engine=manifest["engine"], workers=manifest["workers"],
                    seconds=round(time.perf_counter() - t0, 3), run_seconds=round(run_s, 3),
                    run_seconds_total=round(total + run_s, 3), runs_this_time=len(todo),
                    runs_per_s=round(len(todo) / run_s, 3) if run_s > 0 and todo else None,
                    batch_seconds=batch_seconds, flush_seconds=flush_seconds,
                    batches=len(groups), finished=time.time())  # fmt: skip
    write_json(out / "manifest.json", manifest)
    summarise(out, spec)
    return manifest


def _manifest(spec: Spec, done: set, started: float) -> dict:
    import wmr

    return {"name": spec.name, "spec_digest": spec.digest, "wmr_version": wmr.__version__,
            "design": dict(spec.design), "factors": [f.path for f in spec.factors],
            "points": len(spec.points), "scenarios": list(spec.scenarios),
            "controllers": list(spec.controllers), "seeds": len(spec.seeds),
            "jobs": spec.n_jobs, "done": len(done), "complete": len(done) == spec.n_jobs,
            "started": started}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Summary: main effects


def _levels(values, bins: int = 6):
    """Group keys of a factor column: its levels (up to 12 distinct), else quantile bins."""
    import pandas as pd

    if values.nunique() <= 12:
        return values
    return pd.qcut(values, bins, duplicates="drop").apply(lambda iv: iv.mid)


def summarise(out: str | Path, spec: Spec) -> dict:
    """``summary.md`` and ``summary.png`` of the store: counts, each controller's position RMSE,
    and the main effects (mean position RMSE against each factor, per controller)."""
    import matplotlib.pyplot as plt

    from wmr.io import atomic_write_text, save_figure

    out = Path(out)
    table = read_rows(out)
    if table is None:
        return {}
    df = table.to_pandas()
    ok = df[(df.status == "ok") & ~df.diverged]
    lines = [f"# Sweep {spec.name}", "",
             f"{len(df)} of {spec.n_jobs} runs in the store ({len(spec.points)} design points x "
             f"{len(spec.scenarios)} scenarios x {len(spec.controllers)} controllers x "
             f"{len(spec.seeds)} seeds); errors: {int((df.status == 'error').sum())}, diverged: "
             f"{int(df.diverged.sum())}.", "",
             "| controller | runs | position RMSE mean | std | after transient mean |",
             "|---|---:|---:|---:|---:|"]  # fmt: skip
    for c in spec.controllers:
        d = ok[ok.controller == c]
        lines.append(f"| {c} | {len(d)} | {d.rmse_position.mean():.4g} | "
                     f"{d.rmse_position.std():.3g} | {d.tail_position.mean():.4g} |")
    n = max(1, len(spec.factors))
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.6), squeeze=False, layout="constrained")
    for ax, f in zip(axes[0], spec.factors, strict=False):
        keys = _levels(ok[f.path])
        means = ok.groupby([keys, ok.controller], observed=True).rmse_position.mean().unstack()
        lines += ["", f"Main effect of `{f.path}` (mean position RMSE [m]):", "",
                  "| level | " + " | ".join(means.columns) + " |",
                  "|---|" + "---:|" * len(means.columns)]  # fmt: skip
        for level, row in means.iterrows():
            shown = f"{level:.4g}" if isinstance(level, float) else str(level)
            lines.append(f"| {shown} | " + " | ".join(f"{v:.4g}" for v in row) + " |")
        for c in means.columns:
            ax.plot(range(len(means)) if means.index.dtype == object else means.index,
                    means[c], "o-", color=controllers.colour(c), label=controllers.label(c))
        ax.set(xlabel=f.path, ylabel="mean position RMSE [m]")
        if f.log:
            ax.set_xscale("log")
    if spec.factors:
        axes[0, 0].legend(fontsize=8)
    else:
        axes[0, 0].set_axis_off()
    fig.suptitle(f"sweep {spec.name}: main effects")
    save_figure(fig, out / "summary.png")
    plt.close(fig)
    atomic_write_text(out / "summary.md", "\n".join(lines) + "\n\n![main effects](summary.png)\n")
    return {"rows": len(df)}
