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
    from analysis import _robots_views as views
    from analysis.robots import TITLE

    lad = rob["ladder"]
    rel = [lad[t]["mujoco"]["cells"][c]["mean"] / lad[t]["kinematic"]["cells"][c]["mean"]
           for t in lad for c in rob["controllers"]
           if lad[t]["mujoco"]["cells"][c]["mean"] and lad[t]["kinematic"]["cells"][c]["mean"]]
    slid = [p["demand"] for p in rob["sliding"] if p["sliding"]]
    best = views.best_per_rung(rob)
    names = {r: sorted({c for t in best[r].values() for c in t}) for r in ("kinematic", "mujoco")}
    changes = sum(1 for rr in rob["order_changes"].values() for v in rr.values() if v)
    text = (f"On the MuJoCo robot every controller's error after the transient is "
            f"{min(rel):.2f}–{max(rel):.2f} times its error on the kinematic unicycle "
            f"({rob['seeds']} seeds, the paper's trajectories). It slides once the lateral "
            f"acceleration reaches {min(slid):.2f} of the Coulomb bound μ g. "
            "The best at the defaults is "
            + " ≈ ".join(controllers.label(c) for c in names["kinematic"]) + " on the unicycle and "
            + " ≈ ".join(controllers.label(c) for c in names["mujoco"]) + " on MuJoCo "
            f"(ties by paired test), with {changes} significant order reversals between rungs.")
    return Finding("Which controller on which robot?", text, TITLE, "robots_ladder.png")


#: (records read, the finding's function) in report order; the first record is required, the
#: others are passed as None when absent.
FINDINGS: tuple[tuple[tuple[str, ...], Callable[..., Finding]], ...] = (
    (("reproduction",), reproduction),
    (("jacobians",), jacobians),
    (("margins", "boundedness"), margins),
    (("robots",), robots),
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
