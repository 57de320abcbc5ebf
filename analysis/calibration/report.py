"""The calibration study's report section, in sentences and tables computed from its record
only (``analysis.calibration``; DESIGN §7.8: the answer first, in a few short sentences; no
sentence over ``analysis.prose.MAX_WORDS`` words)."""

from __future__ import annotations

import math

from analysis import common
from analysis.calibration.rule import DIVERGENCE_LEVEL as RULE_LEVEL
from analysis.calibration.waves import RECOVER
from analysis.calibration.waves import VALID_WITHIN_3 as VALID
from analysis.common import fmt
from wmr import controllers

__all__ = ["TITLE", "LEVEL_NOTE", "notes", "table", "render"]

TITLE = "Could any setting give the paper's tables? Calibration, sensitivity and fair tuning"


def _label(name: str) -> str:
    s, c, a = name.split("/")
    return f"{s} {controllers.label(c)} {a}"


def _pct(p: dict) -> str:
    if p["p"] == 0.0:
        return f"0 of {p.get('n_runs', p.get('n'))} (at most {100 * p['ci_high']:.1f} %)"
    return f"{100 * p['p']:.1f} % [{100 * p['ci_low']:.1f}, {100 * p['ci_high']:.1f}]"


def _answer(r: dict) -> list[str]:
    """The answer in a few short sentences (DESIGN §7.8), then the rule at each discrepancy."""
    pl, ver, fit, po = r["planted"], r["verdict"], r["best_fit"], r["p_paper_order"]
    cov = pl["coverage"]
    far = max(pl["power"], key=float)  # the farthest distance: where a rule must decide
    v = ver["by_delta"][f"{ver['delta']:g}"]
    sens = r["sensitivity"]["pawn"]["indices"].get("rms_log_ratio")
    top = [n for n in sens["ties"][0] if n != "dummy"] if sens else []
    inert = bool(sens) and "dummy" in sens["ties"][0]
    above = list(sens.get("above_dummy", [])) if sens else []
    rule = [
        f"**The answer.** The rule is history-matching implausibility on log RMSE, with "
        f"{r['rule']['K']} seeds per candidate and threshold {ver['threshold']:.2f}.",
        f"At the verdict's model discrepancy of {100 * pl['delta']:.0f} % it accepts a planted "
        f"truth {cov['k']:.0f} of {cov['n']:.0f} times ({_pct(cov)}; nominal "
        f"{100 * pl['nominal']:.0f} %).",
        "At that discrepancy it rules out points at unit-cube distance "
        + ", ".join(f"{d}: {_pct(x)}" for d, x in pl["power"].items()) + ".",
        *([f"It is too loose to decide (power below 90 % at distance {far})."]
          if pl["too_loose"] else
          [f"The 90 % power criterion at distance {far} holds at its point estimate only (its "
           f"interval reaches {100 * pl['power'][far]['ci_low']:.1f} %)."]
          if pl["power"][far]["ci_low"] < 0.9 else []),
        _fresh(pl, r.get("planted_fresh"), far),
        "Over the moves that keep every discrete setting at the truth's level it rules out "
        + ", ".join(f"{d}: {x['k']:.0f} of {x['n']:.0f}"
                    for d, x in pl["power_continuous_only"].items()) + ".",
        "Around the truths it accepts, it rules out "
        + ", ".join(f"{d}: {x['k']:.0f} of {x['n']:.0f}"
                    for d, x in pl["power_given_accepted"].items()) + ".",
        _fair_short(r["fair_tuning"]),
    ]
    earlier, dkey = pl["by_delta_earlier_threshold"], f"{pl['delta']:g}"
    derive = [
        f"The threshold {pl['threshold']:.2f} is the normal Sidak quantile for 36 numbers at "
        f"{100 * pl['nominal']:.0f} %.",
        *([f"Without a model discrepancy (a planted truth has none) it accepts "
           f"{_pct(pl['by_delta']['0']['coverage'])}: the statistical model's own calibration "
           f"(with the stated {100 * pl['delta']:.0f} %: {100 * cov['p']:.0f} %). On the "
           f"{pl['coverage_all_finite']['n']:.0f} planted truths whose numbers are all finite, "
           f"as the paper's, it accepts {_pct(pl['coverage_all_finite'])}."]
          if "0" in pl.get("by_delta", {}) else []),
        "Each number is judged against Student t at the Welch-Satterthwaite degrees of freedom "
        "of its variance, since only the seed spread is estimated and the rounding and the "
        "discrepancy are stated.",
        f"The earlier threshold, t with {r['rule']['K'] - 1} degrees of freedom for every number "
        f"({earlier['threshold']:.2f}), rules out "
        f"{_pct(earlier[dkey]['power'][far])} at distance {far}.",
        "Divergence is judged as a binomial count over the 12 runs jointly: the product of the "
        "rule of succession's chances that each of the paper's runs ends as it did (finite); "
        f"below {RULE_LEVEL:g} the candidate is ruled out, beside the RMSE judged over the "
        f"finite seeds. {pl['truths_with_diverged_runs']['n']} of {cov['n']:.0f} planted truths "
        f"had a diverged seed among their {r['rule']['K']}; the rule accepts "
        f"{pl['truths_with_diverged_runs']['accepted']} of them.",
        f"The verdict judges its candidates at seeds {_span(ver['seeds'])}, none of which "
        f"selected them (those were {_span(ver['selection_seeds'])}).",
    ]
    verdict = [
        "**Does any plausible setting reproduce Tables 1-3?** "
        + (f"Yes: {v['count']} of {ver['n_candidates']} candidates are not ruled out"
           if v["count"] else f"None of the {ver['n_candidates']} candidates examined is")
        + f" (model discrepancy {100 * ver['delta']:.0f} %; smallest max implausibility "
        f"{v['min_max_implausibility']:.1f}).",
        _by_discrepancy(r, far),
        f"Scope: {ver['scope']}.",
        "The earlier '0 of 4,096 feasible' is retracted.",
    ]
    closest = [
        f"**Closest fit.** rms log ratio {fit['rms_log_ratio']:.3f} (factor "
        f"{math.exp(fit['rms_log_ratio']):.2f}) over {len(fit['seeds'])} seeds; "
        f"{fit['n_within']} of {len(fit['residuals'])} numbers are within the rule.",
        f"CMA-ES's {len(fit['restarts'])} restarts end at "
        + ", ".join(f"{x['rms_log_ratio']:.3f}" for x in fit["restarts"])
        + f" (spread {fit['spread']['range']:.3f}, "
        + ("within" if fit["spread"]["agree"] else "beyond")
        + f" the stated {fit['spread']['tolerance']:g}: "
        + ("they agree)." if fit["spread"]["agree"] else "the spread is the result)."),
        _converged(fit),
        *([f"The best fit sits on the prior's edge in {_edge_text(fit['edges'])} (reported, "
           "the prior's range not widened: the fit and the verdict hold inside the prior's "
           "box)."] if fit["edges"] else []),
        *([f"It takes the end level of the discrete settings {', '.join(fit['edges_discrete'])}."]
          if fit.get("edges_discrete") else []),
    ]
    ranking = [
        f"**The paper's ranking over the prior.** All nine orders as printed: "
        f"{_pct(po['all_nine'])}; IAPID-NN-DEKF lowest on all nine: "
        f"{_pct(po['iapid_first_all'])} (Clopper-Pearson over {po['n_points']} points).",
        *([f"PAWN's first tied group on the discrepancy holds an inert dummy setting and "
           f"{len(top)} settings, so it ranks none of them; "
           + (f"{len(above)} have estimates above the dummy's upper bound ({', '.join(above)}), "
              "yet their intervals overlap the dummy's: tied with it."
              if above else "none lies above the dummy's bound.")] if inert or not top else
          ["Settings that decide the discrepancy most (PAWN's first tied group, above an inert "
           "dummy setting): " + ", ".join(top) + "."]),
    ]
    deltas = sorted(set(pl.get("by_delta", {})) | set(ver["by_delta"]), key=float)
    rows = []
    for dl in deltas:
        x, y = pl.get("by_delta", {}).get(dl), ver["by_delta"].get(dl)
        e = earlier.get(dl)
        rows.append([f"{100 * float(dl):.0f} %",
                     _pct(x["coverage"]) if x else "—",
                     _pct(x["power"][far]) if x else "—",
                     f"{_pct(e['coverage'])}; {_pct(e['power'][far])}" if e else "—",
                     y["count"] if y else "—"])  # fmt: skip
    by_delta = "\n".join([
        f"The rule at each model discrepancy: the planted-truth coverage, the power at distance "
        f"{far}, both with the earlier t threshold, and the candidates not ruled out (of "
        f"{ver['n_candidates']}):", "",
        *common.md_table(["discrepancy", "coverage", f"power at {far}",
                          "earlier threshold: coverage; power", "candidates not ruled out"],
                         rows)])  # fmt: skip
    return [" ".join(rule), " ".join(derive), " ".join(verdict), " ".join(closest),
            " ".join(ranking), by_delta]


