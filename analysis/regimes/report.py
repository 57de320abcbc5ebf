"""The regime study's verdicts, prose, table and figure, from its record only (issue 22 item 7).

The verdict rule is :mod:`analysis.regimes.rule`'s; here it is applied to the record (which
tuned verdicts are withheld, and why) and written out.
"""

from __future__ import annotations

import numpy as np

from analysis import common
from analysis.regimes import frozen, planted, rule
from analysis.regimes.frozen import frozen_word, inert
from analysis.regimes.pairs import best_label, kinematic, selection_too_close
from analysis.regimes.planted import IA, KEY, span
from analysis.regimes.rule import MIN_PAIRS, _combine, _div, _one, _word, classify
from wmr import controllers

__all__ = ["verdicts", "classify", "notes", "table", "figure", "standing_count", "frozen_word",
           "inert", "MIN_PAIRS"]

BSC = "adaptive-bsc - backstepping"


def _arms_of(record: dict, name: str, pose: str) -> tuple[str, str]:
    if name == KEY:
        b = record["best"][pose]
        return b["best-adaptive"], b["best-fixed"]
    a, b = name.split(" - ")
    return a, b


def _withheld(record: dict, name: str, mech: str, pose: str) -> str | None:
    """Why the tuned verdict of ``name`` on ``mech`` / ``pose`` is withheld (None: it is not)."""
    if mech in record["design"].get("mujoco", ()):
        return "MuJoCo: tuned on kinematic plants; 2 ms physics not converged"
    c = record["contrasts"][name]
    close = selection_too_close(record, pose) if name == KEY else None
    if close:
        return close
    frozen = (record.get("adaptation") or {}).get("arms", {})
    arm, fixed = _arms_of(record, name, pose)
    if arm in frozen and fixed not in frozen:  # an adaptive law against a fixed one
        fw = frozen_word(record, arm, mech, pose)
        if fw == "same within 5 %":
            return (f"{controllers.label(arm)}'s adaptation inert here (frozen, the same within "
                    "5 %): two tunings of fixed laws")  # fmt: skip
        tw = _word(c["tuned"], mech, pose)
        base = tw.split(" ")[0]
        # a divergence edge needs the adaptation's own (frozen: the same word); an RMSE one
        # its direction
        ok = fw == tw if "divergence" in tw else (fw or "").startswith(base)
        if fw is not None and base in ("pays", "costs") and not ok:
            return (f"{controllers.label(arm)}'s adaptation is not shown to {base[:-1]} here "
                    f"(frozen: {fw}): the tuned gains, not the adaptation, may decide it")
    if "restarts" in c:
        words = [_word(c["tuned"], mech, pose)] + [_word(e, mech, pose)
                                                   for e in c["restarts"].values()]
        return (None if len(set(words)) == 1 else
                "restart-dependent (best / best, best / other, other / best, other / other: "
                + ", ".join(words) + ")")  # fmt: skip
    arms = record["tuning"]["arms"][pose]
    bad = [a for a in _arms_of(record, name, pose)
           if a in arms and not arms[a]["agreement"]["agree"]]  # fmt: skip
    return f"tuning restarts disagree ({', '.join(bad)})" if bad else None


def verdicts(record: dict) -> dict:
    """Per mechanism and contrast: the verdict on each pose source (the model's cell estimate
    and that pose's paired divergence test), and the mechanism's (``rule._combine``); beside it
    the ratio averaged over the pose sources; and the same at the shared defaults
    (``"default"``)."""
    out: dict = {"rule": rule.__doc__.split("\n\n", 1)[1].strip(), "mechanisms": {}}
    for m in record["mechanisms"]:
        out["mechanisms"][m] = {}
        for name, c in record["contrasts"].items():
            model = c["tuned"]["model"] or {"cells": {}, "mechanisms": {}}
            poses = {p: _one(model["cells"].get(m, {}).get(p), _div(c, m, p),
                             _withheld(record, name, m, p)) for p in record["poses"]}
            entry = _combine(poses, _one(model["mechanisms"].get(m), 0))
            dm = (c.get("default") or {}).get("model")
            if dm and m in dm.get("cells", {}):
                dp = {p: _one(dm["cells"][m].get(p), _div(c, m, p, "default"))
                      for p in record["poses"] if p in c["default"]}  # fmt: skip
                entry["default"] = _combine(dp, _one(dm.get("mechanisms", {}).get(m), 0))
            out["mechanisms"][m][name] = entry
    return out


