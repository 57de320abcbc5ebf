"""This tree against a given commit, pair by pair, in one run (issue 25 item 4; issue 19 item 7).

``compare(ref)`` makes (or reuses) a git worktree of ``ref`` beside the repository's temporary
files and runs the same small timing program in two fresh processes -- one importing this tree's
``wmr``, one the worktree's (``PYTHONPATH`` first: it comes before the editable install) -- in
turn, ABBA, ``pairs`` times.  Each process warms every controller up, then times ``runs`` full
lemniscate runs of each (this thread's CPU time per run, set-up included) and as many one-step
runs (the set-up alone), and reports the medians; the rows of :data:`DRIVER_ROWS` time the same
on short runs through the Python driver and on the MuJoCo robot.  The ratio of the two trees is
taken pair by pair, so a drift of the machine's speed between pairs cancels; the median ratio
is reported with a distribution-free interval (order statistics of the pairs,
:func:`median_interval`).
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["NOTE", "PROGRAM", "DRIVER_ROWS", "worktree", "time_tree", "compare",
           "median_interval", "table"]

#: The timing program, run in a fresh interpreter against the ``wmr`` on its path.  It uses only
#: what every version of the suite has (scenario.load/builtin, sim.simulate).  A variant
#: ``name~approximate`` is the controller with ``gradient = "approximate"`` (the SGD step without
#: the exact gradient's heading term, as before it was added), where the tree has that setting.
#: A suffix ``@python`` runs the controller through the Python driver, ``@mujoco`` on the shipped
#: MuJoCo robot (``mujoco/lemniscate``, where the tree has it), both over the first
#: :data:`SHORT_SECONDS` of the run.  ``steps`` is each row's step count: per step = (run -
#: set-up) / steps.
PROGRAM = r"""
import dataclasses, importlib, json, sys, time
import numpy as np
import wmr
from wmr import controllers, scenario as scn
try:
    from wmr.closedloop import sim
except ImportError:  # a commit before wmr's subpackages (spelt so that no rewrite touches it)
    sim = importlib.import_module("wmr" + ".sim")
names, runs, short_s = sys.argv[1].split(","), int(sys.argv[2]), float(sys.argv[3])
lem = scn.load(scn.builtin("lemniscate"))
jobs = {}
for name in names:
    head, _, mode = name.partition("@")
    base, _, variant = head.partition("~")
    if base not in controllers.REGISTRY:
        continue
    if not mode and not getattr(controllers.get(base), "compiled", True):
        continue  # a Python-level controller (nmpc): its own bench row times it
    sc, driver = lem, None
    if mode == "python":
        sc, driver = dataclasses.replace(lem, duration=short_s), "python"
    elif mode == "mujoco":
        try:
            sc = scn.load(scn.builtin("mujoco/lemniscate"))
        except (FileNotFoundError, OSError):
            continue
        sc = dataclasses.replace(sc, duration=short_s)
    st = None
    if variant:
        try:
            st = dataclasses.replace(sc.settings(base), gradient=variant)
        except TypeError:
            continue
    # a commit before the Python driver has no `driver` argument: pass it only when it is used
    jobs[name] = (base, st, sc, dataclasses.replace(sc, duration=sc.dt),
                  {"driver": driver} if driver else {})
for base, st, sc, one, driver in jobs.values():  # warm-up: compilation or the disk cache
    sim.simulate(sc, base, 0, settings=st, keep_trajectory=False, **driver)
    sim.simulate(one, base, 0, settings=st, keep_trajectory=False, **driver)
out = {"wmr": wmr.__file__, "run_ms": {}, "setup_ms": {}, "steps": {}}
for name, (base, st, sc, one, driver) in jobs.items():
    full, short = [], []
    for seed in range(runs):
        t0 = time.thread_time()
        sim.simulate(sc, base, seed, settings=st, keep_trajectory=False, **driver)
        full.append(time.thread_time() - t0)
        t0 = time.thread_time()
        sim.simulate(one, base, seed, settings=st, keep_trajectory=False, **driver)
        short.append(time.thread_time() - t0)
    out["run_ms"][name] = 1e3 * float(np.median(full))
    out["setup_ms"][name] = 1e3 * float(np.median(short))
    out["steps"][name] = sc.n_steps
print(json.dumps(out))
"""
#: Rows :func:`compare` adds by default: the Python driver and the MuJoCo robot (short runs).
DRIVER_ROWS = ("backstepping@python", "pid@python", "iapid-nn-dekf@python",
               "backstepping@mujoco", "pid@mujoco", "iapid-nn-dekf@mujoco")
#: The duration [s] of the rows of :data:`DRIVER_ROWS`.
SHORT_SECONDS = 2.0


def worktree(ref: str, repo: Path | None = None) -> Path:
    """A detached git worktree of ``ref`` (a commit, tag or branch) of ``repo`` (default: the
    repository this file is in), made under the temporary folder once and reused."""
    repo = Path(repo or Path(__file__).resolve().parents[2])
    sha = subprocess.run(["git", "-C", str(repo), "rev-parse", "--verify", f"{ref}^{{commit}}"],
                         capture_output=True, text=True, check=True).stdout.strip()  # fmt: skip
    path = Path(tempfile.gettempdir()) / f"wmr-against-{sha[:12]}"
    if not (path / "wmr" / "__init__.py").exists():
        subprocess.run(["git", "-C", str(repo), "worktree", "add", "--detach", str(path), sha],
                       capture_output=True, text=True, check=True)  # fmt: skip
    return path


def time_tree(tree: Path, names, runs: int, short_seconds: float = SHORT_SECONDS) -> dict:
    """One process of :data:`PROGRAM` against the ``wmr`` of ``tree``: its medians."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        filter(None, (str(tree), os.environ.get("PYTHONPATH"))))}  # fmt: skip
    out = subprocess.run([sys.executable, "-c", PROGRAM, ",".join(names), str(runs),
                          repr(short_seconds)],
                         capture_output=True, text=True, env=env, cwd=str(tree), check=True,
                         timeout=1800)  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def _per_step(rec: dict) -> dict:
    """``rec`` with ``step_us``: (run - set-up) / steps [us] per row (a tree's program that
    reports its steps)."""
    if "steps" in rec:
        rec["step_us"] = {name: 1e3 * (rec["run_ms"][name] - rec["setup_ms"][name]) / n
                          for name, n in rec["steps"].items()}  # fmt: skip
    return rec


