"""The boundedness study's rendering (``analysis.boundedness``): per-scenario notes, the figure,
the table and the report paragraph.

All are rendered from a scenario's record (and the scenario's own settings: its sample period,
disturbances and pose-filter tuning), beside the computation, never inside it.
"""

from __future__ import annotations

import numpy as np

from analysis import common
from wmr.scenario import Scenario

__all__ = ["notes", "figure", "table", "summary"]


def notes(rec: dict, sc: Scenario) -> list[str]:
    """Plain-language reading of one scenario's numbers (computed, not written by hand)."""
    a = rec["alpha"]
    lines = [
        f"Lemma 2's alpha = {a:.3g} with the run's constants (c_bar = {rec['c_bar']:.3g} at "
        f"t = {rec['c_bar_attained_at_s']:.3g} s, median ||H_k|| {rec['norm_H_median']:.3g}, "
        f"p_max = {rec['p_max']:.6g}, q_min = {rec['q_min']:.3g}, r_min = {rec['r_min']:.3g}); "
        f"E10's closed form q/(p0 (1 + p0 c^2/r)^2) = {rec['alpha_closed_form_e10']:.3g} "
        f"(~1e-8/(1+c^2)^2 for the paper's tuning): the guaranteed contraction per step is "
        f"negligible, e-folding of Theorem 1's transient after "
        f"{rec['weight_error_theorem1_decay_time_s']:.3g} s of simulated time.",
        f"Consistency check, not evidence: inequality (48) holds at "
        f"{100 * rec['ineq48_fraction']:.1f} % of the {rec['filter_updates']} filter steps with "
        f"Lemma 2's alpha, as it must: with the run's own constants (48) is a theorem for an exact "
        f"Kalman step (wmr.estimation.stability), so this checks the computation, not the filter's "
        f"boundedness, which needs the constants to hold on an infinite horizon.  The smallest "
        f"achieved "
        f"contraction is {rec['alpha_actual_min']:.3g} = {rec['alpha_actual_min_over_alpha']:.3g} "
        f"x alpha (Lemma 2 gives away the ratio ||M||_bound^2 / ||M||^2 = "
        f"{(rec['norm_M_bound'] / rec['norm_M_max']) ** 2:.3g} and the slack in y <= ||M||^2 "
        f"p_max / q_min). The achieved minimum is q_min / (p_max + q_min) = "
        f"{rec['q_min'] / (rec['p_max'] + rec['q_min']):.3g}: the least-excited weight direction, "
        f"where I - K H ~ I and P only grows by Q; even the actual contraction e-folds only after "
        f"{sc.dt / rec['alpha_actual_min']:.3g} s of simulated time.",
        f"p_min = {rec['p_min']:.3g} >= q_min by construction (P_{{k|k-1}} = P_{{k|k}} + Q). "
        f"p_max = {rec['p_max']:.7g} is reached at t = {rec['p_max_attained_at_s']:.3g} s: "
        f"P0 + Q grows by q per step along directions not yet excited by H_k; the final P has "
        f"eigenvalues in [{rec['final_eig_min']:.3g}, {rec['final_eig_max']:.3g}] "
        f"({rec['final_eigs_above_0.99_p0']} of {rec['n_weights']} above 0.99 p0). A uniform "
        f"p_max on an infinite horizon needs persistent excitation of all weight directions, "
        f"which nothing in the scheme guarantees.",
        f"Weight filter NIS mean {rec['weight_nis_mean']:.3g} vs chi^2 band "
        f"[{rec['weight_nis_bounds'][0]:.3g}, {rec['weight_nis_bounds'][1]:.3g}]: R = "
        f"{rec['r_min']:g} I is a learning-rate knob, not a noise covariance (E11), so the filter "
        f"is not consistent in its output space.",
        *_target_noise_notes(rec),
        f"Weight error proxy ||theta_k - theta*|| goes {rec['weight_error_initial']:.3g} -> "
        f"{rec['weight_error_final']:.3g} (theta*: end of a run twice as long); Theorem 1's bound "
        f"at the end of the run is {rec['weight_error_theorem1_bound_final']:.3g} (transient gain "
        f"p_max/p_min = {rec['weight_error_theorem1_transient_gain']:.3g}, noise floor "
        f"{rec['weight_error_theorem1_noise_floor']:.3g})"
        + (": vacuous." if rec["weight_error_bound_vacuous"] else ".")
        + f" Theorem 1 is moreover local: it needs ||e_0|| <= alpha / (2 p_max kappa_max) = "
        f"{rec['weight_error_theorem1_eps_times_kappa_max']:.3g} / kappa_max (eq. 57), with "
        f"kappa_max of Assumption 2 unknown; the initial weight error here is of order "
        f"{rec['weight_error_initial']:.2g}.",
        f"Pose EKF over {rec['consistency_runs']} seeds: mean NEES {rec['nees_mean']:.3g} "
        f"(NEES of the run average in the 95 % band [{rec['nees_bounds'][0]:.3g}, "
        f"{rec['nees_bounds'][1]:.3g}] at {100 * rec['nees_in_band']:.0f} % of the steps), mean "
        f"NIS {rec['nis_mean']:.3g} ({100 * rec['nis_in_band']:.0f} % in band), "
        f"{'below' if rec['nees_mean'] < 3 else 'above'} 3. For an exact model the pose filter's "
        f"NEES is below 3 by design: its process noise Q_loc (std "
        f"{sc.estimator.process_std} per step) is a tuning choice while the plant has no "
        f"process noise except the disturbance, and the steady-state scalar filter gives NEES "
        f"{rec['nees_predicted_exact_model']:.3g}, NIS {rec['nis_predicted_exact_model']:.3g} "
        f"(wmr.estimation.stability.random_walk_consistency): the filter is over-cautious, not "
        "optimistic.",
    ]
    for name, w in rec["consistency_windows"].items():
        if name != "all":
            lines.append(f"Window {name}: mean NEES {w['nees_mean']:.3g} (in band "
                         f"{100 * w['nees_in_band']:.0f} %, above {100 * w['nees_above_band']:.0f} "
                         f"%), mean NIS {w['nis_mean']:.3g}.")  # fmt: skip
    return lines


