"""Reliability study (issue 7): bad inputs tried, faults injected, long runs, determinism.

Writes ``out/results/reliability.json`` (the report's reliability section) with, for each check,
what was tried and what happened.  ``main`` ends by asserting every outcome is the expected one.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import math
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from wmr import cli, controllers
from wmr import scenario as scn
from wmr.ekf import repair_covariance
from wmr.io import write_json
from wmr.sim import simulate
from wmr.study import Job, run_jobs

__all__ = ["BAD_SCENARIOS", "bad_inputs", "long_runs", "seam_crossings", "fault_injection",
           "determinism", "main"]  # fmt: skip

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


def long_runs(hours: float = 1.0) -> dict:
    """A long run of every controller (no trajectory kept): finite, and memory independent of
    the run length (peak traced allocation of a run of 2 chunks of ``wmr.loop.CHUNK`` steps vs the
    full run; below one chunk the buffers are smaller, so that is the fair baseline)."""
    from wmr.loop import CHUNK

    sc = scn.load(scn.builtin("lemniscate"))
    out = {}
    for name in controllers.NAMES:
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


def determinism() -> dict:
    """Same jobs serially and on two workers, twice: bit-identical rows."""
    scenarios = [scn.load(scn.builtin(n)) for n in scn.PAPER_SCENARIOS]
    jobs = [Job(sc, n, s) for sc in scenarios for n in controllers.NAMES for s in range(2)]
    a = run_jobs(jobs, workers=1, progress=False)
    b = run_jobs(jobs, workers=2, progress=False)
    c = run_jobs(jobs, workers=2, progress=False)
    return {"runs": len(jobs), "serial_equals_parallel": a == b, "parallel_repeatable": b == c}


def main(out: str | Path = "paper", hours: float = 1.0) -> dict:
    """Run every check, write ``results/reliability.json`` and assert the expected outcomes."""
    result = {"bad_inputs": bad_inputs(), "long_runs": long_runs(hours),
              "seam": seam_crossings(), "faults": fault_injection(),
              "determinism": determinism()}  # fmt: skip
    bi = result["bad_inputs"]
    result["summary"] = {
        "bad_inputs_tried": bi["tried"], "bad_inputs_as_expected": bi["as_expected"],
        "long_runs_finite": all(v["finite"] and not v["diverged"]
                                for v in result["long_runs"].values()),
        "seam_no_divergence": all(not v["diverged"] for k, v in result["seam"].items()
                                  if isinstance(v, dict)),
        "serial_equals_parallel": result["determinism"]["serial_equals_parallel"],
        "saturation_respected": all(result["faults"]["saturation_respected"].values()),
    }  # fmt: skip
    write_json(Path(out) / "results" / "reliability.json", result)
    s = result["summary"]
    assert s["bad_inputs_as_expected"] == s["bad_inputs_tried"], [
        c for c in bi["cases"] if c["exit_code"] != 2 or c["traceback"] or c["wrote_output"]]
    assert s["long_runs_finite"] and s["serial_equals_parallel"] and s["saturation_respected"], s
    for name, v in result["long_runs"].items():  # memory does not grow with run length
        assert v["peak_traced_mb_long"] < 1.5 * v["peak_traced_mb_short"] + 1.0, (name, v)
    return result



# --- Study shape (DESIGN §3.6); transitional adapter, replaced when the module is split --------
STEM = "reliability"
TITLE = "Reliability"


def run(out, *, quick: bool = False, workers: int | None = None) -> dict:
    """Run the study into ``out`` (see :func:`main`)."""
    return main(out)


def check(record: dict) -> None:
    """The headline claims are asserted inside :func:`main` for now."""


render = None  # the report renders this study's section from its stored files

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="paper")
    parser.add_argument("--hours", type=float, default=1.0)
    a = parser.parse_args()
    main(a.out, a.hours)
