"""The reproduction study's report sections (``analysis.reproduction``): the ranking verdict,
the tie-aware reading, the equivalence tests, the paired and tail tables, and the ablations.

Every sentence is rendered from the record; nothing here runs a simulation.
"""

from __future__ import annotations

from analysis import common
from analysis.common import fmt
from analysis.reproduction.stats import AXES
from wmr import controllers

__all__ = ["TABLE_NUMBER", "REGIMES_SECTION", "gains_text", "ranking_section", "ablations_section"]

#: The paper's table of each scenario.
TABLE_NUMBER = {"lemniscate": 1, "sinusoid": 2, "sinusoid-perturbed": 3}

#: Where the report answers what adaptation does away from the suite's defaults (the regime
#: study, ``analysis/regimes/``; its title starts so).
REGIMES_SECTION = "When does adaptation pay?"


def gains_text(g) -> str:
    """A gain tuple as the report prints it: ``(1, 2.5, 3)``."""
    return "(" + ", ".join(f"{x:g}" for x in g) + ")"


def _verdict(rep: dict) -> list[str]:
    reproduced = [v for e in rep["scenarios"].values()
                  for v in e["paper_ranking_reproduced"].values()]  # fmt: skip
    best = {sc: e["ranking"]["default"]["position"][0] for sc, e in rep["scenarios"].items()}
    n_best = sum(1 for b in best.values() if b == "iapid-nn-dekf")
    return [f"**Verdict.** The paper's order of the four controllers is reproduced on "
            f"{sum(reproduced)} of {len(reproduced)} (scenario, axis) pairs.  "
            f"IAPID-NN-DEKF has the lowest mean position RMSE in {n_best} of {len(best)} "
            "scenarios (best: "
            + ", ".join(f"{sc}: {controllers.label(b)}" for sc, b in best.items()) + ").",
            ""]  # fmt: skip


def _tie_aware(rep: dict) -> list[str]:
    contra = {(sc, axis): c for sc, e in rep["scenarios"].items()
              for axis, c in e.get("paper_ranking_contradicted", {}).items()}  # fmt: skip
    if not contra:
        return []
    n_contra = sum(1 for c in contra.values() if c)
    n_big = sum(1 for c in contra.values() if any(x["mean_diff"] >= 1e-3 for x in c))
    k = len(next(iter(rep["scenarios"].values()))["paper_ranking"]["x"])
    items = [f"- {sc} {axis}: " + ", ".join(f"{controllers.label(c['paper_worse'])} < "
                                           f"{controllers.label(c['paper_better'])}" for c in cs)
             for (sc, axis), cs in contra.items() if cs]  # fmt: skip
    return [f"**Tie-aware check.** Means that differ by less than the seed-to-seed noise "
            "should not count against the paper.  So the order is also tested pair by pair: "
            "the paper's order is *contradicted* on an axis when a controller it ranks lower "
            "is significantly better in our runs (paired Wilcoxon over the seeds, Holm-"
            f"adjusted over the {k * (k - 1) // 2} pairs of the axis, family-wise "
            f"α = {rep['alpha']:g}).  Contradicted on {n_contra} of {len(contra)} (scenario, "
            "axis) pairs" + (", as listed below" if n_contra else "")
            + f".  Counting only reversals larger than 1 mm (1 mrad for θ): "
            f"{n_big} of {len(contra)}.", "", *items, *([""] if items else [])]  # fmt: skip


def _adaptation(rep: dict) -> list[str]:
    exc = rep.get("gain_excursion", {})
    if not exc:
        return []
    rel = {g: max(r["max_rel"][g] for d in exc.values() for r in d.values())
           for g in ("Kpv", "Kiv", "Kpw", "Kiw")}  # fmt: skip
    kd = max(r["max_abs"][g] for d in exc.values() for r in d.values() for g in ("Kdv", "Kdw"))
    return ["**Gain adaptation at the suite's defaults.** Over a run (seed 0, every scenario) "
            "SGD moves the proportional and integral gains by at most "
            + ", ".join(f"{g} {100 * v:.1f} %" for g, v in rel.items())
            + f"; the derivative gains start at 0 and reach {kd:.3f} (the reproduction notes, "
            "E5d, attribute this to measurement noise; not measured in this study).",
            ""]  # fmt: skip


