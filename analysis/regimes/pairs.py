"""The regime study's pairs: two arms' runs aligned seed by seed (the unit of every paired
endpoint and of the contrast model), the best arms per pose source, and each mechanism's paired
endpoints."""

from __future__ import annotations

import numpy as np

from analysis.regimes import stats as rstats
from wmr import controllers

__all__ = ["FIXED", "ADAPTIVE", "POSES", "PAIRINGS", "best_arm", "pairs_of", "paper_pairs",
           "kinematic",
           "join", "stable", "model_frame", "endpoints", "best_label",
           "selection_too_close"]

FIXED = ("pid", "backstepping", "nmpc")
ADAPTIVE = ("adaptive-pid", "iapid-nn-dekf", "adaptive-nn", "adaptive-bsc")
POSES = ("raw", "filtered")


def best_arm(tuned: dict, pose: str, arms) -> str:
    """The arm of ``arms`` (those tuned) with the lowest training objective on ``pose``."""
    return min((c for c in arms if c in tuned[pose]), key=lambda c: tuned[pose][c]["objective"])


#: The pairings of the two arms' tuning restarts beside (best, best), which is level "tuned":
#: (a's level, b's level), "tuned-other" being each arm's runner-up restart.
PAIRINGS = (("tuned", "tuned-other"), ("tuned-other", "tuned"), ("tuned-other", "tuned-other"))


def pairs_of(rows, a: str, b: str, best: dict, levels: tuple[str, str] | None = None):
    """Both arms' runs aligned on (level, pose, mechanism, trajectory, seed); with ``levels``
    (a's, b's), a's runs at the first level against b's at the second, labelled "tuned"."""
    key = ["level", "pose", "mechanism", "trajectory", "seed"]
    parts = []
    for pose in POSES:
        ca = best[pose].get(a, a)
        cb = best[pose].get(b, b)
        x = rows[(rows.pose == pose) & (rows.controller == ca)]
        y = rows[(rows.pose == pose) & (rows.controller == cb)]
        if levels:
            x = x[x.level == levels[0]].assign(level="tuned")
            y = y[y.level == levels[1]].assign(level="tuned")
        parts.append(join(x.set_index(key), y.set_index(key)))
    import pandas as pd

    return pd.concat(parts, ignore_index=True)


def paper_pairs(rows):
    """The paper's asymmetric arm: IAPID on the filtered pose against APID on the raw pose
    (``pose_source = "paper"`` gives each exactly these poses), at the defaults."""
    key = ["mechanism", "trajectory", "seed"]
    r = rows[rows.level == "default"]
    x = r[(r.pose == "filtered") & (r.controller == "iapid-nn-dekf")].set_index(key)
    y = r[(r.pose == "raw") & (r.controller == "adaptive-pid")].set_index(key)
    return join(x, y)


def join(x, y):
    """Runs of arm a (``x``) and arm b (``y``) on the same index: ``*_a`` and ``*_b`` columns."""
    cols = ["tail_position", "failed"]
    return x[cols].add_suffix("_a").join(y[cols].add_suffix("_b"), how="inner").reset_index()


def stable(p):
    """The both-stable pairs of ``p`` (:func:`join`'s columns) with their ``delta`` = log r_a -
    log r_b: the model's frame."""
    ok = p[~p.failed_a & ~p.failed_b & (p.tail_position_a > 0) & (p.tail_position_b > 0)].copy()
    ok["delta"] = np.log(ok.tail_position_a) - np.log(ok.tail_position_b)
    return ok


def model_frame(rows, tuned: dict, contrast: tuple[str, str], level: str):
    """The model's frame of ``contrast`` (a, b) at ``level`` ("tuned", "default"): the
    both-stable pairs of every pose source with ``delta``."""
    best = {pose: {"best-adaptive": best_arm(tuned, pose, ADAPTIVE),
                   "best-fixed": best_arm(tuned, pose, FIXED)} for pose in POSES}
    p = pairs_of(rows, *contrast, best)
    return stable(p[p.level == level])


def endpoints(p, mechs, trajs) -> dict:
    """Per mechanism: paired divergence (the seed sign-flip test over its trajectories and
    seeds, McNemar beside it) and the RMSE on both-stable pairs per trajectory."""
    out = {}
    for m in mechs:
        pm = p[p.mechanism == m]
        if pm.empty:
            continue
        out[m] = {"divergence": rstats.paired_failures(pm.failed_a, pm.failed_b, pm.seed),
                  "trajectories": {}}
        for t in trajs:
            q = pm[pm.trajectory == t]
            if not q.empty:
                out[m]["trajectories"][t] = rstats.pair_rmse(
                    q.tail_position_a, q.failed_a, q.tail_position_b, q.failed_b)
    return out


def best_label(record: dict, key: str) -> str:
    """The best arm ``key`` ("best-adaptive", "best-fixed") by pose source, named once if the
    same on both."""
    by = {p: controllers.label(record["best"][p][key]) for p in record["poses"]}
    if len(set(by.values())) == 1:
        return next(iter(by.values()))
    return " / ".join(f"{c} ({p})" for p, c in by.items())


def selection_too_close(record: dict, pose: str) -> str | None:
    """Why the best adaptive or best fixed arm on ``pose`` is not a choice the tuning made (the
    runner-up arm's training objective is closer to the best's than either arm's own restarts
    are to each other), or None; only in a record with the runner-up restarts' runs."""
    if not record.get("restart_pairings"):
        return None
    arms = record["tuning"]["arms"][pose]
    for family in (ADAPTIVE, FIXED):
        ranked = sorted((c for c in family if c in arms), key=lambda c: arms[c]["objective"])
        if len(ranked) < 2:
            continue
        a, b = ranked[:2]
        margin = arms[b]["objective"] - arms[a]["objective"]
        spread = max(arms[a]["agreement"]["spread"], arms[b]["agreement"]["spread"])
        if margin < spread:
            la, lb = controllers.label(a), controllers.label(b)
            return (f"best arm not chosen by the tuning ({la} over {lb} by {margin:.4f}, "
                    f"restart spread {spread:.4f})")
    return None


def kinematic(record: dict) -> list[str]:
    """The record's simulated plants (its mechanisms off the MuJoCo robot), in order."""
    return [m for m in record["mechanisms"] if m not in record["design"].get("mujoco", ())]
