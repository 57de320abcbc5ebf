"""Errata checked with exact Jacobians: closed forms vs CasADi AD, and the learned Jacobian.

Issue 4, item 2.  Two parts, one study (``STEM = "jacobians"``):

- **The point study** (:mod:`analysis.jacobians.points`): every Jacobian the closed loop uses is
  compared with the independent CasADi oracle at seeded random points, at edge points and at the
  states visited by the paper's scenarios; the paper's printed forms (eqs. 4/6, errata E3, and
  eqs. 22-24, errata E7) go through the same check and fail it.
- **The learned Jacobian**: the Jacobian that the IAPID-NN-DEKF identifier learns in closed loop
  against the true plant Jacobian, and the SGD gain-update direction it produces against the one the
  true Jacobian would give (:func:`wmr.estimation.identification.jacobian_quality`), over seeds,
  with and without pose-measurement noise, at each pose-EKF process noise of :data:`PROCESS_STD`,
  and for the oracle arm (:data:`ORACLE`, its identifier trained on the true poses); beside it the
  noise on the identifier's velocity targets against their signal (:func:`target_noise_summary`),
  which the notes compare the errors with.

:func:`run` writes ``results/jacobians.json``, ``tables/jacobians.md``,
``figures/jacobians_errors.png`` (closed form vs AD, log scale, printed forms included) and
``figures/jacobians_learned.png`` (learned vs true plant Jacobian along each paper scenario);
:func:`check` asserts the headline claims on the record; :func:`render` is the report section.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from analysis import common
from analysis.jacobians.points import (
    CLOSED_FORM_TOL,
    DET_TOL,
    IDENTITY_TOL,
    PRINTED_MIN_ERROR,
    PRINTED_MIN_RESIDUAL,
    SEED,
    along_run,
    plot_errors,
    point_study,
)
from wmr import scenario as scn
from wmr.closedloop.probes import target_noise
from wmr.estimation.identification import QUALITY_KEYS, JacobianQuality, jacobian_quality

__all__ = [
    "STEM",
    "TITLE",
    # the point study (analysis.jacobians.points), re-exported
    "SEED",
    "CLOSED_FORM_TOL",
    "PRINTED_MIN_ERROR",
    "IDENTITY_TOL",
    "PRINTED_MIN_RESIDUAL",
    "DET_TOL",
    "point_study",
    "along_run",
    "plot_errors",
    # the learned Jacobian and the study
    "CONTROLLER",
    "POINTS",
    "LEARNED_SEEDS",
    "LEARNED_KEYS",
    "LEARNED_DEFINITION",
    "ORACLE",
    "PROCESS_STD",
    "VARIANTS_DEFINITION",
    "without_noise",
    "with_process_std",
    "learned_study",
    "target_noise_summary",
    "summarise_learned",
    "compute",
    "plot_learned",
    "table",
    "notes",
    "run",
    "check",
    "render",
]

STEM = "jacobians"
TITLE = "Errata checked with exact Jacobians (CasADi)"

#: Random points per check of the point study (``quick``: :data:`QUICK_POINTS`).
POINTS = 1000
#: Seeds of the learned-vs-true study per scenario (``quick``: :data:`QUICK_SEEDS`).
LEARNED_SEEDS = 5
QUICK_POINTS = 50
QUICK_SEEDS = 2
#: Duration [s] of the paper scenarios in ``quick`` mode (the full study runs them whole).
QUICK_DURATION = 4.0
#: The controller whose identified Jacobian is studied.
CONTROLLER = "iapid-nn-dekf"
#: The arm whose identifier trains on the true poses (same PID on the same estimate): what the
#: estimation noise costs the identifier, separated from what its model class can learn.
ORACLE = "iapid-oracle"
#: Pose-EKF process-noise std per step [m, m, rad] at which the learned Jacobian is measured (the
#: first is the shipped default).
PROCESS_STD = (0.01, 0.003)
# Per-step series of :func:`wmr.estimation.identification.jacobian_quality` summarised per scenario.
LEARNED_KEYS = QUALITY_KEYS
#: What the ``learned_jacobian`` section of the record holds (stored in it).
LEARNED_DEFINITION = (
    "per step k >= 1: rel_error = ||J_NN - J||_F / ||J||_F with J_NN = dt dNN/d(v, w) the "
    "identified J_{k-1} logged by the controller and J = dq_k/du_{k-1} of the ZOH step at "
    "(q_hat_{k-1}, u_{k-1}); J = 0 would score 1.  cosine: between g_NN and g = "
    "J^T T_e^T Gamma e_k (the SGD direction of eqs. 9-17 per channel); sign_v, sign_w: "
    "fraction of steps where the v- and w-gains would move the same way; norm_ratio "
    "||J_NN||/||J||; matrix_cosine: of J_NN and J as 6-vectors; rel_error_v/_w: per "
    "column.  Each entry: the per-run mean over the last half of the run, then mean and "
    "std over seeds (rel_error_whole_run: over the whole run).  noise_free: the same "
    "without pose-measurement noise (a diagnostic, not a paper scenario)."
)
#: What the ``process_noise``, ``oracle`` and ``target_noise`` entries hold (stored).
VARIANTS_DEFINITION = (
    "process_noise[std]: the same summary with the pose EKF's process-noise std set to std per "
    "step on every axis (dataclasses.replace of the scenario's estimator; same seeds).  oracle: "
    "the same summary for iapid-oracle, whose identifier trains on the true poses (the PID acts "
    "on the same estimate).  target_noise[std]: the identifier's velocity targets "
    "(q_hat_k - q_hat_(k-1))/dt against the true increment (q_k - q_(k-1))/dt along the same "
    "runs (k = 1..N-1): std over the run of their difference per axis (x, y [m/s], theta "
    "[rad/s]) and its RMS norm over (x, y) and over all three; RMS of the true increment (the "
    "signal) likewise; per run, then mean and std over seeds."
)


# ---------------------------------------------------------------------------------------------
# The learned Jacobian along closed-loop runs
# ---------------------------------------------------------------------------------------------


def without_noise(scenario: scn.Scenario) -> scn.Scenario:
    """The scenario with zero pose-measurement noise (a diagnostic: how much of the identifier's
    error the noise causes)."""
    noise = dataclasses.replace(scenario.noise, pose_std=(0.0,) * len(scenario.noise.pose_std))
    return dataclasses.replace(scenario, noise=noise)


def with_process_std(scenario: scn.Scenario, std: float) -> scn.Scenario:
    """The scenario with the pose EKF's process-noise std ``std`` [m, m, rad per step] on every
    axis (nothing else changes)."""
    est = dataclasses.replace(scenario.estimator,
                              process_std=(float(std),) * len(scenario.estimator.process_std))
    return dataclasses.replace(scenario, estimator=est)


def learned_study(scenarios: dict[str, scn.Scenario], seeds: int = LEARNED_SEEDS,
                  noise: bool = True, controller: str = CONTROLLER
                  ) -> tuple[dict, dict, dict]:  # fmt: skip
    """``controller`` (default ``iapid-nn-dekf``) on each scenario for seeds ``0 .. seeds-1``.

    ``noise=False`` runs the scenarios without pose-measurement noise (:func:`without_noise`).

    Returns
    -------
    runs : dict of list of RunResult
        Per scenario name, the runs (with trajectories) in seed order.
    series : dict of list of JacobianQuality
        Their per-step Jacobian quality against the scenario's nominal ZOH plant.
    summary : dict
        Per scenario, :func:`summarise_learned` of its series.
    """
    from wmr.closedloop.sim import simulate

    runs, series, summary = {}, {}, {}
    for name, sc in scenarios.items():
        sc = sc if noise else without_noise(sc)
        runs[name] = []
        for seed in range(seeds):
            r = simulate(sc, controller, seed)
            if r.diverged:
                raise RuntimeError(f"{controller} diverged on {name}, seed {seed}: {r.cause}")
            runs[name].append(r)
        series[name] = [jacobian_quality(r, integrator=sc.integrator) for r in runs[name]]
        summary[name] = summarise_learned(series[name])
    return runs, series, summary


def summarise_learned(series: list[JacobianQuality]) -> dict:
    """Mean and std (ddof 1) over seeds of the per-run means over the last half of each run, of
    every series of :data:`LEARNED_KEYS`; ``rel_error_whole_run``: the same over the whole run;
    ``rel_error_final``: the last step's error per seed."""

    def over_seeds(key: str, start: float = 0.5) -> dict:
        v = np.asarray([s.tail_mean(key, start) for s in series])
        return {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0}

    out: dict = {"seeds": len(series)}
    for key in LEARNED_KEYS:
        out[key] = over_seeds(key)
    out["rel_error_whole_run"] = over_seeds("rel_error", start=0.0)
    out["rel_error_final"] = [float(s.rel_error[-1]) for s in series]
    return out


