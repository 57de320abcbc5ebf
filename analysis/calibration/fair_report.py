"""The calibration report's fair-tuning answer (``analysis.calibration.fair``'s record, in
sentences computed from it only; ``analysis.calibration.report`` places them)."""

from __future__ import annotations

import math

from analysis import common
from analysis.calibration import fair_planted
from analysis.calibration.verdicts import EQUIV
from analysis.common import fmt
from wmr import controllers

__all__ = ["answer", "short", "span", "summary_of", "planted"]


def span(seeds: list[int]) -> str:
    """Seeds as ``a-b`` when consecutive, else listed."""
    if len(seeds) > 2 and list(seeds) == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(map(str, seeds))


def short(f: dict) -> str:
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
    by_fail = [n for n, v in f["against_best"].items() if v["verdict"] == "fails more"]
    failing = sorted({cells[i].split("@")[1] for n in by_fail
                      for i, k in enumerate(f["arms"][n]["held_out"]["per_cell_failures"]) if k})
    return (f"Tuned by the shared stage (every adaptation setting free) on held-out "
            f"plants, {lead}"
            + (f", its lead over {_names(by_fail)} resting on where they fail "
               f"({', '.join(failing)})" if by_fail and failing else "")
            + ("; " + "; ".join(rest) if rest else "") + ".")


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
#: The same for a single arm.
_ONE = {"fails more": "fails more", "higher": "is higher",
        "worse": "fails more or is higher, depending on the restarts"}
#: How the answer names the arms of each verdict against a best not shown best.
_AGAINST = {"tie": "{} tie with it",
            "equivalent": "{} are equivalent to it within 5 %",
            "restart-dependent": "against {} the verdict depends on which restart is run",
            "mixed": "with {} the failure counts and the accuracy lean opposite ways, neither "
                     "told apart (mixed: no claim)",
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
        said = "; ".join(f"{_names(ns)} {_WORSE[w] if len(ns) > 1 else _ONE[w]}"
                         for w, ns in by.items())
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


def _whole(f: dict, failing: list[str], cells: list[str]) -> str:
    """Where the failures are whole cells (every seed fails) and what the failure test then
    generalises over (DESIGN §7: the seeds are its replicates; the plants are fixed)."""
    if not failing:
        return ""
    arms = f["arms"]
    seeds = arms[failing[0]]["held_out"]["tracking_failure"]["n"] // len(cells)
    per, plants = [], set()
    for n in failing:
        by: dict[str, int] = {}
        for c, k in zip(cells, arms[n]["held_out"]["per_cell_failures"], strict=True):
            if k == seeds:
                by[c.split("@")[1]] = by.get(c.split("@")[1], 0) + 1
                plants.add(c.split("@")[1])
        if by:
            per.append(f"{_arm(n)} " + ", ".join(f"{p} {k}" for p, k in by.items()))
    runs = sum(arms[n]["held_out"]["tracking_failure"]["diverged"] for n in failing)
    whole = sum(k for n in failing for k in arms[n]["held_out"]["per_cell_failures"]
                if k == seeds)
    if not per:
        return ""
    total = len({c.split("@")[1] for c in cells})
    return (f"{whole} of these {runs} failures are whole cells, an arm failing at every one of "
            f"the {seeds} seeds of a scenario on a plant (cells per plant: {'; '.join(per)}). "
            "The failure test's replicates are the seeds: it tells that these arms fail more "
            f"on these {total} plants, not on plants in general, and a verdict won on failures "
            f"rests on {len(plants)} of the {total} plants ({', '.join(sorted(plants))}).")


def _restarts(f: dict) -> str:
    """Whether each arm's tuning restarts agree (DESIGN §7.7), stated where they do not."""
    arms = f["arms"]
    every = [*f["ranking"], *(n for n in arms if n not in f["ranking"])]
    off = [n for n in every if not arms[n]["agreement"]["agree"]]
    if not off:
        return "Every arm's tuning restarts agree within their tolerance."
    ok = [n for n in every if arms[n]["agreement"]["agree"]]
    said = ", ".join(f"{_arm(n)} {arms[n]['agreement']['spread']:.4f} (tolerance "
                     f"{arms[n]['agreement']['tolerance']:.4f})" for n in off)
    return (f"The tuning's restarts end apart, beyond 5 % of the better objective, for "
            f"{len(off)} of {len(arms)} arms: {said}"
            + (f"; only {_names(ok)} {'agrees' if len(ok) == 1 else 'agree'}" if ok else "")
            + ". Those arms' tuning has not converged at this budget (not raised); the four "
            "restart pairings carry the difference into each verdict.")


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
            + _own_missed(c, x, y))