def _mm(x: float) -> str:
    return f"{1e3 * x:+.2f}"


def _pair_label(pair: str) -> str:
    return " − ".join(controllers.label(x) for x in pair.split(" vs "))


def _equivalence_pairs(eq: dict, metric: str) -> dict:
    """pair -> {scenario: test record} of one metric, pairs in the record's order."""
    out: dict = {}
    for sc, pairs in eq["scenarios"].items():
        for pair, rec in pairs.items():
            if metric in rec:
                out.setdefault(pair, {})[sc] = rec[metric]
    return out


def _defaults_clause(rep: dict) -> str:
    """The settings the equivalence holds at, read from the record."""
    d = rep.get("adaptation_defaults")
    if not d:
        return "at the suite's defaults"
    first = next(iter(d.values()))
    mu = sorted(set(first["mu"]))
    tails = [e["runs"]["pid"]["default"]["tail_position"]["mean"]
             for e in rep["scenarios"].values() if "pid" in e["runs"]]  # fmt: skip
    good = (f", with which the fixed PID alone reaches {fmt(min(tails))}–{fmt(max(tails))} m "
            f"position RMSE after the transient" if tails else "")  # fmt: skip
    return (f"at the suite's defaults: good initial gains {gains_text(first['gains'])}{good}, and "
            f"the paper's μ = {', '.join(f'{m:g}' for m in mu)} with the plant Jacobian read "
            f"per {first['jacobian_scale']} (J = dt G, so the SGD step is ~ μ dt e φ; "
            "`wmr.controllers.pid`)")  # fmt: skip


def _equivalence(rep: dict) -> list[str]:
    """The paired tests of "IAPID, APID and the fixed PID are the same controller"."""
    eq = rep.get("equivalence")
    if not eq or not eq["scenarios"]:
        return []
    metric, *others = eq["metrics"]
    margin_mm = f"{1e3 * eq['margin']:g} mm"
    level = f"{100 * (1 - 2 * eq['alpha']):g} %"
    rows, parts, n_eq, n_diff, n_all = [], [], 0, 0, 0
    for pair, recs in _equivalence_pairs(eq, metric).items():
        k = sum(r["equivalent"] for r in recs.values())
        n_eq, n_all = n_eq + k, n_all + len(recs)
        n_diff += sum(r["different"] for r in recs.values())
        rows += [(_pair_label(pair), sc, _mm(r["mean_diff"]),
                  f"[{_mm(r['ci_low'])}, {_mm(r['ci_high'])}]", fmt(r["p"], 3),
                  fmt(r["p_holm"], 3), fmt(r["equivalent"])) for sc, r in recs.items()]
        parts.append(f"{_pair_label(pair)}: equivalent within ±{margin_mm} in {k} of "
                     f"{len(recs)} scenarios")  # fmt: skip
    n_seeds = next(iter(next(iter(eq["scenarios"].values())).values()))[metric]["n"]
    lines = [f"**Are IAPID-NN-DEKF, APID and the fixed PID the same controller?** Paired TOST "
             f"of the {metric} RMSE at a margin of ±{margin_mm} over {n_seeds} seeds, beside the "
             f"two-sided Wilcoxon test of the same differences (Holm over the {n_all} tests; "
             "the table below).  " + "; ".join(parts) + "."]  # fmt: skip
    table = common.md_table(("pair (A − B)", "scenario", "mean difference [mm]",
                             f"{level} interval [mm]", "TOST p", "Wilcoxon p (Holm)",
                             f"equivalent within ±{margin_mm}"), rows)  # fmt: skip
    for other in others:
        counts = [f"{_pair_label(pair)} in {sum(r['equivalent'] for r in recs.values())} of "
                  f"{len(recs)}" for pair, recs in _equivalence_pairs(eq, other).items()]
        if counts:
            lines.append(f"On the RMSE after the transient (t ≥ {rep['transient_s']:g} s), "
                         f"equivalent within ±{margin_mm}: " + ", ".join(counts) + ".")
    if n_eq == n_all:
        lines.append(f"So the three are the same to within ±{margin_mm} on every scenario.  Yet "
                     f"{n_diff} of the {n_all} differences are detectable (Holm-adjusted "
                     f"Wilcoxon p < {eq['alpha']:g}): equivalent at this margin, not identical.")
    else:
        lines.append(f"Equivalence within ±{margin_mm} holds in {n_eq} of the {n_all} "
                     f"(scenario, pair) tests; {n_diff} of the {n_all} differences are "
                     f"detectable (Holm-adjusted Wilcoxon p < {eq['alpha']:g}).")
    lines.append(f"These hold {_defaults_clause(rep)}.  What adaptation does on other plants "
                 "and at tuned settings is the regime study's question "
                 "(`analysis/regimes/`, "
                 f"section \"{REGIMES_SECTION}\").")
    return ["  ".join(lines), "", *table, ""]