def target_noise_summary(runs: list) -> dict:
    """The noise on the identifier's velocity targets along ``runs`` (:func:`wmr.closedloop.probes.
    target_noise`: target minus the true increment, steps ``k = 1 .. N-1``) against the signal
    (the true increment): per run the std of the noise per axis, its RMS norm over (x, y) and
    over (x, y, theta), and the RMS of the signal likewise; then mean and std over the runs."""
    per_run = []
    for r in runs:
        v, s = target_noise(r.q, r.q_hat, r.dt)
        per_run.append({
            "noise_std": v.std(axis=0),
            "noise_rms_xy": np.sqrt(np.mean(np.sum(v[:, :2] ** 2, axis=1))),
            "noise_rms": np.sqrt(np.mean(np.sum(v**2, axis=1))),
            "signal_rms": np.sqrt(np.mean(s**2, axis=0)),
            "signal_rms_xy": np.sqrt(np.mean(np.sum(s[:, :2] ** 2, axis=1))),
            "signal_rms_all": np.sqrt(np.mean(np.sum(s**2, axis=1))),
        })  # fmt: skip
    out = {}
    for key in per_run[0]:
        v = np.array([d[key] for d in per_run])
        std = v.std(axis=0, ddof=1) if len(per_run) > 1 else np.zeros_like(v[0])
        out[key] = {"mean": np.mean(v, axis=0).tolist(), "std": np.asarray(std).tolist()}
    return out


