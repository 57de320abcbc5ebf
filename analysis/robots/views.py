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
    """rung -> {trajectory: the best controller and every controller *equivalent* to it (paired
    TOST at +-5 % of the better mean); a controller not shown equivalent is not tied, whatever
    its p-value."""
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
                if e["pairs"][key].get("equivalent", False):
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


def ratio_range(record: dict) -> tuple[float, float]:
    """The smallest and largest MuJoCo / kinematic ratio of a controller's mean outcome over the
    seeds both rungs ran (every controller and trajectory)."""
    import numpy as np

    out = []
    for rungs in record["ladder"].values():
        for c in record["controllers"]:
            m, k = rungs["mujoco"]["cells"][c]["values"], rungs["kinematic"]["cells"][c]["values"]
            seeds = sorted(set(m) & set(k))
            if seeds:
                out.append(np.mean([m[s] for s in seeds]) / np.mean([k[s] for s in seeds]))
    return float(min(out)), float(max(out))


def _best_sentence(record: dict, rung: str) -> str:
    best = best_per_rung(record)[rung]
    return "; ".join(f"{t} {_names(cs)}" for t, cs in best.items())


def answer(record: dict) -> list[str]:
    """The section's opening: at most five short sentences from the record."""
    ag = record["agreement"]
    steps = [k for k in next(iter(ag.values())) if k != "planted"]
    n_ag = {h: sum(a[h]["agrees"] for a in ag.values()) for h in steps}
    planted = sum(a["planted"]["agrees"] for a in ag.values())
    conv = [v for t in record["convergence"].values() for v in t.values()]
    n_conv = sum(v["converged"] for v in conv)
    slides = [p["demand"] for p in record["sliding"] if p["sliding"]]
    holds = [p["demand"] for p in record["sliding"] if not p["sliding"]]
    changes = {(t, r): v for t, rr in record["order_changes"].items() for r, v in rr.items() if v}
    lo, hi = ratio_range(record)
    ms = 1e3 * record["mj_timestep"]
    out = [f"At a {ms:g} ms physics step the MuJoCo robot's error after the transient is "
           f"{lo:.2f}–{hi:.2f} times the kinematic unicycle's ({len(record['controllers'])} "
           f"controllers, {len(record['ladder'])} trajectories); {n_conv} of {len(conv)} "
           "(controller, trajectory) pairs change by at most 5 % at half that step."]
    out.append("The stiff robot agrees with the unicycle plus its servo lag on "
               + ", ".join(f"{n_ag[h]}" for h in steps) + f" of {len(ag)} trajectories at "
               + ", ".join(f"{1e3 * float(h):g}" for h in steps) + " ms"
               + (f", but the rule also accepts the nominal robot at 2 ms on {planted}: its "
                  "2 mm floor is too loose to tell them apart." if planted
                  else "; it rejects the nominal robot at 2 ms on every trajectory."))
    if slides and holds:
        out.append(f"On steady circles the lowest lateral acceleration that slid was "
                   f"{min(slides):.2f} of the Coulomb bound μ g and the highest that held "
                   f"{max(holds):.2f}.")
    out.append("The best controller (ties: equivalent within 5 %) is, on the unicycle, "
               + _best_sentence(record, "kinematic") + "; on MuJoCo, "
               + _best_sentence(record, "mujoco") + ".")
    out.append(f"{len(changes)} (trajectory, rung) case(s) reverse a pair's order by more than "
               "5 % on both rungs"
               + (": " + "; ".join(f"{t} / {r}: {', '.join(_pair_label(p) for p in v)}"
                                   for (t, r), v in changes.items()) if changes else "") + ".")
    return out