def median_interval(x, level: float = 0.9) -> tuple[float, float, float]:
    """``(median, low, high)`` of ``x`` with a distribution-free interval for the median: the
    order statistics ``x_(j)``, ``x_(n+1-j)`` with the largest ``j`` whose binomial(n, 1/2)
    coverage is at least ``level`` (the whole range when ``n`` is too small for it)."""
    x = np.sort(np.asarray(x, dtype=float))
    n = x.size
    j = 1
    for cand in range(1, n // 2 + 1):
        cover = 1.0 - 2.0 * sum(math.comb(n, i) for i in range(cand)) / 2.0**n
        if cover >= level:
            j = cand
    return float(np.median(x)), float(x[j - 1]), float(x[n - j])


def compare(ref: str, names, pairs: int = 5, runs: int = 20, level: float = 0.9,
            extra=DRIVER_ROWS) -> dict:
    """This tree against ``ref``: per controller (``names`` and the ``extra`` rows), the per-run,
    set-up and per-step CPU medians of each side (the median over pairs) and the paired ratio
    this / ``ref`` with its interval."""
    names = (*names, *(x for x in extra if x not in names))
    here = Path(__file__).resolve().parents[2]
    there = worktree(ref, here)
    rounds = []
    for i in range(pairs):  # ABBA: each side as often first as second
        order = ((here, "this"), (there, "ref")) if i % 2 == 0 else ((there, "ref"), (here, "this"))
        rounds.append({side: _per_step(time_tree(tree, names, runs)) for tree, side in order})
    out = {"ref": ref, "pairs": pairs, "runs_per_process": runs, "level": level,
           "controllers": {}, "this_only": {}}  # fmt: skip
    for name in names:
        if not all(name in r["ref"]["run_ms"] for r in rounds):  # e.g. a setting ref lacks
            if all(name in r["this"]["run_ms"] for r in rounds):
                out["this_only"][name] = {k: float(np.median([r["this"][k][name] for r in rounds]))
                                          for k in ("run_ms", "setup_ms", "step_us")
                                          if all(k in r["this"] for r in rounds)}  # fmt: skip
            continue
        row = {}
        for key in ("run_ms", "setup_ms", "step_us"):
            if not all(key in r[side] for r in rounds for side in ("this", "ref")):
                continue
            this = [r["this"][key][name] for r in rounds]
            that = [r["ref"][key][name] for r in rounds]
            med, lo, hi = median_interval([a / b for a, b in zip(this, that, strict=True)], level)
            row[key] = {"this": float(np.median(this)), "ref": float(np.median(that)),
                        "ratio": med, "ratio_low": lo, "ratio_high": hi}  # fmt: skip
        out["controllers"][name] = row
    return out


def table(rec: dict) -> list[str]:
    """Markdown lines of a :func:`compare` record (per-step columns when it measured them)."""
    steps = any("step_us" in v for v in rec["controllers"].values())
    lines = [f"Against {rec['ref']} ({rec['pairs']} pairs of processes, {rec['runs_per_process']} "
             f"runs each; ratio this / ref, median and {100 * rec['level']:.0f} % interval over "
             "the pairs; CPU ms per run, the 40 s lemniscate (@python, @mujoco: the first "
             f"{SHORT_SECONDS:g} s through the Python driver, on the MuJoCo robot), set-up = a "
             "one-step run" + ("; per step [us] = (run - set-up) / steps" if steps else "")
             + "):", "",
             "| controller | run this | run ref | run ratio | set-up this | set-up ref "
             "| set-up ratio |" + (" step this | step ref | step ratio |" if steps else ""),
             "|---|---:|---:|---:|---:|---:|---:|" + ("---:|---:|---:|" if steps else "")]
    for name, v in rec["controllers"].items():
        cells = [name]
        for key in ("run_ms", "setup_ms", "step_us")[: 3 if steps else 2]:
            r = v.get(key)
            cells += (["—"] * 3 if r is None else
                      [f"{r['this']:.3f}", f"{r['ref']:.3f}", f"{r['ratio']:.3f} "
                       f"[{r['ratio_low']:.3f}, {r['ratio_high']:.3f}]"])  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    for name, v in rec.get("this_only", {}).items():
        lines.append(f"| {name} (this tree only) | {v['run_ms']:.3f} | — | — "
                     f"| {v['setup_ms']:.3f} | — | — |" + (" — | — | — |" if steps else ""))
    return lines + [""]


#: The performance record's note on this measurement (``analysis.performance.notes``).
NOTE = (
    "against (with wmr bench --against REF): analysis.performance.against times this tree and a "
    "git "
    "worktree of REF in fresh processes in turn (ABBA), per-run and one-step CPU medians. The "
    "ratio is the median over the pairs of this / REF, with a distribution-free interval (order "
    "statistics). The row adaptive-pid~approximate is APID without the exact gradient's heading "
    "term (this tree only when REF predates the setting): the difference to adaptive-pid is the "
    "exact gradient's own cost. Rows @python and @mujoco are 2 s runs through the Python driver "
    "and on the shipped MuJoCo robot; per step = (run - set-up) / steps."
)