def _variants(scenarios: dict, seeds: int) -> tuple[dict, dict]:
    """The learned Jacobian at each pose-EKF process noise of :data:`PROCESS_STD` and of the
    oracle arm, with the target noise of the process-noise runs: the record's entries and the
    per-step series (by process noise, and ``"oracle"``)."""
    out: dict = {"variants_definition": VARIANTS_DEFINITION, "process_noise": {},
                 "target_noise": {}}  # fmt: skip
    series = {}
    for std in PROCESS_STD:
        scs = {n: with_process_std(sc, std) for n, sc in scenarios.items()}
        runs, series[std], summary = learned_study(scs, seeds)
        out["process_noise"][f"{std:g}"] = summary
        out["target_noise"][f"{std:g}"] = {n: target_noise_summary(rs) for n, rs in runs.items()}
    _, series["oracle"], out["oracle"] = learned_study(scenarios, seeds, controller=ORACLE)
    return out, series


def compute(points: int = POINTS, seeds: int = LEARNED_SEEDS,
            scenarios: dict[str, scn.Scenario] | None = None) -> tuple[dict, dict]:  # fmt: skip
    """The study's numbers: the record (without ``notes`` and ``figures``) and what the figures
    draw (``raw``: per-point errors; ``series``, ``series_quiet``: the learned-Jacobian series
    with and without noise).  ``scenarios``: default the paper's three."""
    if scenarios is None:
        scenarios = {n: scn.load(scn.builtin(n)) for n in scn.PAPER_SCENARIOS}
    record, raw = point_study(points, SEED)
    runs, series, learned = learned_study(scenarios, seeds)
    _, series_quiet, learned_quiet = learned_study(scenarios, seeds, noise=False)
    record["along_runs"] = {
        "controller": CONTROLLER,
        "seed": 0,
        "scenarios": {n: along_run(rs[0]) for n, rs in runs.items()},
    }
    variants, variant_series = _variants(scenarios, seeds)
    variants["default_process_std"] = [list(sc.estimator.process_std) for sc in scenarios.values()]
    record["learned_jacobian"] = {
        "controller": CONTROLLER,
        "seeds": seeds,
        "definition": LEARNED_DEFINITION,
        "scenarios": learned,
        "noise_free": learned_quiet,
        **variants,
    }
    return record, {"raw": raw, "series": series, "series_quiet": series_quiet,
                    "variants": variant_series}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Figure, table, notes
