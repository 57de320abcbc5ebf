"""The step's cost phase by phase (issue 25): each phase of ``wmr.closedloop.step`` timed alone,
beside the whole kernel, on the inputs a real run gave it.

For a controller on a scenario one run is kept (poses, estimates, commands, reference; its noise
drawn again from the same stream), then each phase runs over those inputs, step after step, inside a
jitted loop of its own -- the phases themselves, as the kernel calls them (the law inlined as in the
kernel, the arrays borrowed as the kernel borrows them: ``wmr._borrow``), so the figure is what the
phase costs in the loop: ``sense`` (measurement and estimate: a copy, or the pose filter's update),
``law`` (the controller, saturation included), ``plant`` (delay, disturbance and the true robot's
step), ``predict`` (the pose filter's prediction, for the controllers that use it) and ``score``.
``kernel`` is the whole compiled step on the same run; ``loop`` what the kernel costs beyond the sum
of its phases. Nothing of the step is written here: the timing loops call the phases.
"""

from __future__ import annotations

import numba
import numpy as np

from analysis.performance.bench import clocks, per_step
from wmr._borrow import borrowed
from wmr.closedloop import metrics
from wmr.closedloop import step as loop
from wmr.closedloop.sim import simulate
from wmr.estimation.ekf import pose_predict, pose_work

__all__ = ["NOTE", "PHASES", "breakdown", "table"]

#: The phases, in the step's order.
PHASES = ("sense", "law", "plant", "predict", "score")


@numba.njit
def _sense(q, noise, q_hat, Pq, use_ekf, Rp, z, work):
    q, noise, q_hat, Pq, Rp, z, work = borrowed((q, noise, q_hat, Pq, Rp, z, work))
    for k in range(noise.shape[0]):
        loop.measure(q[k], noise, k, z)
        loop.estimate(k, z, q_hat, Pq, use_ekf, Rp, work)


@numba.njit
def _predict(q_hat, Pq, u, dt, integrator, Qp, work):
    q_hat, Pq, u, Qp, work = borrowed((q_hat, Pq, u, Qp, work))
    for k in range(u.shape[0]):
        pose_predict(q_hat, Pq, u[k], dt, integrator, Qp, work)


@numba.njit
def _score(q, ref, u, dt, acc, t_tail, bound):
    q, ref, u, acc = borrowed((q, ref, u, acc))
    for k in range(u.shape[0]):
        loop.score(k, dt, q[k + 1], ref[k + 1], u[k], acc, t_tail, bound)


def _law_loop(law):
    law = loop._inlined(law)  # noqa: SLF001 - inlined as the kernel inlines it

    @numba.njit
    def run(p, s, theta, P, q_hat, ref, dt, u, v_max, w_max):
        p, s, theta, P, q_hat, ref, u = borrowed((p, s, theta, P, q_hat, ref, u))
        for k in range(q_hat.shape[0]):
            law(p, s, theta, P, q_hat[k], ref[k], dt, u)
            loop.saturate(u, v_max, w_max)

    return run


def _plant_loop(half):
    @numba.njit
    def run(u, ua, q, dt, integrator, disturbance, plant_arrays, vel_log):
        u, ua, q, disturbance, plant_arrays, vel_log = borrowed(
            (u, ua, q, disturbance, plant_arrays, vel_log))
        for k in range(u.shape[0]):
            half(k, dt, integrator, u[k], ua, q, disturbance, plant_arrays, vel_log)

    return run


def _inputs(scenario, name: str, seed: int):
    r = simulate(scenario, name, seed, keep_trajectory=True)
    n = r.u.shape[0]
    noise = np.vstack([c[3] for c in loop.prepare(scenario, name, seed).chunks()])[:n]
    return {"q": np.ascontiguousarray(r.q), "q_hat": np.ascontiguousarray(r.q_hat),
            "u": np.ascontiguousarray(r.u), "ref": np.ascontiguousarray(r.ref),
            "noise": np.ascontiguousarray(noise), "n": n}  # fmt: skip


