"""The calibration study's report section, in sentences computed from its record only
(``analysis.calibration``; DESIGN §7.8: the answer first, in a few short sentences)."""

from __future__ import annotations

import math

from analysis import common
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
    """The answer in a few short sentences (DESIGN §7.8)."""
    pl, ver, fit, po = r["planted"], r["verdict"], r["best_fit"], r["p_paper_order"]
    cov = pl["coverage"]
    pw = pl["power"]
    key = f"{ver['delta']:g}"
    v = ver["by_delta"][key]
    sens = r["sensitivity"]["pawn"]["indices"].get("rms_log_ratio")
    top = [n for n in sens["ties"][0] if n != "dummy"] if sens else []
    inert = bool(sens) and "dummy" in sens["ties"][0]
    lines = [
        f"**The answer.** The rule (history-matching implausibility on log RMSE, {r['rule']['K']} "
        f"seeds per candidate, threshold {ver['threshold']:.2f}) accepts a planted truth "
        f"{cov['k']:.0f} of {cov['n']:.0f} times ({_pct(cov)}; nominal 95 %) and rules out "
        "points at unit-cube distance " + ", ".join(
            f"{d}: {_pct(x)}" for d, x in pw.items())
        + f", both at the verdict's model discrepancy of {100 * pl['delta']:.0f} %" + (
            ": too loose to decide (power below 90 % at distance 0.3)." if pl["too_loose"]
            else ".") + "  At discrepancy " + "; ".join(
            f"{100 * float(dl):.0f} %: coverage {_pct(x['coverage'])}, power at 0.3 "
            f"{_pct(x['power'][max(x['power'], key=float)])}"
            for dl, x in pl.get("by_delta", {}).items()) + ".",
        "**Does any plausible setting reproduce Tables 1-3?** "
        + (f"Yes: {v['count']} of {ver['n_candidates']} candidates are not ruled out"
           if v["count"] else
           f"None of the {ver['n_candidates']} candidates examined is")
        + f" (model discrepancy {100 * ver['delta']:.0f} %; smallest max implausibility "
        f"{v['min_max_implausibility']:.1f}); at discrepancy " + ", ".join(
            f"{100 * float(d):.0f} %: {x['count']}" for d, x in ver["by_delta"].items())
        + f".  Scope: {ver['scope']}.  The earlier '0 of 4,096 feasible' is retracted.",
        f"**Closest fit.** rms log ratio {fit['rms_log_ratio']:.3f} (factor "
        f"{math.exp(fit['rms_log_ratio']):.2f}) over {len(fit['seeds'])} seeds, "
        f"{fit['n_within']} of 36 numbers within the rule; CMA-ES's {len(fit['restarts'])} "
        f"restarts end at " + ", ".join(f"{x['rms_log_ratio']:.3f}" for x in fit["restarts"])
        + f" (spread {fit['spread']['range']:.3f}, "
        + ("within" if fit["spread"]["agree"] else "beyond")
        + f" the stated {fit['spread']['tolerance']:g}: "
        + ("they agree)" if fit["spread"]["agree"] else "the spread is the result)")
        + (f"; on the prior's edge: {', '.join(fit['edges'])}." if fit["edges"] else "."),
        f"**The paper's ranking over the prior.** All nine orders as printed: "
        f"{_pct(po['all_nine'])}; IAPID-NN-DEKF lowest on all nine: "
        f"{_pct(po['iapid_first_all'])} (Clopper-Pearson over {po['n_points']} points).  "
        "Settings that decide the discrepancy most (PAWN's first tied group): "
        + (", ".join(top) if top else "none separable")
        + (" -- tied with an inert dummy setting, so not separated." if inert else "."),
    ]  # fmt: skip
    return lines


def _answer_tables(r: dict) -> list[str]:
    fit, pts = r["best_fit"], r["points"]
    worst = sorted(fit["residuals"].items(), key=lambda kv: -kv[1]["implausibility"])[:5]
    nums = pts["numbers"]
    never = [n for n, c in nums.items() if not c["spanned"]]
    return [
        "**Where does the closest fit miss?** Largest implausibilities: " + "; ".join(
            f"{_label(n)} {fmt(x['mean'])} vs {fmt(x['paper'])} (x{x['ratio']:.2f}, "
            f"I = {x['implausibility']:.1f})" for n, x in worst) + ".  Numbers outside the "
        f"range the {pts['n']}-point design's seed means span: " + (", ".join(
            f"{_label(n)} (paper {fmt(nums[n]['paper'])}, design {fmt(nums[n]['min'])}-"
            f"{fmt(nums[n]['max'])})" for n in never) or "none") + ".",
    ]  # fmt: skip


