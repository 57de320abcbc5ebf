"""The calibration study's report section, in sentences and tables computed from its record
only (``analysis.calibration``; DESIGN §7.8: the answer first, in a few short sentences; no
sentence over ``analysis.prose.MAX_WORDS`` words)."""

from __future__ import annotations

import math

from analysis import common
from analysis.calibration import fair_report, prior
from analysis.calibration.fair_report import span
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
    if p["p"] == 0.0 and "n_runs" in p:  # a count of runs, its bound over the design's points
        return (f"0 of {p['n_runs']} runs (over {p['n_points']} points: at most "
                f"{100 * p['ci_high']:.1f} %)")
    if p["p"] == 0.0:
        return f"0 of {p.get('n')} (at most {100 * p['ci_high']:.1f} %)"
    return f"{100 * p['p']:.1f} % [{100 * p['ci_low']:.1f}, {100 * p['ci_high']:.1f}]"


def _answer(r: dict) -> list[str]:
    """The answer in a few short sentences (DESIGN §7.8), then the rule at each discrepancy."""
    pl, ver, fit, po = r["planted"], r["verdict"], r["best_fit"], r["p_paper_order"]
    cov = pl["coverage"]
    far = max(pl["power"], key=float)  # the farthest distance: where a rule must decide
    v = ver["by_delta"][f"{ver['delta']:g}"]
    sens = r["sensitivity"]["pawn"]["indices"].get("rms_log_ratio")
    cen = r["sensitivity"]["pawn"].get("every_point", {}).get("outputs", {})
    clear, near = _above(sens, cen.get("rms_log_ratio")) if sens else ([], [])
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
        + _both(pl, r.get("planted_fresh"), "power_continuous_only") + ".",
        "Around the truths it accepts, it rules out "
        + _both(pl, r.get("planted_fresh"), "power_given_accepted") + ".",
        fair_report.short(r["fair_tuning"]),
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
        f"The verdict judges its candidates at seeds {span(ver['seeds'])}, none of which "
        f"selected them (those were {span(ver['selection_seeds'])}).",
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
        f"{_pct(po['iapid_first_all'])} (Clopper-Pearson over {po['n_points']} points; a "
        "controller whose run diverged is ranked last in its table).",
        *(["PAWN has no index of the discrepancy here: too few points where every run "
           "tracked."] if not sens else
          [f"On the {sens['n']} points where every run tracked, PAWN puts "
           + (f"{', '.join(clear)} clearly above its inert floor on the discrepancy (the "
              "settings that decide it)" if clear else
              "no setting clearly above its inert floor on the discrepancy")
           + (f"; {', '.join(near)} {'is' if len(near) == 1 else 'are'} above it but near it "
              "(intervals reaching the floor or the dummy's)" if near else "") + "."]),
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
               "an acceptance by it says little; a rejection stands." if fr["too_loose"] else "")
            + _resolution(fr, far))


def _both(pl: dict, fr: dict | None, block: str) -> str:
    """A power block's counts on the truths the rule was revised against, and on the fresh
    ones at the same distances."""
    def counts(x: dict, keys) -> str:
        return ", ".join(f"{d}: {x[block][d]['k']:.0f} of {x[block][d]['n']:.0f} "
                         f"[{100 * x[block][d]['ci_low']:.0f}, {100 * x[block][d]['ci_high']:.0f}]"
                         for d in keys)  # fmt: skip

    said = counts(pl, pl[block]) + " on the truths it was revised against"
    return said + (f". On the fresh ones: {counts(fr, pl[block])}" if fr else "")


