"""The robot ladder's report section, table and figures (``analysis.robots``).

Every sentence is rendered from the record; nothing here runs a simulation.
"""

from __future__ import annotations

from analysis import common
from analysis.common import fmt
from wmr import controllers

__all__ = ["answer", "table", "render", "figures", "best_per_rung"]


def _mm(x) -> str:
    return "—" if x is None else f"{1e3 * x:.1f}"


def best_per_rung(record: dict) -> dict:
    """rung -> {trajectory: the controllers tied for the lowest mean (the best, and every
    controller whose paired difference from it is not significant)}."""
    out = {}
    for rung in record["rungs"]:
        out[rung] = {}
        for traj, rungs in record["ladder"].items():
            e = rungs[rung]
            if not e["ranking"]:
                out[rung][traj] = []
                continue
            best = e["ranking"][0]
            tied = [best]
            for c in e["ranking"][1:]:
                key = f"{best} vs {c}" if f"{best} vs {c}" in e["pairs"] else f"{c} vs {best}"
                if not e["pairs"][key].get("significant", False):
                    tied.append(c)
            out[rung][traj] = tied
    return out


def _pair_label(pair: str) -> str:
    return " vs ".join(controllers.label(c) for c in pair.split(" vs "))


def shift(record: dict, traj: str, controller: str) -> dict:
    """The MuJoCo-minus-kinematic difference of one controller's outcome on one trajectory,
    paired over the seeds stable on both rungs: mean, Wilcoxon p and whether it is significant
    (Holm over the controllers of the trajectory is applied by :func:`shifts`)."""
    import numpy as np

    from wmr import stats

    lad = record["ladder"][traj]
    a, b = (lad[r]["cells"][controller]["values"] for r in ("mujoco", "kinematic"))
    seeds = sorted(set(a) & set(b))
    d = np.array([a[s] - b[s] for s in seeds])
    p = stats.wilcoxon(d) if len(d) >= 2 and np.any(d != 0) else 1.0
    return {"n": len(seeds), "mean_diff": float(d.mean()) if len(d) else None, "p": float(p)}


def shifts(record: dict, traj: str) -> dict:
    """:func:`shift` for every controller of ``traj``, with Holm-adjusted ``significant``."""
    from wmr import stats

    out = {c: shift(record, traj, c) for c in record["controllers"]}
    for rec, q in zip(out.values(), stats.holm([r["p"] for r in out.values()]), strict=True):
        rec["significant"] = bool(q < record["alpha"])
    return out


def _names(cs) -> str:
    return " ≈ ".join(controllers.label(c) for c in cs) if cs else "none (all diverged)"


def answer(record: dict) -> list[str]:
    """The section's opening: at most five short sentences from the record."""
    ag = record["agreement"]
    n_ag = {r: sum(a[r]["agrees"] for a in ag.values()) for r in ("stiff-mujoco",
                                                                   "stiff-mujoco-fine")}
    half = [t["mean_rel_change"] for t in record["timestep_halved"].values()
            if t["mean_rel_change"] is not None]
    slides = [p for p in record["sliding"] if p["sliding"]]
    onset = min((p["demand"] for p in slides), default=None)
    still = max((p["demand"] for p in record["sliding"] if not p["sliding"]), default=None)
    changes = {(t, r): v for t, rr in record["order_changes"].items() for r, v in rr.items() if v}
    best = best_per_rung(record)
    mj = record["ladder"]
    rel = [mj[t]["mujoco"]["cells"][c]["mean"] / mj[t]["kinematic"]["cells"][c]["mean"]
           for t in mj for c in record["controllers"]
           if mj[t]["mujoco"]["cells"][c]["mean"] and mj[t]["kinematic"]["cells"][c]["mean"]]
    out = [f"With stiff servos and high friction the MuJoCo robot agrees with the kinematic "
           f"unicycle plus its servo lag on {n_ag['stiff-mujoco']} of {len(ag)} trajectories at "
           f"the shipped 2 ms physics step and on {n_ag['stiff-mujoco-fine']} at 0.5 ms "
           "(backstepping, tolerance 5 % or 2 mm)."]
    if half:
        out.append(f"Halving the physics step moves the nominal robot's error under backstepping "
                   f"by {100 * min(half):+.1f} % to {100 * max(half):+.1f} % (per trajectory): "
                   "where that is large, contact physics at 2 ms is not converged.")
    if onset is not None:
        out.append(f"Sliding sets in where Coulomb friction says: the lowest lateral "
                   f"acceleration that slid was {onset:.2f} of the bound μ g, the highest that "
                   f"held {fmt(still, 2)}.")
    out.append(f"At nominal parameters the MuJoCo robot's error after the transient is "
               f"{min(rel):.2f}–{max(rel):.2f} times the kinematic unicycle's over the "
               f"{len(record['controllers'])} controllers and {len(mj)} trajectories.")
    out.append("The best controller (ties by paired test) is " + "; ".join(
        f"{rung}: {_names(sorted(set(c for t in best[rung].values() for c in t)))}"
        for rung in ("kinematic", "mujoco"))
        + f", and a pair's order reverses significantly between the kinematic and another rung "
        f"in {len(changes)} (trajectory, rung) case(s)"
        + (": " + "; ".join(f"{t} / {r}: {', '.join(_pair_label(p) for p in v)}"
                             for (t, r), v in changes.items()) if changes else "") + ".")
    return out


