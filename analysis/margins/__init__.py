"""Study: stability margins of the linearised sampled-data loops (fixed PID of eq. 7, backstepping).

The loops (plant from CasADi's AD of the ZOH error step, controllers as python-control systems,
broken at one plant input with the other loop closed) are built by ``wmr.linear.loops``; their
margins (classical gain and phase margins from the state-space frequency response, balanced disk
margins from ``control.disk_margins``, the same margins from closed-loop eigenvalues) by
``wmr.linear.margins``.

The study computes, at the sinusoid's mean operating point (and three others):

- the loop-at-a-time margins, eigenvalues and slowest time constant of both loops;
- independent cross-checks: closed-loop eigenvalues from python-control == those of CasADi's
  Jacobian of the whole nonlinear closed loop
  (:func:`wmr.model.symbolic.pid_closed_loop_jacobian_function`), entrywise; each margin recomputed
  from closed-loop eigenvalues only; disk margins below the classical ones; backstepping
  ``eig(A_d)`` vs ``exp(eig(A) dt)``, ``O(dt^2)``; the nonlinear loop
  (``wmr.closedloop.sim.simulate``, no noise) started at a small error follows the linear model
  and decays at the slowest ``|z|`` (:func:`decay_check`);
- the stability region in PID-gain space and the stable interval of each gain, against Jury's
  closed-form conditions, and the simulated loop just inside / just outside the limits of
  ``Kdv``, ``Kdw``, ``Kpv`` (:func:`gain_limit_check`);
- the margins along runs as the SGD gains adapt (frozen-time, ``margins.margins_along_run``);
- the printed rotation of eqs. 4/6 (errata E3), whose linearisation depends on the heading
  (:func:`printed_rotation_sweep`);
- Floquet multipliers about the periodic references, beside frozen-time radii (``floquet``).

``run`` writes ``results/margins.json``, ``tables/margins.md`` and ``figures/margins_*.png``;
``check`` asserts the cross-checks; ``render`` gives the report section.  The notes, the table and
the figures are produced from the computed numbers by separate functions.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from analysis import common
from analysis.margins import adaptive as _margins_adaptive
from analysis.margins import nmpc as _margins_nmpc
from analysis.margins.figures import (
    along_runs_figure,
    printed_rotation_figure,
    stability_region_figure,
)
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.controllers import backstepping as bsc_mod
from wmr.controllers import pid as pid_mod
from wmr.linear import floquet
from wmr.linear.loops import (
    BSC_GAINS,
    CHANNELS,
    PID_GAINS,
    OperatingPoint,
    backstepping_loops,
    closed_loop_matrix,
    constant_reference_scenario,
    eigenvalue_distance,
    error_plant,
    jury_v_gain_limits,
    jury_v_loop_stable,
    max_stable_delay,
    operating_point,
    pid_equilibrium,
    pid_loops,
    printed_rotation_sweep,
    routh_w_loop_stable,
    slow_mode_error,
    spectral_radius,
    stability_region,
    stable_gain_interval,
    start_state_map,
    unstable_intervals,
)
from wmr.linear.margins import analyse_loops, compare_margins, json_number, margins_along_run
from wmr.model import symbolic as sym
from wmr.model.kinematics import tracking_error

__all__ = ["STEM", "TITLE", "run", "check", "render", "notes", "table", "decay_check",
           "gain_limit_check", "stability_region_figure", "along_runs_figure",
           "printed_rotation_figure"]  # fmt: skip

STEM = "margins"
TITLE = "Linearised loops: margins (python-control)"
#: Steps between frozen-time analyses along a run, and the runs' seed.
EVERY, SEED = 50, 0
#: ``--quick``: fewer points along runs and on the gain grids (the checks are the same).
QUICK_EVERY, QUICK_GRID = 500, 21
#: Controllers whose margins are followed along runs (the PID family).
ALONG = ("pid", "adaptive-pid", "iapid-nn-dekf")
HEADINGS_DEG = np.linspace(-180.0, 180.0, 361)
FLOQUET_SCENARIOS = ("lemniscate", "sinusoid")  # periodic (sinusoid-perturbed: the sinusoid's)


def run(out, *, quick: bool = False, workers: int | None = None) -> dict:
    """Compute the study (nmpc's, adaptive-bsc's rows: ``analysis.margins.nmpc``, ``_adaptive``),
    write its record, table and figures under ``out``; return the record (``workers``: unused)."""
    every, n_grid = (QUICK_EVERY, QUICK_GRID) if quick else (EVERY, 81)
    scenarios = {name: scn.load(scn.builtin(name)) for name in scn.PAPER_SCENARIOS}
    op = operating_point(scenarios["sinusoid"], "mean")
    curved = operating_point(scenarios["sinusoid"], "max-curvature")
    ops = [op, curved, operating_point(scenarios["lemniscate"], "mean"),
           operating_point(scenarios["lemniscate"], "max-curvature")]  # fmt: skip
    record: dict = {"operating_point": {**op.to_json(), "how": (
        "time-mean v_r of the sinusoid scenario's reference over its 40 s, w_r = 0 (the straight "
        "line; the sinusoid's mean curvature is 0); other points under operating_points")}}
    head, cc = _headline(op)
    record.update(head)
    record["operating_points"], cc["mirror_w_r_max_pm_diff_deg"] = _operating_points(ops)
    cc["simulated_decay"] = [
        decay_check("pid", op, PID_GAINS), decay_check("pid", curved, PID_GAINS),
        decay_check("backstepping", op, BSC_GAINS), decay_check("backstepping", curved, BSC_GAINS),
        decay_check("pid", op, PID_GAINS, feed_forward=False)]  # fmt: skip
    record["stability_region"], regions, region_checks = _gain_space(op, n_grid)
    cc.update(region_checks)
    record["along_runs"], along = _along_runs(scenarios, every, SEED)
    record["printed_rotation"], sweep, cc["printed_at_heading_0_equals_corrected_max_abs"] = (
        _printed_rotation(op))  # fmt: skip
    record["delay_tolerance"] = _delay_tolerance(op)
    record["floquet"] = {"how": floquet.HOW, "circle_closed_form": floquet.circle_check(curved),
                         **{n: floquet.analyse(scenarios[n]) for n in FLOQUET_SCENARIOS}}
    record["cross_checks"] = cc
    record["nmpc"] = _margins_nmpc.margins(ops)
    record["adaptive_bsc"] = _margins_adaptive.margins(ops)
    record["figures"] = [
        common.save_figure(out, "margins_stability_region.png", stability_region_figure(regions)),
        common.save_figure(out, "margins_along_runs.png", along_runs_figure(along)),
        common.save_figure(out, "margins_printed_rotation.png", printed_rotation_figure(sweep)),
    ]
    record["notes"] = notes(record)
    common.write_record(out, STEM, record)
    common.write_table(out, STEM, table(record))
    return record


# ---------------------------------------------------------------------------------------------
# Computation: each returns numbers (JSON-able parts of the record) and what the figures need
# ---------------------------------------------------------------------------------------------


def _headline(op: OperatingPoint) -> tuple[dict, dict]:
    """Fixed PID and backstepping at ``op``: their records and the cross-checks of their
    closed loops (CasADi, eigenvalue margins, ``exp(A dt)``)."""
    dt = op.dt
    loops_pid, loops_bsc = pid_loops(op), backstepping_loops(op)
    res_pid, res_bsc = analyse_loops(loops_pid), analyse_loops(loops_bsc)
    rec = {"pid": {**_controller_record(loops_pid, res_pid, PID_GAINS), "feed_forward": False},
           "backstepping": _controller_record(loops_bsc, res_bsc, BSC_GAINS)}  # fmt: skip
    eig_c = np.linalg.eigvals(np.asarray(
        sym.backstepping_jacobian_function()(op.v_r, op.w_r, *BSC_GAINS)))  # fmt: skip
    rec["backstepping"]["eigenvalues_continuous"] = _eigs_json(eig_c)
    rec["backstepping"]["exp_eig_A_dt"] = _eigs_json(np.exp(eig_c * dt))

    A_casadi = _pid_casadi_matrix(op)
    A_ff = np.asarray(sym.pid_closed_loop_jacobian_function(op.integrator, feed_forward=True)(
        np.zeros(7), op.u_r, PID_GAINS, dt))  # fmt: skip
    A_bd = np.asarray(sym.backstepping_step_jacobian_function(op.integrator)(
        op.v_r, op.w_r, *BSC_GAINS, dt))  # fmt: skip
    d1 = eigenvalue_distance(res_bsc["eigenvalues"], np.exp(eig_c * dt))
    half = closed_loop_matrix(backstepping_loops(dataclasses.replace(op, dt=dt / 2))["v"])
    d2 = eigenvalue_distance(np.linalg.eigvals(half), np.exp(eig_c * dt / 2))
    cc: dict = {
        "pid_closed_loop_vs_casadi_max_abs":
            float(np.abs(closed_loop_matrix(loops_pid["v"]) - A_casadi).max()),
        "pid_feed_forward_jacobian_max_abs_diff": float(np.abs(A_ff - A_casadi).max()),
        "bsc_closed_loop_vs_casadi_max_abs":
            float(np.abs(closed_loop_matrix(loops_bsc["v"]) - A_bd).max()),
        "bsc_discrete_vs_exp_continuous": {"dt": dt, "max_abs_diff": d1,
                                           "max_abs_diff_half_dt": d2, "ratio": d1 / d2,
                                           "over_dt2": d1 / dt**2},
    }  # fmt: skip
    for name, res in (("pid", res_pid), ("backstepping", res_bsc)):
        for ch in CHANNELS:
            cc[f"{name}_{ch}_eigen_vs_frequency"] = {
                **{k: json_number(v) for k, v in res[f"{ch}_eigen"].items()},
                **compare_margins(res[ch], res[f"{ch}_eigen"]),
            }
        cc[f"{name}_loops_same_closed_loop_max_abs"] = res["same_closed_loop"]
    return rec, cc


def _operating_points(ops: list[OperatingPoint]) -> tuple[dict, float]:
    """Margins of both controllers at each of ``ops``, and the largest phase-margin difference
    between the PID loop at ``w_r`` and its mirror image at ``-w_r`` [deg]."""
    rec, mirror_diff = {}, 0.0
    for o in ops:
        rp = analyse_loops(pid_loops(o), cross_check=False)
        rb = analyse_loops(backstepping_loops(o), cross_check=False)
        rec[o.label] = {
            "v_r": o.v_r, "w_r": o.w_r,
            "pid": {**{ch: rp[ch].to_json() for ch in CHANNELS},
                    "spectral_radius": rp["spectral_radius"]},
            "backstepping": {**{ch: rb[ch].to_json() for ch in CHANNELS},
                             "spectral_radius": rb["spectral_radius"]},
        }  # fmt: skip
        # The mirror image (y -> -y) of the loop at -w_r has the same margins.
        mirror = analyse_loops(pid_loops(dataclasses.replace(o, w_r=-o.w_r)), cross_check=False)
        diff = max(abs(mirror[ch].phase_margin_deg - rp[ch].phase_margin_deg) for ch in CHANNELS)
        mirror_diff = max(mirror_diff, diff)
    return rec, mirror_diff


def _gain_space(op: OperatingPoint, n: int) -> tuple[dict, list, dict]:
    """Stability regions (``n`` x ``n`` grids) and one-gain intervals at ``op``: their record,
    the regions (for the figure), and their checks against Jury, Routh and the simulator."""
    dt = op.dt
    reg_v, reg_w = stability_region(op, "v", n), stability_region(op, "w", n)
    P, I = np.meshgrid(reg_v["kp"], reg_v["ki"])
    near = np.abs(reg_v["rho"] - 1.0) < 1e-6
    jury = jury_v_loop_stable(P, I, dt)
    Pw, Iw = np.meshgrid(reg_w["kp"], reg_w["ki"])
    low = Pw < 10.0  # below the sampling-induced upper boundary
    agree_w = (reg_w["rho"] < 1.0)[low] == routh_w_loop_stable(Pw, Iw, op.v_r)[low]
    intervals = {name: [json_number(x) for x in stable_gain_interval(op, i)]
                 for i, name in enumerate(pid_mod.GAIN_NAMES)}  # fmt: skip
    rec = {"operating_point": op.to_json(),
           **{reg["pair"]: {"kp": [float(x) for x in reg["kp"]],
                            "ki": [float(x) for x in reg["ki"]],
                            "stable_fraction": float(np.mean(reg["rho"] < 1.0))}
              for reg in (reg_v, reg_w)},
           "stable_interval_one_gain_at_a_time": intervals}  # fmt: skip
    jury_kpv, jury_kiv = jury_v_gain_limits(PID_GAINS[0], PID_GAINS[1], dt)
    checks = {
        "region_v_agrees_with_jury": float(np.mean((reg_v["rho"] < 1.0)[~near] == jury[~near])),
        "region_w_agrees_with_continuous_routh_for_Kpw_below_10": float(np.mean(agree_w)),
        "gain_limits_vs_jury_rel_diff": max(abs(intervals["Kpv"][1] / jury_kpv - 1),
                                            abs(intervals["Kiv"][1] / jury_kiv - 1)),
        "gain_limits_simulated": [
            d for name in ("Kdv", "Kdw", "Kpv")
            for d in gain_limit_check(op, pid_mod.GAIN_NAMES.index(name), intervals[name][1])],
    }  # fmt: skip
    return rec, [reg_v, reg_w], checks


def _along_runs(scenarios: dict, every: int, seed: int) -> tuple[dict, dict]:
    """Frozen-time margins along a run of each of :data:`ALONG` on each scenario: the record
    (a summary and the series) and the series as arrays (for the figure)."""
    along = {sc_name: {name: margins_along_run(simulate(sc, name, seed=seed), every, sc.integrator)
                       for name in ALONG}
             for sc_name, sc in scenarios.items()}  # fmt: skip
    summary: dict = {}
    for sc_name, recs in along.items():
        summary[sc_name] = {}
        for name, rec in recs.items():
            s = {"max_spectral_radius": float(np.max(rec["rho"])),
                 "gain_change_max_abs": [float(x) for x in np.max(np.abs(
                     rec["gains"] - rec["gains"][0]), axis=0)]}  # fmt: skip
            for ch in CHANNELS:
                for key in ("gm_db", "pm_deg", "dm"):
                    s[f"{ch}_{key}_min"] = json_number(np.min(rec[f"{ch}_{key}"]))
                    s[f"{ch}_{key}_max"] = json_number(np.max(rec[f"{ch}_{key}"]))
            summary[sc_name][name] = s
    rec = {"every_steps": every, "seed": seed, "summary": summary,
           "series": {sc: {n: _arrays_to_json(r) for n, r in recs.items()}
                      for sc, recs in along.items()}}  # fmt: skip
    return rec, along


def _printed_rotation(op: OperatingPoint) -> tuple[dict, dict, float]:
    """The printed rotation (E3) at ``op``: its record, the sweep (for the figure) and how far
    the printed loop at heading 0 is from the corrected one (max abs entry)."""
    sweep = printed_rotation_sweep(op, HEADINGS_DEG)
    pr = sym.pid_closed_loop_jacobian_function(op.integrator, printed=True)
    at_0 = np.asarray(pr(pid_equilibrium(op, PID_GAINS), op.u_r, PID_GAINS, op.dt, 0.0))
    rec = {
        "operating_point": op.to_json(),
        "pid_unstable_headings_deg": unstable_intervals(HEADINGS_DEG, sweep["pid_rho"] > 1 + 1e-12),
        "bsc_unstable_headings_deg": unstable_intervals(HEADINGS_DEG, sweep["bsc_rho"] > 1 + 1e-12),
        "pid_max_spectral_radius": float(np.max(sweep["pid_rho"])),
        "bsc_max_spectral_radius": float(np.max(sweep["bsc_rho"])),
        "spectral_radius_at": {f"{int(h)}": {"pid": float(sweep["pid_rho"][i]),
                                             "backstepping": float(sweep["bsc_rho"][i])}
                               for h in (0, 30, 45, 60, 90, 135, 180)
                               for i in [int(np.argmin(np.abs(HEADINGS_DEG - h)))]},
    }  # fmt: skip
    return rec, sweep, float(np.abs(at_0 - _pid_casadi_matrix(op)).max())


#: Actuator lags [s] at which the delay each loop tolerates is found (issue 12).
DELAY_LAGS = (0.0, 0.1)


def _delay_tolerance(op: OperatingPoint) -> dict:
    """The largest input delay [samples and s] each loop tolerates at ``op``, without actuator
    lag and with the lags of :data:`DELAY_LAGS` (``wmr.linear.loops.max_stable_delay``)."""
    out = {"operating_point": op.to_json(), "lags_s": list(DELAY_LAGS)}
    for name, loops_of in (("pid", pid_loops), ("backstepping", backstepping_loops)):
        steps = [max_stable_delay(dataclasses.replace(op, actuator_tau=tau), loops_of)
                 for tau in DELAY_LAGS]  # fmt: skip
        out[name] = {"max_stable_delay_steps": steps,
                     "max_stable_delay_s": [None if s is None else s * op.dt for s in steps]}
    return out


def decay_check(controller: str, op: OperatingPoint, gains, e0=None,
                feed_forward: bool = True, decades: float = 5.0) -> dict:  # fmt: skip
    """The nonlinear loop (``wmr.closedloop.sim.simulate``, no noise) against its linearisation.

    Starts the robot at the error ``e0`` of a constant-``(v_r, w_r)`` reference (default
    :func:`wmr.linear.loops.slow_mode_error`, ``|e0| = 1e-3``) and runs until the slowest mode has
    decayed by ``decades`` (and for at least three of its oscillation periods).  The PID uses
    feed-forward by default, so that the simulator's zero initial integrals are the equilibrium
    (the linearisation is the same with or without it); with ``feed_forward=False`` (the literal
    eq. 7) the run starts far from its equilibrium (the integrals must first wind up to ``u_r``)
    and only the tail rate is compared.

    Returns the slowest ``|z|``, the decay rate per step fitted to the simulated error norm over
    the last three quarters of the run (:func:`_decay_rate`), that of the linear model fitted
    the same way, and (when the run starts at the equilibrium) the largest deviation of the
    simulated error from the linear prediction relative to the largest error.
    """
    if controller == "pid":
        loops = pid_loops(op, gains)
        settings = pid_mod.FixedSettings(gains=tuple(gains), feed_forward=feed_forward)
    elif controller == "backstepping":
        loops = backstepping_loops(op, gains)
        settings = bsc_mod.Settings(gains=tuple(gains))
    else:
        raise ValueError(f"controller must be 'pid' or 'backstepping', got {controller!r}")
    A = closed_loop_matrix(loops["v"])
    M = start_state_map(controller, error_plant(op))
    e0 = slow_mode_error(A, M) if e0 is None else np.asarray(e0, dtype=float)
    eig = np.linalg.eigvals(A)
    slow = eig[np.argmax(np.abs(eig))]
    rho, ang = float(abs(slow)), abs(float(np.angle(slow)))
    period = 2 * math.pi / ang if ang > 1e-9 else 1.0
    steps = int(math.ceil(max(decades * math.log(10.0) / -math.log(rho), 3.5 * period)))
    run = simulate(constant_reference_scenario(op, steps * op.dt, e0), controller, seed=0,
                   settings=settings)  # fmt: skip
    e_sim = _errors(run)
    x, e_lin = M @ e0, np.empty_like(e_sim)
    for k in range(e_sim.shape[0]):
        e_lin[k] = x[:3]
        x = A @ x
    n_sim, n_lin = np.linalg.norm(e_sim, axis=1), np.linalg.norm(e_lin, axis=1)
    start = int(0.25 * steps)
    out = {"controller": controller,
           "feed_forward": bool(feed_forward) if controller == "pid" else None,
           "operating_point": op.to_json(), "e0": [float(v) for v in e0], "steps": steps,
           "slowest_eigenvalue_abs": rho, "rate_simulated": _decay_rate(n_sim, ang, start),
           "rate_linear_model": _decay_rate(n_lin, ang, start),
           "diverged": run.diverged}  # fmt: skip
    out["rate_rel_error"] = abs((1 - out["rate_simulated"]) - (1 - rho)) / (1 - rho)
    if controller != "pid" or feed_forward:
        out["max_deviation_from_linear_rel"] = float(np.max(np.abs(e_sim - e_lin)) / np.max(n_lin))
    return out


def gain_limit_check(op: OperatingPoint, index: int, limit: float, factors=(0.98, 1.02),
                     steps: int = 3000, size: float = 1e-3) -> list[dict]:  # fmt: skip
    """Simulate the fixed PID with gain ``index`` at ``factor * limit`` (others at defaults).

    The nonlinear loop (feed-forward on, so that it starts at its equilibrium; no noise) starts
    at an error of norm ``size`` that excites the slowest mode; returns, per factor, the
    closed-loop ``max|z|`` of the linearisation, the largest error norm over the last tenth of
    the run and over the whole run relative to the initial one, and the divergence time if any.
    (Beyond the ``Kdw`` limit the loop chatters at the Nyquist frequency, grows to large
    errors, then bursts irregularly rather than diverging: the peak is the robust sign.)
    """
    out = []
    for factor in factors:
        K = list(PID_GAINS)
        K[index] = factor * limit
        A = closed_loop_matrix(pid_loops(op, K)["v"])
        e0 = slow_mode_error(A, start_state_map("pid", error_plant(op)), size)
        settings = pid_mod.FixedSettings(gains=tuple(K), feed_forward=True,
                                         gain_max=tuple(max(g, 50.0) for g in K))  # fmt: skip
        run = simulate(constant_reference_scenario(op, steps * op.dt, e0), "pid", seed=0,
                       settings=settings)  # fmt: skip
        norms = np.linalg.norm(_errors(run), axis=1)
        out.append({"gain": pid_mod.GAIN_NAMES[index], "value": factor * limit,
                    "factor": factor, "spectral_radius": spectral_radius(A),
                    "tail_over_initial": float(np.max(norms[-max(len(norms) // 10, 1) :]) / size),
                    "peak_over_initial": float(np.max(norms) / size),
                    "diverged_at": run.diverged_at})  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------
# Checks, prose, table, report section (from the record only)
# ---------------------------------------------------------------------------------------------


def check(record: dict) -> None:
    """The headline claims: the margins and eigenvalues are confirmed by the independent
    computations, and the record holds the contracted keys (works on the stored JSON)."""
    for name in ("pid", "backstepping"):
        for ch in CHANNELS:
            for key in ("gain_margin_db", "phase_margin_deg", "disk_margin"):
                v = record[name][ch][key]
                assert v == "inf" or isinstance(v, float), (name, ch, key, v)
    assert isinstance(record["backstepping"]["eigenvalues"], list)
    cc = record["cross_checks"]
    for key in ("pid_closed_loop_vs_casadi_max_abs", "bsc_closed_loop_vs_casadi_max_abs",
                "pid_feed_forward_jacobian_max_abs_diff",
                "printed_at_heading_0_equals_corrected_max_abs"):  # fmt: skip
        assert cc[key] < 1e-12, (key, cc[key])
    # eig(A_d) - exp(eig(A) dt) is O(dt^2): halving dt divides it by ~4.
    assert 3.0 < (r := cc["bsc_discrete_vs_exp_continuous"])["ratio"] < 5.0, r
    for name in ("pid", "backstepping"):
        for ch in CHANNELS:
            c = cc[f"{name}_{ch}_eigen_vs_frequency"]
            for key in ("gain_margin_rel_diff", "gain_margin_lower_rel_diff",
                        "phase_margin_abs_diff_deg", "disk_margin_rel_diff"):  # fmt: skip
                assert c[key] < 1e-6, (name, ch, key, c)
            assert c["disk_gm_below_classical"] and c["disk_pm_below_classical"], (name, ch, c)
    for d in cc["simulated_decay"]:
        assert not d["diverged"], d
        assert d["rate_rel_error"] < 1e-3, d
        if "max_deviation_from_linear_rel" in d:
            assert d["max_deviation_from_linear_rel"] < 0.02, d
    assert cc["region_v_agrees_with_jury"] == 1.0, cc["region_v_agrees_with_jury"]
    assert cc["gain_limits_vs_jury_rel_diff"] < 1e-9, cc["gain_limits_vs_jury_rel_diff"]
    for d in cc["gain_limits_simulated"]:  # just inside the limit decays, just outside grows
        if d["factor"] < 1.0:
            assert d["diverged_at"] is None and d["tail_over_initial"] < 1.0, d
        else:
            assert d["diverged_at"] is not None or d["peak_over_initial"] > 10.0, d
    _margins_adaptive.check(record)  # frozen adaptive-bsc: BSC's margins once adapted
    fq = record.get("floquet", {})  # records older than issue 14 have none
    for name in floquet.CONTROLLERS if fq else ():  # Phi = A^N up to round-off (N products)
        c = fq["circle_closed_form"][name]
        assert c["monodromy_rel_diff"] < 1e-10 and c["multipliers_rel_diff"] < 1e-8, c
        sims = [fq[sc][name]["simulated"] for sc in FLOQUET_SCENARIOS]
        assert all(s.get("modal_ratio_rel_error", 0.0) < floquet.SIM_TOL for s in sims), sims
        assert name == "backstepping" or all("skipped" not in s for s in sims), sims


def notes(record: dict) -> list[str]:
    """The report's notes on the study, from the record (and the SGD clamp of
    ``wmr.controllers.pid.Settings``, which they compare with the derivative-gain limits)."""
    intervals = record["stability_region"]["stable_interval_one_gain_at_a_time"]
    kd_limits = (intervals["Kdv"][1], intervals["Kdw"][1])
    clamp = pid_mod.Settings().gain_max
    kd_clamp = (clamp[2], clamp[5])
    below = max(kd_clamp[0] / kd_limits[0], kd_clamp[1] / kd_limits[1]) < 1
    return [
        "Margins are loop-at-a-time (loop broken at one plant input, the other loop closed); "
        "they ignore simultaneous perturbations of both channels.",
        "gain_margin_db is the upper gain margin (gain increase); gain_margin_lower_db the lower "
        "one (gain reduction that destabilises; '-inf' if none). Infinite margins are 'inf'.",
        "Eigenvalues are [re, im] pairs of the discrete closed loop (|z| < 1 stable), largest "
        "modulus first; the PID closed loop has 7 states (e1, e2, e3, I[e1], I[s], e1_prev, "
        "s_prev), two of them at z = 0 because Kdv = Kdw = 0.",
        "Classical margins come from the state-space frequency response with root refinement; "
        "python-control 0.10.2 stability_margins misplaces crossovers for these loops "
        "(polynomial method, poles clustered at z = 1) and never reports a phase crossover at "
        "the Nyquist frequency (z = -1), where the upper gain margins of these loops are. Its "
        "FRD result is kept under 'python_control' for the phase margin.",
        "Disk margins: control.disk_margins (skew 0, alpha = 1/max|S - 1/2|), SISO, on the grid "
        "plus the refined peak frequency; along runs the same formula is evaluated directly.",
        "Linearisation without feed-forward (literal eq. 7) and with it are identical at a "
        "constant (v_r, w_r): the feed-forward only moves the integrals' equilibrium to zero.",
        "Along runs the analysis is frozen-time (gains and (v_r, w_r) frozen at t_k).",
        "stable_interval_one_gain_at_a_time: each gain varied alone, the others at their "
        f"defaults. The derivative gains destabilise the loop at Kdv ~ {kd_limits[0]:.3g} and "
        f"Kdw ~ {kd_limits[1]:.3g} (dt = {record['operating_point']['dt']:g}); the SGD clamp "
        f"gain_max of wmr.controllers.pid.Settings is Kdv <= {kd_clamp[0]:g}, Kdw <= "
        f"{kd_clamp[1]:g}: " + ("below" if below else "NOT below") + " those limits.",
        "Printed rotation (E3): on a straight line the controller sees N(theta) e with "
        "N = [[1,0,0],[sin 2theta, cos 2theta, 0],[0,0,1]]; the loop depends on the heading.",
    ]


def table(record: dict) -> str:
    """``tables/margins.md``: margins at the operating point, at the other points, and the
    stable interval of each PID gain."""
    op = record["operating_point"]
    lines = [f"Loop-at-a-time margins of the linearised sampled-data loops at v_r = "
             f"{op['v_r']:.4f} m/s, w_r = {op['w_r']:.4f} rad/s, dt = {op['dt']} s "
             f"({op['label']}); GM upper/lower in dB, PM and disk PM in deg, "
             f"alpha = balanced disk margin.", ""]  # fmt: skip
    rows = []
    for name, label in (("pid", "PID (eq. 7, fixed)"), ("backstepping", "BSC")):
        rec = record[name]
        for ch in CHANNELS:
            m = rec[ch]
            rows.append((label, ch, _f(m["gain_margin_db"]), _f(m["gain_margin_lower_db"]),
                         _f(m["phase_margin_deg"]), _f(m["disk_margin"], 3),
                         _f(m["disk_gain_margin_db"]), _f(m["disk_phase_margin_deg"]),
                         f"{rec['spectral_radius']:.5f}",
                         f"{rec['slowest_time_constant_s']:.2f}"))  # fmt: skip
    lines += common.md_table(("controller", "loop", "GM", "GM lower", "PM", "alpha", "disk GM",
                              "disk PM", "max abs(z)", "slowest tau [s]"), rows)  # fmt: skip
    lines += ["", "Other operating points (PID / BSC, GM upper dB / PM deg / alpha per loop):", ""]
    rows = []
    for label, rec in record["operating_points"].items():
        loops = (rec[name][ch] for name in ("pid", "backstepping") for ch in CHANNELS)
        cells = [f"{_f(m['gain_margin_db'], 1)} / {_f(m['phase_margin_deg'], 1)} / "
                 f"{_f(m['disk_margin'], 3)}" for m in loops]  # fmt: skip
        rows.append((label, f"{rec['v_r']:.3f}", f"{rec['w_r']:.3f}", *cells))
    lines += common.md_table(("operating point", "v_r", "w_r", "PID v", "PID w", "BSC v",
                              "BSC w"), rows)  # fmt: skip
    iv = record["stability_region"]["stable_interval_one_gain_at_a_time"]
    gains = ", ".join(f"{g:g}" for g in record["pid"]["gains"])
    lines += ["", f"Stable interval of each PID gain, the others at ({gains}), at the operating "
              "point above:", ""]
    lines += common.md_table(("gain", *iv),
                             [("stable for", *(f"({_f(lo, 3)}, {_f(hi, 3)})"
                                               for lo, hi in iv.values()))])  # fmt: skip
    dtol = record.get("delay_tolerance")
    if dtol:  # records older than issue 12 have none
        lines += ["", "Largest input delay the loop tolerates (whole samples, ms), with a first-"
                  "order actuator lag of each time constant, at the operating point above:", ""]
        lines += common.md_table(("controller", *(f"lag {1e3 * tau:g} ms" for tau in
                                                  dtol["lags_s"])),
                                 [(label, *(f"{s} ({1e3 * x:g})" if s is not None else "unstable"
                                            for s, x in zip(dtol[name]["max_stable_delay_steps"],
                                                            dtol[name]["max_stable_delay_s"],
                                                            strict=True)))
                                  for name, label in (("pid", "PID (eq. 7, fixed)"),
                                                      ("backstepping", "BSC"))])  # fmt: skip
    lines += _margins_nmpc.table_lines(record) + _margins_adaptive.table_lines(record)  # issue 21
    fq = record.get("floquet")  # records older than issue 14 have none
    return "\n".join(lines + (_floquet_table(fq) if fq else [])) + "\n"


def render(record: dict) -> str:
    """The report section: the notes, the table and the figures."""
    return common.section(TITLE, notes(record), table(record), sorted(record["figures"]))


# ---------------------------------------------------------------------------------------------
# Private helpers
# ---------------------------------------------------------------------------------------------


def _floquet_table(fq: dict) -> list[str]:
    rows = [(f"{sc} ({fq[sc]['period_s']:.2f} s, {fq[sc]['steps']} steps)", name,
             " / ".join(f"{m:.3g}" if m > b else f"<{b:.1g}" for m, b in
                        zip(r["moduli"], r["moduli_error_bound"], strict=True)),
             f"{r['average_rate']:.6f}", f"{r['time_constant_s']:.2f}",
             f"{r['frozen_rho_min']:.6f} .. {r['frozen_rho_max']:.6f}",
             f"{r['frozen_period_prediction']:.3g}", common.fmt(r["simulated"].get(
                 "modal_ratio_rel_error"), 6)) for sc in FLOQUET_SCENARIOS
            for name in floquet.CONTROLLERS for r in [fq[sc][name]]]  # fmt: skip
    return ["", "Floquet multipliers about the periodic references (largest abs(mu), '<': below "
            "round-off), rate per step abs(mu_1)^(1/N), time constant, frozen-time max abs(z) "
            "along the orbit, its geometric mean^N (frozen-time abs(mu_1)), simulated abs(mu_1) "
            "relative error (—: unresolved):", "", *common.md_table(("reference", "loop",
            "abs(mu)", "rate", "tau [s]", "frozen max abs(z)", "frozen^N", "sim. rel. err."), rows)]


def _pid_casadi_matrix(op: OperatingPoint) -> np.ndarray:
    """CasADi's Jacobian of the whole nonlinear PID closed loop at its equilibrium (7, 7)."""
    return np.asarray(sym.pid_closed_loop_jacobian_function(op.integrator)(
        pid_equilibrium(op, PID_GAINS), op.u_r, PID_GAINS, op.dt))  # fmt: skip