def _fresh(pl: dict, fr: dict | None, far: str) -> str:
    """The rule out of sample: the fresh planted truths beside the ones it was revised on."""
    said = (f"These {pl['n_truths']} truths (generator seed {pl['generator_seed']}) are the ones "
            "the rule's divergence count was revised against")
    if not fr:
        return said + ": fresh truths would test it out of sample."
    return (f"{said}. On {fr['n_truths']} fresh truths (generator seed "
            f"{fr['generator_seed']}), drawn once it was fixed, it accepts the truth "
            f"{fr['coverage']['k']:.0f} times ({_pct(fr['coverage'])}) and rules out "
            f"{_pct(fr['power'][far])} at distance {far}."
            + (" Out of sample it is too loose to decide (power below 90 % at that distance): "
               "an acceptance by it says little; a rejection stands." if fr["too_loose"] else ""))


def _fair_short(f: dict) -> str:
    """Who wins under fair tuning, in one sentence for the section's opening."""
    lead = (f"no arm beats {_arm(f['best'])}" if f["best_determined"] else
            f"no arm is shown best ({_arm(f['best'])} is the candidate)")
    wt, d = f.get("where_all_track"), f.get("at_defaults")
    rest = []
    if wt:
        rest.append(f"where every tuned arm tracks (plants chosen after the fact, from the "
                    f"held-out runs), {_arm(wt['best'])} "
                    + ("is beaten by none" if wt["best_determined"] else "is the candidate"))
    if d:
        rest.append(f"at the defaults, {_arm(d['best'])} "
                    + ("is beaten by none" if d["best_determined"] else "is the candidate"))
    cells = f["held_out"]["cells"]
    failing = sorted({cells[i].split("@")[1] for n in f["ranking"]
                      for i, k in enumerate(f["arms"][n]["held_out"]["per_cell_failures"]) if k})
    return (f"Tuned by the shared stage (some adaptation settings stay fixed) on held-out "
            f"plants, {lead}"
            + (f", a lead that rests on where tuned arms fail ({', '.join(failing)})"
               if failing else "")
            + ("; " + "; ".join(rest) if rest else "") + ".")