def _r(v: dict) -> str:
    if v["ratio"] is None:
        return "no stable pairs"
    lo, hi = v["ratio_ci"]
    return f"{v['ratio']:.3f} [{lo:.3f}, {hi:.3f}], n = {v['n_stable']}"


def _lbl(c: str) -> str:
    return controllers.label(c)


def notes(record: dict) -> str:
    """The section's text, all from the record: the answer first, in short sentences (DESIGN
    §7.8), then the details, their numbers in tables (Markdown; ``analysis.prose``'s rule)."""
    from analysis.regimes import frozen  # (it words its cells by this module's rule)

    blocks = [*_answer(record), _reading(), _defaults(record), planted.said(record),
              planted.said_tuned(record),
              _tracking(record), *_per_pose(record), frozen.notes(record), _interactions(record),
              _tuning(record),
              _extra(record), _rates(record), _recovery(record), _cost(record)]  # fmt: skip
    return "\n\n".join(b for b in blocks if b)


def _answer(record: dict) -> list[str]:
    """The answer (at most six short sentences) and the study's scope (three more)."""
    v = record["verdict"]["mechanisms"]
    words = ("pays", "pays (divergence)", "costs", "costs (divergence)", "same within 5 %",
             "undecided", "depends on the pose source", "withheld")  # fmt: skip

    def at_defaults(name: str) -> dict:
        return {w: [m for m in v if v[m][name].get("default", {}).get("verdict") == w]
                for w in words}  # fmt: skip

    def said(by: dict) -> str:
        return "; ".join(f"{w} on {', '.join(ms)}" for w, ms in by.items() if ms) or "none"

    best = record["best"]
    tot = {}
    for pose in record["poses"]:
        for _m, arms in record["divergence"]["tuned"][pose].items():
            if _m in record["design"].get("mujoco", ()):
                continue  # the kinematic plants' (the MuJoCo robot's are in the table)
            for c, x in arms.items():
                k, n = tot.get(c, (0, 0))
                tot[c] = (k + x["diverged"], n + x["n"])
    order = sorted(tot, key=lambda c: -tot[c][0] / max(tot[c][1], 1))
    d, s = record["design"], record["seeds"]
    ada = _lbl(best["raw"]["best-adaptive"])
    fix = _lbl(best["raw"]["best-fixed"])
    arms = [t for p in record["tuning"]["arms"].values() for t in p.values()]
    n_dis = sum(not t["agreement"]["agree"] for t in arms)
    same = set(at_defaults(IA)["same within 5 %"]) == set(d["mechanisms"])
    if record.get("restart_pairings"):
        answer = _answer_pairings(record, n_dis, len(arms))
    else:  # a record without the runner-up restarts' runs (the earlier rule)
        answer = [
            "**The answer.** At the shared default settings IAPID-NN-DEKF and APID differ only "
            "in the Jacobian.",
            f"There, IAPID-NN-DEKF against APID on the same pose: {said(at_defaults(IA))}.",
            *(["At the paper's SGD rate the identified Jacobian neither pays nor costs; what a "
               "tuned rate does is withheld below."] if same else []),
            f"At the defaults the best adaptive arm ({ada}) against the best fixed one ({fix}): "
            f"{said(at_defaults(KEY))}.",
            f"Tuned verdicts are withheld where an arm's two tuning restarts disagree ({n_dis} "
            f"of {len(arms)} tuned arms, at {d['per_setting']} evaluations per free setting) "
            "and on the MuJoCo robot.",
            "The tuned ratios below are descriptive, not verdicts."]
    adapt = (frozen.pays_said(record), frozen.apid_inert(record), _bsc_said(record))
    scope = [x for x in adapt if x] + [
        "Divergence at the tuned settings on the kinematic plants (10 m bound): "
        + (", ".join(f"{_lbl(c)} {tot[c][0]} of {tot[c][1]}" for c in order if tot[c][0])
           or "none") + ".",
        f"Level '{record['level']}': {s['tuned']} seeds at the tuned settings "
        f"({d['mujoco_seeds']} on the MuJoCo robot, lemniscate only), {s['default']} at the "
        "defaults.",
        "The earlier regime verdicts (cells counted at a rate grid; then tuned contrasts read as "
        "effects of the arms) are retracted.",
    ]
    return [" ".join(answer), " ".join(scope)]