def _errors(run) -> np.ndarray:
    """The corrected tracking errors (eq. 6) along ``run``, shape (n + 1, 3)."""
    return np.array([tracking_error(q, r) for q, r in zip(run.q, run.ref, strict=True)])


def _decay_rate(norms: np.ndarray, angle: float, start: int, harmonics: int = 4) -> float:
    """Per-step decay rate of ``norms[start:]``: least-squares slope of ``log |x_k|``.

    A damped mode ``z = rho exp(j angle)`` gives ``|x_k| = rho^k p(k)`` with ``p`` periodic of
    frequency ``2 angle`` per step; ``log p`` is fitted by ``harmonics`` Fourier pairs beside the
    line ``log c + k log rho`` (none for a real mode), so the slope is not biased by the
    oscillation.
    """
    k = np.arange(start, norms.size, dtype=float)
    cols = [np.ones_like(k), k - k[0]]
    if angle > 1e-9:
        for h in range(1, harmonics + 1):
            cols += [np.cos(2 * h * angle * k), np.sin(2 * h * angle * k)]
    coef, *_ = np.linalg.lstsq(np.column_stack(cols), np.log(norms[start:]), rcond=None)
    return float(np.exp(coef[1]))


def _controller_record(loops: dict, res: dict, gains) -> dict:
    rec = {"gains": [float(g) for g in gains]}
    for ch in CHANNELS:
        rec[ch] = res[ch].to_json()
    rec["eigenvalues"] = _eigs_json(res["eigenvalues"])
    rec["spectral_radius"] = res["spectral_radius"]
    rec["slowest_time_constant_s"] = -loops["v"].dt / math.log(res["spectral_radius"])
    return rec


def _eigs_json(z: np.ndarray) -> list:
    """Eigenvalues as ``[re, im]`` pairs, largest modulus first."""
    z = np.asarray(z, dtype=complex)
    z = z[np.lexsort((z.imag, -np.round(np.abs(z), 12)))]
    return [[float(x.real), float(x.imag)] for x in z]


def _arrays_to_json(rec: dict) -> dict:
    return {k: ([json_number(v) for v in np.ravel(a)] if np.ndim(a) == 1 else
                [[json_number(v) for v in row] for row in a]) for k, a in rec.items()}  # fmt: skip


def _f(x, nd=2):
    """A table cell: ``"inf"``-like strings as they are, None as a dash, else ``nd`` decimals."""
    return x if isinstance(x, str) else ("—" if x is None else f"{x:.{nd}f}")

