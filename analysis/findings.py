""""What the suite found": the report's opening, one short paragraph per question (issue 24).

Each finding answers one question in at most three sentences, every number read from a stored
record (``results/<study>.json``) with its interval where it has one, and ends in a link to the
section that shows the evidence.  A finding whose record is not stored is left out (the report
says which).  Nothing here runs a simulation; nothing is typed by hand but the questions and
the paper's printed tables (cited: ``analysis.reproduction.PAPER_RMSE``).

A finding is a function ``record(s) -> Finding``; :data:`FINDINGS` lists them in report order
with the records each reads.  A study redone under a new record shape adds or replaces its
function here.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from analysis import common
from analysis.common import fmt
from wmr import controllers
from wmr import scenario as scn

__all__ = ["SUMMARY", "Finding", "FINDINGS", "slug", "findings", "render"]

#: The summary's heading.
SUMMARY = "What the suite found"


@dataclass(frozen=True)
class Finding:
    """One answer: the question, its text (<= 3 sentences), the section it links to, and the
    figure of the strip beside the summary (a file name under ``figures/``, or None)."""

    question: str
    text: str
    section: str
    figure: str | None = None


def slug(heading: str) -> str:
    """The anchor of a heading, as GitHub and the HTML report both make it: lower case, every
    character but letters, digits, spaces, hyphens and underscores dropped, spaces to hyphens."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def _t95(n: int) -> float:
    from scipy import stats

    return float(stats.t.ppf(0.975, n - 1)) if n > 1 else math.inf


def _mean_ci(rec: dict) -> tuple[float, float, float]:
    """Mean and its 95 % t interval from a record's ``{"mean", "std", "n"}``."""
    h = _t95(rec["n"]) * rec["std"] / math.sqrt(rec["n"])
    return rec["mean"], rec["mean"] - h, rec["mean"] + h


def _mm(x: float) -> str:
    return f"{1e3 * x:.1f}"


# --- the findings -------------------------------------------------------------------------


def reproduction(rep: dict) -> Finding:
    """Does the paper reproduce?  Its ranking, and how our errors compare with its tables."""
    from analysis.reproduction import PAPER_RMSE, TITLE

    pairs = [v for e in rep["scenarios"].values() for v in e["paper_ranking_reproduced"].values()]
    contra = [c for e in rep["scenarios"].values()
              for c in e.get("paper_ranking_contradicted", {}).values()]  # fmt: skip
    ratios = []
    for sc, table in PAPER_RMSE.items():
        for ctl, paper in table.items():
            run = rep["scenarios"][sc]["runs"][ctl]["default"]
            ratios += [run[ax]["mean"] / p for ax, p in zip(("x", "y", "theta"), paper,
                                                            strict=True)]  # fmt: skip
    lem = rep["scenarios"]["lemniscate"]["runs"]
    m, lo, hi = _mean_ci(lem["iapid-nn-dekf"]["default"]["position"])
    mb, lob, hib = _mean_ci(lem["backstepping"]["default"]["position"])
    best = sorted({e["ranking"]["default"]["position"][0] for e in rep["scenarios"].values()})
    text = (f"Not its ranking: the paper's order of the four controllers holds on "
            f"{sum(pairs)} of {len(pairs)} (scenario, axis) pairs, and paired tests contradict "
            f"it on {sum(1 for c in contra if c)} of {len(contra)}. "
            f"Our errors are {min(ratios):.2f}–{max(ratios):.2f} times the paper's printed "
            f"RMSEs ({len(ratios)} numbers, {rep['seeds']} seeds each). "
            f"On the lemniscate IAPID-NN-DEKF tracks to {_mm(m)} mm (95 % CI {_mm(lo)}–"
            f"{_mm(hi)}) against backstepping's {_mm(mb)} mm ({_mm(lob)}–{_mm(hib)}); the "
            f"lowest mean position RMSE of each of the {len(rep['scenarios'])} scenarios "
            "belongs to " + " or ".join(controllers.label(b) for b in best)
            + ("" if "iapid-nn-dekf" in best else ", never to IAPID-NN-DEKF") + ".")
    return Finding("Does the paper reproduce?", text, TITLE, "reproduction_paths.png")