def _converged(fit: dict) -> str:
    """Whether CMA-ES's restarts stopped by its own rule or at the evaluation cap, and how much
    each was still improving over its last tenth of generations."""
    capped = [x for x in fit["restarts"] if not x["stop"]]
    gains = [x["history"][-max(1, len(x["history"]) // 10) - 1] - x["history"][-1]
             for x in capped]  # fmt: skip
    if not capped:
        return "Every restart stopped by CMA-ES's own tolerance."
    return (f"{len(capped)} of {len(fit['restarts'])} restarts stopped at their evaluation "
            f"cap ({max(x['nfev'] for x in capped):,} with the start), their best improving by "
            f"{min(gains):.3f}-{max(gains):.3f} over their last tenth of generations: the fit "
            "has not converged, and the spread measures the budget as much as distinct optima.")


def _by_discrepancy(r: dict, far: str) -> str:
    """The verdict's count at every discrepancy, each with the rule's power there."""
    ver, pl = r["verdict"], r["planted"]
    parts = [f"{100 * float(d):.0f} %: {v['count']} (power at {far} "
             f"{100 * pl['by_delta'][d]['power'][far]['p']:.0f} %)"
             for d, v in sorted(ver["by_delta"].items(), key=lambda kv: float(kv[0]))]
    return ("Candidates not ruled out, by the discrepancy granted: " + "; ".join(parts)
            + ". A looser discrepancy keeps more, and rules out less of what is wrong.")


def _answer_tables(r: dict) -> list[str]:
    fit, pts = r["best_fit"], r["points"]
    worst = sorted(fit["residuals"].items(), key=lambda kv: -kv[1]["implausibility"])[:5]
    nums = pts["numbers"]
    never = [n for n in nums if not nums[n]["spanned"]]
    rows = [[_label(n), fmt(x["mean"]), fmt(x["paper"]), f"x{x['ratio']:.2f}",
             f"{x['implausibility']:.3f}"] for n, x in worst]  # fmt: skip
    out = "\n".join([
        f"**Where does the closest fit miss?** Its {len(worst)} largest implausibilities:", "",
        *common.md_table(["number", "closest fit", "paper", "ratio", "implausibility"], rows),
        "", f"Numbers outside the range the {pts['n']}-point design's seed means span: "
        + (f"{len(never)}." if never else "none.")])  # fmt: skip
    if never:
        out += "\n\n" + "\n".join(common.md_table(
            ["number", "paper", "design range"],
            [[_label(n), fmt(nums[n]["paper"]), f"{fmt(nums[n]['min'])}-{fmt(nums[n]['max'])}"]
             for n in never]))  # fmt: skip
    return [out]


def _answer_ranking(r: dict) -> list[str]:
    po = r["p_paper_order"]
    lab = controllers.label
    conv, ind = po["convergence"], po["independent_halves"]
    tau = po["kendall_tau"]
    rows = [["all nine (scenario, axis) orders as printed", _pct(po["all_nine"]), "—"],
            ["IAPID-NN-DEKF lowest on all nine", _pct(po["iapid_first_all"]), "—"],
            ["IAPID-NN-DEKF lowest on at least one", _pct(po["iapid_first_any"]), "—"],
            ["mean Kendall tau against the paper's orders",
             f"{tau['mean']:.3f} [{tau['ci'][0]:.3f}, {tau['ci'][1]:.3f}]", "—"]]  # fmt: skip
    rows += [[f"pairwise: {lab(a)} < {lab(b)}",
              _pct(v), f"{100 * v['paper']:.0f} %"]
             for k, v in po["pairwise"].items() if k.startswith("iapid-nn-dekf")
             for a, b in [k.split(" < ")]]  # fmt: skip
    return ["\n".join([
        f"**How likely is the paper's ranking over the prior?** Over {po['n_points']} points x "
        f"{po['n_seeds']} seeds (single runs, as the paper's tables; exact intervals over the "
        "points). A pairwise row is the share of the 9 (scenario, axis) comparisons IAPID wins:",
        "", *common.md_table(["", "over the prior", "paper"], rows), "",
        f"Between the design's independent halves (A and B) the probabilities agree within "
        f"their intervals for {ind['agreeing']} of {ind['compared']} (half nested in the "
        f"whole: {conv['agreeing']} of {conv['compared']})."])]  # fmt: skip


def _answer_sensitivity(r: dict) -> list[str]:
    sen = r["sensitivity"]["pawn"]

    def group(g: list[str]) -> str:
        return ", ".join(g[:6]) + ("..." if len(g) > 6 else "")

    rows = []
    for o in ("rms_log_ratio", "margin:adaptive-pid", "margin:backstepping", "diverged_share"):
        x = sen["indices"].get(o)
        if x:
            ties = [*x["ties"][:2], [], []][:2]
            rows.append([o, *[group(g) if g else "—" for g in ties], len(x["above_dummy"]),
                         f"{x['dummy_high']:.3f}"])  # fmt: skip
    scr = r["screening"]
    fixed = [n for n in r["prior"] if not r["prior"][n].get("varied", True)]
    return ["\n".join([
        "**Which unstated settings decide it?** Morris screening "
        f"({scr['trajectories']} trajectories, {scr['points']} points) fixed {len(fixed)} "
        f"settings ({', '.join(fixed) or 'none'}). PAWN indices on the {sen['n']} design "
        "points are median KS statistics, bounded in [0, 1]. The settings of a tied group have "
        "overlapping intervals; the first two groups are shown, at most six names each:", "",
        *common.md_table(["output", "first tied group", "second tied group",
                          "settings above the dummy's bound", "the dummy's bound"], rows),
    ])]  # fmt: skip


def _arm(name: str) -> str:
    """An arm's label: its controller's, with the pose source when it is not the measured one."""
    c, pose = name.split("@")
    return controllers.label(c) + ("" if pose == "raw" else f" ({pose} pose)")


def _ratio(p: dict) -> str:
    if p["ci"] is None:
        return "—"
    return f"{p['ratio']:.3f} [{p['ratio_ci'][0]:.3f}, {p['ratio_ci'][1]:.3f}]"


def _fails(s: dict) -> str:
    d = s["tracking_failure"]
    return f"{d['diverged']}/{d['n']}"


def _names(names: list[str]) -> str:
    return ", ".join(_arm(n) for n in names)


#: How the answer names the arms of each verdict against a best shown best.
_WORSE = {"fails more": "fail more", "higher": "are higher",
          "worse": "fail more or are higher, depending on the restarts"}
#: How the answer names the arms of each verdict against a best not shown best.
_AGAINST = {"tie": "{} tie with it",
            "equivalent": "{} are equivalent to it within 5 %",
            "restart-dependent": "against {} the verdict depends on which restart is run",
            "mixed": "{} track more accurately where both track but fail where it does not "
                     "(mixed)",
            "undetermined": "against {} it is undetermined",
            "lower": "{} are lower than it at all four pairings",
            "fails less": "{} fail less than it at all four pairings",
            "better": "{} are lower or fail less than it at all four pairings"}  # fmt: skip


def _candidate(f: dict, arms: dict) -> str:
    """Why the candidate best is the candidate, from the record: its failures (and the arms
    that share that count), then its mean log RMSE over its own tracking runs."""
    best = f["best"]
    d = arms[best]["held_out"]["tracking_failure"]
    same = [n for n in f["ranking"][1:]
            if arms[n]["held_out"]["tracking_failure"]["diverged"] == d["diverged"]]
    fewest = f"{d['diverged']}/{d['n']} held-out runs, the fewest" + (
        f" (as {_names(same)})" if same else "")
    tail = (", and among those the lowest mean log RMSE over its own tracking runs"
            if same else "")
    return f"{_arm(best)} is the candidate: it fails to track on {fewest}{tail}"


def _who(f: dict, where: str, arms: dict) -> str:
    """The answer's sentence on who is best on the cells ``where`` names (``arms``: the arms'
    held-out summaries on those cells)."""
    best = f["best"]
    if f["best_determined"]:
        by: dict[str, list[str]] = {}
        for n, v in f["against_best"].items():
            by.setdefault(v["verdict"], []).append(n)
        said = "; ".join(f"{_names(ns)} {_WORSE[w]}" for w, ns in by.items())
        return (f"Tuned by the shared stage, no arm beats {_arm(best)} {where}: against it "
                f"{said}, at all four pairings of the two arms' restarts.")
    by: dict[str, list[str]] = {}
    for n, v in f["against_best"].items():
        by.setdefault(v["verdict"], []).append(n)
    parts = [say.format(_names(by[w])) for w, say in _AGAINST.items() if w in by]
    return (f"Tuned by the shared stage, no arm is shown best {where}. {_candidate(f, arms)}; but "
            f"{'; '.join(parts)}.")


def _by_plant(s: dict, cells: list[str]) -> str:
    """An arm's tracking failures per plant (the cells ``scenario@plant``), the plants with
    any."""
    per: dict[str, int] = {}
    for c, k in zip(cells, s["per_cell_failures"], strict=True):
        per[c.split("@")[1]] = per.get(c.split("@")[1], 0) + k
    return ", ".join(f"{p} {k}" for p, k in per.items() if k)


def _order(f: dict) -> str:
    """The candidate ranking with each consecutive verdict: ``A < B ? C``."""
    sym = {"higher": "<", "fails more": "<", "worse": "<", "tie": "~", "equivalent": "~"}
    out = _arm(f["ranking"][0])
    for o in f["order"]:
        out += f" {sym.get(o['verdict'], '?')} {_arm(o['pair'][1])}"
    return out


def _beside(f: dict, ho: dict, arms: dict) -> list[str]:
    """What the ranking says where every arm tracks (the plants without a tuned failure) and
    at the defaults: the failures' share of the verdict."""
    out = []
    wt = f.get("where_all_track")
    if wt:
        plants = sorted({ho["cells"][i].split("@")[1] for i in wt["cells"]})
        out.append(_who(wt, f"on the plants where every tuned arm tracks ({', '.join(plants)}; "
                        "chosen after the fact from the held-out runs)",
                        {n: {"held_out": summary_of(arms, n, wt["cells"])} for n in arms}))
    d = f.get("at_defaults")
    if d:
        vs = d["against_best"]
        said = "; ".join(f"{_arm(n)} {v['word']}" for n, v in vs.items())
        out.append(f"At their defaults (untuned) {_arm(d['best'])} is the candidate "
                   + ("and every other arm is higher or fails more against it" if
                      d["best_determined"] else "but not shown best") + f" ({said}).")
    return out


def summary_of(arms: dict, name: str, cells: list[int]) -> dict:
    """An arm's tuned held-out failures on the main cells ``cells`` (positions), from its
    per-cell counts (for :func:`_candidate`'s sentence)."""
    s = arms[name]["held_out"]
    k = sum(s["per_cell_failures"][i] for i in cells)
    n = s["tracking_failure"]["n"] * len(cells) // len(s["per_cell_failures"])
    return {"tracking_failure": {"diverged": k, "n": n}}


def _edges(f: dict) -> str:
    """The arms whose best tuning ends on its box's edge (DESIGN §7.2: flagged, not hidden)."""
    arms = f["arms"]
    on = [f"{_arm(n)} {len(arms[n]['edges'])} of {len(arms[n]['free'])}"
          for n in f["ranking"] if arms[n]["edges"]]
    return ("Settings whose tuned optimum lies on its box's edge (reported, the boxes not "
            f"widened): {', '.join(on)}." if on else "No tuned optimum lies on a box's edge.")


def _swap(f: dict) -> str:
    """The settings swap of the two laws with the same free settings."""
    sw = f["swap"]
    x, y = (_arm(n) for n in sw["arms"])

    def said(k: str) -> str:
        v = sw["comparisons"][k]
        return f"{_ratio(v)} ({v['word']}, {v['common_cells']} cells)"

    c = sw["comparisons"]
    common = [c["both_at_x"]["word"], c["both_at_y"]["word"]]
    read = ("at common settings the two laws are not told apart"
            if all(w in ("tie", "equivalent", "undetermined", "mixed") for w in common) else
            f"at common settings {x} is '{common[0]}' at {x}'s and '{common[1]}' at {y}'s")
    return (f"The two laws with the same free settings, {x} and {y}, were also run with each "
            f"other's best settings (best restarts only). {x} over {y}: {said('as_tuned')} as "
            f"tuned, {said('both_at_x')} with both at {x}'s settings, {said('both_at_y')} with "
            f"both at {y}'s. Each law with the other's settings over itself with its own: {x} "
            f"{said('x_swapped')}, {y} {said('y_swapped')}. So {read}."
            + (" Each law does better with the other's settings than with its own: its own "
               "tuning did not find its best, so the tuning, not the law, decides the pair as "
               "tuned." if all(c[k]["word"] in _BETTER for k in ("x_swapped", "y_swapped"))
               else ""))


#: The words of a comparison in which the first arm does better.
_BETTER = ("lower", "fails less", "better")


def _fixed(f: dict) -> str:
    """Each arm's numeric settings the tuning left at their defaults (the record's)."""
    arms = f["arms"]
    return "; ".join(f"{_arm(n)}: {', '.join(arms[n]['fixed'])}" for n in f["ranking"]
                     if arms[n]["fixed"]) or "none"  # fmt: skip


def _answer_fair(r: dict) -> list[str]:
    f = r["fair_tuning"]
    arms, best, b, ho = f["arms"], f["best"], f["budget"], f["held_out"]
    pa = f["paper_arm"]
    failing = [n for n in f["ranking"] if arms[n]["held_out"]["tracking_failure"]["diverged"]]
    vs = {**f["against_best"], pa["arm"]: pa["against_best"]}
    rows = [[_arm(n), str(len(arms[n]["free"])), str(arms[n]["evaluations"]),
             "yes" if arms[n]["agreement"]["agree"] else "no", str(len(arms[n]["edges"])),
             _fails(arms[n]["held_out"]), _fails(arms[n]["other_held_out"]),
             fmt(arms[n]["held_out"]["median_rmse"]),
             fmt(arms[n]["other_held_out"]["median_rmse"]),
             fmt(arms[n]["default_held_out"]["median_rmse"]),
             "—" if n == best else _ratio(vs[n]["tuned"]),
             "—" if n == best else str(vs[n]["tuned"]["common_cells"]),
             "—" if n == best else ", ".join(vs[n]["pairings"].values()),
             "candidate best" if n == best else vs[n]["verdict"]]
            for n in [*f["ranking"], pa["arm"]]]  # fmt: skip
    where = (f"on the paper's three scenarios over {len(ho['plants'])} held-out simulated "
             "plants")
    worse = [n for n in failing
             if arms[n]["default_held_out"]["tracking_failure"]["diverged"] == 0]
    per_plant = "; ".join(f"{_arm(n)} {_fails(arms[n]['held_out'])} "
                          f"({_by_plant(arms[n]['held_out'], ho['cells'])})" for n in failing)
    lines = [_who(f, where, arms),
             (f"Held out, arms fail to track (diverged, or RMSE after the transient above "
              f"{ho['tracking_m']:g} m) on these runs, by plant: {per_plant}." if failing else
              "No arm fails to track held out."),
             *([f"At their defaults {_names(worse)} track every held-out run; tuned "
                "on the training plants, they do not."] if worse else []),
             *_beside(f, ho, arms),
             f"The paper's set-up, {_arm(pa['arm'])}, is '{pa['against_raw']['verdict']}' "
             f"against the same law on the measured pose and '{pa['against_best']['verdict']}' "
             f"against {_arm(best)}.", _swap(f), _edges(f)]
    ap = f.get("apart")
    if ap:
        held = {n: {"held_out": s} for n, s in ap["held_out"].items()}
        fails = ", ".join(f"{_arm(n)} {_fails(ap['held_out'][n])}" for n in ap["ranking"])
        lines.append(_who(ap, "on the MuJoCo robot (compared apart: "
                              f"{', '.join(ap['plants'])})", held)
                     + f" Failures there: {fails}.")
    return ["\n".join([
        "**Who wins under fair tuning?** " + " ".join(lines), "",
        f"Candidate order (<: told apart at all four restart pairings, ~: tied, ?: "
        f"restart-dependent, mixed or undetermined): {_order(f)}.", "",
        "Every arm acts on the measured pose, so the arms differ only in the law. Each arm's "
        f"free settings were tuned by the shared stage (analysis/tuning.py) with "
        f"{b['per_setting']} evaluations per setting per restart and {b['restarts']} CMA-ES "
        f"restarts. Left at their defaults (not free): {_fixed(f)}. Training used the regime "
        f"study's {len(b['training'])} trajectory-plant pairs "
        f"({', '.join(b['training'])}) at seeds {_span(b['train_seeds'])}: other members of the "
        "held-out trajectories' families, on plants with some of the held-out mechanisms at "
        "other magnitudes (analysis/calibration/fair.py says which).",
        f"Held out: the {len(ho['cells'])} cells ({', '.join(ho['plants'])}; the skid outward) "
        f"at seeds {_span(b['test_seeds'])}, each arm at its best restart, its runner-up and "
        "its defaults. Failing to track is its own endpoint, compared seed by seed: the cells "
        "where one arm fails and the other tracks, minus the reverse, tested by an exact "
        "sign-flip test over the seeds.",
        "A ratio is the geometric mean over seeds of an arm's RMSE over the candidate best's, "
        "on the cells where both track at every seed (their number beside it), with its 95 % "
        "t interval. The four words are the verdicts at the pairings best/best, "
        "best/runner-up, runner-up/best and runner-up/runner-up; 'worse' when they differ but "
        "each says higher or fails more.",
        "", *common.md_table(["arm", "free settings", "evaluations", "restarts agree",
                              "optimum on an edge", "fail to track", "(runner-up)",
                              "median RMSE [m]", "(runner-up)", "at defaults [m]",
                              "ratio to the candidate best [95 % CI]", "cells",
                              "at the four pairings", "verdict"], rows)])]  # fmt: skip


def _vol(x: float) -> str:
    return f"{100 * x:.2g} %"


def _answer_sequential(r: dict) -> list[str]:
    """The sequential design: is the emulator valid, what do the waves keep for the paper's
    tables, and do they recover planted truths."""
    seq = r["sequential"]
    val, pap, rec = seq["emulator"]["validation"], seq["paper"], seq["recovery"]
    w0, wv = rec["wave0"], rec["waves"]
    n_w = len(pap["retained"]) - 1
    kept = pap["retained"][-1]
    met = wv["recovered"]["p"] >= 0.9 and wv["volume_at_most_5pc"]["p"] >= 0.9
    words = [
        "**Can a search find the truth?** History-matching waves on a Gaussian-process "
        f"emulator of the 36 numbers, trained on the {seq['emulator']['trained_on']} design "
        f"points and then on {seq['per_wave']} new points per wave.",
        f"At the {val['points']} planted truths {100 * val['within_2']:.0f} % of its "
        f"standardised errors lie within +-2 and {100 * val['within_3']:.0f} % within +-3 "
        f"(N(0, 1): 95 % and 99.7 %).",
        f"Its implausibility at wave 0 keeps {_pct(w0['recovered'])} of the "
        f"{w0['recovered']['n']:.0f} planted truths.",
        f"Valid needs at least {100 * VALID:.0f} % within +-3 and {100 * RECOVER:.0f} % of the "
        "truths kept, so the emulator is "
        + ("valid." if val["valid"] else "not valid: its waves decide nothing, and the verdict "
           "rests on the direct rule."),
        f"For the paper's tables wave 0 keeps {_vol(pap['retained'][0])} of the prior's volume"
        + (f" and wave {n_w} keeps {_vol(kept)}" if n_w else "")
        + (f"; the least implausible point scores {pap['least_implausibility']:.2f} on the "
           f"emulator against the threshold {seq['threshold']:.2f}, and "
           f"{pap['least_direct']['max_implausibility']:.2f} when run at seeds "
           f"{_span(pap['least_direct']['seeds'])} and judged by the rule itself."
           if "least_implausibility" in pap else
           ": no sampled point is left, so none is plausible."),
        f"For a planted truth wave 0 keeps a median {_vol(w0['retained_volume_median'])} of the "
        "volume.",
        f"After {n_w} waves the first {wv['truths']} truths are retained in "
        f"{_pct(wv['recovered'])}.",
        f"At most 5 % of the volume is kept in {_pct(wv['volume_at_most_5pc'])}.",
        "The criterion, >= 90 % retained with <= 5 % of the volume, is "
        + ("met." if met else "not met."),
    ]
    return [" ".join(words)]


def notes(record: dict) -> str:
    """The study's answers, computed from the record: short sentences, their numbers in tables
    (Markdown; ``analysis.prose``'s rule)."""
    c = record["cost"]
    out = _answer(record) + _answer_tables(record) + _answer_ranking(record)
    out += _answer_sequential(record) + _answer_sensitivity(record) + _answer_fair(record)
    sizes = (f"{record['planted']['n_truths']} planted truths, {record['points']['n']:,} design "
             f"points and {len(record['best_fit']['restarts'])} CMA-ES restarts")
    out.append(f"**Level: {record['level']}** ({sizes}), {_level_note(record)}. Cost: "
               f"{c['runs_in_store']:,} runs in the store; {c['runs_total']:,} runs were "
               f"run for it in {c['seconds_running_total']:.0f} s of running over every "
               f"invocation ({c['runs_this_time']:,} runs and {c['seconds']:.0f} s wall in "
               f"the last, on {c['engine']}). The fitted settings: "
               f"{', '.join(record['best_fit']['scenario_files'])} (a fit, not the "
               "defaults).")  # fmt: skip
    if record["level"] == "quick":
        out.insert(0, "A QUICK run (a few points, short runs): its numbers answer nothing.")
    return "\n\n".join(out)


#: What each level is, in the report (sentences after "Level: <name>,").
LEVEL_NOTE = {
    "quick": "the tests' few points on short runs",
    "medium": "the committed record and the study `make calibration` runs. Its time: {timed}. The "
              "larger `--full` level ({full}) does not fit the 90-minute budget on 2 workers. "
              "Its stages there: {full_timed}",
    "full": "a larger study than the 90-minute budget allows on 2 workers (`--full`)",
}


def _level_note(record: dict) -> str:
    """The level's sentence, with the sizes of the record and of the full level, and the
    measured wall times (:data:`stages.TIMED`)."""
    from analysis.calibration import stages

    f = stages.FULL
    full = (f"{f.n_truths} planted truths, {2 * 2**f.design_m:,} design points, "
            f"{f.cma_restarts} CMA-ES restarts of popsize {f.cma_popsize}")
    return LEVEL_NOTE.get(record["level"], "").format(
        full=full, timed=stages.TIMED["medium"], full_timed=stages.TIMED["full"])


def table(record: dict) -> str:
    """The 36 numbers: paper, the range over the design, the closest fit and its
    implausibility."""
    rows = []
    for n, x in record["best_fit"]["residuals"].items():
        cv = record["points"]["numbers"][n]
        rows.append([_label(n), record["paper"][n]["printed"], f"{fmt(cv['min'])}-"
                     f"{fmt(cv['max'])}", fmt(x["mean"]), f"{x['ratio']:.2f}",
                     f"{x['implausibility']:.2f}", "yes" if x["within"] else "no"])  # fmt: skip
    header = ["number", "paper", "design range", "closest fit", "ratio", "implausibility",
              "within"]  # fmt: skip
    return "\n".join(common.md_table(header, rows)) + "\n"


def _span(seeds: list[int]) -> str:
    """Seeds as ``a-b`` when consecutive, else listed."""
    if len(seeds) > 2 and list(seeds) == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(map(str, seeds))


def _edge_text(edges: list[dict]) -> str:
    """The best fit's settings on a box edge, each with its side and the restarts ending there."""
    return "; ".join(f"{e['setting']} ({e['side']}, at {e['value']:.4g}; "
                     f"{', '.join(e['restarts'])})" for e in edges)


def render(record: dict) -> str:
    """The report's section of this study."""
    return common.section(TITLE, notes(record), table(record), record["figures"])
