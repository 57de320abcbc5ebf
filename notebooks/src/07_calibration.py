# %% [md]
# # 07 — Could any setting give the paper's tables? Calibration, sensitivity, fair tuning
#
# The paper leaves dt, the run length, the trajectories, the gains, the noise and the nature of
# its perturbation unsaid. `analysis/calibration.py` writes those settings down as a prior (each
# range with where it comes from), screens them (Morris), runs a scrambled Sobol design of
# 4096 points x 2 seeds through the engine, fits the 36 numbers of Tables 1–3 by differential
# evolution, measures how robust the paper's ranking is over the prior (Sobol indices, P(order))
# and tunes every controller with the same budget. The full study has its own command
# (`python -m analysis.calibration --full`; its cost is printed below); this notebook reads its
# committed record and reruns one small thing: the fitted scenarios, seed 0.
# %%
import json
from pathlib import Path

from analysis import _calibration_prior as prior
from analysis import calibration

ROOT = Path(calibration.__file__).resolve().parent.parent  # the repository
record = json.loads((ROOT / "paper" / "results" / "calibration.json").read_text())
calibration.check(record)
print("level:", record["level"], "| design points:", record["points"]["n"],
      "| seeds:", record["seeds"])
print("settings in the prior:", len(record["prior"]), "| shared by all four controllers:",
      sum(p["group"] == "shared" for p in record["prior"].values()))
cost = record["cost"]
print(f"cost: {cost['runs_total']:,} runs, {cost['seconds_running_total'] / 60:.0f} min of running")
# %% [md]
# ## Does any setting reproduce the tables?
#
# A point is *feasible* when all 36 numbers lie within their tolerance: the rounding of the
# printed digits plus z seed standard deviations of one run around our mean, with z chosen so
# that a setting that *is* the paper's passes all 36 at once 95 % of the time (Šidák), and no
# diverged seed. The narrower per-number bands (z = 2) are counted beside it.
# %%
feas, tol = record["feasible"], record["tolerance"]
print(f"z = {tol['z']:.2f} (joint {tol['joint_level']:.0%}); per-number z = {tol['z_per_number']}")
print("feasible points:", feas["count"], "of", record["points"]["n"],
      "| most numbers matched at one point:", feas["best_n_within"], "of 36")
print("with per-number bands:", feas["count_per_number_bands"], "points,",
      "best", feas["best_n_within_per_number_bands"], "of 36")
print("numbers never reached at any point:", len(feas["never_reached"]))
print("numbers outside the range the design spans:", feas["never_spanned"])
for f, k in feas["all_within_factor"].items():
    print(f"  all 36 within a factor {f}: {k} points")
# %% [md]
# ## The closest fit and its residuals
# %%
fit = record["best_fit"]
print(f"rms log ratio {fit['rms_log_ratio']:.3f}, max |log ratio| {fit['max_abs_log_ratio']:.3f},"
      f" {fit['n_within']} of 36 within tolerance ({len(fit['seeds'])} seeds)")
worst = sorted(fit["residuals"].items(), key=lambda kv: -abs(kv[1]["log_ratio"]))[:6]
for name, r in worst:
    print(f"  {name:<40} paper {r['paper']:.4f}  fit {r['mean']:.4f}  x{r['ratio']:.2f}")
# %% [md]
# The fitted settings ship as scenario files (a fit, not the defaults). Rerunning them for
# seed 0 gives the record's numbers exactly:
# %%
from wmr import scenario as scn
from wmr.sim import simulate

ours = []
for f in fit["scenario_files"]:
    sc = scn.load(ROOT / f)
    for c in prior.CONTROLLERS:
        r = simulate(sc, c, fit["seeds"][0], keep_trajectory=False)
        ours += [r.rmse[a] if not r.diverged else prior.DIVERGED_RMSE for a in prior.AXES]
# the record was made on another CPU (numpy's sin/cos differ in the last bits): compare to 1e-12
same = np.allclose(ours, fit["per_seed"][0], rtol=1e-12, atol=0.0)
print("seed-0 numbers equal the record's (to 1e-12 relative):", same)
# %% [md]
# ## How likely is the paper's ranking over the prior?
# %%
po = record["p_paper_order"]
show = lambda p: f"{100 * p['p']:.1f} % [{100 * p['ci_low']:.1f}, {100 * p['ci_high']:.1f}]"  # noqa: E731
print("all nine (scenario, axis) orders as printed:", show(po["all_nine"]))
print("IAPID-NN-DEKF lowest on all nine:", show(po["iapid_first_all"]))
print(f"mean Kendall tau vs the paper's orders: {po['kendall_tau']['mean']:.3f}")
for k, v in po["pairwise"].items():
    if k.startswith("iapid-nn-dekf"):
        print(f"  P({k}) = {show(v)}  (paper: {100 * v['paper']:.0f} %)")
# %% [md]
# ## Which settings decide it, and who wins when every controller is tuned alike?
# %%
ix = record["sensitivity"]["sobol"]["N"]["indices"]
for out in ("margin:backstepping", "margin:adaptive-nn", "margin:adaptive-pid", "rms_log_ratio"):
    if ix.get(out):
        top = sorted(ix[out].items(), key=lambda kv: -kv[1]["total"])[:3]
        print(f"{out:<22}", ", ".join(f"{n} {v['total']:.2f}" for n, v in top))
fair = record["fair_tuning"]
print("held-out ranking after equal tuning:", fair["ranking_held_out"])
# %%
from analysis import _calibration_figures as figures

fig = figures.residual_profile(record)