def _order(names) -> str:
    return " < ".join(controllers.label(n) for n in names)


def _orders(rep: dict) -> list[str]:
    lines = []
    for sc, entry in rep["scenarios"].items():
        ours = entry["ranking"]["default"]
        lines.append(f"**{sc}.**")
        for axis in AXES:
            same = entry.get("paper_ranking_reproduced", {}).get(axis)
            lines.append(f"- {axis}: paper {_order(entry['paper_ranking'][axis])}; ours "
                         f"{_order(ours[axis])} — {'reproduced' if same else 'not reproduced'}")
        lines.append(f"- position RMSE (frame-invariant): {_order(ours['position'])}")
        lines.append(f"- position RMSE after the transient (t ≥ {rep['transient_s']:g} s): "
                     f"{_order(ours['tail_position'])}")  # fmt: skip
        lines.append("")
    return lines


def _tail_table(rep: dict) -> list[str]:
    lines = [f"Position RMSE [m] after the transient (t ≥ {rep['transient_s']:g} s), "
             "mean ± std; in brackets the share of the full-run figure that remains (a small "
             "share: the initial pose error dominated it; near 1: a steady tracking error):", ""]
    rows = []
    for sc, entry in rep["scenarios"].items():
        cells = []
        for n in controllers.NAMES:
            rec = entry["runs"].get(n, {}).get("default", {})
            t, full = rec.get("tail_position"), rec.get("position")
            if not t or t["mean"] is None:
                cells.append("—")
            else:
                share = t["mean"] / full["mean"]
                cells.append(f"{t['mean']:.4f} ± {t['std']:.4f} ({share:.2f})")
        rows.append([sc, *cells])
    header = ["scenario", *(controllers.label(n) for n in controllers.NAMES)]
    return lines + common.md_table(header, rows) + [""]


def _paired_table(rep: dict) -> list[str]:
    rows = []
    for sc, entry in rep["scenarios"].items():
        for pair, rec in entry["paired"].items():
            r = rec["position"]
            if r.get("n"):
                a, b = pair.split(" vs ")
                rows.append([sc, f"{controllers.label(a)} vs {controllers.label(b)}",
                             fmt(r["mean_diff"]), fmt(r["std_diff"]), f"{r['wins']}/{r['n']}",
                             fmt(r["wilcoxon_p"], 3)])  # fmt: skip
    return (["Paired comparisons of the position RMSE (difference A − B per seed; wins = seeds "
             "where A is better; Wilcoxon signed-rank p):", ""]
            + common.md_table(["scenario", "A vs B", "mean diff [m]", "std", "wins", "p"], rows)
            + [""])  # fmt: skip


def ranking_section(rep: dict) -> str:
    lines = ["## Does the paper's ranking appear?", ""]
    lines += _verdict(rep) + _tie_aware(rep) + _adaptation(rep) + _equivalence(rep)
    lines += _orders(rep) + _tail_table(rep) + _paired_table(rep)
    return "\n".join(lines)