def _standing(v: dict, kin: list[str], name: str, setting: str | None) -> str:
    """The verdicts of ``name`` that stand (not withheld), grouped by word: a mechanism named
    once when both pose sources agree, else per pose source, with the range of the cells'
    ratios; the withheld ones counted."""
    groups: dict = {}
    for m in kin:
        e = v[m][name] if setting is None else v[m][name].get("default")
        if not e:
            continue
        poses = e["poses"]
        if len({x["verdict"] for x in poses.values()}) == 1:
            w = next(iter(poses.values()))["verdict"]
            groups.setdefault(w, []).append((m, [x["ratio"] for x in poses.values()]))
        else:
            for p, x in poses.items():
                groups.setdefault(x["verdict"], []).append((f"{m} ({p})", [x["ratio"]]))
    parts = []
    for w, items in groups.items():
        if w == "withheld":
            continue
        rs = [r for _, rr in items for r in rr if r is not None]
        rng = (f" (ratio {min(rs):.3f}" + (f"–{max(rs):.3f})" if max(rs) != min(rs) else ")")
               if rs and "divergence" not in w else "")  # fmt: skip
        parts.append(f"{w} on {', '.join(lbl for lbl, _ in items)}{rng}")
    held = groups.get("withheld", [])
    n_held = sum(len(rr) for _, rr in held)
    return ("; ".join(parts) or "no verdict stands") + (
        f"; {n_held} (mechanism, pose source) verdicts withheld" if n_held else "")


def standing_count(record: dict) -> tuple[int, int]:
    """How many of the distinct tuned (mechanism, contrast, pose source) verdicts off the
    MuJoCo robot stand (are not withheld), of how many: the best arms' contrast is not counted
    on a pose source where its arms are another contrast's (the same comparison twice)."""
    v, mj = record["verdict"]["mechanisms"], record["design"].get("mujoco", ())
    twice = {p for p, _ in _twice(record)}
    cells = [x for m in v if m not in mj for n, e in v[m].items()
             for p, x in e["poses"].items() if not (n == KEY and p in twice)]  # fmt: skip
    return sum(x["verdict"] != "withheld" for x in cells), len(cells)


def bsc_standing(record: dict) -> str:
    """Tuned Adaptive BSC against BSC, the fixed law it adapts (the matched contrast of an
    adaptive arm whose fixed law is an arm): its standing verdicts (:func:`_standing`), "" for
    a record without that contrast or the restarts' runs."""
    v = record["verdict"]["mechanisms"]
    if not record.get("restart_pairings") or not all(BSC in e for e in v.values()):
        return ""
    kin = kinematic(record)
    return _standing(v, kin, BSC, None)


def _bsc_said(record: dict) -> str:
    said = bsc_standing(record)
    return ("Tuned, Adaptive BSC against BSC (the same law with its adaptation added, each "
            f"tuned): {said}." if said else "")