def _vec(x, digits: int = 2) -> str:
    return "(" + ", ".join(f"{v:.{digits}f}" for v in x) + ")"


def _target_noise_notes(rec: dict) -> list[str]:
    """The real noise on the identifier's targets, and Theorem 1 with it (if recorded)."""
    if "target_noise_cov" not in rec:
        return []
    return [
        f"The real noise on the weight filter's targets (target minus the true pose increment, "
        f"from the pose estimate's error; the innovation would also carry the network's "
        f"approximation error, which is not noise): std {_vec(rec['target_noise_std'])} m/s, "
        f"m/s, rad/s (RMS norm {rec['target_noise_rms_norm']:.2f}) against a signal of RMS "
        f"{_vec(rec['target_signal_rms'])} (norm {rec['target_signal_rms_norm']:.2f}); the "
        f"filter's R = {rec['r_min']:g} I is {rec['filter_r_over_target_noise']:.3g} times its "
        f"largest covariance eigenvalue.  It is the pose filter's differenced error: the "
        f"exact-model steady state (wmr.estimation.stability.random_walk_increment_noise) "
        "predicts std "
        f"{_vec(rec['target_noise_std_predicted_exact_model'])} and lag-1 autocorrelation "
        f"{_vec(rec['target_noise_lag1_predicted_exact_model'])}; measured "
        f"{_vec(rec['target_noise_lag1_autocorr'])}, so the noise is not white, while "
        f"Theorem 1 assumes white noise.",
        f"Theorem 1's noise term mu = max E[s^T Pi s]: {rec['weight_error_theorem1_mu']:.3g} "
        f"with the filter's R as the noise covariance (nominal), "
        f"{rec['weight_error_theorem1_mu_measured_noise']:.3g} with the measured target-noise "
        f"covariance ({rec['weight_error_theorem1_mu_q_part']:.3g} of it from Q); the bound at "
        f"the end of the run is {rec['weight_error_theorem1_bound_final']:.3g} (nominal) and "
        f"{rec['weight_error_theorem1_bound_final_measured_noise']:.3g} (measured noise), against "
        f"an initial weight error of {rec['weight_error_initial']:.3g}: "
        + ("vacuous either way" if rec["weight_error_bound_vacuous"]
           and rec["weight_error_bound_vacuous_measured_noise"] else "not vacuous with the "
           "measured noise" if rec["weight_error_bound_vacuous"] else "not vacuous")
        + f", since the floor 2 p_max mu / alpha divides by Lemma 2's alpha = {rec['alpha']:.3g}.",
    ]