def _one_round(scenario, name, x, laws, halves) -> dict:
    """(wall, CPU) seconds per step of each phase and of the kernel, once."""
    sc, n, out = scenario, x["n"], {}
    run = loop.prepare(sc, name, 0)
    t0 = clocks()
    _sense(x["q"], x["noise"], run.q_hat, run.Pq, run.use_ekf, run.Rp, np.zeros(3), pose_work())
    out["sense"] = per_step(t0, n)
    t0 = clocks()
    laws[name](run.p, run.s, run.theta, run.P, x["q_hat"], x["ref"], sc.dt, np.zeros(2),
               sc.limits.v_max, sc.limits.w_max)  # fmt: skip
    out["law"] = per_step(t0, n)
    arrays = (run.plant_table, run.plant_at, run.plant_ints, run.plant_vel, run.plant_buffer)
    t0 = clocks()
    halves[name](x["u"], np.zeros(2), run.q.copy(), sc.dt, run.integrator, run.disturbance,
                 arrays, loop._NO_LOGS.vel)  # noqa: SLF001  # fmt: skip
    out["plant"] = per_step(t0, n)
    if run.use_ekf:
        t0 = clocks()
        _predict(run.q_hat, run.Pq, x["u"], sc.dt, run.integrator, run.Qp, pose_work())
        out["predict"] = per_step(t0, n)
    else:
        out["predict"] = (0.0, 0.0)
    t0 = clocks()
    _score(x["q"], x["ref"], x["u"], sc.dt, np.zeros(metrics.N_ACC), metrics.TRANSIENT,
           sc.divergence_bound)  # fmt: skip
    out["score"] = per_step(t0, n)
    run = loop.prepare(sc, name, 0)  # the whole step: the kernel on the same run
    kern = loop.kernel(name, run.controller.law, run.plant_kind, run.controller.oracle)
    t0 = clocks()
    loop.run(run, None)
    out["kernel"] = per_step(t0, n)
    del kern
    return out


def breakdown(scenario, names, repeats: int = 5) -> dict:
    """``{controller: {phase: CPU µs per step, ..., "sum", "kernel", "loop"}}`` for the compiled
    controllers of ``names`` (a Python-level one, nmpc, has no kernel to take apart): the least
    disturbed (minimum) of ``repeats`` interleaved rounds; ``kernel`` is a whole run (its
    per-run set-up included, spread over the steps)."""
    from wmr import controllers

    names = [n for n in names if controllers.get(n).compiled]  # a Python-level law has no phases
    x = {name: _inputs(scenario, name, 0) for name in names}
    laws = {name: _law_loop(controllers.get(name).law) for name in names}
    halves = {}
    for name in names:
        run = loop.prepare(scenario, name, 0)
        c = run.controller
        half = loop._bind(c.name, c.law, run.plant_kind, c.oracle, compiled=True)[0]  # noqa: SLF001
        halves[name] = _plant_loop(half)
    samples = {name: [] for name in names}
    for _ in range(repeats + 1):  # the first round compiles
        for name in names:
            samples[name].append(_one_round(scenario, name, x[name], laws, halves))
    out = {}
    for name in names:
        rounds = samples[name][1:]
        best = {k: min(r[k][1] for r in rounds) * 1e6 for k in (*PHASES, "kernel")}
        best["sum"] = sum(best[k] for k in PHASES)
        best["loop"] = best["kernel"] - best["sum"]
        out[name] = best
    return out


def table(phases: dict) -> list[str]:
    """Markdown lines: CPU µs per step, phase by phase."""
    cols = (*PHASES, "sum", "kernel", "loop")
    lines = ["| controller | " + " | ".join(cols) + " |", "|---|" + "---:|" * len(cols)]
    for name, v in phases.items():
        lines.append(f"| {name} | " + " | ".join(f"{v[c]:.3f}" for c in cols) + " |")
    return lines + [""]


#: The performance record's note on this measurement (``analysis.performance.notes``).
NOTE = (
    "phases: analysis.performance.phases times each phase of wmr.closedloop.step alone in a "
    "jitted loop, over the "
    "inputs a kept lemniscate run gave it (sense = measurement and estimate, law with "
    "saturation, plant, the pose filter's predict, score). Each is the minimum of interleaved "
    "rounds, in CPU time; kernel is loop.run of the same run. The set-up, run_overhead_ms, is "
    "the CPU time of a one-step run (prepare, the kernel's call, the record), the minimum of "
    "interleaved repeats."
)