# ---------------------------------------------------------------------------------------------


def plot_learned(series: dict[str, list[JacobianQuality]], axes=None, window: float = 1.0,
                 reference: dict[str, list[JacobianQuality]] | None = None):  # fmt: skip
    """Relative error of the learned Jacobian (left) and the rolling mean cosine between the
    learned and true SGD directions (right) per scenario; one thin line per seed, median bold.

    ``reference``: series of the same scenarios without measurement noise, drawn as a dashed
    median.  Returns the figure."""
    import matplotlib.pyplot as plt

    scen = list(series)
    if axes is None:
        fig, axes = plt.subplots(len(scen), 2, figsize=(12, 2.8 * len(scen)), squeeze=False,
                                 sharex=True, layout="constrained")  # fmt: skip
    else:
        fig = np.atleast_1d(axes).ravel()[0].figure
        axes = np.atleast_2d(axes)
    for row, name in zip(axes, scen, strict=True):
        ss = series[name]
        t = ss[0].t
        dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
        w = max(1, int(round(window / dt)))
        rel = np.array([s.rel_error for s in ss])
        cos = np.array([_rolling_mean(s.cosine, w) for s in ss])
        for r, c in zip(rel, cos, strict=True):
            row[0].plot(t, r, color="tab:blue", lw=0.5, alpha=0.4)
            row[1].plot(t, c, color="tab:purple", lw=0.5, alpha=0.4)
        row[0].plot(t, np.median(rel, axis=0), color="tab:blue", lw=1.5, label="median over seeds")
        row[1].plot(t, np.median(cos, axis=0), color="tab:purple", lw=1.5,
                    label=f"median, {window:g} s rolling mean")  # fmt: skip
        if reference is not None and name in reference:
            rs = reference[name]
            rel0 = np.median([s.rel_error for s in rs], axis=0)
            cos0 = np.median([_rolling_mean(s.cosine, w) for s in rs], axis=0)
            for ax, curve in zip(row[:2], (rel0, cos0), strict=True):
                ax.plot(rs[0].t, curve, color="tab:orange", ls="--", lw=1.2,
                        label="median, no measurement noise")  # fmt: skip
        row[0].axhline(1.0, color="k", ls="--", lw=0.8, label="J = 0 (knows nothing)")
        row[0].set_yscale("log")
        row[0].set_ylabel(f"{name}\n||J_NN - J|| / ||J||", fontsize=9)
        row[1].axhline(0.0, color="k", lw=0.5)
        row[1].set_ylim(-1.05, 1.05)
        row[1].set_ylabel("cos(g_NN, g_true)", fontsize=9)
        for ax in row:
            ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7)
    axes[0, 1].legend(fontsize=7)
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("t [s]")
    return fig