def _own_missed(c: dict, x: str, y: str) -> str:
    """Which law does better with the other's settings than with its own (its own tuning did
    not find its best)."""
    better = [k for k in ("x_swapped", "y_swapped") if c[k]["word"] in _BETTER]
    if len(better) == 2:
        return (" Each law does better with the other's settings than with its own: its own "
                "tuning did not find its best, so the tuning, not the law, decides the pair as "
                "tuned.")
    if better:
        law, other = (x, y) if better[0] == "x_swapped" else (y, x)
        return (f" {law} does better with {other}'s settings than with its own on the held-out "
                "plants: its own tuning did not find its best there.")
    return ""


#: The words of a comparison in which the first arm does better.
_BETTER = ("lower", "fails less", "better")


def _fixed(f: dict) -> str:
    """Each arm's numeric settings the tuning left at their defaults (the record's)."""
    arms = f["arms"]
    return "; ".join(f"{_arm(n)}: {', '.join(arms[n]['fixed'])}" for n in f["ranking"]
                     if arms[n]["fixed"]) or "none"  # fmt: skip


def answer(r: dict) -> list[str]:
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
             *([_whole(f, failing, ho["cells"])] if failing else []),
             *([f"At their defaults {_names(worse)} track every held-out run; tuned "
                "on the training plants, they do not."] if worse else []),
             *_beside(f, ho, arms),
             f"The paper's set-up, {_arm(pa['arm'])}, is '{pa['against_raw']['verdict']}' "
             f"against the same law on the measured pose and '{pa['against_best']['verdict']}' "
             f"against {_arm(best)}.", _swap(f), _restarts(f), _edges(f)]
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
        f"({', '.join(b['training'])}) at seeds {span(b['train_seeds'])}: other members of the "
        "held-out trajectories' families, on plants with some of the held-out mechanisms at "
        "other magnitudes (analysis/calibration/fair.py says which).",
        f"Held out: the {len(ho['cells'])} cells ({', '.join(ho['plants'])}; the skid outward) "
        f"at seeds {span(b['test_seeds'])}, each arm at its best restart, its runner-up and "
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
                              "at the four pairings", "verdict"], rows)]), *planted(f)]  # fmt: skip


def _pc(x: dict) -> str:
    return f"{100 * x['share']:.0f} %"


