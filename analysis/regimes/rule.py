"""The regime study's verdict rule: one contrast's word on one pose source, and the
mechanism's word from its pose sources' (``analysis.regimes.report`` applies it to the record,
``analysis.regimes.coverage`` to planted truth).

A mechanism's verdict on a contrast ``a - b`` (tuned settings, the model's estimate averaged
per pose source, as the ratio of the both-stable RMSEs ``exp(log r_a - log r_b)``):

On each pose source (the model's cell estimate):

- ``"withheld"`` (tuned settings only): the verdict is not the same word at every pairing of
  the two arms' tuning restarts (each arm at its best and at its runner-up restart: four
  pairings, the record's ``restart_pairings`` beside the tuned one; the tuned contrast would
  otherwise measure how well each arm's tuning went, not the arms); in a record without the
  runner-up runs, whenever either arm's restarts disagree; or the mechanism is a MuJoCo robot
  (the arms were tuned on kinematic training plants, the PID family's tuned gains do not track
  there, and the 2 ms physics step is not converged: the robot ladder's audit);
- ``"costs (divergence)"``: ``a`` diverges significantly more often than ``b`` (the exact
  sign-flip test over the seeds at 0.05, ``stats.paired_failures``); ``"pays (divergence)"``:
  ``b`` does;
- ``"same within 5 %"``: else, the 95 % interval of the ratio lies inside ``[1/1.05, 1.05]``
  (a difference that exists but is smaller than the margin is "the same" in practice);
- ``"pays"``: else, the interval lies below 1; ``"costs"``: above 1;
- ``"undecided"``: otherwise, or fewer than ``MIN_PAIRS`` = 6 both-stable pairs.

The mechanism's verdict is the pose sources' common word.  Where they differ: a decided word
(not "undecided" or "withheld") that stands on some pose sources while the others are
undecided or withheld is given with the pose sources named (``"same within 5 % (raw; undecided
on filtered)"``); two decided words that can both hold of one ratio (``"same within 5 %"`` and
``"pays"`` of 0.97, say) are both given, by pose source; only words that contradict (a
"pays" against a "costs") give ``"depends on the pose source"``.  (Before, any difference gave
it: a planted ratio of 1 then read "depends on the pose source" 28 % of the time, where one
pose source's interval was merely wider.)
The same rule at the shared default settings (no tuning: nothing withheld for it) is the
``"default"`` verdict beside each tuned one; for IAPID - APID it is the verdict on the
identifier itself (the arms then differ only in the Jacobian).
"""

from __future__ import annotations

__all__ = ["MIN_PAIRS", "classify", "compatible", "contradict", "_combine", "_one", "_div",
           "_word"]

#: Fewest both-stable pairs behind a verdict (fewer: "undecided"; a cell's interval from the
#: model's pooled clusters is not evidence about two or three pairs).
MIN_PAIRS = 6
#: The words that decide nothing.
OPEN = ("undecided", "withheld")


def _div(c: dict, mech: str, pose: str, setting: str | None = "tuned") -> int:
    """+1 when a diverges significantly more often than b on ``mech`` and ``pose`` (the seed
    sign-flip test at 0.05), -1 when b does, 0 otherwise (``setting`` None: ``c`` is one
    level's)."""
    d = (c if setting is None else c[setting])[pose].get(mech, {}).get("divergence")
    if not (d and d["p"] < 0.05):
        return 0
    return 1 if d["a_only"] > d["b_only"] else -1 if d["b_only"] > d["a_only"] else 0


def _div_worse(c: dict, mech: str, pose: str) -> bool:
    """Whether a diverges significantly more often than b on ``mech`` and ``pose`` (tuned)."""
    return _div(c, mech, pose) > 0


def classify(est: dict | None, div_worse, margin: float = 0.05) -> str:
    """The verdict word (see the module) from the model's estimate ``est`` (``ratio_ci``) and
    the paired divergence (``div_worse``: +1 / True a diverges more, -1 b does, 0 / False)."""
    if div_worse is True or div_worse == 1:
        return "costs (divergence)"
    if div_worse == -1:
        return "pays (divergence)"
    if est is None or est["n"] < MIN_PAIRS:
        return "undecided"
    lo, hi = est["ratio_ci"]
    if lo > 1 / (1 + margin) and hi < 1 + margin:
        return "same within 5 %"
    if hi < 1.0:
        return "pays"
    if lo > 1.0:
        return "costs"
    return "undecided"


def _one(est: dict | None, worse, withheld: str | None = None) -> dict:
    return {"verdict": "withheld" if withheld else classify(est, worse),
            "withheld": withheld, "diverges_more": worse == 1 or worse is True,
            "ratio": None if est is None else est["ratio"],
            "ratio_ci": None if est is None else est["ratio_ci"],
            "n_stable": 0 if est is None else est["n"]}  # fmt: skip


def _word(level: dict, mech: str, pose: str) -> str:
    """The verdict word of one pairing's contrast entry (``level``: its poses and model)."""
    model = level["model"] or {"cells": {}}
    return classify(model["cells"].get(mech, {}).get(pose), _div(level, mech, pose, None))


def compatible(word: str, ratio: float, margin: float = 0.05) -> bool:
    """Whether ``word`` (of one pose source) holds of a true ratio ``ratio`` (the planted
    truth): "pays" of a ratio below 1, "costs" above, "same within 5 %" inside the margin; a
    word that decides nothing (:data:`OPEN`) holds of any."""
    if word in OPEN:
        return True
    if word.startswith("pays"):
        return ratio < 1.0
    if word.startswith("costs"):
        return ratio > 1.0
    if word == "same within 5 %":
        return 1 / (1 + margin) < ratio < 1 + margin
    raise ValueError(f"not a pose source's verdict word: {word!r}")


def contradict(words) -> bool:
    """Whether decided pose-source words cannot hold of one ratio: a "pays" beside a "costs"
    (with or without "(divergence)"), or "same within 5 %" beside a divergence word (a
    significant divergence difference is no sameness)."""
    w = set(words) - set(OPEN)
    pays = any(x.startswith("pays") for x in w)
    costs = any(x.startswith("costs") for x in w)
    div = any("divergence" in x for x in w)
    return (pays and costs) or (div and "same within 5 %" in w)


def _combine(poses: dict, mean: dict) -> dict:
    """The mechanism's entry: ``mean`` (its pose-averaged estimate) with the verdict combined
    from the pose sources' (``poses``: pose -> :func:`_one`) by the module's rule."""
    words = {p: v["verdict"] for p, v in poses.items()}
    kinds = list(dict.fromkeys(words.values()))
    decided = [w for w in kinds if w not in OPEN]
    if len(kinds) == 1:
        verdict = kinds[0]
    elif contradict(decided):
        verdict = "depends on the pose source"
    else:
        main = decided[0] if decided else "undecided"
        where = ", ".join(p for p, w in words.items() if w == main)
        rest = "; ".join(f"{w} on {p}" for p, w in words.items() if w != main)
        verdict = f"{main} ({where}; {rest})"
    mean["verdict"] = verdict
    mean["diverges_more"] = any(v["diverges_more"] for v in poses.values())
    return {**mean, "poses": poses}