def table(record: dict) -> str:
    """Position RMSE after the transient [mm], mean ± std over the stable seeds, per trajectory,
    controller (rows) and rung (columns); ``(k div.)`` when k runs diverged."""
    lines = []
    for traj, rungs in record["ladder"].items():
        lines += [f"**{traj}** (position RMSE after the transient [mm], mean ± std over "
                  f"{record['seeds']} seeds)", ""]
        rows = []
        for c in record["controllers"]:
            row = [controllers.label(c)]
            for rung in record["rungs"]:
                cell = rungs[rung]["cells"][c]
                s = f"{_mm(cell['mean'])} ± {_mm(cell['std'])}"
                if cell["diverged"]:
                    lo, hi = cell["diverged_ci"]
                    s += f" ({cell['diverged']} div., CI {lo:.2f}–{hi:.2f})"
                row.append(s)
            rows.append(row)
        lines += common.md_table(["controller", *record["rungs"]], rows) + [""]
    return "\n".join(lines)


def _agreement_table(record: dict) -> list[str]:
    rows = [(t, step, _mm(a["mujoco"]), _mm(a["kinematic_plus_lag"]), _mm(a["difference"]),
             _mm(a["tolerance"]), fmt(a["agrees"]), str(a["seeds"]))
            for t, both in record["agreement"].items()
            for step, a in zip(("2 ms", "0.5 ms"), both.values(), strict=True)]  # fmt: skip
    return common.md_table(("trajectory", "physics step", "stiff MuJoCo [mm]",
                            "kinematic + lag [mm]", "difference [mm]", "tolerance [mm]",
                            "agrees", "seeds"), rows)  # fmt: skip


def _fitted_table(record: dict) -> list[str]:
    rows = []
    for t, f in record["fitted"].items():
        vals = ", ".join(f"{k} {v:.3g}" for k, v in f["values"].items()
                         if k not in f["not_identifiable"])  # fmt: skip
        lad = record["ladder"][t]
        sig = shifts(record, t)
        shares = []
        for c in record["controllers"]:
            k, m, fi = (lad[r]["cells"][c]["mean"] for r in ("kinematic", "mujoco", "fitted"))
            if None in (k, m, fi):
                continue
            name = controllers.label(c)
            shares.append(f"{name} {(fi - k) / (m - k):.2f}" if sig[c]["significant"]
                          else f"{name} — (no significant difference)")
        rows.append((t, vals, str(f["delay"]), ", ".join(f["not_identifiable"]) or "—",
                     "; ".join(shares)))  # fmt: skip
    return common.md_table(("trajectory", "fitted [plant] (identifiable)", "delay [steps]",
                            "not identifiable", "share of the kinematic-to-MuJoCo difference "
                            "the fitted plant closes"), rows)  # fmt: skip


