"""Reliability study (issue 7): bad inputs tried, faults injected, long runs, determinism.

``run`` writes ``out/results/reliability.json`` with, for each check, what was tried and what
happened, and ``out/tables/reliability.md``; ``check`` asserts every outcome is the expected one;
``render`` gives the report's "Reliability" section.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from analysis import common
from analysis.common import fmt
from wmr import cli, controllers
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.engine.study import Job, run_jobs
from wmr.estimation.ekf import repair_covariance

__all__ = ["STEM", "TITLE", "BAD_SCENARIOS", "BAD_OPTIONS", "bad_inputs", "long_runs",
           "seam_crossings", "fault_injection", "determinism", "run", "check", "table", "render"]

STEM = "reliability"
TITLE = "Reliability"
#: Peak resident memory [MB] allowed to ``wmr run`` of one hour with trajectories (issue 12).
RUN_MEMORY_MB = 500.0

_VALID = """name = "r"
duration = 2.0
dt = 0.01
initial_pose = [0.0, 0.0, 0.0]
[reference]
kind = "sinusoid"
speed = 0.5
amplitude = 1.0
omega = 0.5
"""
#: Malformed scenario files: (what is wrong, the file's text).
BAD_SCENARIOS: list[tuple[str, str]] = [
    ("TOML syntax error", _VALID.replace("dt = 0.01", "dt = = 0.01")),
    ("missing key", _VALID.replace('name = "r"\n', "")),
    ("wrong type", _VALID.replace("dt = 0.01", 'dt = "fast"')),
    ("NaN", _VALID.replace("dt = 0.01", "dt = nan")),
    ("infinity", _VALID.replace("duration = 2.0", "duration = inf")),
    ("non-positive dt", _VALID.replace("dt = 0.01", "dt = 0.0")),
    ("negative duration", _VALID.replace("duration = 2.0", "duration = -2.0")),
    ("dt > duration", _VALID.replace("dt = 0.01", "dt = 5.0")),
    ("duration not a whole number of steps", _VALID.replace("dt = 0.01", "dt = 0.03")),
    ("absurd size", _VALID.replace("duration = 2.0", "duration = 1e9")),
    ("wrong vector length", _VALID.replace("[0.0, 0.0, 0.0]", "[0.0, 0.0]")),
    ("unknown reference kind", _VALID.replace('kind = "sinusoid"', 'kind = "spiral"')),
    ("unknown key", "colour = 3\n" + _VALID),
    ("unknown key in a table", _VALID + "[noise]\npose_std = [0.0, 0.0, 0.0]\nbias = 1\n"),
    ("negative noise", _VALID + "[noise]\npose_std = [0.01, -0.01, 0.0]\n"),
    ("reversed disturbance window",
     _VALID + "[[disturbance]]\nstart = 1.5\nstop = 1.0\nvelocity = [0.1, 0.3]\n"),
    ("disturbance outside the run",
     _VALID + "[[disturbance]]\nstart = 5.0\nstop = 6.0\nvelocity = [0.1, 0.3]\n"),
    ("unknown controller section", _VALID + "[controllers.mpc]\nhorizon = 3\n"),
    ("non-positive gain", _VALID + "[controllers.backstepping]\ngains = [2.0, -1.0, 4.0]\n"),
    ("unknown integrator", _VALID.replace('name = "r"', 'name = "r"\nintegrator = "rk45"')),
    ("not UTF-8", "\udcff"),
    ("unknown plant key", _VALID + "[plant]\nv_gian = 0.8\n"),
    ("negative actuator lag", _VALID + "[plant]\nactuator_tau = -0.1\n"),
    ("fractional delay", _VALID + "[plant]\ndelay_steps = 1.5\n"),
    ("lagged-velocity model without [plant.lagged-velocity]",
     _VALID + '[plant]\nmodel = "lagged-velocity"\n'),
    ("non-positive mass",
     _VALID + '[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\nmass = 0.0\n'),
    ("plant change after the run", _VALID + "[plant]\n[[plant.change]]\nat = 9.0\nslip = 0.1\n"),
    ("plant change of a fixed key",
     _VALID + "[plant]\n[[plant.change]]\nat = 1.0\ndelay_steps = 3\n"),
    ("the earlier model name", _VALID + '[plant]\nmodel = "dynamic"\n[plant.dynamic]\n'),
    ("too few waypoints", _VALID.replace(
        'kind = "sinusoid"\nspeed = 0.5\namplitude = 1.0\nomega = 0.5',
        'kind = "waypoints"\npoints = [[0.0, 0.0, 0.0], [3.0, 1.0, 0.0]]')),
    ("missing waypoint file", _VALID.replace(
        'kind = "sinusoid"\nspeed = 0.5\namplitude = 1.0\nomega = 0.5',
        'kind = "waypoints"\nfile = "nowhere.csv"')),
]  # fmt: skip
#: Bad command-line options: (what is wrong, argv after the scenario path is substituted).
BAD_OPTIONS: list[tuple[str, list[str]]] = [
    ("unknown controller", ["run", "{ok}", "--controller", "mpc"]),
    ("non-integer seed", ["run", "{ok}", "--seed", "x"]),
    ("negative seed", ["run", "{ok}", "--seed", "-1"]),
    ("missing file", ["run", "{dir}/nope.toml"]),
    ("folder as scenario", ["run", "{dir}"]),
    ("unknown command", ["fly"]),
    ("unknown option", ["run", "{ok}", "--speed", "3"]),
    ("zero seeds", ["reproduce", "--seeds", "0", "--out", "{dir}/rep"]),
]


def _cli(argv: list[str]) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = cli.main(argv)
    return code, err.getvalue()


def bad_inputs() -> dict:
    """Every malformed scenario and bad option through the CLI: exit 2, one line, nothing
    written."""
    outcomes = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        ok = tmp_path / "ok.toml"
        ok.write_text(_VALID)
        cases = []
        for what, text in BAD_SCENARIOS:
            path = tmp_path / f"bad-{len(cases)}.toml"
            path.write_bytes(text.encode("utf-8", "surrogateescape"))
            cases.append((f"scenario: {what}", ["run", str(path), "--out", str(tmp_path / "o")]))
        for what, argv in BAD_OPTIONS:
            cases.append((f"option: {what}", [a.format(ok=ok, dir=tmp) for a in argv]))
        for what, argv in cases:
            code, err = _cli(argv)
            lines = err.strip().splitlines()
            written = (tmp_path / "o").exists() or (tmp_path / "rep").exists()
            outcomes.append({"input": what, "exit_code": code, "one_line": len(lines) == 1,
                             "starts_with_error": bool(lines) and lines[0].startswith("error: "),
                             "traceback": "Traceback" in err, "wrote_output": written,
                             "message": lines[0].replace(tmp, "<tmp>") if lines else "",
                             })  # fmt: skip
    good = [o for o in outcomes if o["exit_code"] == 2 and o["one_line"] and
            o["starts_with_error"] and not o["traceback"] and not o["wrote_output"]]  # fmt: skip
    return {"tried": len(outcomes), "as_expected": len(good), "cases": outcomes}


def long_runs(hours: float = 1.0, names=None) -> dict:
    """A long run of every controller (``names``: those only; no trajectory kept): finite, and
    memory independent of the run length (peak traced allocation of a run of 2 chunks of
    ``wmr.closedloop.step.CHUNK`` steps vs the full run; below one chunk the buffers are smaller, so
    that is the fair baseline)."""
    from wmr.closedloop.step import CHUNK

    sc = scn.load(scn.builtin("lemniscate"))
    out = {}
    for name in names or controllers.NAMES:
        simulate(dataclasses.replace(sc, duration=1.0), name, seed=0)  # compile outside the trace
        peaks = []
        for duration in (2 * CHUNK * sc.dt, hours * 3600.0):
            sc_long = dataclasses.replace(sc, duration=duration)
            tracemalloc.start()
            t0 = time.perf_counter()
            r = simulate(sc_long, name, seed=0, keep_trajectory=False)
            elapsed = time.perf_counter() - t0
            peaks.append(tracemalloc.get_traced_memory()[1])
            tracemalloc.stop()
        out[name] = {"steps": sc_long.n_steps, "diverged": r.diverged, "cause": r.cause,
                     "finite": all(math.isfinite(v) for v in r.rmse.values()),
                     "rmse_position": r.rmse["position"], "seconds": round(elapsed, 2),
                     "peak_traced_mb_short": round(peaks[0] / 2**20, 3),
                     "peak_traced_mb_long": round(peaks[1] / 2**20, 3)}  # fmt: skip
    return out


#: Runs ``wmr run`` and then reports the process's own peak resident memory: ``VmHWM`` of
#: ``/proc/self/status`` (the high-water mark of this program's memory since its exec; the
#: ``ru_maxrss`` a parent sees after ``wait`` also counts the parent's memory at the fork).
_MEASURED_RUN = """
import resource, sys
from wmr import cli
code = cli.main(sys.argv[1:])
try:
    kb = next(int(line.split()[1]) for line in open("/proc/self/status")
              if line.startswith("VmHWM:"))