def jacobians(jac: dict) -> Finding:
    """Which of the paper's equations are wrong (checked against CasADi AD)."""
    from analysis.jacobians import TITLE

    net, rot = jac["network_input"], jac["rotation"]
    step = max(v["max_rel_error"] for v in jac["unicycle_step"].values())
    text = (f"The network's input Jacobian of eqs. 22–24 as printed is off by a median "
            f"relative error of {net['printed_median_rel_error']:.2f} against CasADi AD "
            f"({100 * net['printed_fraction_above_0.1']:.1f} % of {net['n']} points above "
            f"0.1); the corrected form agrees to {fmt(net['corrected_max_rel_error'], 1)}. "
            f"The rotation of eqs. 4/6 has determinant {rot['printed_det_equals']}, singular "
            "at " + ", ".join(f"{a:g}°" for a in rot["printed_singular_at_deg"])
            + f", where the corrected one has determinant {rot['corrected_det']}. "
            f"Every other closed form of the suite matches AD to {fmt(step, 1)} or better.")
    return Finding("Which of its equations are wrong?", text, TITLE)


def margins(mar: dict, bnd: dict | None) -> Finding:
    """Are the linearised loops stable, and with what margins?"""
    from analysis.margins import TITLE

    def worst(ctl: str, key: str) -> float:
        return min(mar[ctl][ch][key] for ch in ("v", "w"))

    dl = mar["delay_tolerance"]
    fq = [mar["floquet"][sc][c]["stable"] for sc in ("lemniscate", "sinusoid")
          for c in ("pid", "backstepping")]  # fmt: skip
    text = (f"Yes at the suite's gains: at the operating point {mar['operating_point']['label']} "
            f"the fixed PID keeps at least {worst('pid', 'gain_margin_db'):.1f} dB and "
            f"{worst('pid', 'phase_margin_deg'):.0f}° per loop, backstepping "
            f"{worst('backstepping', 'gain_margin_db'):.1f} dB and "
            f"{worst('backstepping', 'phase_margin_deg'):.0f}°, and the loops about the periodic "
            f"references are stable in {sum(fq)} of {len(fq)} Floquet checks. "
            f"The PID tolerates {dl['pid']['max_stable_delay_s'][0]:g} s of delay, "
            f"backstepping {dl['backstepping']['max_stable_delay_s'][0]:g} s.")
    if bnd:
        alphas = [bnd[sc]["alpha"] for sc in bnd]
        dt = scn.load(scn.builtin("lemniscate")).dt  # the boundedness study's scenarios' dt
        text += (f" The DEKF's boundedness constant α of Lemma 2 is at most "
                 f"{fmt(max(alphas), 2)}, so its guaranteed contraction takes "
                 f"~{fmt(dt / max(alphas), 1)} s to shrink an error by e: no practical bound.")
    return Finding("Are its loops stable, and with what margins?", text, TITLE)


def robots(rob: dict) -> Finding:
    """Where the kinematic model stops predicting the physics robot, and which controller to use
    on which robot model (the ladder; the regime study adds the tuned arms)."""
    from analysis.robots import TITLE, views

    lo, hi = views.ratio_range(rob)
    slid = [p["demand"] for p in rob["sliding"] if p["sliding"]]
    best = views.best_per_rung(rob)
    same = best["kinematic"] == best["mujoco"]
    changes = sum(1 for rr in rob["order_changes"].values() for v in rr.values() if v)
    text = (f"At a {1e3 * rob['mj_timestep']:g} ms physics step every controller's error after "
            f"the transient on the MuJoCo robot is {lo:.2f}–{hi:.2f} times its error on the "
            f"kinematic unicycle ({rob['mj_seeds']} seeds; the shipped 2 ms step is not "
            f"converged), and it slides from {min(slid):.2f} of the Coulomb bound (μ g). "
            "The best controller at the defaults, per trajectory, is "
            + views._best_sentence(rob, "mujoco")
            + (" on both robots" if same else " on MuJoCo (" + views._best_sentence(
                rob, "kinematic") + " on the unicycle)")
            + f"; {changes} pair order(s) reverse by more than 5 % between rungs.")
    return Finding("Which controller on which robot?", text, TITLE, "robots_ladder.png")