def render(record: dict) -> str:
    """The report section."""
    from analysis.robots import TITLE

    lag = record["servo_lag"]
    notes = " ".join(answer(record))
    extra = [
        "",
        "Servo lag from the physics' step response (63 % rise): nominal "
        f"{lag['nominal']['tau_v']:g} s forward, {lag['nominal']['tau_w']:g} s yaw; stiff "
        f"{lag['stiff']['tau_v']:g} s and {lag['stiff']['tau_w']:g} s (the kinematic comparison "
        "uses their mean as `actuator_tau`).",
        "",
        *_agreement_table(record), "",
        "The kinematic plant `wmr identify` fits to each MuJoCo log (backstepping, seed 0).  A "
        "share of 1 means the fitted plant predicts the MuJoCo robot's error, 0 the kinematic "
        "unicycle's, a negative one that the fitted plant moves the error away from MuJoCo's.  "
        "It is given where the MuJoCo-minus-kinematic difference is significant "
        "(paired Wilcoxon over the seeds, Holm over the controllers):",
        "",
        *_fitted_table(record), "",
        f"Cost: {record['cost']['runs']} runs, {record['cost']['seconds']:.0f} s"
        + (" (quick level)." if record["quick"] else "."),
        "",
    ]  # fmt: skip
    return (common.section(TITLE, notes, table(record), record["figures"]).rstrip("\n")
            + "\n" + "\n".join(extra))


def figures(out, record: dict) -> list[str]:
    """The sliding map and the ladder's bars; returns the file names."""
    import matplotlib.pyplot as plt
    import numpy as np

    from analysis.robots import STEM

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    pts = record["sliding"]
    for mu in sorted({p["friction"] for p in pts}):
        sel = [p for p in pts if p["friction"] == mu]
        ax[0].semilogy([p["demand"] for p in sel], [max(p["slip_angle"], 1e-5) for p in sel],
                       "o", label=f"μ = {mu:g}")  # fmt: skip
        ax[1].semilogy([p["demand"] for p in sel], [max(p["slip_ratio"], 1e-5) for p in sel],
                       "o", label=f"μ = {mu:g}")  # fmt: skip
    for a, what in zip(ax, ("side-slip angle [rad]", "wheel slip ratio [-]"), strict=True):
        a.axvline(1.0, color="k", lw=0.8, ls="--")
        a.set_xlabel("|v w| / (μ g)")
        a.set_ylabel(what)
        a.legend(fontsize=7)
    ax[0].axhline(record["sliding_threshold_rad"], color="r", lw=0.8, ls=":")
    fig.suptitle("Steady circles of the MuJoCo robot: sliding against the Coulomb bound")
    fig.tight_layout()
    names = [common.save_figure(out, f"{STEM}_sliding.png", fig)]

    trajs = list(record["ladder"])
    fig, axes = plt.subplots(1, len(trajs), figsize=(4.5 * len(trajs), 3.8), squeeze=False)
    width = 0.8 / len(record["rungs"])
    for a, t in zip(axes[0], trajs, strict=True):
        x = np.arange(len(record["controllers"]))
        for i, rung in enumerate(record["rungs"]):
            cells = record["ladder"][t][rung]["cells"]
            m = [1e3 * (cells[c]["mean"] or np.nan) for c in record["controllers"]]
            s = [1e3 * (cells[c]["std"] or 0.0) for c in record["controllers"]]
            a.bar(x + i * width, m, width, yerr=s, label=rung)
        a.set_xticks(x + width * (len(record["rungs"]) - 1) / 2)
        a.set_xticklabels([controllers.label(c) for c in record["controllers"]], rotation=45,
                          ha="right", fontsize=7)  # fmt: skip
        a.set_yscale("log")
        a.set_title(t)
        a.set_ylabel("position RMSE after transient [mm]")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    names.append(common.save_figure(out, f"{STEM}_ladder.png", fig))
    return names