def figure(sc: Scenario, ws: dict, ps: dict, rec: dict):
    """Six panels: eigenvalues of P, ||H_k||, contraction vs alpha, weight error, NEES, NIS.

    ``ws``, ``ps``: the per-step series of the weight filter and of the pose filter's consistency;
    ``rec``: the scenario's record.  Returns the matplotlib figure (the caller saves it).
    """
    import matplotlib.pyplot as plt

    t = ws["t"]

    def line(ax, key, **kw):  # skip the steps that were not instrumented (NaN)
        ok = ~np.isnan(ws[key])
        ax.plot(t[ok], ws[key][ok], **kw)

    fig, ax = plt.subplots(2, 3, figsize=(15, 7.5), layout="constrained")
    a = ax[0, 0]
    line(a, "lmax_prior", label=r"$\lambda_{max}(P_{k|k-1})$")
    line(a, "lmin_prior", label=r"$\lambda_{min}(P_{k|k-1})$")
    line(a, "lmin_post", lw=0.8, alpha=0.7, label=r"$\lambda_{min}(P_{k|k})$")
    a.axhline(rec["q_min"], color="k", ls=":", lw=1, label=r"$\underline{q}$")
    a.set(yscale="log", title="weight covariance (Assumption 1)", xlabel="t [s]")
    a.legend(fontsize=8)
    a = ax[0, 1]
    line(a, "norm_H", lw=0.8, label=r"$\|H_k\|_2$")
    a.axhline(rec["c_bar"], color="k", ls="--", lw=1, label=rf"$\bar c$ = {rec['c_bar']:.3g}")
    a.set(title="weight Jacobian", xlabel="t [s]")
    a.legend(fontsize=8)
    a = ax[0, 2]
    line(a, "alpha_k", lw=0.8, label=r"achieved: $1-\lambda_{max}$ in (48)")
    a.axhline(rec["alpha"], color="r", ls="--", lw=1,
              label=rf"Lemma 2: $\alpha$ = {rec['alpha']:.2g}")  # fmt: skip
    a.set(yscale="log", title="contraction of (48): holds where blue >= red", xlabel="t [s]")
    a.legend(fontsize=8)
    a = ax[1, 0]
    line(a, "err", label=r"$\|\hat\theta_k-\theta^*\|$ (proxy)")
    line(a, "filter_rms", label=r"$\sqrt{\mathrm{tr}\,P_{k|k}}$ (filter's own)")
    line(a, "bound", color="k", ls="--", lw=1, label="Theorem 1 bound (filter's R)")
    if "bound_measured" in ws:
        line(a, "bound_measured", color="0.4", ls=":", lw=1,
             label="Theorem 1 bound (measured target noise)")  # fmt: skip
    line(a, "pred_error", lw=0.5, alpha=0.6, label="network prediction error")
    a.set(yscale="log", title="weight error and its bound", xlabel="t [s]")
    a.legend(fontsize=7)
    _consistency_panels(ax[1, 1:], sc, ps, rec)
    fig.suptitle(f"Boundedness (E10) and pose-filter consistency: {sc.name}")
    return fig


def _consistency_panels(axes, sc: Scenario, ps: dict, rec: dict) -> None:
    """The pose filter's run-averaged NEES and NIS against their 95 % band."""
    lo, hi = ps["band"]
    width = max(1, round(1.0 / sc.dt))  # 1 s moving average
    for a, key, lab in ((axes[0], "nees", "NEES"), (axes[1], "nis", "NIS")):
        v = ps[key]
        ok = ~np.isnan(v)
        a.plot(ps["t"][ok], v[ok], lw=0.4, alpha=0.5,
               label=f"mean {lab} over {rec['consistency_runs']} runs")  # fmt: skip
        smooth = np.convolve(v[ok], np.ones(width) / width, mode="valid")
        a.plot(ps["t"][ok][width - 1 :], smooth, color="C3", lw=1.2, label="1 s moving average")
        a.axhspan(lo, hi, color="g", alpha=0.2, label="95 % band (per step)")
        a.axhline(3.0, color="k", ls=":", lw=1)
        for d in sc.disturbances:
            a.axvspan(d.start, d.stop, color="0.5", alpha=0.2)
        a.set(yscale="log", title=f"pose EKF {lab}", xlabel="t [s]")
        a.legend(fontsize=7, loc="lower right")


#: Rows of the table: label, record key, format.
_ROWS = (
    ("c_bar = max ||H_k||", "c_bar", ".3g"),
    ("p_min (prior)", "p_min", ".3g"),
    ("p_max (prior)", "p_max", ".7g"),
    ("q_min", "q_min", ".3g"),
    ("r_min", "r_min", ".3g"),
    ("Lemma 2 alpha", "alpha", ".3g"),
    ("E10 closed form", "alpha_closed_form_e10", ".3g"),
    ("(48) fraction with Lemma 2 alpha (consistency check)", "ineq48_fraction", ".4f"),
    ("min achieved contraction", "alpha_actual_min", ".3g"),
    ("  / Lemma 2 alpha", "alpha_actual_min_over_alpha", ".3g"),
    ("P SPD at every step", "P_spd_every_step", ""),
    ("weight NIS mean", "weight_nis_mean", ".3g"),
    ("weight error proxy, start", "weight_error_initial", ".3g"),
    ("weight error proxy, end", "weight_error_final", ".3g"),
    ("Theorem 1 bound, end (filter's R as noise)", "weight_error_theorem1_bound_final", ".3g"),
    ("Theorem 1 bound, end (measured target noise)",
     "weight_error_theorem1_bound_final_measured_noise", ".3g"),
    ("target noise RMS norm [m/s, rad/s]", "target_noise_rms_norm", ".3g"),
    ("target signal RMS norm [m/s, rad/s]", "target_signal_rms_norm", ".3g"),
    ("filter R / largest target-noise variance", "filter_r_over_target_noise", ".3g"),
    ("pose NEES mean", "nees_mean", ".3g"),
    ("pose NIS mean", "nis_mean", ".3g"),
    ("NEES steps in 95 % band", "nees_in_band", ".2f"),
)