def _answer_pairings(record: dict, n_dis: int, n_arms: int) -> list[str]:
    """The answer in five sentences for a record with the runner-up restarts' runs: the tuned
    verdicts that stand (with their ratios), the defaults', and how many tuned verdicts the
    restarts leave standing."""
    d, v = record["design"], record["verdict"]["mechanisms"]
    kin = kinematic(record)
    ada, fix = best_label(record, "best-adaptive"), best_label(record, "best-fixed")
    kept, n_cells = standing_count(record)
    mj = " off the MuJoCo robot, where all are withheld" if d.get("mujoco") else ""
    off = frozen.inert_said(record)
    return [
        f"**The answer.** Tuned, the best adaptive arm ({ada}) against the best fixed one "
        f"({fix}): {_standing(v, kin, KEY, None)}."
        + (f" Switched off at its tuned settings, its adaptation changes the RMSE by less than "
           f"5 %: {off} simulated plants." if off else ""),
        f"Tuned, IAPID-NN-DEKF against APID on the same pose: {_standing(v, kin, IA, None)}; "
        f"APID against the fixed PID: {_standing(v, kin, 'adaptive-pid - pid', None)}.",
        "At the shared defaults, where the two differ only in the Jacobian, IAPID-NN-DEKF "
        f"against APID: {_standing(v, kin, IA, 'default')}; APID against the fixed PID there: "
        f"{_standing(v, kin, 'adaptive-pid - pid', 'default')}.",
        f"At the defaults, {ada} against {fix}: {_standing(v, kin, KEY, 'default')}.",
        "A tuned verdict stands only where all four pairings of the two arms' best and "
        "runner-up tuning restarts give it, and the best arms only where the tuning told them "
        "from the runner-up arm. An adaptive law against its fixed one stands only where its "
        "adaptation, switched off at its tuned settings, points the same way. "
        f"{kept} of {n_cells} distinct verdicts stand{mj}{_once(record)} ({n_dis} of "
        f"{n_arms} arms' restarts disagree at {d['per_setting']} evaluations per free "
        "setting)."]


def _twice(record: dict) -> list[tuple[str, str]]:
    """The (pose source, contrast) where the best arms' contrast is another contrast's
    comparison (the same two arms)."""
    return sorted({(p, n) for p in record["poses"] for n in record["contrasts"]
                   if n != KEY and _arms_of(record, KEY, p) == _arms_of(record, n, p)})


def _once(record: dict) -> str:
    """Where the best arms' contrast is another contrast's comparison, which name counts it."""
    twice = _twice(record)
    if not twice:
        return ""
    names = sorted({n for _, n in twice})
    return (f" (the best arms' contrast counted once, as {', '.join(names)}, on "
            f"{', '.join(p for p, _ in twice)})")


def _reading() -> str:
    return ("**How to read the ratios.** A ratio is exp of the model's contrast: log RMSE after "
            "the transient on the both-stable pairs, clustered by seed (Student t at G - 1 df, G "
            "seeds). The trajectories are "
            "fixed effects, so an interval is over seeds on these trajectories. A ratio is "
            "averaged over the pose sources, then given per pose source; n is the count of "
            "both-stable pairs.")


def _ci(e: dict) -> str:
    return f"{e['ratio']:.3f} [{e['ratio_ci'][0]:.3f}, {e['ratio_ci'][1]:.3f}]"


def _defaults(record: dict) -> str:
    """IAPID - APID at the shared defaults (the identifier itself), per mechanism."""
    dm = record["contrasts"][IA]["default"]["model"]
    if not dm:
        return ""
    v = record["verdict"]["mechanisms"]
    rows = [[m, _ci(e), v.get(m, {}).get(IA, {}).get("default", {}).get("verdict", "—")]
            for m, e in dm["mechanisms"].items()]  # fmt: skip
    cov = span(record, IA, "t(G-1)")
    caveat = (f"The model has {dm['clusters']} seeds as clusters"
              + (f"; its interval (Student t at {dm['clusters'] - 1} df) covers planted ratios "
                 f"{cov} of the time at this layout (below)." if cov else
                 (", too few for a cluster-robust interval to be trusted." if dm["clusters"] < 10
                  else "."))
              + " The fit's warnings: "
              + ("; ".join(dict.fromkeys(dm["warnings"])) or "none") + ".")  # fmt: skip
    return "\n".join([
        "**At the defaults** (the same settings for IAPID and APID), IAPID - APID, ratio of "
        "both-stable RMSE with its 95 % interval:", "",
        *common.md_table(["mechanism", "ratio [95 % interval]", "verdict"], rows), "", caveat])