def regimes(reg: dict) -> Finding:
    """When does adaptation pay, and against what: the verdicts at the shared default settings
    (where two arms differ only in what is compared), the tuned ones where the tuning
    converged."""
    from analysis.regimes import TITLE

    mech = reg["verdict"]["mechanisms"]
    ia = "iapid-nn-dekf - adaptive-pid"

    def at_defaults(contrast: str, word: str) -> list[str]:
        return [m for m, v in mech.items() if v[contrast].get("default", {}).get("verdict") == word]

    same = at_defaults(ia, "same within 5 %")
    same_pid = at_defaults("adaptive-pid - pid", "same within 5 %")
    n_default = sum(1 for v in mech.values() if "default" in v[ia])
    arms = [t for per in reg["tuning"]["arms"].values() for t in per.values()]
    n_dis = sum(not t["agreement"]["agree"] for t in arms)
    n_withheld = sum(v["verdict"] == "withheld" for e in mech.values() for v in e.values())
    text = (f"At the paper's defaults IAPID-NN-DEKF equals APID (they differ only in the "
            f"Jacobian) within 5 % on {len(same)} of {n_default} plants"
            + (f", and APID the fixed PID on {len(same_pid)}. " if len(same) == n_default
               else ". ")
            + (_tuned_sentence(reg) if reg.get("restart_pairings") else
               f"Tuned verdicts are withheld ({n_withheld} of "
               f"{sum(len(e) for e in mech.values())}) because the tuning's restarts disagree "
               f"for {n_dis} of {len(arms)} arms and the MuJoCo mechanisms were tuned on "
               "kinematic plants."))
    return Finding("When does adaptation pay, and against what?", text, TITLE,
                   reg["figures"][0] if reg.get("figures") else None)


def _tuned_sentence(reg: dict) -> str:
    """How many tuned verdicts off the MuJoCo robot hold at every pairing of the two arms'
    tuning restarts (and, for the best arms, their choice)."""
    from analysis.regimes.frozen import plants_where
    from analysis.regimes.report import bsc_standing, inert, standing_count

    kept, n = standing_count(reg)
    bsc = bsc_standing(reg)
    by: dict[str, list[tuple]] = {}  # arm -> (pose source, inert, costs, plants)
    for p, (a, ms, k) in inert(reg).items():
        by.setdefault(a, []).append((p, len(ms), len(plants_where(reg, a, p, "costs")), k))
    off = "; ".join(f"{controllers.label(a)}'s adaptation is inert on "
                    f"{'/'.join(str(x[1]) for x in xs)} and costs on "
                    f"{'/'.join(str(x[2]) for x in xs)} of {xs[0][3]} plants "
                    f"({'/'.join(x[0] for x in xs)})" for a, xs in by.items())
    return (f"Tuned, {kept} of {n} distinct simulated-plant verdicts survive the restart, "
            "best-arm and adaptation-off checks"
            + (f"; Adaptive BSC against BSC {bsc}." if bsc else ".")
            + (f" Switched off at its tuned settings, {off}." if off else ""))