def planted(f: dict) -> list[str]:
    """The comparison rule on planted truth (``analysis.calibration.fair_planted``): a
    paragraph and a table; nothing where the record has no planted study or no comparison
    with the runs to plant in (fewer than 3 held-out seeds or 2 cells that always track)."""
    pl = f.get("planted")
    done = {k: c for k, c in (pl or {}).get("comparisons", {}).items() if c["noise"]}
    if not done:
        return []
    la, ratios, extra = pl["least_accepts"], pl["ratios"], pl["fail_extra"]

    def at(c: dict, rho: float, fx: float = 0.0, mode: str = "truths") -> dict:
        return next(t for t in c[mode] if t["rho"] == rho and t["f"] == fx)

    rows = [[k.replace("@raw", ""), f"{c['noise']['seed_sd']:.3f} / {c['noise']['pair_sd']:.3f}",
             f"{c['noise']['tracked']} / {c['noise']['varying']} / {c['noise']['fixed']}",
             f"{100 * c['noise']['random_failures']:.1f} %",
             _pc(min((t["accepts"] for t in c["truths"]), key=lambda x: x["share"])),
             *[_pc(at(c, r)["power"]) for r in ratios],
             *[_pc(at(c, 1.0, fx)["power"]) for fx in extra], _resolution(c, ratios, at)]
            for k, c in done.items()]  # fmt: skip
    top = max(ratios)
    cov = [t["coverage"]["share"] for c in done.values() for t in c["truths"]
           if t["coverage"] and t["coverage"]["n"]]  # fmt: skip
    rows_all = [t for c in done.values() for m in ("truths", "as_run") for t in c[m]]
    n_def = sum(t["definite"]["k"] for t in rows_all)
    n_all = sum(t["definite"]["n"] for t in rows_all)
    n_false = sum(t["false_among_definite"]["k"] for t in rows_all)
    low = [k for k, c in done.items() if at(c, top)["power"]["share"] < 0.9]
    why = {k: (sum(at(c, top)["verdicts"].get(w, 0.0) for w in ("mixed", "restart-dependent")),
               c["noise"]["varying"], c["noise"]["random_failures"]) for k, c in done.items()}
    text = [
        f"**The rule on planted truth** ({pl['replicates']} synthetic comparisons per truth, "
        "each from its comparison's own held-out runs by a seed bootstrap, "
        "analysis/calibration/fair_planted.py). It accepts the truth in at least "
        f"{100 * la['share']:.0f} % of them ({la['k']}/{la['n']}, {100 * la['ci_low']:.1f}-"
        f"{100 * la['ci_high']:.1f} %, {la['comparison'].replace('@raw', '')}; target "
        f"{100 * pl['accept_target']:.0f} %). {n_def:,} of its {n_all:,} verdicts over every "
        f"planted truth and both modes ({100 * n_def / n_all:.0f} %) are definite, and "
        f"{n_false:,} of those {_is(n_false)} false; the rest claim nothing (tie, mixed, "
        "restart-dependent)" + (", so its acceptance is mostly of verdicts that claim nothing"
                                if 2 * n_def < n_all else "")
        + ". The best/best pairing's 95 % interval covers the planted ratio in "
        f"{100 * min(cov):.0f}-{100 * max(cov):.0f} % (a bootstrap of "
        f"{next(iter(done.values()))['noise']['seeds']} seeds).",
        _alike(done, low, top, why) + " " + _as_run(done, top),
        "",
        "Columns (restarts alike): the noise (a seed effect's and a run's own sd, log units). "
        "The cells that always track, those where some level's failures vary over the seeds, "
        "and those where every level fails always or never (failed at every level, not "
        "noise). The share of the four levels' runs failing in the varying cells; the least "
        "acceptance over the planted truths. The share naming each planted ratio (equivalent "
        "inside +-5 %, else higher or lower, or worse or better) and each planted extra "
        "failure probability (fails more). The smallest ratio named in 90 % from there on, "
        "at every planted ratio at least as far from 1.",
        "", *common.md_table(["comparison", "noise sd", "cells", "random failures",
                              "accepts the truth", *[f"{r:g}x" for r in ratios],
                              *[f"fails +{100 * x:g} %" for x in extra], "named from"],
                             rows)]  # fmt: skip
    best = pl.get("best")
    if best:
        by = {b["rho"]: b for b in best["by_rho"]}
        eq = by.get(1.0)
        better = [b for r, b in by.items() if r < 1]
        planted_better = [*better, *best.get("by_fail", [])]
        most = max((b["right"]["share"] for b in planted_better), default=1.0)
        text += ["", f"The best-arm claim, on the {len(best['arms'])} matched arms' own runs "
                 f"({best['noise']['tracked']} cells always tracked). With every arm equal it "
                 f"claims a best in {eq['claims']['k']}/{eq['claims']['n']} replicates."
                 + "".join(f" With one arm {100 * (1 - b['rho']):.0f} % better it claims that "
                           f"arm in {b['right']['k']}/{b['right']['n']} and another in "
                           f"{b['wrong']['k']}." for b in better)
                 + _by_fail(best.get("by_fail", []))
                 + (f" So it seldom names a planted better arm. {_claims_rest(f)}"
                    if most < 0.5 else "")]  # fmt: skip
    return ["\n".join(text)]


def _by_fail(rows: list[dict]) -> str:
    """The best-arm claim with the other arms failing more (a clause, or nothing)."""
    if not rows:
        return ""
    n = rows[0]["claims"]["n"]
    extra = "/".join(f"{100 * b['f']:g}" for b in rows)
    return (f" With every other arm failing in an extra {extra} % of its runs (independent "
            f"runs, not whole plants) it claims the arm that fails less in "
            f"{'/'.join(str(b['right']['k']) for b in rows)} of {n} and another in "
            f"{'/'.join(str(b['wrong']['k']) for b in rows)}.")


def _claims_rest(f: dict) -> str:
    """What the record's best-arm claims rest on, beside a planted study that seldom names a
    planted better arm (at most 20 % better, without whole-cell failures)."""
    out = []
    if f.get("best_determined"):
        by: dict[str, list[str]] = {}
        for n, v in f["against_best"].items():
            by.setdefault(v["verdict"], []).append(n)
        parts = []
        if by.get("fails more"):
            parts.append(f"against {_names(by['fails more'])} on failures, largely whole "
                         "cells where an arm fails at every seed, which no planted truth here "
                         "contains")
        if by.get("higher"):
            parts.append(f"against {_names(by['higher'])} on accuracy: " + ", ".join(
                _gap(f, n) for n in by["higher"]))
        if by.get("worse"):
            parts.append(f"against {_names(by['worse'])} on failures or accuracy, by the "
                         "restarts")
        out.append(f"The held-out claim ({_arm(f['best'])}) rests {'; '.join(parts)}.")
    wt = f.get("where_all_track")
    if wt and wt["best_determined"]:
        r = [v["tuned"]["ratio"] for v in wt["against_best"].values() if v["tuned"]["ratio"]]
        out.append(f"The claim where every arm tracks ({_arm(wt['best'])}) rests on gaps of "
                   f"{min(r):.2f}-{max(r):.2f}x, larger than any planted one: its power there "
                   "is not measured.")
    return " ".join(out)