def _tracking(record: dict) -> str:
    """The second endpoint: tracking failure against divergence (tuned settings)."""
    tr = record.get("tracking")
    if not tr:
        return ""
    tot = {}
    for what, src in (("track", tr["counts"]["tuned"]), ("div", record["divergence"]["tuned"])):
        for by in src.values():
            for arms in by.values():
                for c, x in arms.items():
                    k = tot.setdefault(c, {"track": 0, "div": 0, "n": 0})
                    k[what] += x["diverged"]
                    k["n"] += x["n"] if what == "div" else 0
    ch = tr["verdict_changes"]
    said = "; ".join(f"{x['contrast']} on {x['mechanism']} ({x['setting']}): "
                     f"{x['both_stable']} -> {x['both_tracking']}" for x in ch)
    return (f"**Tracking failure.** A run fails to track when it diverges or its RMSE after the "
            f"transient is above {tr['threshold_m']:g} m: {tr['reason']}. "
            + _failed(tot)
            + ("Comparing on both-tracking instead of both-stable pairs changes no verdict."
               if not ch else f"Comparing on both-tracking pairs changes {len(ch)} "
               f"{'verdict' if len(ch) == 1 else 'verdicts'}: "
               + said + ".")
            + " The counts per mechanism and pose, with Clopper-Pearson intervals, are in the "
              "tracking table below.")


def _failed(tot: dict) -> str:
    """Failed to track / diverged per arm; the run count said once where it is common."""
    ns = {t["n"] for t in tot.values()}
    each = (lambda t: "") if len(ns) == 1 else (lambda t: f" of {t['n']}")
    head = f"of {ns.pop()} runs per arm, " if len(ns) == 1 else ""
    return (f"At the tuned settings, {head}failed to track / diverged: "
            + ", ".join(f"{_lbl(c)} {t['track']} / {t['div']}{each(t)}" for c, t in tot.items())
            + ". ")


def _per_pose(record: dict) -> list[str]:
    """The two contrasts of the answer at the tuned settings: per mechanism, the verdict and the
    ratio over both pose sources and on each."""
    v = record["verdict"]["mechanisms"]
    out = []
    for name, what in ((KEY, "best adaptive - best fixed"), (IA, "IAPID - APID")):
        rows = [[m, v[m][name]["verdict"], _r(v[m][name]),
                 *[f"{x['verdict']}: {_r(x)}" for x in v[m][name]["poses"].values()]]
                for m in record["mechanisms"]]  # fmt: skip
        poses = list(v[record["mechanisms"][0]][name]["poses"])
        out.append("\n".join([
            f"**Tuned: {what}**, the verdict and the ratio of both-stable RMSE (95 % interval, "
            "pairs), over both pose sources and on each:", "",
            *common.md_table(["mechanism", "verdict", "both pose sources", *poses], rows)]))
    out[-1] += ("\n\nAPID - PID and oracle - IAPID, with their verdicts, are in the verdict "
                "table below.")
    return out


def _interactions(record: dict) -> str:
    model = record["contrasts"][IA]["tuned"]["model"]
    tests = model["tests"]
    if not (tests["pose_source"] and tests["mechanism"]):
        return "Interaction tests: too few cells."
    return (f"Interactions of IAPID - APID: pose source p = {tests['pose_source']['p']:.3g}, "
            + (f"trajectory p = {tests['trajectory']['p']:.3g}, " if tests["trajectory"] else "")
            + f"mechanism p = {tests['mechanism']['p']:.3g} (cluster-robust Wald F tests over the "
            f"simulated plants, {model['clusters']} clusters; the fit's warnings: "
            f"{len(model['warnings'])})."
            + _apart(tests.get("apart"), record["design"].get("mujoco_seeds")))


def _apart(t: dict | None, seeds: int | None) -> str:
    """The MuJoCo cells' own interaction tests (not pooled with the simulated plants)."""
    if not t:
        return ""
    said = [f"{k.replace('_', ' ')} p = {t[k]['p']:.3g}" for k in ("pose_source", "mechanism")
            if t[k]]  # fmt: skip
    return (f" The MuJoCo cells ({', '.join(t['mechanisms'])}; {seeds} seeds, withheld) are "
            f"tested apart: {', '.join(said) or 'too few cells'}.")


def _extends() -> str:
    """Which tuned arms' free settings begin with another arm's (``tuning.FREE``), by base."""
    from analysis import tuning

    by: dict = {}
    for a, fa in tuning.FREE.items():
        base = [b for b, fb in tuning.FREE.items() if len(fb) < len(fa) and fa[:len(fb)] == fb]
        if base:
            by.setdefault(max(base, key=lambda b: len(tuning.FREE[b])), []).append(a)
    return "; ".join(f"{', '.join(_lbl(a) for a in arms)} on {_lbl(b)}'s"
                     for b, arms in by.items())


