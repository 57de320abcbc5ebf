"""The adaptation switched off: each adaptive arm at its tuned settings with its adaptation
frozen (:data:`analysis.regimes.design.FROZEN`), against itself adapting, seed by seed.

The hostile audit of the full record found DA-NN's tuned adaptation inert on the filtered pose
(its filter's ``q`` at the floor, ``r`` near the ceiling: frozen, it tracked the same, 3.238 vs
3.238 mm), so "best adaptive against best fixed" there compared two tunings of fixed laws.  The
run level ``tuned-frozen`` answers it for every adaptive arm, mechanism and pose source: the
contrast "arm - arm frozen" (the same arm, the same tuned settings and seeds; the adaptation
alone differs) goes through the study's contrast model and verdict rule
(``analysis.regimes.report``); an adaptive law's tuned verdict against a fixed one is withheld
where its adaptation is inert or, frozen, does not point the verdict's way
(``report._withheld``; :func:`frozen_word`).

Only each arm's best tuning restart is frozen: the contrast is a property of that tuned setting.
"""

from __future__ import annotations

from collections.abc import Mapping

from analysis import common
from analysis.regimes import design
from analysis.regimes import stats as rstats
from analysis.regimes.pairs import POSES, endpoints, kinematic, pairs_of, stable
from analysis.regimes.rule import _word
from wmr import controllers

__all__ = ["LEVEL", "tables", "analyse", "notes", "frozen_word", "plants_where", "inert",
           "inert_said", "pays_said", "apid_inert"]

#: The run level of the frozen arms.
LEVEL = "tuned-frozen"


def tables(tuned: Mapping[str, Mapping]) -> dict[str, dict]:
    """The adaptive arms' settings tables with the adaptation frozen: each arm's tuned table
    (``tuned``: arm -> table) with :data:`~analysis.regimes.design.FROZEN` written over it."""
    return {c: {**t, **design.FROZEN[c]} for c, t in tuned.items() if c in design.FROZEN}


def analyse(rows, mechs: list[str], trajs: list[str]) -> dict | None:
    """Per adaptive arm run frozen: "arm - arm frozen" at the tuned settings (level "tuned"
    against :data:`LEVEL`), its paired endpoints per pose source and the contrast model; None
    without frozen runs."""
    frozen = rows[rows.level == LEVEL]
    if frozen.empty:
        return None
    out: dict = {"level": LEVEL, "frozen": design.FROZEN, "arms": {}}
    for c in dict.fromkeys(frozen.controller):
        p = pairs_of(rows, c, c, {pose: {} for pose in POSES}, ("tuned", LEVEL))
        e: dict = {pose: endpoints(p[p.pose == pose], mechs, trajs) for pose in POSES}
        ok = stable(p)
        e["model"] = (rstats.contrast_model(ok, apart=tuple(design.MUJOCO)) if len(ok) > 2
                      else None)  # fmt: skip
        out["arms"][c] = e
    return out


def notes(record: dict) -> str:
    """The paragraph and table: each adaptive arm's adaptation against none, per mechanism and
    pose source (the verdict word and the ratio adapting / frozen)."""
    ad = record.get("adaptation")
    if not ad:
        return ""
    rows = []
    for c, e in ad["arms"].items():
        cells = (e["model"] or {"cells": {}})["cells"]
        for pose in record["poses"]:
            line = [controllers.label(c), pose]
            for m in record["mechanisms"]:
                x = cells.get(m, {}).get(pose)
                w = frozen_word(record, c, m, pose)
                line.append("—" if x is None else f"{x['ratio']:.3f} ({_short(w)})")
            rows.append(line)
    said = inert_said(record)
    return "\n".join([
        "**The adaptation switched off.** Each adaptive arm at its tuned settings with its "
        "adaptation frozen, against itself adapting (the same settings and seeds; "
        "`analysis.regimes.frozen`). A ratio below 1 means the adaptation pays given the "
        "initial gains the tuning chose for the adapting arm; against a tuned fixed law it is "
        "APID - PID, Adaptive BSC - BSC and best adaptive - best fixed. The best adaptive arm's "
        f"adaptation is inert (the same within 5 % frozen) {said} simulated plants. An "
        "adaptive law's verdict against a fixed one is withheld where its adaptation is inert "
        "or, frozen, does not point the verdict's way. Only each arm's best restart is "
        "frozen.", "",
        *common.md_table(["arm", "pose", *record["mechanisms"]], rows)])


def frozen_word(record: dict, arm: str, mech: str, pose: str) -> str | None:
    """The verdict word of "``arm`` - ``arm`` frozen" at the tuned settings on ``mech`` /
    ``pose`` (``analysis.regimes.frozen``), or None where the record has no frozen runs of
    it."""
    e = (record.get("adaptation") or {}).get("arms", {}).get(arm)
    return _word(e, mech, pose) if e and mech in e.get(pose, {}) else None


def plants_where(record: dict, arm: str, pose: str, word: str) -> list[str]:
    """The simulated plants where ``arm`` against itself switched off at its tuned settings
    says ``word`` ("pays" and "costs" with or without divergence; "same" for "same within
    5 %": the adaptation inert there)."""
    return [m for m in kinematic(record)
            if (frozen_word(record, arm, m, pose) or "").startswith(word)]


def inert(record: dict) -> dict[str, tuple[str, list[str], int]]:
    """Per pose source: the best adaptive arm, the simulated plants where its adaptation is
    inert (switched off at its tuned settings, the same within 5 %), and how many simulated
    plants there are; empty without frozen runs."""
    if not record.get("adaptation"):
        return {}
    n = len(kinematic(record))
    return {p: (a, plants_where(record, a, p, "same"), n)
            for p in record["poses"] for a in [record["best"][p]["best-adaptive"]]}


def inert_said(record: dict) -> str:
    """The best adaptive arms' inert plants counted, per pose source ("" without)."""
    return "; ".join(f"{controllers.label(a)} ({p}) on {len(ms)} of {n}"
                     for p, (a, ms, n) in inert(record).items())  # fmt: skip


def pays_said(record: dict) -> str:
    """Per adaptive arm with frozen runs: on how many simulated plants its adaptation pays
    against itself switched off (with or without divergence), per pose source ("" without
    frozen runs)."""
    arms = (record.get("adaptation") or {}).get("arms", {})
    parts = [f"{controllers.label(a)} " + ", ".join(
        f"{len(plants_where(record, a, p, 'pays'))} {p}" for p in record["poses"])
        for a in arms]  # fmt: skip
    if not parts:
        return ""
    return ("Against itself switched off at its tuned settings (the matched contrast of "
            f"adaptation alone), adaptation pays on this many of the {len(kinematic(record))} "
            "simulated plants per pose source: " + "; ".join(parts) + ".")


def apid_inert(record: dict) -> str:
    """Where APID's adaptation is inert (frozen, the same within 5 %), IAPID-NN-DEKF against
    APID sets the identifier's adaptation against APID's tuned gains held fixed ("" where it
    is nowhere inert or the record has no frozen runs of it)."""
    n = {p: plants_where(record, "adaptive-pid", p, "same") for p in record["poses"]}
    said = "; ".join(f"{p}: {', '.join(ms)}" for p, ms in n.items() if ms)
    return (f"Where APID's own adaptation is inert (frozen, the same within 5 %; {said}), "
            "IAPID-NN-DEKF against APID sets the identifier's adaptation against APID's tuned "
            "gains held fixed, not against a working adaptation." if said else "")


def _short(word: str) -> str:
    return {"same within 5 %": "same", "costs (divergence)": "costs, div.",
            "pays (divergence)": "pays, div."}.get(word, word)