def _answer_ranking(r: dict) -> list[str]:
    po = r["p_paper_order"]
    pw = po["pairwise"]
    lab = controllers.label
    beats = "; ".join(f"{lab(k.split(' < ')[0])} < {lab(k.split(' < ')[1])}: {_pct(v)} (paper "
                      f"{100 * v['paper']:.0f} %)" for k, v in pw.items()
                      if k.startswith("iapid-nn-dekf"))  # fmt: skip
    conv, ind = po["convergence"], po["independent_halves"]
    return [
        f"**How likely is the paper's ranking over the prior?** Over {po['n_points']} points x "
        f"{po['n_seeds']} seeds (single runs, as the paper's tables; exact intervals over the "
        f"points): all nine (scenario, axis) orders as printed {_pct(po['all_nine'])}; "
        f"IAPID-NN-DEKF lowest on all nine {_pct(po['iapid_first_all'])}, on at least one "
        f"{_pct(po['iapid_first_any'])}; mean Kendall tau against the paper's orders "
        f"{po['kendall_tau']['mean']:.3f} [{po['kendall_tau']['ci'][0]:.3f}, "
        f"{po['kendall_tau']['ci'][1]:.3f}].  Pairwise, share of the 9 (scenario, axis) "
        f"comparisons IAPID wins: {beats}.  Between the design's independent halves (A and B) "
        f"the probabilities agree within their intervals for {ind['agreeing']} of "
        f"{ind['compared']} (half nested in the whole: {conv['agreeing']} of "
        f"{conv['compared']}).",
    ]  # fmt: skip


def _answer_sensitivity(r: dict) -> list[str]:
    sen = r["sensitivity"]["pawn"]
    parts = []
    for o in ("rms_log_ratio", "margin:adaptive-pid", "margin:backstepping", "diverged_share"):
        x = sen["indices"].get(o)
        if not x:
            continue
        groups = x["ties"][:2]
        parts.append(f"{o}: " + " > ".join("{" + ", ".join(g[:6]) + ("..." if len(g) > 6
                                                                        else "") + "}"
                                           for g in groups)
                     + f" ({len(x['above_dummy'])} settings above the dummy's "
                       f"{x['dummy_high']:.3f})")  # fmt: skip
    scr = r["screening"]
    fixed = [n for n in r["prior"] if not r["prior"][n].get("varied", True)]
    return [
        "**Which unstated settings decide it?** Morris screening "
        f"({scr['trajectories']} trajectories, {scr['points']} points) fixed {len(fixed)} "
        f"settings ({', '.join(fixed) or 'none'}).  PAWN indices on the {sen['n']} design "
        "points (median KS, bounded in [0, 1]; tied groups in braces, a group's intervals "
        "overlap): " + "; ".join(parts) + ".",
    ]  # fmt: skip


def _answer_fair(r: dict) -> list[str]:
    f = r["fair_tuning"]
    lab = controllers.label
    c = f["controllers"]
    rows = ", ".join(f"{lab(k)} {fmt(c[k]['held_out']['position'])} m (default gains "
                     f"{fmt(c[k]['default_held_out']['position'])} m, effort "
                     f"{fmt(c[k]['held_out']['effort'], 3)})" for k in f["ranking_held_out"])
    best = f["ranking_held_out"][0]
    n_seeds = len(f["budget"]["test_seeds"])
    wins = ", ".join(f"{lab(k)} {v}/{n_seeds}" for k, v in f["wins_of_best"].items())
    tie = f.get("tie_with_best", [])
    return [
        f"**Who wins under fair tuning?** (the interim stage; the shared tuning stage of "
        f"analysis/tuning.py replaces it) Each controller's free gains tuned by the same "
        f"optimiser with {f['budget']['evaluations']} evaluations on "
        f"{len(f['training'])} training trajectories, then run on the paper's three scenarios "
        f"(held out, seeds {f['budget']['test_seeds'][0]}-{f['budget']['test_seeds'][-1]}): "
        f"lowest mean log RMSE {lab(best)}"
        + (f", tied within its paired interval with {', '.join(lab(t) for t in tie)}"
           if tie else "") + f"; mean position RMSE: {rows}.  Seeds on which {lab(best)} "
        f"beats each other controller (mean position RMSE over the three scenarios): {wins}.",
    ]  # fmt: skip


def notes(record: dict) -> list[str]:
    """The study's answers, in sentences computed from the record."""
    c = record["cost"]
    out = _answer(record) + _answer_tables(record) + _answer_ranking(record)
    out += _answer_sensitivity(record) + _answer_fair(record)
    out.append(f"Level: {record['level']} ({LEVEL_NOTE.get(record['level'], '')}).  Cost: "
               f"{c['runs_in_store']:,} runs in the store; {c['runs_total']:,} runs were "
               f"run for it in {c['seconds_running_total']:.0f} s of running over every "
               f"invocation ({c['runs_this_time']:,} runs and {c['seconds']:.0f} s wall in "
               f"the last, on {c['engine']}); the fitted "
               f"settings: {', '.join(record['best_fit']['scenario_files'])} (a fit, not the "
               "defaults).")  # fmt: skip
    if record["level"] == "quick":
        out.insert(0, "A QUICK run (a few points, short runs): its numbers answer nothing.")
    return out


#: What each level is, in the report.
LEVEL_NOTE = {
    "quick": "the tests' few points on short runs",
    "medium": "the committed record, a reduced level: 20 planted truths (the full study "
              "100), 256 design points (4,096), 5 CMA-ES restarts of 40 evaluations (6 of "
              "240); it took 42 minutes wall on the 2-core machine shared by four engineers "
              "(the 25-minute target was missed); the full study is `make calibration`",
    "full": "the whole study (`make calibration`)",
}


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


def render(record: dict) -> str:
    """The report's section of this study."""
    return common.section(TITLE, notes(record), table(record), record["figures"])


