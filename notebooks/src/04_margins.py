# %% [md]
# # 04 — Stability margins of the linearised loops
#
# About perfect tracking of a reference with constant `(v_r, w_r)`, the sampled error dynamics
# are linearised with CasADi's exact Jacobians (`wmr.model.symbolic`), the PID of eq. (7) becomes a
# discrete LTI controller, and python-control gives the loops at `dt`. Margins are
# **loop-at-a-time**: broken at the plant input `v` with the `w` loop closed, and vice versa.
# The loops are built by `wmr.linear.loops`, their margins computed by `wmr.linear.margins`. The full study
# (more operating points, all runs, the printed rotation, every cross-check) is
# `analysis/margins/`, which writes `paper/results/margins.json`.
#
# In the report: [Linearised loops: margins (python-control)](../paper/report.md#linearised-loops-margins-python-control).
# %%
from IPython.display import display

from analysis import margins as study
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.controllers.pid import GAIN_NAMES
from wmr.linear import loops as lp
from wmr.linear import margins as mg


def show(fig):
    """Display a figure once (closed after display, so the inline backend does not repeat it)."""
    display(fig)
    plt.close(fig)


sc = scn.load(scn.builtin("sinusoid"))
op = lp.operating_point(sc, "mean")  # time-mean v_r of the sinusoid, on a straight line (w_r = 0)
print(f"operating point: v_r = {op.v_r:.3f} m/s, w_r = {op.w_r:.1f} rad/s, dt = {op.dt} s")


def fmt(x, nd=1):
    return "inf" if x == float("inf") else ("-inf" if x == float("-inf") else f"{x:.{nd}f}")


header = ("loop", "GM [dB]", "GM low", "PM [deg]", "alpha", "disk GM", "disk PM")
print(f"{header[0]:<8}" + "".join(f"{h:>9}" for h in header[1:]))
for name, loops in (("PID", lp.pid_loops(op)), ("BSC", lp.backstepping_loops(op))):
    for ch in lp.CHANNELS:
        m = mg.loop_margins(loops[ch])
        print(f"{name + ' ' + ch:<8}{fmt(m.gain_margin_db):>9}{fmt(m.gain_margin_lower_db):>9}"
              f"{fmt(m.phase_margin_deg):>9}{m.disk_margin:>9.2f}{fmt(m.disk_gain_margin_db):>9}"
              f"{fmt(m.disk_phase_margin_deg):>9}")
    z = np.linalg.eigvals(lp.closed_loop_matrix(loops["v"]))
    print(f"{name} closed loop: max|z| = {np.max(np.abs(z)):.4f}, "
          f"slowest time constant = {-op.dt / np.log(np.max(np.abs(z))):.1f} s")
# %% [md]
# The upper gain margins sit at the Nyquist frequency (`z = −1`); the `w` loop of the PID is
# conditionally stable (two integrations in the plant, one in the PID): cutting its gain by
# about 36 dB destabilises it.
#
# **Cross-check.** The same margins from closed-loop eigenvalues only: the smallest real gain,
# phase rotation and disk perturbation that put an eigenvalue on the unit circle.
# %%
for name, loops in (("PID", lp.pid_loops(op)), ("BSC", lp.backstepping_loops(op))):
    for ch in lp.CHANNELS:
        m, e = mg.loop_margins(loops[ch]), mg.eigen_margins(loops[ch])
        agree = (abs(m.gain_margin / e["gain_margin"] - 1) < 1e-6
                 and abs(m.phase_margin_deg - e["phase_margin_deg"]) < 1e-6
                 and abs(m.disk_margin / e["disk_margin"] - 1) < 1e-6)
        print(f"{name} {ch}: frequency-domain and eigenvalue margins agree: {agree}; "
              f"disk margins below classical: {m.disk_phase_margin_deg <= m.phase_margin_deg}")
# %% [md]
# **Eigenvalues vs the simulator.** The nonlinear loop (`wmr.closedloop.sim.simulate`, no noise), started
# at a 1 mm / 1 mrad error that excites the slowest mode, decays at the rate of the slowest
# closed-loop eigenvalue. (The PID run uses the feed-forward so that the simulator's zero initial
# integrals are the equilibrium; the linearisation is the same with or without it.)
# %%
for name, gains in (("pid", lp.PID_GAINS), ("backstepping", lp.BSC_GAINS)):
    d = study.decay_check(name, op, gains)
    print(f"{name}: max|z| = {d['slowest_eigenvalue_abs']:.5f}, fitted rate = "
          f"{d['rate_simulated']:.5f}, deviation from the linear model < 1%: "
          f"{d['max_deviation_from_linear_rel'] < 0.01}")
# %% [md]
# ## Stability region in PID-gain space
#
# Spectral radius of the closed loop over two gains, the others at their defaults (5, 5, 0, 10,
# 2, 0). On a straight line the `v` loop decouples and its region has a closed form (Jury);
# the `w` loop's low-gain boundary is the continuous-time Routh condition, its high-gain
# boundary (`Kpw ≈ 2/dt`) comes from sampling.
# %%
regions = [lp.stability_region(op, "v", n=41), lp.stability_region(op, "w", n=41)]
P, I = np.meshgrid(regions[0]["kp"], regions[0]["ki"])
print("v-region equals Jury's conditions:",
      bool(np.array_equal(regions[0]["rho"] < 1, lp.jury_v_loop_stable(P, I, op.dt))))
show(study.stability_region_figure(regions))
# %% [md]
# Each gain alone, the others at their defaults: the interval keeping the loop stable. The
# derivative gains reach the limit just below 1, above the SGD clamp `Kd ≤ 0.5` of the adaptive
# controllers.
# %%
for i, name in enumerate(GAIN_NAMES):
    lo, hi = lp.stable_gain_interval(op, i)
    print(f"{name}: stable for {lo:.3f} < {name} < {hi:.3f}")
# %% [md]
# ## Margins along a run as the SGD gains adapt (sinusoid, seed 0)
#
# Frozen-time analysis: at every 100th step the loop is relinearised at the local `(v_r, w_r)`
# with the gains in use then. The fixed PID is shown for comparison.
# %%
along = {"sinusoid": {name: mg.margins_along_run(simulate(sc, name, seed=0), every=100)
                      for name in ("pid", "adaptive-pid", "iapid-nn-dekf")}}
for name, rec in along["sinusoid"].items():
    gm_v, gm_w = rec["v_gm_db"].min(), rec["w_gm_db"].min()
    print(f"{name:<14} min upper GM v / w: {gm_v:.0f} / {gm_w:.0f} dB, "
          f"closed loop stable throughout: {bool(np.all(rec['rho'] < 1))}")
show(study.along_runs_figure(along))
# %% [md]
# ## The printed rotation of eqs. (4)/(6) (errata E3)
#
# On a straight line with heading θ, the printed matrix feeds the controllers
# `e2' = sin 2θ e1 + cos 2θ e2` instead of `e2`: for 45° < |θ| < 135° the lateral feedback
# changes sign and both the PID and backstepping loops become unstable.
# %%
sweep = lp.printed_rotation_sweep(op, np.linspace(-180, 180, 361))
for name in ("pid", "bsc"):
    print(name, "unstable for headings [deg]:",
          lp.unstable_intervals(sweep["headings_deg"], sweep[f"{name}_rho"] > 1 + 1e-12))
show(study.printed_rotation_figure(sweep))
