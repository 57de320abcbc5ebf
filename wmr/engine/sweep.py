"""Sweeps (DESIGN §3.5): a spec file, its design, its jobs and the summary of its store.

```toml
name = "mismatch-vs-mu" scenarios = ["lemniscate", "my-scenario.toml"]   # built-in names, or paths
relative to this file controllers = ["pid", "adaptive-pid", "iapid-nn-dekf"] seeds = 20
# seeds 0..19, or a list [3, 7] measures = ["jacobian", "recovery"]              # optional:
wmr.closedloop.measures (columns beyond RMSEs)

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
design point the same noise (common random numbers).  The spec's ``digest`` covers the spec, every
scenario file it names and any file those name (a waypoint table).

Running a sweep is the engine's (``wmr.engine.sweeps``; its names ``run_sweep``, ``read_rows``,
``check_out``, ``finished_jobs``, ``error_jobs``, ``schema``, ``write_shard`` are importable from
here too): the store is a folder, ``spec.toml`` (a copy), ``manifest.json``, and
``rows/part-*.parquet``, immutable shards each written atomically and flushed at least every
``flush_seconds`` of work; rerunning the same command resumes (finished jobs are skipped, none
runs twice) and a different spec in a non-empty folder is refused.  :func:`summarise` writes
``summary.md`` and ``summary.png`` (main effects: mean position RMSE against each factor, per
controller).
"""

from __future__ import annotations

import copy
import hashlib
import importlib
import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wmr import controllers
from wmr import scenario as scn
from wmr._settings import InputError
from wmr.engine.jobs import COLUMNS, Job

#: Names of running a sweep, defined in ``wmr.engine.sweeps`` (see ``__getattr__``).
_ENGINE = ("run_sweep", "read_rows", "check_out", "finished_jobs", "error_jobs", "schema",
           "write_shard")
__all__ = ["SweepError", "Factor", "Spec", "load_spec", "loads_spec", "design_points", "COLUMNS",
           "jobs", "summarise", *_ENGINE]  # fmt: skip

#: Design kinds.
KINDS = ("grid", "sobol", "lhs", "random")
_TOP_KEYS = {"name", "scenarios", "controllers", "seeds", "design", "factors", "measures",
             "plugins"}


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
    measures: tuple[str, ...] = ()  # wmr.closedloop.measures.MEASURES: columns beyond the RMSEs

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
    loaded = _plugins(data.get("plugins", []), source, fail)
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
    from wmr.closedloop.measures import MEASURES

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
    inputs: dict = {"spec": data, "scenarios": [d for d, _ in docs]}
    files = {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for d, src in docs
             for p in _named_files(d, src)}  # fmt: skip
    if files:  # (a spec that names no file keeps the digest it always had)
        inputs["files"] = files
    if loaded:  # the plugins' code is an input of their runs
        inputs["plugins"] = {p.ref: hashlib.sha256(p.source).hexdigest() if p.source else p.ref
                             for p in loaded}  # fmt: skip
    digest = hashlib.sha256(json.dumps(inputs, sort_keys=True, default=str).encode()).hexdigest()
    return Spec(name=name, source=source, scenarios=tuple(entries), controllers=tuple(names),
                seeds=tuple(seeds), design=design, factors=factors, points=tuple(points),
                runs=runs, digest=digest, measures=tuple(dict.fromkeys(measures)))  # fmt: skip


def _plugins(refs: Any, source: str, fail) -> tuple:
    """Load the spec's ``plugins`` (DESIGN §3.8: files relative to the spec, or module names)
    before its controllers are checked; a bad plugin is a :class:`SweepError` naming it."""
    from wmr import plugins

    fail(isinstance(refs, list) and all(isinstance(r, str) for r in refs), "plugins", refs,
         "must be a list of plugin files or module names")  # fmt: skip
    base = Path(source).parent if not source.startswith("<") else None
    out = []
    for ref in refs:
        try:
            out.append(plugins.load(ref, base_dir=base))
        except plugins.PluginError as err:
            fail(False, "plugins", ref, str(err))
    return tuple(out)


def _named_files(doc: Mapping, source: str) -> list[Path]:
    """The files a scenario document (file ``source``) names: every ``file`` key of its tables
    (a waypoint table's ``reference.file``), relative to the scenario's folder (the scenario is
    already valid, so they exist)."""
    base = Path(source).parent if not source.startswith("<") else Path(".")
    out = []
    for key, value in doc.items():
        if key == "file" and isinstance(value, str):
            out.append(base / value)
        elif isinstance(value, Mapping):
            out += _named_files(value, source)
        elif isinstance(value, list):
            out += [p for v in value if isinstance(v, Mapping) for p in _named_files(v, source)]
    return out


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
# Jobs


def jobs(spec: Spec, job_ids) -> list[Job]:
    """The job (``wmr.engine.jobs.Job``) of each of ``job_ids``: its run, and as labels its
    design point and the point's factor values (columns named by the factors' paths)."""
    out = []
    paths = [f.path for f in spec.factors]
    for j in job_ids:
        point, s, c, r = spec.job(j)
        labels = (("point", point), *zip(paths, spec.points[point], strict=True))
        out.append(Job(spec.runs[point][s], spec.controllers[c], spec.seeds[r],
                       measures=spec.measures, job_id=j, labels=labels))  # fmt: skip
    return out


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

    from wmr.engine.store import ShardStore
    from wmr.io import atomic_write_text, save_figure

    out = Path(out)
    table = ShardStore(out).read()
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
    shown_factors = [f for f in spec.factors if ok[f.path].astype(str).nunique() > 1]
    n = max(1, len(shown_factors))  # (a single-level factor has no main effect to draw)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 3.6), squeeze=False, layout="constrained")
    panels = iter(axes[0])
    for f in spec.factors:
        keys = _levels(ok[f.path])
        means = ok.groupby([keys, ok.controller], observed=True).rmse_position.mean().unstack()
        lines += ["", f"Main effect of `{f.path}` (mean position RMSE [m]):", "",
                  "| level | " + " | ".join(means.columns) + " |",
                  "|---|" + "---:|" * len(means.columns)]  # fmt: skip
        for level, row in means.iterrows():
            shown = f"{level:.4g}" if isinstance(level, float) else str(level)
            lines.append(f"| {shown} | " + " | ".join(f"{v:.4g}" for v in row) + " |")
        if f not in shown_factors:
            continue
        ax = next(panels)
        for c in means.columns:
            ax.plot(range(len(means)) if means.index.dtype == object else means.index,
                    means[c], "o-", color=controllers.colour(c), label=controllers.label(c))
        ax.set(xlabel=f.path, ylabel="mean position RMSE [m]")
        if f.log:
            ax.set_xscale("log")
    if shown_factors:
        axes[0, 0].legend(fontsize=8)
    else:
        axes[0, 0].set_axis_off()
    fig.suptitle(f"sweep {spec.name}: main effects")
    save_figure(fig, out / "summary.png")
    plt.close(fig)
    atomic_write_text(out / "summary.md", "\n".join(lines) + "\n\n![main effects](summary.png)\n")
    return {"rows": len(df)}


def __getattr__(name: str):
    """The names of running a sweep, from ``wmr.engine.sweeps`` (loaded on first use)."""
    if name in _ENGINE:
        return getattr(importlib.import_module("wmr.engine.sweeps"), name)
    raise AttributeError(f"module 'wmr.engine.sweep' has no attribute {name!r}")