def _rolling_mean(x: np.ndarray, w: int) -> np.ndarray:
    """Centred mean over ``w`` samples, ignoring NaN and shrinking at the ends (no zero padding)."""
    ok = np.isfinite(x)
    k = np.ones(w)
    s = np.convolve(np.where(ok, x, 0.0), k, "same")
    n = np.convolve(ok.astype(float), k, "same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, s / np.maximum(n, 1.0), np.nan)


def table(record: dict) -> str:
    """``tables/jacobians.md`` (also the report's table): the max error of every check against
    its threshold, then the learned-Jacobian summary per scenario."""
    ni, nw, rot = record["network_input"], record["network_weights"], record["rotation"]
    n_e = rot["error_dynamics_points"]
    rows = [(f"ZOH step `{name}`: F, G", e["n"], e["max_rel_error"], "< 1e-10")
            for name, e in record["unicycle_step"].items()]  # fmt: skip
    rows += [
        ("network dz/dx, corrected (E7)", ni["n"], ni["corrected_max_rel_error"], "< 1e-10"),
        ("network H = dz/dθ (E8)", nw["n"], nw["max_rel_error"], "< 1e-10"),
        ("network dz/dx, printed eqs. 22–24 (median)", ni["n"], ni["printed_median_rel_error"],
         "> 0.1 (fails)"),
        ("network dz/dx, printed eqs. 22–24 (max)", ni["n"], ni["printed_max_rel_error"],
         "> 0.1 (fails)"),
        ("Kanayama error dynamics, rotation (abs.)", n_e,
         rot["error_dynamics_max_residual"]["corrected"], "< 1e-12"),
        ("Kanayama error dynamics, printed eqs. 4/6 (abs., median)", n_e,
         rot["error_dynamics_median_residual"]["printed"], "> 1e-3 (fails)"),
        ("det T_e(printed) − cos 2θ (abs.)", rot["grid_points"],
         rot["max_abs_det_minus_cos_2theta"], f"< {DET_TOL:g}"),
    ]  # fmt: skip
    lines = [f"Closed forms vs CasADi AD at {record['points']} seeded random points per check "
             "(plus edge points); relative Frobenius error unless marked abs.", ""]  # fmt: skip
    lines += common.md_table(("check", "points", "error", "claim"),
                             ((a, n, f"{v:.3g}", c) for a, n, v, c in rows))  # fmt: skip
    lines += ["", f"`det T_e` printed: `{rot['printed_det']}` = cos 2θ; corrected: "
              f"`{rot['corrected_det']}`.", ""]  # fmt: skip
    learned = record.get("learned_jacobian")
    if learned:
        lines += [f"Learned (IAPID-NN-DEKF) vs true plant Jacobian, mean ± std over "
                  f"{learned['seeds']} seeds, last half of each run:", ""]  # fmt: skip
        header = ("scenario", "rel. error", "column v", "column w", "‖J_NN‖/‖J‖",
                  "cos(J_NN, J)", "cos(g_NN, g)", "same sign v", "same sign w")  # fmt: skip
        variants = [("", learned["scenarios"]), (" (no noise)", learned.get("noise_free", {}))]
        variants += [(f" (process noise {std})", d)
                     for std, d in learned.get("process_noise", {}).items()
                     if d != learned["scenarios"]]  # the default's rows are the first ones
        if "oracle" in learned:
            variants.append((" (oracle)", learned["oracle"]))
        cells = [[f"{sc}{suffix}"] + [f"{d[k]['mean']:.3f} ± {d[k]['std']:.3f}"
                                      for k in LEARNED_KEYS]
                 for suffix, entries in variants for sc, d in entries.items()]  # fmt: skip
        lines += common.md_table(header, cells)
        lines += ["", "Relative error 1 is what J = 0 scores.  (no noise): the same runs without "
                  "pose-measurement noise, a diagnostic."
                  + ("  (process noise s): the pose EKF's process-noise std s per step (the "
                     "default's rows are the first).  (oracle): iapid-oracle, whose identifier "
                     "trains on the true poses." if "oracle" in learned else ""), ""]  # fmt: skip
        lines += _target_noise_table(learned)
    return "\n".join(lines)


def _target_noise_table(learned: dict) -> list[str]:
    """The noise on the identifier's targets against the signal, per process noise."""
    tn = learned.get("target_noise")
    if not tn:
        return []

    def ms(d: dict, i: int | None = None) -> str:
        m, s = (d["mean"], d["std"]) if i is None else (d["mean"][i], d["std"][i])
        return f"{m:.3f} ± {s:.3f}"

    rows = [[sc, std, *(ms(d["noise_std"], i) for i in range(3)), ms(d["noise_rms_xy"]),
             ms(d["signal_rms_xy"]), ms(d["noise_rms"]), ms(d["signal_rms_all"])]
            for std, per in tn.items() for sc, d in per.items()]  # fmt: skip
    header = ("scenario", "process std", "noise std x [m/s]", "noise std y [m/s]",
              "noise std θ [rad/s]", "noise RMS (x, y) [m/s]", "signal RMS (x, y) [m/s]",
              "noise RMS (x, y, θ)", "signal RMS (x, y, θ)")  # fmt: skip
    return (["The identifier's targets (q̂_k − q̂_(k−1))/dt: their noise (target minus the true "
             f"increment (q_k − q_(k−1))/dt) against the signal (the true increment), mean ± std "
             f"over {learned['seeds']} seeds:", ""]
            + common.md_table(header, rows) + [""])  # fmt: skip


def notes(record: dict) -> list[str]:
    """The report's bullet points, every number read from ``record``."""
    ni, rot = record["network_input"], record["rotation"]
    lines = [
        "Every closed form of the library (ZOH step Jacobians F, G for exact/Euler/RK4; the "
        "corrected network input Jacobian W diag(1 - h^2) V; the weight Jacobian H) agrees with "
        f"CasADi AD to rounding: max relative error {_max_closed(record):.1e} at random, edge "
        "and along-run points.",
        f"The printed eqs. 22-24 fail the same check: median relative error "
        f"{ni['printed_median_rel_error']:.2f}, above 0.1 at "
        f"{100 * ni['printed_fraction_above_0.1']:.0f}% of the points.",
        f"det T_e(printed) = {rot['printed_det']} = cos 2theta (max deviation "
        f"{rot['max_abs_det_minus_cos_2theta']:.1e} on {rot['grid_points']} angles): singular at "
        "+-45 and +-135 deg.",
        "Kanayama's error dynamics hold with the rotation (max residual "
        f"{rot['error_dynamics_max_residual']['corrected']:.1e}) and not with the printed matrix "
        f"(median residual {rot['error_dynamics_median_residual']['printed']:.2f}).",
    ]
    lines.append("Learned vs true plant Jacobian, means over the last half of the runs and over "
                 "seeds (relative error 1 = the trivial J = 0), per scenario:")
    for sc, d in record["learned_jacobian"]["scenarios"].items():
        h = {k: d[k]["mean"] for k in LEARNED_KEYS}
        lines.append(f"{sc}: relative error {h['rel_error']:.2f}, norm ratio "
                     f"{h['norm_ratio']:.1f}, matrix cosine {h['matrix_cosine']:.2f}; SGD "
                     f"direction cosine {h['cosine']:.2f}, same sign v/w {h['sign_v']:.2f}/"
                     f"{h['sign_w']:.2f}.")  # fmt: skip
    quiet = record["learned_jacobian"].get("noise_free")
    if quiet:
        lines.append(_explanation(record["learned_jacobian"]))
    return lines


def _span(values) -> str:
    lo, hi = min(values), max(values)
    return f"{lo:.2f}" if f"{lo:.2f}" == f"{hi:.2f}" else f"{lo:.2f}–{hi:.2f}"


def _per_scenario(entries: dict, key: str = "rel_error") -> str:
    return "/".join(f"{d[key]['mean']:.2f}" for d in entries.values())


def _explanation(learned: dict) -> str:
    """Where the learned Jacobian's error comes from, as the record's numbers say: the noise on
    the identifier's targets at each pose-EKF process noise, the error there, the oracle's error
    and the noise-free diagnostic; the conclusion is chosen by those numbers."""
    quiet = learned["noise_free"]
    names = "/".join(learned["scenarios"])
    nf = (f"Without pose-measurement noise (a diagnostic: no noise in the targets nor in the "
          f"inputs) {names} {_per_scenario(quiet)} (norm ratio {_per_scenario(quiet, 'norm_ratio')}"
          f", column w {_per_scenario(quiet, 'rel_error_w')}, column v "
          f"{_per_scenario(quiet, 'rel_error_v')}).")  # fmt: skip
    pn, tn = learned.get("process_noise"), learned.get("target_noise")
    oracle = learned.get("oracle")
    if not (pn and tn and oracle):
        return nf
    stds = sorted(pn, key=float, reverse=True)
    noise = {std: [d["noise_rms_xy"]["mean"] for d in tn[std].values()] for std in stds}
    signal = [d["signal_rms_xy"]["mean"] for d in tn[stds[0]].values()]
    err = {std: [d["rel_error"]["mean"] for d in pn[std].values()] for std in stds}
    err_o = [d["rel_error"]["mean"] for d in oracle.values()]
    hi, lo = stds[0], stds[-1]
    default = {row[0] for row in learned.get("default_process_std", [])}
    tag = " (the default)" if default == {float(hi)} else ""
    share = [(e - o) / e for e, o in zip(err[hi], err_o, strict=True)]
    follows = (all(a < b for a, b in zip(err[lo], err[hi], strict=True))
               and all(o < e for o, e in zip(err_o, err[hi], strict=True))
               and max(noise[lo]) < min(noise[hi]))  # fmt: skip
    text = (
        "Where the error comes from.  The identifier's targets are (q_hat_k - q_hat_(k-1))/dt; "
        f"with the pose EKF's process noise {hi} per step{tag} the noise on them (target "
        f"minus the true increment) has RMS {_span(noise[hi])} m/s over (x, y), against a true "
        f"(x, y) velocity of RMS {_span(signal)} m/s; at {lo} it is {_span(noise[lo])} m/s.  The "
        f"learned Jacobian's relative error ({names}): {_per_scenario(pn[hi])} at {hi}, "
        f"{_per_scenario(pn[lo])} at {lo}; the oracle identifier (trained on the true poses, "
        f"its PID acting on the same noisy estimate, so its inputs keep the closed loop's "
        f"noise) {_per_scenario(oracle)}: {100 * min(share):.0f}–{100 * max(share):.0f} % of "
        f"the default's error goes when only the targets are noise-free.  "
    )
    if follows:
        most = "most of" if min(share) > 0.5 else "part of"
        text += (f"So {most} the error at the defaults comes with the noise the pose estimate "
                 f"passes into the identifier's targets (the error follows that noise); the "
                 f"noise the closed loop puts into the inputs, which the oracle keeps, and the "
                 f"network's model class leave the oracle's {_span(err_o)}.  ")  # fmt: skip
    else:
        text += ("These numbers do not show the error following the noise on the targets "
                 "in every scenario (compare the rows above).  ")
    return text + nf


def _closed_form_errors(record: dict) -> list[tuple[str, float]]:
    """Every (label, max relative error) of a closed form against AD: at the random and edge
    points, then along each run."""
    out = [(f"step {k}", e["max_rel_error"]) for k, e in record["unicycle_step"].items()]
    out += [("network dz/dx", record["network_input"]["corrected_max_rel_error"]),
            ("network H", record["network_weights"]["max_rel_error"])]  # fmt: skip
    for sc, a in record.get("along_runs", {}).get("scenarios", {}).items():
        out += [(f"{sc}: step {k}", e["max_rel_error"]) for k, e in a["unicycle_step"].items()]
        out += [(f"{sc}: network dz/dx", a["network_input"]["corrected_max_rel_error"]),
                (f"{sc}: network H", a["network_weights"]["max_rel_error"])]  # fmt: skip
    return out


def _max_closed(record: dict) -> float:
    return max(v for _, v in _closed_form_errors(record))


# ---------------------------------------------------------------------------------------------
# The study shape (DESIGN §3.6)
# ---------------------------------------------------------------------------------------------


def run(out, *, quick: bool = False, workers: int | None = None, points: int | None = None,
        seeds: int | None = None) -> dict:  # fmt: skip
    """Run the study into ``out``; returns the record written to ``results/jacobians.json``.

    ``quick``: :data:`QUICK_POINTS` points, :data:`QUICK_SEEDS` seeds and the paper scenarios cut
    to :data:`QUICK_DURATION` s.  ``points``, ``seeds`` override either.  ``workers`` is not used:
    the 30 runs and the CasADi batches take about a minute in one process.
    """
    scenarios = {n: scn.load(scn.builtin(n)) for n in scn.PAPER_SCENARIOS}
    if quick:
        scenarios = {n: dataclasses.replace(sc, duration=QUICK_DURATION)
                     for n, sc in scenarios.items()}  # fmt: skip
    points = points or (QUICK_POINTS if quick else POINTS)
    seeds = seeds or (QUICK_SEEDS if quick else LEARNED_SEEDS)
    record, drawn = compute(points, seeds, scenarios)
    record["notes"] = notes(record)
    fig = plot_learned(drawn["series"], reference=drawn["series_quiet"])
    fig.suptitle(f"Learned ({CONTROLLER}) vs true plant Jacobian, {seeds} seeds")
    record["figures"] = [common.save_figure(out, f"{STEM}_errors.png", plot_errors(drawn["raw"])),
                         common.save_figure(out, f"{STEM}_learned.png", fig)]  # fmt: skip
    common.write_table(out, STEM, table(record))
    common.write_record(out, STEM, record)
    return record


def check(record: dict) -> None:
    """The headline claims; raises ``AssertionError`` naming the one broken.

    Closed forms agree with AD to :data:`CLOSED_FORM_TOL` everywhere (random, edge and along-run
    points); the printed eqs. 22-24 fail (median above :data:`PRINTED_MIN_ERROR`, also along each
    run); Kanayama's error dynamics hold with the rotation (residual below :data:`IDENTITY_TOL`,
    also along each run) and not with the printed matrix; ``det T_e(printed) = cos 2theta`` and
    the rotation's determinant is 1 (to :data:`DET_TOL`); the learned Jacobian's error is finite
    (the oracle's too), and at the default pose-EKF process noise it is the default runs' (same
    seeds, same runs).
    """
    for sc, a in record.get("along_runs", {}).get("scenarios", {}).items():
        r = a["error_dynamics_max_residual"]["corrected"]
        assert r < IDENTITY_TOL, (f"{sc}: corrected error-dynamics residual {r:.3g} >= "
                                  f"{IDENTITY_TOL}")  # fmt: skip
        p = a["network_input"]["printed_median_rel_error"]
        assert p > PRINTED_MIN_ERROR, f"{sc}: printed eqs. 22-24 median error {p:.3g} along the run"
    for label, v in _closed_form_errors(record):
        assert v < CLOSED_FORM_TOL, f"{label}: closed form vs AD {v:.3g} >= {CLOSED_FORM_TOL}"
    p = record["network_input"]["printed_median_rel_error"]
    assert p > PRINTED_MIN_ERROR, (f"printed eqs. 22-24 median error {p:.3g} <= "
                                   f"{PRINTED_MIN_ERROR}: they should fail the check")  # fmt: skip
    rot = record["rotation"]
    r_c = rot["error_dynamics_max_residual"]["corrected"]
    r_p = rot["error_dynamics_median_residual"]["printed"]
    assert r_c < IDENTITY_TOL, f"corrected error-dynamics residual {r_c:.3g} >= {IDENTITY_TOL}"
    assert r_p > PRINTED_MIN_RESIDUAL, (f"printed residual (median) {r_p:.3g} <= "
                                        f"{PRINTED_MIN_RESIDUAL}")  # fmt: skip
    d = rot["max_abs_det_minus_cos_2theta"]
    assert d < DET_TOL, f"det T_e(printed) - cos 2theta up to {d:.3g} >= {DET_TOL}"
    assert rot["max_abs_corrected_det_minus_1"] < DET_TOL, "corrected det T_e is not 1"
    for sc, d in record.get("learned_jacobian", {}).get("scenarios", {}).items():
        assert math.isfinite(d["rel_error"]["mean"]), f"{sc}: learned Jacobian error is not finite"
    learned = record.get("learned_jacobian", {})
    for row in learned.get("default_process_std", []):  # the same seeds, the same runs
        d = learned["process_noise"].get(f"{row[0]:g}")
        assert d is None or d == learned["scenarios"], (
            f"the learned Jacobian at the default process noise {row[0]:g} differs from the "
            "default runs'")
    for sc, d in learned.get("oracle", {}).items():
        assert math.isfinite(d["rel_error"]["mean"]), f"{sc}: the oracle's error is not finite"


def render(record: dict) -> str:
    """The report section: the notes, the table of :func:`table` and the figures."""
    return common.section(TITLE, notes(record), table(record), record["figures"])