except OSError:
    kb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(f"peak-kb {kb}", file=sys.stderr)
sys.exit(code)
"""


def run_memory(hours: float = 1.0) -> dict:
    """``wmr run`` of every controller over ``hours`` of the lemniscate *with* trajectories (CSV
    and figure), in a child process: its peak resident memory, wall time and what it wrote."""
    import subprocess

    sc = scn.load(scn.builtin("lemniscate"))
    text = Path(scn.builtin("lemniscate")).read_text().replace(
        f"duration = {sc.duration}", f"duration = {hours * 3600.0}")  # fmt: skip
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "long.toml"
        path.write_text(text)
        argv = [sys.executable, "-c", _MEASURED_RUN, "run", str(path), "--controller", "all",
                "--out", str(Path(tmp) / "out")]  # fmt: skip
        t0 = time.perf_counter()
        done = subprocess.run(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        elapsed = time.perf_counter() - t0
        lines = done.stderr.strip().splitlines()
        peak = next((int(x.split()[1]) for x in lines if x.startswith("peak-kb ")), -1024)
        files = sorted(p.name for p in (Path(tmp) / "out").glob("*"))
        size = sum(p.stat().st_size for p in (Path(tmp) / "out").glob("*"))
    return {"hours": hours, "steps": round(hours * 3600.0 / sc.dt),
            "controllers": len(controllers.NAMES), "exit_code": done.returncode,
            "stderr": "\n".join(x for x in lines if not x.startswith("peak-kb "))[:200],
            "seconds": round(elapsed, 1), "peak_rss_mb": round(peak / 1024, 1), "files": files,
            "written_mb": round(size / 2**20, 1)}  # fmt: skip


def shipped_scenarios(max_seconds: float | None = None) -> dict:
    """Every shipped scenario with every controller (seed 0): finite, or its divergence reported
    with time and cause.  ``max_seconds``: each run cut to at most this long (the quick level)."""
    out = {}
    for name in scn.shipped():
        sc = scn.load(scn.builtin(name))
        if max_seconds is not None and sc.duration > max_seconds:
            sc = dataclasses.replace(sc, duration=max_seconds)
        out[name] = {"plant": sc.plant.describe()}
        for c in controllers.NAMES:
            r = simulate(sc, c, seed=0, keep_trajectory=False)
            out[name][c] = {"rmse_position": r.rmse["position"], "diverged": r.diverged,
                            "diverged_at": r.diverged_at, "cause": r.cause}  # fmt: skip
    return out


def seam_crossings(turns: int = 50) -> dict:
    """Circles of many turns: the heading crosses ±pi twice a turn; errors must stay small."""
    text = (f'name = "seam"\nduration = {10.0 * turns}\ndt = 0.01\n'
            'initial_pose = [1.0, 0.0, 1.5707963267948966]\n'
            '[reference]\nkind = "circle"\nradius = 1.0\nperiod = 10.0\n'
            '[noise]\npose_std = [0.01, 0.01, 0.01]\n')  # fmt: skip
    sc = scn.loads(text, "seam")
    out = {"turns": turns, "expected_seam_crossings": turns}  # heading grows by 2 pi per turn
    for name in controllers.NAMES:
        r = simulate(sc, name, seed=0)
        wrapped = np.angle(np.exp(1j * r.q[:, 2]))
        crossings = int(np.sum(np.abs(np.diff(wrapped)) > np.pi))
        out[name] = {"diverged": r.diverged, "rmse_theta": r.rmse["theta"],
                     "heading_seam_crossings": crossings}  # fmt: skip
    return out


def fault_injection() -> dict:
    """Faults injected on purpose and what the suite did about them."""
    sc = scn.load(scn.builtin("sinusoid"))
    res = {}
    # 1. a covariance with a negative diagonal entry is repaired and counted
    P = np.eye(4)
    P[2, 2] = -1.0
    repaired = bool(repair_covariance(P, 1e-12))
    res["negative_covariance_diagonal"] = {
        "repaired": repaired, "positive_definite_after": bool(np.all(np.linalg.eigvalsh(P) > 0))}
    # 2. a controller whose output overflows: the run stops with a non-finite cause
    from wmr.controllers import backstepping

    wild = backstepping.Settings(gains=(1e308, 1e308, 1e308))
    r = simulate(sc, "backstepping", seed=0, settings=wild)
    res["overflowing_controller"] = {"diverged": r.diverged, "diverged_at": r.diverged_at,
                                     "cause": r.cause}  # fmt: skip
    # 3. huge measurement noise: each run is reported (diverged or not), the study goes on
    noisy = dataclasses.replace(sc, noise=scn.Noise((5.0, 5.0, 3.0)), divergence_bound=2.0)
    jobs = [Job(noisy, n, 0) for n in controllers.NAMES] + [Job(sc, "backstepping", 0)]
    rows = run_jobs(jobs, workers=1, progress=False)
    res["huge_noise"] = {r.controller: {"diverged": r.diverged, "diverged_at": r.diverged_at,
                                        "cause": r.cause} for r in rows[:-1]}  # fmt: skip
    res["huge_noise"]["control run"] = {"diverged": rows[-1].diverged,
                                        "rmse_position": rows[-1].rmse_position}  # fmt: skip
    # 4. saturation: commanded inputs never exceed the limits
    lim = dataclasses.replace(sc, limits=scn.Limits(0.3, 0.5))
    sat = {}
    for name in controllers.NAMES:
        r = simulate(lim, name, seed=0)
        sat[name] = bool(np.all(np.abs(r.u[:, 0]) <= 0.3) and np.all(np.abs(r.u[:, 1]) <= 0.5))
    res["saturation_respected"] = sat
    return res


def determinism(seeds: int = 2) -> dict:
    """Same jobs (every controller on the paper's scenarios, ``seeds`` seeds) serially and on two
    workers, twice: bit-identical rows."""
    scenarios = [scn.load(scn.builtin(n)) for n in scn.PAPER_SCENARIOS]
    jobs = [Job(sc, n, s) for sc in scenarios for n in controllers.NAMES for s in range(seeds)]
    a = run_jobs(jobs, workers=1, progress=False)
    b = run_jobs(jobs, workers=2, progress=False)
    c = run_jobs(jobs, workers=2, progress=False)
    return {"runs": len(jobs), "serial_equals_parallel": a == b, "parallel_repeatable": b == c}


def run(out, *, quick: bool = False, workers: int | None = None) -> dict:
    """Run every check into ``out`` and write the record ``results/reliability.json`` and
    ``tables/reliability.md``; return the record.  ``quick``: a 3-minute long run instead of an
    hour, 6 turns of the circle instead of 50, the shipped scenarios' runs cut to 10 s and the
    determinism check on 1 seed instead of 2.  The determinism check always compares the serial
    path with 2 workers (``workers`` is not used)."""
    # quick: the compiled controllers' long runs only (a Python-level one, nmpc, costs ~1 ms a
    # step: its long run is in the full study and, shorter, in tests/test_reliability.py)
    compiled = [n for n in controllers.NAMES if controllers.REGISTRY[n].compiled]
    record = {"bad_inputs": bad_inputs(),
              "long_runs": long_runs(0.05, compiled) if quick else long_runs(1.0),
              "run_memory": run_memory(0.05 if quick else 1.0),
              "shipped_scenarios": shipped_scenarios(10.0 if quick else None),
              "seam": seam_crossings(6 if quick else 50), "faults": fault_injection(),
              "determinism": determinism(1 if quick else 2)}  # fmt: skip
    bi = record["bad_inputs"]
    record["summary"] = {
        "bad_inputs_tried": bi["tried"], "bad_inputs_as_expected": bi["as_expected"],
        "long_runs_finite": all(v["finite"] and not v["diverged"]
                                for v in record["long_runs"].values()),
        "seam_no_divergence": all(not v["diverged"] for k, v in record["seam"].items()
                                  if isinstance(v, dict)),
        "serial_equals_parallel": record["determinism"]["serial_equals_parallel"],
        "saturation_respected": all(record["faults"]["saturation_respected"].values()),
        "shipped_runs_accounted_for": all(
            (v["diverged"] and v["diverged_at"] is not None and v["cause"])
            or (not v["diverged"] and math.isfinite(v["rmse_position"]))
            for sc in record["shipped_scenarios"].values() for k, v in sc.items()
            if k != "plant"),
    }  # fmt: skip
    common.write_record(out, STEM, record)
    common.write_table(out, STEM, table(record))
    return record


def check(record: dict) -> None:
    """Every bad input exits 2 with one line and writes nothing; long runs stay finite and their
    memory does not grow with the run length; serial and parallel rows are identical; every
    controller respects the saturation."""
    s = record["summary"]
    assert s["bad_inputs_as_expected"] == s["bad_inputs_tried"], [
        c for c in record["bad_inputs"]["cases"]
        if c["exit_code"] != 2 or c["traceback"] or c["wrote_output"]]  # fmt: skip
    assert s["long_runs_finite"] and s["serial_equals_parallel"] and s["saturation_respected"], s
    for name, v in record["long_runs"].items():  # memory does not grow with run length
        assert v["peak_traced_mb_long"] < 1.5 * v["peak_traced_mb_short"] + 1.0, (name, v)
    m = record["run_memory"]
    assert m["exit_code"] == 0 and len(m["files"]) == m["controllers"] + 2, m
    assert m["peak_rss_mb"] < RUN_MEMORY_MB, m  # issue 12: one hour with trajectories
    assert s["shipped_runs_accounted_for"], record["shipped_scenarios"]


# --- Rendering: the report's section, from the record ------------------------------------------


def _hours(steps: int) -> float:
    """``steps`` of the lemniscate scenario (the long runs') in hours."""
    return steps * scn.load(scn.builtin("lemniscate")).dt / 3600.0


def table(record: dict) -> str:
    """The bad inputs tried and the long runs (Markdown; ``tables/reliability.md``)."""
    rows = []
    for c in record["bad_inputs"]["cases"]:
        msg = c["message"].replace("|", "\\|")
        msg = msg if len(msg) < 110 else msg[:107] + "..."
        rows.append([c["input"], c["exit_code"], f"`{msg}`"])
    lines = common.md_table(["bad input", "exit", "message"], rows)
    long = record["long_runs"]
    hours = round(_hours(next(iter(long.values()))["steps"]), 9)
    simulated = "one simulated hour" if hours == 1 else f"{hours:g} simulated hours"
    lines += ["", f"Long runs ({simulated}, no trajectory kept; memory traced by "
              "tracemalloc):", ""]  # fmt: skip
    header = ["controller", "steps", "finite", "position RMSE [m]", "wall [s]",
              "peak MB (2 chunks)", f"peak MB ({hours:g} h)"]
    rows = [[controllers.label(name), v["steps"], fmt(v["finite"]), fmt(v["rmse_position"]),
             fmt(v["seconds"], 1), fmt(v["peak_traced_mb_short"], 2),
             fmt(v["peak_traced_mb_long"], 2)] for name, v in long.items()]  # fmt: skip
    return "\n".join(lines + common.md_table(header, rows)) + "\n"


def render(record: dict) -> str:
    """The report's "Reliability" section."""
    s = record["summary"]
    notes = [f"Bad inputs tried through the CLI: {s['bad_inputs_tried']}; exit code 2 with one "
             f"`error:` line, no traceback and nothing written: {s['bad_inputs_as_expected']}.",
             f"Serial and 2-worker studies bit-identical: {fmt(s['serial_equals_parallel'])}; "
             f"saturation respected by every controller: {fmt(s['saturation_respected'])}."]
    seam = record["seam"]
    lines = [f"Heading seam: circles of {seam['turns']} turns (the heading crosses ±π once a "
             "turn), noise 0.01:", ""]
    lines += [f"- {controllers.label(k)} crossed {v['heading_seam_crossings']} times, θ RMSE "
              f"{fmt(v['rmse_theta'])};" for k, v in seam.items() if isinstance(v, dict)]
    lines += [""]
    f = record["faults"]
    neg, wild = f["negative_covariance_diagonal"], f["overflowing_controller"]
    lines += ["Faults injected:", "",
              f"- a covariance with a negative diagonal entry: repaired {fmt(neg['repaired'])}, "
              f"positive definite after {fmt(neg['positive_definite_after'])};",
              f"- a controller whose output overflows (backstepping gains 1e308): diverged at "
              f"{fmt(wild['diverged_at'], 2)} s ({wild['cause']});",
              "- pose noise std (5 m, 5 m, 3 rad) with a 2 m divergence bound (the next run of "
              "the same study completed normally):",
              *(f"  - {controllers.label(k)} "
                + (f"diverged at {fmt(v['diverged_at'], 2)} s ({v['cause']});"
                   if v["diverged"] else "did not diverge;")
                for k, v in f["huge_noise"].items() if k != "control run"), ""]  # fmt: skip
    m = record["run_memory"]
    notes.append(f"`wmr run` of all {m['controllers']} controllers over {m['hours']:g} simulated "
                 f"hour(s) ({m['steps']} steps each) with trajectories (CSV, figure): peak "
                 f"resident memory {fmt(m['peak_rss_mb'], 1)} MB (limit {RUN_MEMORY_MB:g} MB), "
                 f"{fmt(m['seconds'], 1)} s, {fmt(m['written_mb'], 1)} MB written.")
    shipped = record["shipped_scenarios"]
    diverged = [f"{sc} / {controllers.label(c)} at {fmt(v['diverged_at'], 2)} s ({v['cause']})"
                for sc, runs in shipped.items() for c, v in runs.items()
                if c != "plant" and v["diverged"]]  # fmt: skip
    notes.append(f"Every shipped scenario ({len(shipped)}) with every controller: "
                 + ("no run diverged." if not diverged else "diverged: " + "; ".join(diverged)))
    return common.section(TITLE, notes, table(record)) + "\n" + "\n".join(lines)


if __name__ == "__main__":
    sys.exit(common.main(sys.modules[__name__]))
