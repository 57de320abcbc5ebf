"""The performance study's measuring tools: clocks, the python-control comparator's timing, the
machine and memory.

Every per-step figure is ``(wall, CPU)`` seconds: the wall clock (``time.perf_counter``) and this
thread's CPU clock (``time.thread_time``), which leaves out the time other processes hold the
core on a shared machine.
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from wmr.closedloop import sim
from wmr.linear import nlsys

__all__ = [
    "clocks",
    "per_step",
    "steps_done",
    "same_rows",
    "rss_mb",
    "machine",
    "cold_process_first_run",
    "time_python_control",
    "time_python_control_overhead",
    "best",
    "median",
    "python_control",
    "python_control_table",
    "weights_figure",
]


def clocks() -> tuple[float, float]:
    """Wall clock and this thread's CPU clock [s]."""
    return time.perf_counter(), time.thread_time()


def per_step(c0: tuple[float, float], steps: int = 1) -> tuple[float, float]:
    """(wall, thread CPU) seconds per step since the clocks ``c0``."""
    wall, cpu = clocks()
    return (wall - c0[0]) / steps, (cpu - c0[1]) / steps


def steps_done(r) -> int:
    """The steps a run simulated (fewer than ``n_steps`` if it diverged)."""
    return round(r.diverged_at / r.dt) if r.diverged else r.n_steps


def same_rows(a, b) -> bool:
    """Study rows equal field by field (NaN equal to NaN: a diverged run's RMSE)."""

    def key(r):
        return tuple("nan" if isinstance(v, float) and math.isnan(v) else v
                     for v in dataclasses.astuple(r))  # fmt: skip

    return len(a) == len(b) and all(key(x) == key(y) for x, y in zip(a, b, strict=True))


def rss_mb(who=resource.RUSAGE_SELF) -> float:
    """Peak resident memory [MB] of this process (or of its largest child)."""
    return resource.getrusage(who).ru_maxrss / 1024.0  # kB on Linux


def machine() -> dict:
    """CPU, usable cores, versions and the load average now."""
    import control
    import numba

    model = platform.processor()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        usable = os.cpu_count()
    return {"cpu_count": os.cpu_count(), "usable_cpus": usable, "cpu_model": model,
            "platform": platform.platform(), "python": platform.python_version(),
            "numpy": np.__version__, "numba": numba.__version__, "control": control.__version__,
            "load_average_start": list(os.getloadavg())}  # fmt: skip


def cold_process_first_run() -> float | None:
    """Seconds for a fresh interpreter to run its first ``iapid-nn-dekf`` simulate."""
    root = Path(sim.__file__).resolve().parents[2]
    code = ("import time; from wmr.closedloop import sim; from wmr import scenario as s; "
            "sc = s.load(s.builtin('lemniscate'));"
            "t = time.perf_counter(); sim.simulate(sc, 'iapid-nn-dekf', 0, keep_trajectory=False);"
            "print(time.perf_counter() - t)")  # fmt: skip
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(filter(None, (str(root), os.environ.get("PYTHONPATH")))),
    )
    try:
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             cwd=root, env=env, timeout=600, check=True)  # fmt: skip
        return float(out.stdout.strip().splitlines()[-1])
    except (subprocess.SubprocessError, ValueError, IndexError):
        return None


def time_python_control(scenario, controller: str, repeats: int, full, copy_only: bool = False):
    """Time the closed loop as a python-control nlsys (``wmr.linear.nlsys``) on ``scenario`` and,
    right after each repeat, the kernel (``simulate`` of ``full``, no trajectory), so the two share
    the machine's state.  With ``copy_only`` each repeat first times the copy-only nlsys of the same
    state size (:func:`time_python_control_overhead`), interleaved for the same reason.

    Returns ``(pc, kernel, max |q - q_simulate|, copy, n_states)``: per repeat, (wall, CPU)
    seconds per step (``copy`` empty without ``copy_only``); the largest difference between the
    nlsys's poses and ``simulate``'s on ``scenario``; the nlsys's number of states.
    """
    q_sim = sim.simulate(scenario, controller, 0, keep_trajectory=True).q
    times, kernel, err, copy = [], [], math.nan, []
    n_states = 0
    for _ in range(repeats):
        cl = nlsys.closed_loop(scenario, controller, 0)
        n_states = cl.layout.n_states
        if copy_only:
            copy += time_python_control_overhead(n_states, len(cl.T), scenario.dt, 1)
        t0 = clocks()
        resp = cl.response()
        times.append(per_step(t0, len(cl.T)))  # one update per instant of T
        t0 = clocks()
        r = sim.simulate(full, controller, 0, keep_trajectory=False)
        kernel.append(per_step(t0, steps_done(r)))
        err = float(np.max(np.abs(resp.states[0:3].T - q_sim)))
        del resp, cl
    return times, kernel, err, copy, n_states