def table(record: dict) -> str:
    """Position RMSE after the transient [mm], mean ± std over the stable seeds, per trajectory,
    controller (rows) and rung (columns); ``(k div.)`` when k runs diverged."""
    lines = []
    for traj, rungs in record["ladder"].items():
        lines += [f"**{traj}** (position RMSE after the transient [mm], mean ± std over "
                  f"{record['seeds']} seeds; MuJoCo at {1e3 * record['mj_timestep']:g} ms over "
                  f"{record['mj_seeds']})", ""]
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
    rows = [(t, "nominal robot at 2 ms (planted)" if h == "planted" else f"{1e3 * float(h):g} ms",
             _mm(a["mujoco"]), _mm(a["kinematic_plus_lag"]), f"{100 * a['relative']:+.0f} %",
             _mm(a["tolerance"]), fmt(a["agrees"]), fmt(a["floor_dominates"]), str(a["seeds"]))
            for t, both in record["agreement"].items() for h, a in both.items()]  # fmt: skip
    return common.md_table(("trajectory", "stiff robot's physics step", "MuJoCo [mm]",
                            "kinematic + lag [mm]", "difference", "tolerance [mm]", "agrees",
                            "2 mm floor decides", "seeds"), rows)  # fmt: skip


def _convergence_table(record: dict) -> list[str]:
    rows = []
    for t, per in record["convergence"].items():
        for c, v in per.items():
            rows.append((t, controllers.label(c), _mm(v["shipped"]), _mm(v["rung"]),
                         _mm(v["finer"]), fmt(v["rel_change"], 3), fmt(v["converged"])))
    return common.md_table(("trajectory", "controller", "2 ms [mm]",
                            f"{1e3 * record['mj_timestep']:g} ms (the rung) [mm]", "0.25 ms [mm]",
                            "change rung -> 0.25 ms", "converged (<= 5 %)"), rows)  # fmt: skip


def _fitted_table(record: dict) -> list[str]:
    """Per trajectory, the fitted plant (values, intervals, the lag at its bound) and, per
    controller, whether it predicts the MuJoCo robot better than the bare unicycle: |f - m|
    against |k - m|, and the share of m - k it closes where |m - k| exceeds 5 % of k."""
    rows = []
    for t, f in record["fitted"].items():
        vals = ", ".join(f"{k} {v:.3g} ± {1.96 * f['se'].get(k, float('nan')):.1g}"
                         for k, v in f["values"].items() if k not in f["not_identifiable"])
        lad = record["ladder"][t]
        better, parts = 0, []
        for c in record["controllers"]:
            k, m, fi = (lad[r]["cells"][c]["mean"] for r in ("kinematic", "mujoco", "fitted"))
            if None in (k, m, fi):
                continue
            better += abs(fi - m) < abs(k - m)
            if abs(m - k) > record["relevant"] * k:
                parts.append(f"{controllers.label(c)} {(fi - k) / (m - k):.2f}")
        rows.append((t, vals + ("; lag at its bound 0" if f["lag_at_bound"] else ""),
                     str(f["delay"]), f"{better} of {len(record['controllers'])}",
                     "; ".join(parts) or "—"))  # fmt: skip
    return common.md_table(("trajectory", "fitted [plant] (95 % intervals)", "delay [steps]",
                            "controllers it predicts better than the unicycle",
                            "share of m − k closed (where m − k exceeds 5 % of k in size)"), rows)


def render(record: dict) -> str:
    """The report section."""
    from analysis.robots import LEFT_OUT, TITLE

    lag = record["servo_lag"]
    notes = " ".join(answer(record))
    extra = [
        "",
        "Convergence of the MuJoCo rung in its physics step (every controller, seed 0):",
        "",
        *_convergence_table(record), "",
        "Servo lag from the physics' small-step response (63 % rise, unsaturated: largest "
        f"torque {lag['nominal']['max_torque_ratio']:.2f} of the limit): nominal "
        f"{1e3 * lag['nominal']['tau_v']:g} ms forward, {1e3 * lag['nominal']['tau_w']:g} ms "
        f"yaw; stiff {1e3 * lag['stiff']['tau_v']:g} ms and {1e3 * lag['stiff']['tau_w']:g} ms "
        "(the kinematic comparison uses their mean as `actuator_tau`).",
        "",
        *_agreement_table(record), "",
        "The kinematic plant `wmr identify` fits to each MuJoCo log (backstepping, seed 0, "
        "in-sample for that cell).  A share of 1 means the fitted plant predicts the MuJoCo "
        "robot's error, 0 the unicycle's, a negative one that it moves the error away:",
        "",
        *_fitted_table(record), "",
        "Left out: " + "; ".join(f"{controllers.label(c)} ({why})"
                                for c, why in LEFT_OUT.items()) + ".",
        "",
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