def _tuning(record: dict) -> str:
    """Per tuned arm and pose source: its budget (free settings, evaluations), whether its
    restarts agree, and optima on a box edge."""
    rows = []
    for p, arms in record["tuning"]["arms"].items():
        for a, t in arms.items():
            g = t["agreement"]
            rows.append([a, p, str(len(t["free"])), f"{t['evaluations']:,}",
                         f"{'agree' if g['agree'] else 'disagree'} (spread "
                         f"{g['spread']:.3g}, tolerance {g['tolerance']:.3g})",
                         ", ".join(e["setting"] + " " + e["edge"] for e in t["edges"]) or "—"])
    b = record["tuning"]["budget"]
    one = next(iter(next(iter(record["tuning"]["arms"].values())).values()))
    return "\n".join([
        f"**Tuning.** {b['restarts']} restarts per arm and pose source of {b['per_setting']} "
        f"evaluations per free setting, each evaluation {one['runs_per_evaluation']} training "
        "runs. The budget is per setting, not per arm: an arm that extends another's settings "
        f"({_extends()}) searches the shared ones within a larger budget. Restarts disagree "
        "when their spread is above 5 % of the best objective (the tolerance). An optimum on a "
        "box edge names the setting and the edge.", "",
        *common.md_table(["arm", "pose", "free settings", "evaluations", "restarts",
                          "optimum on a box edge"], rows)])


def _extra(record: dict) -> str:
    """Two more contrasts per mechanism: the best adaptive arm against the PID tuned on the test
    mechanism (same budget) and the paper's asymmetric arm."""
    k = record.get("known_pid")
    known = {}
    if k and k["model"]:
        for m, e in k["model"]["mechanisms"].items():
            said = []
            for who, sign in (("the adaptive arm", 1), ("the known-mechanism PID", -1)):
                on = [p for p, d in k["divergence"].items() if m in d and d[m]["p"] < 0.05
                      and sign * (d[m]["a_only"] - d[m]["b_only"]) > 0]  # fmt: skip
                said += [f"{who} diverges more on the {', '.join(on)} pose"] if on else []
            known[m] = _ci(e) + (f" ({'; '.join(said)})" if said else "")
    paper = {}
    for m, x in record["paper_arm"]["endpoints"].items():
        t = [y for y in x["trajectories"].values() if y["n_stable"]]
        if t:
            paper[m] = f"{100 * float(np.median([y['rel_diff'] for y in t])):+.1f} %"
    mechs = [m for m in record["mechanisms"] if m in known or m in paper]
    if not mechs:
        return ""
    lead = [f"**PID tuned on the test mechanism, and the paper's arm.** Column 'vs PID tuned on "
            f"the mechanism': {k['label']}, as the ratio of both-stable RMSE."] if known else [
            "**The paper's arm.**"]  # fmt: skip
    lead.append(f"Column 'paper's arm': {record['paper_arm']['label']}, as the median relative "
                "difference of the both-stable means over trajectories.")
    header = ["mechanism", *(["vs PID tuned on the mechanism"] if known else []), "paper's arm"]
    rows = [[m, *([known.get(m, "—")] if known else []), paper.get(m, "—")] for m in mechs]
    return "\n".join([" ".join(lead), "", *common.md_table(header, rows)])


def _rates(record: dict) -> str:
    from analysis.regimes import rates

    return rates.notes(record.get("rates"))


def _recovery(record: dict) -> str:
    """Per pose source and contrast, the recovery after a change (tuned settings)."""
    rec = record.get("recovery")
    if not rec:
        return ""
    rows = []
    for pose, r in rec["poses"].items():
        n = min(x["n"] for arms in r["arms"].values() for x in arms.values())
        for name in (IA, KEY):
            cells = [x for x in r["contrasts"].get(name, {}).values() if x["n_stable"] > 1]
            if not cells:
                continue
            rel = float(np.median([x["rel_diff"] for x in cells]))
            lower = sum(x["ci_high"] is not None and x["ci_high"] < 0 for x in cells)
            higher = sum(x["ci_low"] is not None and x["ci_low"] > 0 for x in cells)
            rows.append([pose, name, n, len(cells), f"{100 * rel:+.1f} %", lower, higher])
    return "\n".join([
        f"**Recovery** (tuned settings): position RMSE over the {rec['window_s']:g} s after the "
        "payload change or the disturbance's start, on the both-stable pairs. Lower and higher "
        "count the scenarios whose 95 % interval lies below or above 0.", "",
        *common.md_table(["pose", "contrast", "seeds", "scenarios", "median difference",
                          "lower", "higher"], rows)])  # fmt: skip