def time_python_control_overhead(nx: int, steps: int, dt: float, repeats: int) -> list:
    """Per-step (wall, CPU) seconds of ``input_output_response`` on an ``nlsys`` with ``nx``
    states whose update only copies the state (as the closed loop's update does first): what
    python-control costs per step before any of the loop's arithmetic."""
    import control as ct

    system = ct.nlsys(lambda t, x, u, params: x.copy(), lambda t, x, u, params: x[0:3], dt=dt,
                      states=nx, inputs=8, outputs=3, name="copy-only")  # fmt: skip
    T = np.arange(steps) * dt
    U = np.zeros((8, steps))
    X0 = np.zeros(nx)
    times = []
    for _ in range(repeats):
        t0 = clocks()
        resp = ct.input_output_response(system, T, U, X0)
        times.append(per_step(t0, steps))
        del resp
    return times


def best(samples, clock: int = 0) -> float:
    """Minimum over repeats [µs] of the ``clock`` (0 wall, 1 CPU) of (wall, CPU) samples [s]."""
    return min(x[clock] for x in samples) * 1e6


def median(samples, clock: int = 0) -> float:
    """Median over repeats [µs] of the ``clock`` of (wall, CPU) samples [s]."""
    return float(np.median([x[clock] for x in samples])) * 1e6


def python_control(lem, steps: int, repeats: int, subject: str) -> tuple[dict, dict]:
    """The closed loop as a python-control nlsys (``wmr.linear.nlsys``) on the first ``steps`` steps
    of the lemniscate, each repeat timed beside a kernel run; and python-control's own cost per step
    (a copy-only nlsys of the same state size)."""
    short = dataclasses.replace(lem, duration=steps * lem.dt)
    pc, overhead = {}, {}
    for controller in (subject, "backstepping"):
        subject = controller == subject
        t_pc, t_k, err, t_copy, nx = time_python_control(short, controller, repeats, lem,
                                                                copy_only=subject)  # fmt: skip
        pc[f"{controller}/jit"] = {
            "us_per_step": best(t_pc), "us_per_step_median": median(t_pc),
            "cpu_us_per_step": best(t_pc, 1), "kernel_us_per_step_beside": best(t_k),
            "kernel_cpu_us_per_step_beside": best(t_k, 1), "steps": steps,
            "max_abs_q_difference": err,
            "ratio": float(np.median([a[1] / b[1] for a, b in zip(t_pc, t_k, strict=True)])),
            "ratio_wall_min_over_min": best(t_pc) / best(t_k),
        }  # fmt: skip
        if subject:
            overhead = {"n_states": nx, "copy_only_nlsys_us_per_step": best(t_copy),
                        "copy_only_nlsys_cpu_us_per_step": best(t_copy, 1),
                        "copy_only_nlsys_us_per_step_median": median(t_copy)}  # fmt: skip
    return pc, overhead


def python_control_table(rec: dict, subject: str) -> list[str]:
    """The performance record's python-control table (``subject``: the controller whose closed
    loop the nlsys runs)."""
    lines = ["| python-control nlsys | µs/step | ratio to the kernel | max abs q difference |",
             "|---|---:|---:|---:|"]  # fmt: skip
    for key, v in rec["python_control"].items():
        lines.append(f"| {key} | {v['us_per_step']:.1f} | {v['ratio']:.1f}x "
                     f"| {v['max_abs_q_difference']:.1e} |")  # fmt: skip
    a = rec.get("python_control_overhead")
    if a:
        pc = rec["python_control"][f"{subject}/jit"]
        lines += [
            "", f"python-control's own cost (CPU µs/step): an nlsys of the same {a['n_states']} "
            "states whose update only copies the state costs "
            f"{a['copy_only_nlsys_cpu_us_per_step']:.1f} per step; the closed loop as an nlsys "
            f"costs {pc['cpu_us_per_step']:.1f}.  The kernel takes "
            f"{rec['cpu_us_per_step'][subject]:.2f}, of which the Joseph weight update alone is "
            f"{rec['weight_update_cpu_us_per_step']:.2f}, and the floor (a standard-form update "
            f"alone, nothing else of the loop) is {rec['floor_cpu_us_per_step']:.2f}.",
        ]  # fmt: skip
    return lines + [""]


def weights_figure(rec: dict):
    """Cost per step against the network size: closed loop, library update, floor."""
    import matplotlib.pyplot as plt

    v = rec["vs_weights"]
    n = np.array([x["n_weights"] for x in v], dtype=float)
    floor = np.array([x["floor_us_per_step"] for x in v])
    limit = rec["targets"]["floor_ratio_max"]
    fig, ax = plt.subplots(figsize=(6, 4.2), layout="constrained")
    ax.loglog(n, [x["us_per_step"] for x in v], "o-", label="iapid-nn-dekf closed-loop step")
    ax.loglog(n, [x["weight_update_us_per_step"] for x in v], "s--",
              label="wmr.estimation.ekf.weight_update alone")  # fmt: skip
    ax.loglog(n, floor, "^-", label="floor (minimal EKF update)")
    ax.loglog(n, limit * floor, ":", color="gray", label=f"{limit:g} x floor (target)")
    ax.set_xlabel("number of network weights n")
    ax.set_ylabel("µs per step")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("Cost per step against the network size")
    return fig
