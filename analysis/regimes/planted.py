"""The regime study's rule on planted truth, worded for the report (``analysis.regimes.coverage``
measures it): its coverage, acceptance of the truth and power at the defaults' and the tuned
settings' layouts, and the smallest effect it detects."""

from __future__ import annotations

import math

from analysis import common
from analysis.regimes import rule

__all__ = ["span", "detectable", "said", "said_tuned"]

#: The contrasts the report names most (their record keys).
KEY = "best-adaptive - best-fixed"
IA = "iapid-nn-dekf - adaptive-pid"
#: The verdict words of the planted-truth table's columns.
_COV_WORDS = ("pays", "costs", "same within 5 %", "undecided")


def span(record: dict, name: str, interval: str, key: str = "coverage_cells") -> str:
    """The range of the planted-truth coverage of ``name``'s ``interval`` over the ratios."""
    c = record.get("coverage", {}).get("contrasts", {}).get(name, {}).get("intervals", {})
    if interval not in c:
        return ""
    v = [round(100 * x[key]) for x in c[interval].values()]
    return f"{min(v)} %" if min(v) == max(v) else f"{min(v)}-{max(v)} %"


def detectable(by: dict, share: float = 0.9) -> str:
    """The smallest planted effect the rule names ('pays' below 1, 'costs' above) in at least
    ``share`` of cells, and the largest it does not, from the planted-truth table ``by``
    (planted ratio -> entry); "" without planted effects."""
    eff = sorted((abs(math.log(float(r))), r, x["verdicts"]["pays" if float(r) < 1 else "costs"])
                 for r, x in by.items() if float(r) != 1)  # fmt: skip
    if not eff:
        return ""
    first = next((i for i, (_, _, w) in enumerate(eff) if w >= share), None)
    if first is None:
        return f"none (no planted ratio is named in {100 * share:.0f} % of cells)"
    said = f"{eff[first][1]} ({100 * eff[first][2]:.0f} %)"  # (its share of cells)
    if first:
        said += f"; the smaller {eff[first - 1][1]} in {100 * eff[first - 1][2]:.0f} % of cells"
    return said


def said(record: dict) -> str:
    """The rule on planted truth (``analysis.regimes.coverage``): a sentence and a table."""
    cov = record.get("coverage")
    if not cov:
        return ""
    c0 = next(iter(cov["contrasts"].values()))
    rows = []
    for name, c in cov["contrasts"].items():
        for interval, by in c["intervals"].items():
            for ratio, x in by.items():
                v = x["verdicts"]
                rows.append([name, interval, ratio, f"{100 * x['coverage_cells']:.1f} %",
                             f"{100 * x['coverage_mechanisms']:.1f} %",
                             *[f"{100 * v.get(w, 0.0):.0f} %" for w in _COV_WORDS],
                             *[f"{100 * x[k]:.0f} %" if k in x else "—"
                               for k in ("depends", "accepts", "correct")]])  # fmt: skip
    t = {n: c["intervals"].get("t(G-1)", {}) for n, c in cov["contrasts"].items()}
    acc = [100 * x["accepts"] for by in t.values() for x in by.values() if "accepts" in x]
    short = [n for n, by in t.items() if any(x.get("accepts", 1.0) < 0.9 for x in by.values())]
    ba = t.get(KEY, {})
    said = (f" The rule accepts the planted truth (no word false of it) in {min(acc):.0f}-"
            f"{max(acc):.0f} % of mechanisms"
            + (f"; below DESIGN §7.6's 90 % for {', '.join(short)}." if short else
               ", at or above DESIGN §7.6's 90 %.") if acc else "")  # fmt: skip
    power = (f" Its power, both pose sources given the planted word, with {KEY}'s noise: "
             + ", ".join(f"{100 * x['correct']:.0f} % at {r}" for r, x in ba.items())
             + ". The smallest planted effect it names ('pays' below 1, 'costs' above) in 90 % "
             f"of cells: {detectable(ba)}." if ba else "")  # fmt: skip
    return "\n".join([
        f"**The rule on planted truth.** Synthetic pairs with the defaults' layout "
        f"({c0['clusters']} seeds as clusters, {c0['pairs']} both-stable pairs) and the "
        f"record's noise per mechanism, {c0['replicates']} replicates per planted ratio. "
        f"The normal interval covers the planted ratio {span(record, IA, 'normal')} of the "
        f"time; Student t at G - 1 df covers {span(record, IA, 't(G-1)')}, and the rule uses "
        f"it.{said}{power} A word's share counts (mechanism, pose source) verdicts; 'pays' is "
        "true of 0.97. The noise is Gaussian: a seed effect per mechanism and a pair's own "
        "noise, at the record's residual levels.", "",
        *common.md_table(["contrast", "interval", "planted", "covered (cells)",
                          "covered (mechanisms)", "pays", "costs", "same", "undecided",
                          "poses contradict", "accepts truth", "decides right"], rows)])


def _few(record: dict, name: str, mechs: list[str]) -> tuple[int, int]:
    """How many of contrast ``name``'s (mechanism, pose source) cells among ``mechs`` have
    fewer than ``rule.MIN_PAIRS`` both-stable pairs at the tuned settings, of how many."""
    v = record["verdict"]["mechanisms"]
    n = [x["n_stable"] for m in mechs for x in v[m][name]["poses"].values()]
    return sum(k < rule.MIN_PAIRS for k in n), len(n)


def said_tuned(record: dict) -> str:
    """The rule on planted truth at the tuned settings' layout: a sentence and a table ("" for
    a record without it)."""
    cov = (record.get("coverage_tuned") or {}).get("contrasts", {})
    if not cov:
        return ""
    rows, parts = [], []
    for name, c in cov.items():
        t = c["intervals"]["t(G-1)"]
        for r, x in t.items():
            rows.append([name, r, f"{100 * x['coverage_cells']:.1f} %",
                         f"{100 * x['accepts']:.0f} %", f"{100 * x['correct']:.0f} %"])
        acc = [round(100 * x["accepts"]) for x in t.values()]
        rng = f"{min(acc)} %" if min(acc) == max(acc) else f"{min(acc)}-{max(acc)} %"
        few = _few(record, name, c["mechanisms"])
        parts.append(f"For {name} ({c['pairs']} pairs, {c['clusters']} seeds) it accepts the "
                     f"truth in {rng}; the smallest effect named in 90 % of cells: "
                     f"{detectable(t)}."
                     + (f" {few[0]} of its {few[1]} cells {'has' if few[0] == 1 else 'have'} "
                        f"fewer than {rule.MIN_PAIRS} both-stable pairs at the tuned settings, "
                        "where the ratio rule names nothing." if few[0] else ""))
    c0 = next(iter(cov.values()))
    return "\n".join([
        "**The rule on planted truth at the tuned layout.** The same synthetic pairs on the "
        "tuned settings' both-stable pairs of the simulated plants (fewer where an arm diverges), "
        f"{c0['replicates']} replicates per planted ratio, Student t at G - 1 df. "
        + " ".join(parts) + " The divergence words are outside this check: the synthetic "
        "pairs have no divergence. Their test is the exact sign-flip test over the seeds (the "
        "runs of a seed share its noise, so the seed is the unit), and a divergence verdict "
        "speaks for the seeds on these trajectories, not for other trajectories.", "",
        *common.md_table(["contrast", "planted", "covered (cells)", "accepts truth",
                          "decides right"], rows)])