def _ablation_cell(rec: dict | None) -> str:
    if rec is None:
        return "—"
    m, s = rec["position"]["mean"], rec["position"]["std"]
    cell = "diverged" if m is None else f"{m:.4f} ± {s:.4f}"
    if rec["n_diverged"] and m is not None:
        cell += f" ({rec['n_diverged']} diverged)"
    return cell


def _ablation_table(entry: dict, variants: list[str]) -> list[str]:
    names = [n for n in controllers.NAMES if n in entry["runs"]]
    rows = [[v, *(_ablation_cell(entry["runs"][n].get(v)) for n in names)] for v in variants]
    lines = common.md_table(["variant", *(controllers.label(n) for n in names)], rows) + [""]
    default = entry["ranking"]["default"]["position"]
    changed = [v for v in entry["ranking"] if v != "default"
               and entry["ranking"][v]["position"] != default]  # fmt: skip
    if changed:
        lines.append("The position ranking of the paper's four controllers changes under: "
                     + ", ".join(changed) + ".")  # fmt: skip
    else:
        lines.append("No variant changes the position ranking of the paper's four controllers.")
    return lines + [""]


def _figure(name: str, caption: str) -> list[str]:
    return [f"![{caption}](figures/{name})", ""]


def _figures(rep: dict) -> list[str]:
    """The paths (Figure 4), the errors of the first and the last scenario (Figures 8, 10) and
    the ablations, as the record lists them."""
    names = rep["figures"]
    scenarios = list(rep["scenarios"])
    lines = []
    wanted = [("_paths.png", "Figure 4")]
    wanted += [(f"_errors_{sc}.png", f"Figure {7 + TABLE_NUMBER[sc]}")
               for sc in (scenarios[0], scenarios[-1])]  # fmt: skip
    wanted += [("ablations.png", "Ablations")]
    for suffix, caption in wanted:
        lines += [x for n in names if n.endswith(suffix) for x in _figure(n, caption)]
    return lines


def _feed_forward(rep: dict) -> list[str]:
    """Which controller has the lowest mean position RMSE without and with feed-forward."""
    ff = rep.get("feed_forward_best")
    if not ff:
        return []
    family = sorted({n for d in ff.values() for n in d["with"]["on_variant"]},
                    key=controllers.NAMES.index)  # fmt: skip
    count = {k: sum(d[k]["best"] in family for d in ff.values()) for k in ("without", "with")}

    def bests(key: str) -> str:
        return ", ".join(f"{sc} {controllers.label(d[key]['best'])} ({fmt(d[key]['mean'])} m)"
                         for sc, d in ff.items())  # fmt: skip

    return [f"**Feed-forward.** Lowest mean position RMSE of the {len(controllers.NAMES)} "
            f"controllers per scenario, without the `feed-forward` variant: {bests('without')}; "
            f"with it (the controllers it applies to, "
            f"{', '.join(controllers.label(n) for n in family)}, on their feed-forward runs, the "
            f"others on their default runs): {bests('with')}.  The PID family has the lowest "
            f"mean in {count['with']} of {len(ff)} scenarios with feed-forward and in "
            f"{count['without']} of {len(ff)} without.", ""]  # fmt: skip


def ablations_section(rep: dict) -> str:
    lines = ["## Ablations and sensitivities", "",
             "Position RMSE, mean ± std over seeds, per variant (— : not applicable):", ""]
    variants = ["default", *rep["variants"]]
    for sc, entry in rep["scenarios"].items():
        lines += [f"**{sc}**", ""] + _ablation_table(entry, variants)
    lines += _feed_forward(rep)
    lines += ["Variants:", ""] + [f"- `{k}`: {v}" for k, v in rep["variants"].items()]
    if rep.get("divergences"):
        lines += ["", f"Runs that diverged: {len(rep['divergences'])}."]
        for d in rep["divergences"][:20]:
            lines.append(f"- {d['scenario']} / {d['controller']} / {d['variant']} / seed "
                         f"{d['seed']}: at {fmt(d['diverged_at'], 2)} s, {d['cause']}")
    else:
        lines += ["", "No run diverged."]
    return "\n".join(lines + [""] + _figures(rep))