def _cost(record: dict) -> str:
    c = record["cost"]
    return (f"Cost: {c['runs']:,} evaluation runs, {c['run_seconds_total']:.0f} s of running over "
            f"the invocations that filled the stores. The last invocation ran "
            f"{c['runs_this_time']:,} of them in {c['seconds']:.0f} s (tuning "
            f"{c['tuning_seconds']:.0f} s; an arm tuned before is read back from its cache) on "
            f"{c['engine']}."
            + (" This record was re-derived from those stores without running." if
               c.get("rederived") else ""))  # fmt: skip


def _count_rows(record: dict, counts: dict) -> list[list[str]]:
    """Rows (mechanism, pose, one ``k/n [low, high]`` cell per arm) of a table of event counts
    ``counts[pose][mechanism][arm]`` (divergence, tracking failure)."""
    rows = []
    for m in record["mechanisms"]:
        for pose in record["poses"]:
            arms = counts[pose].get(m, {})
            rows.append([m, pose, *[
                f"{arms[a]['diverged']}/{arms[a]['n']} [{arms[a]['ci_low']:.2f}, "
                f"{arms[a]['ci_high']:.2f}]" if a in arms else "—" for a in record["arms"]]])
    return rows


def table(record: dict) -> str:
    """Per mechanism and arm at the tuned settings: divergence (k/n, Clopper-Pearson) per pose
    source, and the verdicts (``tables/regimes.md``)."""
    header = ["mechanism", "pose", *[_lbl(a) for a in record["arms"]]]
    lines = ["Divergence at the tuned settings (diverged/runs, 95 % Clopper-Pearson):", "",
             *common.md_table(header, _count_rows(record, record["divergence"]["tuned"])),
             ""]  # fmt: skip
    tr = record.get("tracking")
    if tr:
        lines += [f"Tracking failure at the tuned settings (diverged or RMSE after the transient "
                  f"above {tr['threshold_m']:g} m; failed/runs, 95 % Clopper-Pearson):", "",
                  *common.md_table(header, _count_rows(record, tr["counts"]["tuned"])),
                  ""]  # fmt: skip
    v = record["verdict"]["mechanisms"]
    names = list(record["contrasts"])
    lines += ["Verdicts (ratio of both-stable RMSE, 95 % interval, pairs):", "",
              *common.md_table(["mechanism", *names],
                               [[m, *[f"{v[m][n]['verdict']}: {_r(v[m][n])}" for n in names]]
                                for m in record["mechanisms"]])]  # fmt: skip
    return "\n".join(lines) + "\n"


def figure(record: dict):
    """Each contrast's ratio per mechanism with its interval, per pose source (tuned)."""
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter

    names = list(record["contrasts"])
    mechs = record["mechanisms"]
    fig, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names), 0.4 * len(mechs) + 1.8),
                             sharey=True, squeeze=False, layout="constrained")  # fmt: skip
    for ax, n in zip(axes[0], names, strict=True):
        model = record["contrasts"][n]["tuned"]["model"]
        for k, pose in enumerate(record["poses"]):
            for i, m in enumerate(mechs):
                e = (model or {}).get("cells", {}).get(m, {}).get(pose)
                if e:
                    y = i + (k - 0.5) * 0.3
                    ax.plot(e["ratio_ci"], [y, y], "-", color=f"C{k}")
                    ax.plot(e["ratio"], y, "o", color=f"C{k}", label=pose if i == 0 else None)
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())  # (minor labels overlap on short ranges)
        ax.set_title(n, fontsize=8)
        ax.set_xlabel("RMSE ratio a / b (both stable)")
    axes[0, 0].set_yticks(range(len(mechs)), mechs, fontsize=7)
    axes[0, 0].legend(fontsize=7)
    return fig