def table(record: dict) -> str:
    """``tables/boundedness.md``: the headline numbers per scenario, and the pose filter's
    consistency per time window where a scenario has a disturbance."""
    names = list(record)
    md = ["Boundedness of the weight filter (Assumption 1, Lemma 2, eq. 48, Theorem 1; errata E10) "
          "and pose-EKF consistency, IAPID-NN-DEKF", ""]  # fmt: skip
    md += common.md_table(["quantity", *names], (
        [label, *(format(record[n][key], f) if f else str(record[n][key]) for n in names)]
        for label, key, f in _ROWS
        if all(key in record[n] for n in names)))  # fmt: skip
    first = record[names[0]]
    band = first["nees_bounds"]
    md += ["", f"95 % band of the run-averaged NEES/NIS (3 dof, {first['consistency_runs']} "
           f"runs): [{band[0]:.3g}, {band[1]:.3g}].", ""]  # fmt: skip
    for n in names:
        wins = record[n]["consistency_windows"]
        if len(wins) > 1:
            md += [f"Pose consistency per window, {n}:", ""]
            md += common.md_table(
                ["window", "NEES mean", "NEES in / above band", "NIS mean", "NIS in / above band"],
                ([w, f"{r['nees_mean']:.3g}", f"{r['nees_in_band']:.2f} / "
                  f"{r['nees_above_band']:.2f}", f"{r['nis_mean']:.3g}",
                  f"{r['nis_in_band']:.2f} / {r['nis_above_band']:.2f}"]
                 for w, r in wins.items()))  # fmt: skip
            md.append("")
    return "\n".join(md)


def summary(record: dict) -> str | None:
    """The section's paragraph: what (48) is, and Theorem 1 with the filter's R and with the
    measured target noise, per scenario (from the record)."""
    names = list(record)
    if not all("target_noise_cov" in record[n] for n in names):
        return None

    def each(key: str, spec: str, scale: float = 1.0, unit: str = "") -> str:
        return ", ".join(f"{format(scale * record[n][key], spec)}{unit} ({n})" for n in names)

    vacuous = all(record[n]["weight_error_bound_vacuous"]
                  and record[n]["weight_error_bound_vacuous_measured_noise"] for n in names)
    std = [x for n in names for x in record[n]["target_noise_std"]]
    span = (f"{min(std):.2f}" if f"{min(std):.2f}" == f"{max(std):.2f}"
            else f"{min(std):.2f}–{max(std):.2f}")  # fmt: skip
    rows = [(n, f"{record[n]['filter_r_over_target_noise']:.3g}",
             f"{record[n]['weight_error_theorem1_bound_final']:.3g}",
             f"{record[n]['weight_error_theorem1_bound_final_measured_noise']:.3g}",
             f"{record[n]['weight_error_initial']:.3g}", f"{record[n]['alpha']:.3g}")
            for n in names]  # fmt: skip
    table = common.md_table(("scenario", "filter R / largest target-noise variance",
                             "bound at the end, nominal", "bound at the end, measured",
                             "initial weight error", "Lemma 2's α"), rows)  # fmt: skip
    return (
        "Inequality (48) with Lemma 2's α is a *consistency check*, not evidence: with the run's "
        "own constants it is a theorem for an exact Kalman step (`wmr.estimation.stability`).  So "
        "its "
        f"holding at {each('ineq48_fraction', '.1f', 100.0, ' %')} of the filter steps checks "
        "the computation; boundedness needs Assumption 1's constants on an infinite horizon.  "
        "Theorem 1's noise term is read two ways.  Nominal: the filter's R taken as the noise "
        "covariance.  Measured: the second moment of the real noise on the identifier's targets "
        "(target minus the true pose increment, i.e. the pose estimate's error differenced over "
        f"dt, std {span} per axis in m/s or rad/s)."
        + ("  The bound is vacuous in both readings, since its floor 2 p_max μ/α divides by "
           "Lemma 2's α." if vacuous else "")
        + "  The per-scenario notes are in `results/boundedness.json`.\n\n"
        + "\n".join(table)
    )  # fmt: skip