def _resolution(fr: dict, far: str) -> str:
    """Where the rule reaches 90 % power out of sample: the fresh truths' longer distances
    (added once the power at ``far`` was seen), overall, along moves that keep every discrete
    setting, and on the truths whose numbers are all finite."""
    longer = [d for d in fr["power"] if float(d) > float(far)]
    if not longer:
        return ""
    res, pw = fr["resolves_at"], fr["power"]

    def line(block: str) -> str:
        return ", ".join(f"{d}: {fr[block][d]['k']:.0f} of {fr[block][d]['n']:.0f} "
                         f"[{100 * fr[block][d]['ci_low']:.1f}, "
                         f"{100 * fr[block][d]['ci_high']:.1f}]" for d in longer)

    t = f"{100 * res['target']:.0f} %"
    if res["point"] is None:
        where = f"It reaches {t} power at no measured distance"
    else:
        where = (f"Its power first reaches {t} at distance {res['point']:g}, "
                 + ("where its whole interval clears it" if res["interval"] == res["point"]
                    else f"its whole interval first at {res['interval']:g}"
                    if res["interval"] is not None else
                    "at its point estimate only: no measured interval clears it"))
    short = [d for d in longer if pw[d]["ci_low"] < res["target"]]
    after = [f"{d:g}" for d in fr.get("added_after_seen", [])]
    return ((f" Longer moves (distances {', '.join(after)}, added to the design after its fresh "
             f"power at {far} was first seen)" if after else " Longer moves") + " are ruled out "
            + ", ".join(f"{_pct(pw[d])} of the time at {d}" for d in longer)
            + " (median actual distances "
            + ", ".join(f"{pw[d]['actual_distance_median']:.2f}" for d in longer)
            + ": reflection at the cube's edges shortens them). " + where
            + (f"; the interval at {', '.join(short)} reaches below it" if short else "")
            + f". Along the moves that keep every discrete setting: {line('power_continuous_only')}"
            f"; on the truths whose numbers are all finite: {line('power_all_finite')}.")


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
    cen = sen.get("every_point", {}).get("outputs", {})
    for o, x in sen["indices"].items():
        if x:
            clear, near = _above(x, cen.get(o))
            first = x["ties"][0]
            rows.append([o, x["n"], group(first) + (" (the dummy among them)" if "dummy" in first
                                                      else ""), group(clear) or "none",
                         group(near) or "none", f"{x['dummy_high']:.3f}"])  # fmt: skip
    scr = r["screening"]
    fixed = [n for n in r["prior"] if not r["prior"][n].get("varied", True)]
    screened = (f"**Which unstated settings decide it?** Morris screening "
                f"({scr['trajectories']} trajectories, {scr['points']} points) fixed "
                f"{len(fixed)} settings ({', '.join(fixed) or 'none'}).")
    if not rows:
        return [screened + f" No output has enough of the design's {sen['n']} points for PAWN "
                "at this level."]
    return ["\n".join([
        "**Which unstated settings decide it?** Morris screening "
        f"({scr['trajectories']} trajectories, {scr['points']} points) fixed {len(fixed)} "
        f"settings ({', '.join(fixed) or 'none'}); a diverged run enters the screening at "
        f"{prior.DIVERGED_RMSE:g} m, so that a setting that drives runs out of bounds shows a "
        f"large effect there. PAWN indices on the design's {sen['n']} "
        "points are median KS statistics, bounded in [0, 1]. Divergence is its own output (the "
        "share of diverged runs, on every point); each tracking output is analysed on the "
        "points where none of the runs it needs diverged (its n), so it describes the "
        "settings that track. The inert floor is the 95th percentile of the index of "
        "independent random columns. A setting is clearly above it when its interval's lower "
        "end is above both the floor and the dummy setting's interval, and, for a law's log "
        "RMSE and the discrepancy, stays so when the points the "
        "tracked analysis leaves out are added back ranked worst (placed past the worst "
        "tracked value); a setting above the floor otherwise is near it. "
        f"{_moved(sen)} The settings of a tied group have "
        "overlapping intervals; the first is shown, at most six names:", "",
        *common.md_table(["output", "n", "first tied group", "clearly above the floor",
                          "near the floor", "the floor"], rows),
    ])]  # fmt: skip


def _above(x: dict, cen: dict | None) -> tuple[list[str], list[str]]:
    """An output's settings above the inert floor: clearly (its interval's lower end above
    both the floor and the dummy setting's own interval, and likewise on every point where
    that analysis exists) or near it."""
    above = list(x["above_dummy"])

    def clear_in(y: dict, n: str) -> bool:
        return y["indices"][n]["low"] > max(y["dummy_high"], y["indices"]["dummy"]["high"])

    clear = [n for n in above if clear_in(x, n) and (cen is None or clear_in(cen, n))]
    return clear, [n for n in above if n not in clear]


def _moved(sen: dict) -> str:
    """How many of the tracking outputs' settings above the inert floor are clearly above it."""
    cen = sen.get("every_point", {}).get("outputs", {})
    pairs = [_above(x, cen.get(o)) for o, x in sen["indices"].items()
             if x and o != "diverged_share"]  # fmt: skip
    if not pairs:
        return "No tracking output has enough points for PAWN here."
    clear, near = sum(len(c) for c, _ in pairs), sum(len(n) for _, n in pairs)
    return (f"Over the {len(pairs)} tracking outputs, {clear} of the {clear + near} places "
            f"above the floor are clear of it and {near} near it (their intervals reach the "
            "floor or the dummy's, or are not clear of them on every point).")


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
           f"{span(pap['least_direct']['seeds'])} and judged by the rule itself."
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


def _tuning_cost(record: dict) -> str:
    """The fair tuning's own runs (in the shared tuning cache, not in the stores' counts)."""
    arms = record["fair_tuning"]["arms"].values()
    if not all("runs_per_evaluation" in a for a in arms):  # records before it
        return ""
    n = sum((a["evaluations"] + 1) * a["runs_per_evaluation"] for a in arms)
    return (f" The fair tuning's own training runs are not among them: {n:,} (each arm's "
            "evaluations and one at its defaults), kept in the tuning cache that the regime "
            "study shares, their time not recorded.")


def notes(record: dict) -> str:
    """The study's answers, computed from the record: short sentences, their numbers in tables
    (Markdown; ``analysis.prose``'s rule)."""
    c = record["cost"]
    out = _answer(record) + _answer_tables(record) + _answer_ranking(record)
    out += _answer_sequential(record) + _answer_sensitivity(record) + fair_report.answer(record)
    sizes = (f"{record['planted']['n_truths']} planted truths, {record['points']['n']:,} design "
             f"points and {len(record['best_fit']['restarts'])} CMA-ES restarts")
    out.append(f"**Level: {record['level']}** ({sizes}), {_level_note(record)}. Cost: "
               f"{c['runs_in_store']:,} runs in its stores; {c['runs_total']:,} runs were "
               f"run for it in {c['seconds_running_total']:.0f} s of running over every "
               f"invocation ({c['runs_this_time']:,} runs and {c['seconds']:.0f} s wall in "
               f"the last, on {c['engine']}).{_tuning_cost(record)} The fitted settings: "
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




def _edge_text(edges: list[dict]) -> str:
    """The best fit's settings on a box edge, each with its side and the restarts ending there."""
    return "; ".join(f"{e['setting']} ({e['side']}, at {e['value']:.4g}; "
                     f"{', '.join(e['restarts'])})" for e in edges)


def render(record: dict) -> str:
    """The report's section of this study."""
    return common.section(TITLE, notes(record), table(record), record["figures"])