def _gap(f: dict, name: str) -> str:
    """An arm's ratio to the best, with the planted study's power at the largest planted ratio
    for that comparison (restarts alike) where it has one."""
    r = f"{f['against_best'][name]['tuned']['ratio']:.2f}x"
    c = f["planted"]["comparisons"].get(fair_planted.label(name, f["best"]), {})
    top = max(f["planted"]["ratios"])
    row = next((t for t in c.get("truths", []) if t["rho"] == top and t["f"] == 0), None)
    return r if row is None else (f"{r} (a planted {top:g}x is named there in "
                                  f"{_pc(row['power'])})")


def _cmp(label: str) -> str:
    """A planted comparison's label ("a vs b", arm names) in the arms' labels."""
    a, b = label.split(" vs ")
    return f"{_arm(a)} vs {_arm(b)}"


def _alike(done: dict, low: list[str], top: float, why: dict) -> str:
    """Power with the restarts alike: how many comparisons name the largest planted ratio in
    90 %, and why the others do not."""
    out = (f"With the restarts alike, {len(done) - len(low)} of {len(done)} comparisons name a "
           f"planted {top:g}x in at least 90 % of them.")
    if not low:
        return out
    mixed = [100 * why[k][0] for k in low]
    cells = [why[k][1] for k in low]
    share = [100 * why[k][2] for k in low]
    return (out + f" The other {len(low)} ({', '.join(_cmp(k) for k in low)}) do not: at "
            f"{top:g}x their verdict is 'mixed' or 'restart-dependent' in {min(mixed):.0f}-"
            f"{max(mixed):.0f} %. Each has {min(cells)}-{max(cells)} cells where a level's "
            f"failures vary over the seeds ({min(share):.1f}-{max(share):.1f} % of its runs), and "
            "any failure difference against the accuracy's direction makes a pairing 'mixed'.")


def _as_run(done: dict, top: float) -> str:
    """Power with the restarts as they ran, at the largest planted ratio and at 1.1x: where the
    four pairings' truths straddle the margin only 'restart-dependent' names the truth; where
    they do not, a definite verdict must."""
    def at(rho: float) -> str:
        rows = [t for c in done.values() for t in c["as_run"] if t["rho"] == rho]
        split = [t for t in rows if fair_planted._right("restart-dependent", t["truths"], t["f"])]
        rest = [100 * sum(x for w, x in t["verdicts"].items() if w in fair_planted.DEFINITE
                          and fair_planted._right(w, t["truths"], t["f"]))
                for t in rows if t not in split]  # fmt: skip
        out = f"they straddle it in {len(split)} of {len(rows)} comparisons"
        if split:
            least = min(100 * t["verdicts"].get("restart-dependent", 0.0) for t in split)
            out += f", where 'restart-dependent' names the truth in at least {least:.0f} %"
        if rest:
            said = _listed(sorted(rest))
            out += (f"; in the other {len(rest) if len(rest) > 1 else 'one'} a definite "
                    f"verdict names it in {said} %")
        return out
    return (f"With the restarts as they ran, each pairing has its own truth, and the restarts' "
            f"offsets can put those on both sides of the +-5 % margin. At {top:g}x {at(top)}. "
            f"At 1.1x {at(1.1)}.")


def _listed(xs: list[float]) -> str:
    """Percentages listed (one, or all of them: a range would hide how they spread)."""
    v = [f"{x:.0f}" for x in xs]
    return v[0] if len(set(v)) == 1 else ", ".join(v[:-1]) + f" and {v[-1]}"


def _is(n: int) -> str:
    return "is" if n == 1 else "are"


def _cells(n: int) -> str:
    return "cell" if n == 1 else "cells"


def _resolution(c: dict, ratios: list[float], at) -> str:
    """The smallest planted ratio outside the margin from which on (every ratio at least as
    far from 1, in either direction) the comparison names the truth in at least 90 %; "none"
    otherwise."""
    far = sorted((r for r in ratios if abs(math.log(r)) >= EQUIV), key=lambda r: abs(math.log(r)))
    ok = [at(c, r)["power"]["share"] >= 0.9 for r in far]
    first = next((i for i in range(len(far)) if all(ok[i:])), None)
    return "none" if first is None else f"{far[first]:g}x"