def calibration(cal: dict) -> Finding:
    """Could any plausible setting give the paper's tables (the rule's coverage and power, the
    verdict and its scope, the ranking's probability over the prior)."""
    from analysis.calibration import TITLE
    from analysis.calibration.rule import DELTA

    pl, v, fit, po = cal["planted"], cal["verdict"], cal["best_fit"], cal["p_paper_order"]
    cov = pl["coverage"]
    at = v["by_delta"][f"{DELTA:g}"]  # the verdict's discrepancy (its key: the rule's constant)
    widest = max(v["by_delta"], key=float)  # the largest discrepancy shown (a key: a constant)
    a9, ia = po["all_nine"], po["iapid_first_all"]
    n_ok = at["count"]
    passes = (f"{n_ok} of the {v['n_candidates']} settings examined pass"
              if n_ok else f"None of the {v['n_candidates']} settings examined passes")
    there = "that discrepancy"  # the verdict's is the planted truths' (calibration.check)
    spread = fit["spread"]
    x = cal.get("planted_fresh") or pl  # out of sample where fresh truths exist
    cov = x["coverage"]
    text = (f"The feasibility rule (threshold {v['threshold']:.2f}, Šidák over 36 numbers, "
            f"{100 * pl['delta']:.0f} % discrepancy) accepts {int(cov['k'])} of "
            f"{int(cov['n'])} {'fresh ' if x is not pl else ''}planted truths "
            f"({100 * cov['ci_low']:.1f}–{100 * cov['ci_high']:.1f} %, nominal "
            f"{100 * pl['nominal']:.0f} %) and " + _power_short(x) + ". "
            + f"{passes} at {there} (smallest maximum "
            f"implausibility {at['min_max_implausibility']:.2f}), "
            f"{v['by_delta'][widest]['count']} at {100 * float(widest):.0f} %"
            + (f"; the fit's {len(fit['restarts'])} restarts disagree (spread "
               f"{spread['range']:.3f}), so the rest of the prior is not ruled out. "
               if not spread["agree"] else ". ")
            + f"Over the prior the paper's full ranking appears in {a9['k_runs']} of "
            f"{a9['n_runs']} runs (at most {100 * a9['ci_high']:.1f} % of the prior's "
            f"{a9['n_points']} points), IAPID-NN-DEKF best on all nine axes in "
            f"{100 * ia['p']:.1f} % ({100 * ia['ci_low']:.1f}–{100 * ia['ci_high']:.1f} %).")
    figure = next((f for f in cal.get("figures", []) if "residual" in f), None)
    return Finding("Could any setting give its tables?", text, TITLE, figure)


#: (records read, the finding's function) in report order; the first record is required, the
#: others are passed as None when absent.
FINDINGS: tuple[tuple[tuple[str, ...], Callable[..., Finding]], ...] = (
    (("reproduction",), reproduction),
    (("jacobians",), jacobians),
    (("margins", "boundedness"), margins),
    (("robots",), robots),
    (("regimes",), regimes),
    (("calibration",), calibration),
)


def findings(out: str | Path) -> list[Finding]:
    """The findings whose first record is stored in ``out/results``, in report order."""
    found = []
    for stems, fn in FINDINGS:
        records = [common.load_record(out, s) for s in stems]
        if records[0] is not None:
            found.append(fn(*records))
    return found


def render(found: list[Finding]) -> list[str]:
    """The summary's Markdown lines: a heading, one paragraph per finding with its link, then
    the figure strip."""
    if not found:
        return []
    lines = [f"## {SUMMARY}", ""]
    for f in found:
        lines += [f"**{f.question}** {f.text} [→ {f.section}](#{slug(f.section)})", ""]
    strip = [f.figure for f in found if f.figure]
    if strip:
        lines += [" ".join(f"![{n}](figures/{n})" for n in strip), ""]
    return lines


def _power_short(x: dict) -> str:
    """The calibration rule's power at the issue's distance on planted truths ``x`` (the
    fresh ones where they exist), and where it first reaches 90 % when it is too loose."""
    from analysis.calibration.rule import DECIDE_AT

    pw = x["power"][f"{DECIDE_AT:g}"]
    # the first longer distance reaching 90 %: the record's resolves_at (calibration.check
    # asserts the two agree; read off the power's keys so that it survives a record whose
    # floats are perturbed, as tests/test_summary.py does)
    res = min((d for d, y in x["power"].items() if float(d) > DECIDE_AT and y["p"] >= 0.9),
              key=float, default=None)  # fmt: skip
    if not x["too_loose"]:
        verdict = ("" if pw["ci_low"] >= 0.9 else
                   ", meeting the 90 % criterion at its point estimate only")
    elif res is None:
        verdict = ": too loose by the 90 % criterion at every distance measured"
    else:
        y = x["power"][res]
        verdict = (": too loose by the 90 % criterion, reached only at "
                   f"{y['distance']:g} ({int(y['k'])} of {int(y['n'])}), a distance added later")
    return (f"rules out {int(pw['k'])} of {int(pw['n'])} points {pw['distance']:g} away "
            "(unit cube)" + verdict)
