"""When does adaptation pay?  The regime study (issue 14).

A factorial over what the paper left unvaried, run through the sweep engine (``wmr.sweep``):

- the **plant mechanism** (``wmr.plant``): the ideal unicycle, a 20 % wheel-radius error,
  unequal wheels, 100 ms actuator lag plus a 2-sample delay, an outward lateral skid in turns
  (``slip``, DESIGN §3.3), and a payload on a lagged velocity loop (an inner velocity loop whose
  ~50 ms lag grows to ~75 ms when the mass grows 50 % at 20 s) (the shipped ``lemniscate-*``
  scenarios' plants);
- the **SGD rate** as read by the step: mu in {0.9, 9} with the plant Jacobian per step or per
  second (``jacobian_scale``), i.e. 1x, 10x, 100x and 1000x the paper's per-step reading;
- the **initial PID gains**: good (the suite's default) or weak (a fifth of them);
- the **pose-EKF process noise** (0.01, the default, or 0.003 per step);
- the paper's three **trajectories**;

with 20 seeds and common random numbers (a seed gives every arm the same noise), and six arms:
the fixed PID, APID (SGD with the model Jacobian), IAPID-NN-DEKF, the oracle IAPID (its
identifier trained on the true poses: what the estimation noise costs), backstepping and DA-NN.
Nothing is tuned: every setting comes from the factorial.

Outcome per run: the position RMSE after the initial transient (``t >= 5 s``); beside it the
control effort, the recovery after the payload change or the disturbance, and the quality of
the Jacobian the SGD step used against the true robot's one-step Jacobian (``wmr.measures``).
Per cell (a combination of the factors): mean +- std of each arm; paired Wilcoxon tests of
IAPID vs APID, APID vs the fixed PID, IAPID vs the fixed PID and the oracle vs IAPID, Holm-adjusted
within the cell; TOST of IAPID vs APID at :data:`MARGIN`; a bootstrap interval of each tested
difference; and the arm with the lowest mean.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

from analysis import common
from wmr import controllers, stats, sweep
from wmr import scenario as scn

__all__ = ["STEM", "TITLE", "ARMS", "MECHANISMS", "MARGIN", "run", "check", "render", "table",
           "cells"]  # fmt: skip

STEM = "regimes"
TITLE = "When does adaptation pay? Regimes of plant, learning rate, gains and noise"
#: The arms, in table order; the PID family shares the factors of the SGD step.
ARMS = ("pid", "adaptive-pid", "iapid-nn-dekf", "iapid-oracle", "backstepping", "adaptive-nn")
PID_FAMILY = ARMS[:4]
#: Plant mechanisms: the ``[plant]`` of each (the shipped lemniscate-* scenarios' plants): "slip"
#: skids outward (``v_s = -slip v w``; the committed record's slip cells were run with the
#: earlier inward sign, DESIGN §3.3), "payload" is a payload on a lagged velocity loop.
MECHANISMS = {
    "ideal": "",
    "wheel-radius": "[plant]\nv_gain = 0.8\nw_gain = 0.8\n",
    "wheel-asymmetry": "[plant]\nv_from_w = 0.0075\nw_from_v = 0.3333333333333333\n",
    "lag-delay": "[plant]\nactuator_tau = 0.1\ndelay_steps = 2\n",
    "slip": "[plant]\nslip = 0.1\n",
    "payload": ('[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\nmass = 10.0\n'
                "inertia = 0.5\n"
                "friction = [0.5, 0.02]\n[[plant.change]]\nat = 20.0\nmass = 15.0\n"
                "inertia = 0.75\n"),
}  # fmt: skip
#: The SGD rate readings: (label, mu, jacobian_scale); "x1" is the paper's per-step reading.
RATES = (("x1", 0.9, "step"), ("x10", 9.0, "step"), ("x100", 0.9, "second"),
         ("x1000", 9.0, "second"))  # fmt: skip
#: Initial PID gains (Kpv, Kiv, Kdv, Kpw, Kiw, Kdw): the default, and a fifth of it.
GAINS = {"good": (5.0, 5.0, 0.0, 10.0, 2.0, 0.0), "weak": (1.0, 1.0, 0.0, 2.0, 0.4, 0.0)}
PROCESS_STD = (0.01, 0.003)
SEEDS = 20
#: The outcome given to a diverged run [m]: the scenarios' divergence bound (its error exceeded it).
DIVERGED = 10.0
#: Equivalence margin of IAPID vs APID on the after-transient position RMSE [m].
MARGIN = 1e-3
ALPHA = 0.05
#: The tested pairs of a cell: (a, b); the difference is a - b (negative: a is better).
PAIRS = (("iapid-nn-dekf", "adaptive-pid"), ("adaptive-pid", "pid"), ("iapid-nn-dekf", "pid"),
         ("iapid-oracle", "iapid-nn-dekf"))  # fmt: skip
CELL_KEYS = ("mechanism", "trajectory", "rate", "gains", "process_std")


def _design(quick: bool) -> dict:
    if quick:
        return {"mechanisms": ("ideal", "wheel-radius"), "trajectories": ("sinusoid",),
                "rates": RATES, "gains": ("good", "weak"), "process_std": PROCESS_STD[:1],
                "seeds": 3, "duration": 8.0}  # fmt: skip
    return {"mechanisms": tuple(MECHANISMS), "trajectories": scn.PAPER_SCENARIOS,
            "rates": RATES, "gains": tuple(GAINS), "process_std": PROCESS_STD,
            "seeds": SEEDS, "duration": None}  # fmt: skip


def _write_specs(folder: Path, d: dict) -> tuple[Path, Path]:
    """The scenario files (trajectory x mechanism) and the two specs: the PID family over the
    SGD and noise factors, and backstepping and DA-NN (which use neither)."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for traj, mech in itertools.product(d["trajectories"], d["mechanisms"]):
        text = scn.builtin(traj).read_text().replace(f'name = "{traj}"', f'name = "{traj}@{mech}"')
        if d["duration"]:
            text = text.replace("duration = 40.0", f"duration = {d['duration']}")
        (folder / f"{traj}@{mech}.toml").write_text(text + "\n" + MECHANISMS[mech])
        names.append(f"{traj}@{mech}.toml")
    head = (f'scenarios = {names}\nseeds = {d["seeds"]}\nmeasures = ["jacobian", "recovery"]\n')
    rates = [r for r in d["rates"]]
    family = (f'name = "regimes-pid-family"\ncontrollers = {list(PID_FAMILY)}\n{head}'
              '[design]\nkind = "grid"\n[factors]\n'
              f'"controllers.*.mu" = {sorted({r[1] for r in rates})}\n'
              f'"controllers.*.jacobian_scale" = {sorted({r[2] for r in rates})}\n'
              f'"controllers.*.gains" = {[list(GAINS[g]) for g in d["gains"]]}\n'
              f'"estimator.process_std" = {list(d["process_std"])}\n')  # fmt: skip
    others = (f'name = "regimes-others"\ncontrollers = ["backstepping", "adaptive-nn"]\n{head}')
    (folder / "family.toml").write_text(family.replace("'", '"'))
    (folder / "others.toml").write_text(others.replace("'", '"'))
    return folder / "family.toml", folder / "others.toml"


def _store(out: Path, quick: bool) -> Path:
    """Where the sweeps' stores live: beside nothing that is committed (the studies' folder's
    ``regimes/``); an interrupted study resumes, a store of another design or of other code is
    set aside and rebuilt (``wmr.engine.sweeps``)."""
    from wmr.engine.store import studies_folder

    return Path(out) / ".regimes-store" if quick else studies_folder() / STEM


def _frame(stores: list[Path], d: dict):
    """Both stores' rows as one DataFrame with the cell columns."""
    import pandas as pd

    # in job order (a store's shards follow completion order): the cells in the design's order
    rows = pd.concat([sweep.read_rows(s).to_pandas().sort_values("job_id", kind="stable")
                      for s in stores], ignore_index=True)  # fmt: skip
    parts = rows.scenario.str.split("@", expand=True)
    rows["trajectory"], rows["mechanism"] = parts[0], parts[1]
    by_rate = {(m, s): label for label, m, s in RATES}
    fam = rows.controller.isin(PID_FAMILY)
    rows["rate"] = "-"
    rows.loc[fam, "rate"] = [by_rate[(m, s)] for m, s in zip(
        rows.loc[fam, "controllers.*.mu"], rows.loc[fam, "controllers.*.jacobian_scale"],
        strict=True)]  # fmt: skip
    gains = {str(tuple(v)): k for k, v in GAINS.items()}
    rows["gains"] = rows["controllers.*.gains"].map(gains).fillna("-")
    rows["process_std"] = rows["estimator.process_std"].fillna(-1.0)
    return rows


def _cell(rows, others, key: dict, seeds: int) -> dict:
    """One cell's record: each arm's outcomes over the seeds and the tested differences."""
    ok = rows[(rows.status == "ok")]
    arms = {c: ok[ok.controller == c].sort_values("seed") for c in PID_FAMILY}
    base = others[(others.mechanism == key["mechanism"])
                  & (others.trajectory == key["trajectory"])]  # fmt: skip
    for c in ("backstepping", "adaptive-nn"):
        arms[c] = base[(base.controller == c) & (base.status == "ok")].sort_values("seed")
    rec = {**key, "arms": {}}
    for c, a in arms.items():
        rec["arms"][c] = {
            "n": int(len(a)), "diverged": int(a.diverged.sum()),
            "tail_mean": _num(a.tail_position.mean()), "tail_std": _num(a.tail_position.std()),
            "tail_median_with_diverged": _num(a.tail_position.where(~a.diverged, DIVERGED)
                                              .median()),
            "effort_mean": _num(a.effort.mean()),
            "recovery_mean": _num(a.recovery_rmse.mean()),
            **({"jac_rel_error_median": _num(a.jac_rel_error.median()),
                "jac_norm_ratio_median": _num(a.jac_norm_ratio.median()),
                "jac_sign_v_mean": _num(a.jac_sign_v.mean()),
                "jac_sign_w_mean": _num(a.jac_sign_w.mean())}
               if c in ("adaptive-pid", "iapid-nn-dekf", "iapid-oracle") else {}),
        }  # fmt: skip
    # a diverged run counts with the divergence bound as its error: worse than every run that
    # stayed within it (the rank tests do not depend on the value; TOST cannot call it equal)
    series = {c: a.set_index("seed").tail_position.where(~a.set_index("seed").diverged,
                                                         DIVERGED).reindex(range(seeds))
              .to_numpy() for c, a in arms.items()}  # fmt: skip
    tests, pvalues = {}, []
    for a, b in PAIRS:
        d = series[a] - series[b]
        p = stats.wilcoxon(d) if np.sum(np.isfinite(d) & (d != 0)) else 1.0
        pvalues.append(p)
        lo, hi = stats.bootstrap_mean_diff_ci(series[a], series[b], seed=0)
        tests[f"{a} - {b}"] = {"mean_diff": _num(np.nanmean(d)), "ci_low": lo, "ci_high": hi,
                               "rel_diff": _num(np.nanmean(d) / np.nanmean(series[b])),
                               "p": p}  # fmt: skip
    for t, q in zip(tests.values(), stats.holm(pvalues), strict=True):
        t["p_holm"] = q
        t["significant"] = bool(q < ALPHA)
    eq = stats.tost(series["iapid-nn-dekf"], series["adaptive-pid"], MARGIN, ALPHA)
    rec["tests"] = tests
    rec["tost_iapid_apid"] = eq.to_json()
    means = {c: np.nanmean(series[c]) for c in ARMS}
    rec["best"] = min(means, key=means.get)
    return rec


def _num(x) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def cells(rows, d: dict) -> list[dict]:
    """Every cell of the design (the PID family's factors x mechanism x trajectory)."""
    fam = rows[rows.controller.isin(PID_FAMILY)]
    others = rows[~rows.controller.isin(PID_FAMILY)]
    out = []
    for key, group in fam.groupby(list(CELL_KEYS), sort=False):
        out.append(_cell(group, others, dict(zip(CELL_KEYS, key, strict=True)), d["seeds"]))
    return out


def classify(c: dict) -> str:
    """IAPID vs APID in cell ``c``: ``"equivalent"`` when TOST puts the mean difference within
    the margin (a real but sub-margin difference is still "the same" in practice), else
    ``"better"`` / ``"worse"`` when the Holm-adjusted Wilcoxon test is significant, else
    ``"undecided"``."""
    t = c["tests"]["iapid-nn-dekf - adaptive-pid"]
    if c["tost_iapid_apid"]["equivalent"]:
        return "equivalent"
    if t["significant"]:
        return "better" if t["mean_diff"] < 0 else "worse"
    return "undecided"


def verdict(cs: list[dict]) -> dict:
    """Counts over the cells: IAPID vs APID (:func:`classify`), APID vs the fixed PID, IAPID vs
    the fixed PID, the oracle vs IAPID, and where each arm has the lowest mean."""
    v = dict.fromkeys(("iapid_better_than_apid", "iapid_equivalent_to_apid",
                       "iapid_worse_than_apid", "undecided", "apid_better_than_pid",
                       "apid_worse_than_pid", "iapid_better_than_pid", "oracle_better_than_iapid",
                       "oracle_worse_than_iapid"), 0)  # fmt: skip
    names = {"better": "iapid_better_than_apid", "equivalent": "iapid_equivalent_to_apid",
             "worse": "iapid_worse_than_apid", "undecided": "undecided"}  # fmt: skip
    for c in cs:
        v[names[classify(c)]] += 1
        for key, name in (("adaptive-pid - pid", "apid_{}_pid"), ("iapid-nn-dekf - pid",
                                                                   "iapid_{}_pid"),
                          ("iapid-oracle - iapid-nn-dekf", "oracle_{}_iapid")):  # fmt: skip
            t = c["tests"][key]
            if t["significant"]:
                word = "better_than" if t["mean_diff"] < 0 else "worse_than"
                if name.format(word) in v:
                    v[name.format(word)] += 1
    v["cells"] = len(cs)
    v["best_arm"] = {a: sum(c["best"] == a for c in cs) for a in ARMS}
    return v


def run(out, *, quick: bool = False, workers: int | None = None) -> dict:
    """Run both sweeps (resuming their stores), compute the cells and the verdict, write the
    record, table and figure."""
    d = _design(quick)
    store = _store(Path(out), quick)
    family, others = _write_specs(store / "specs", d)
    t0 = time.perf_counter()
    manifests = [sweep.run_sweep(sweep.load_spec(p), store / p.stem, workers=workers,
                                 progress=None, stale="set-aside")
                 for p in (family, others)]  # fmt: skip
    seconds = time.perf_counter() - t0
    rows = _frame([store / "family", store / "others"], d)
    cs = cells(rows, d)
    record = {
        "factors": {"mechanism": list(d["mechanisms"]), "trajectory": list(d["trajectories"]),
                    "rate": [r[0] for r in d["rates"]], "gains": list(d["gains"]),
                    "process_std": list(d["process_std"])},
        "rates": {label: {"mu": mu, "jacobian_scale": s} for label, mu, s in d["rates"]},
        "gain_sets": {g: list(GAINS[g]) for g in d["gains"]},
        "arms": list(ARMS), "seeds": d["seeds"], "outcome": "tail_position", "margin": MARGIN,
        "alpha": ALPHA, "quick": quick, "cells": cs, "verdict": verdict(cs),
        "cost": {"runs": int(sum(m["jobs"] for m in manifests)),
                 "runs_this_time": int(sum(m["runs_this_time"] for m in manifests)),
                 "seconds": seconds,
                 "run_seconds_total": float(sum(m["run_seconds_total"] for m in manifests)),
                 "engine": manifests[0]["engine"],
                 "workers": manifests[0]["workers"]},
    }  # fmt: skip
    record["figures"] = [common.save_figure(out, f"{STEM}_map.png", _figure(record))]
    common.write_record(out, STEM, record)
    common.write_table(out, STEM, table(record))
    return record


def check(record: dict) -> None:
    """The record is whole and its statistics consistent: every cell has every arm over every
    seed (diverged runs counted), the verdict's counts add up to the cells, and a TOST verdict
    of equivalence has its interval inside the margin."""
    v, n = record["verdict"], record["seeds"]
    assert v["cells"] == len(record["cells"]) > 0
    assert (v["iapid_better_than_apid"] + v["iapid_equivalent_to_apid"]
            + v["iapid_worse_than_apid"] + v["undecided"]) == v["cells"], v  # fmt: skip
    assert sum(v["best_arm"].values()) == v["cells"]
    for c in record["cells"]:
        for arm in record["arms"]:
            a = c["arms"][arm]
            assert a["n"] + 0 == n or a["diverged"] > 0, (c["mechanism"], arm, a)
        t = c["tost_iapid_apid"]
        if t["equivalent"]:
            assert -t["delta"] < t["ci_low"] <= t["ci_high"] < t["delta"], t
        for test in c["tests"].values():
            assert 0.0 <= test["p"] <= test["p_holm"] <= 1.0, test


# ---------------------------------------------------------------------------------------------
# Prose, table, figure (from the record only)


def _pct(x) -> str:
    return "—" if x is None else f"{100 * x:+.1f} %"


def _median(xs) -> float | None:
    xs = [x for x in xs if x is not None]
    return float(np.median(xs)) if xs else None


def table(record: dict) -> str:
    """Per mechanism and rate reading: the cells where IAPID beats APID, the PID, and the mean
    relative differences (``tables/regimes.md``)."""
    rows = []
    cs = record["cells"]
    for mech in record["factors"]["mechanism"]:
        for rate in record["factors"]["rate"]:
            sel = [c for c in cs if c["mechanism"] == mech and c["rate"] == rate]
            kinds = [classify(c) for c in sel]
            ap = [c["tests"]["adaptive-pid - pid"] for c in sel]
            rows.append([
                mech, rate, len(sel), kinds.count("better"), kinds.count("equivalent"),
                kinds.count("worse"), kinds.count("undecided"),
                _pct(_median(c["tests"]["iapid-nn-dekf - adaptive-pid"]["rel_diff"] for c in sel)),
                sum(t["significant"] and t["mean_diff"] < 0 for t in ap),
                _pct(_median(t["rel_diff"] for t in ap)),
                ", ".join(sorted({controllers.label(c["best"]) for c in sel})),
            ])  # fmt: skip
    header = ["mechanism", "SGD rate", "cells", "IAPID < APID", "IAPID ≡ APID", "IAPID > APID",
              "undecided", "IAPID vs APID (median rel.)", "APID < PID",
              "APID vs PID (median rel.)", "lowest mean"]  # fmt: skip
    return "\n".join(common.md_table(header, rows)) + "\n"


def _by(cs: list[dict], key: str) -> str:
    """``"level n, ..."`` counts of the cells ``cs`` by factor ``key`` (in the factor's order)."""
    import collections

    n = collections.Counter(str(c[key]) for c in cs)
    return ", ".join(f"{k} {v}" for k, v in n.items()) if n else "none"


def _median_of(cs, arm: str, key: str) -> str:
    return common.fmt(_median(c["arms"][arm].get(key) for c in cs), 3)


def _where_each_arm_wins(cs: list[dict]) -> str:
    """For each arm with the lowest mean somewhere: where (mechanisms, trajectories) and by how
    much it leads the next arm (relative to that arm's mean: median and range over its cells;
    paired tests with intervals exist for the PID family's pairs only, in the cell table)."""
    parts = []
    for a in ARMS:
        won = [c for c in cs if c["best"] == a]
        if not won:
            continue
        leads = []
        for c in won:
            m = {b: x["tail_mean"] for b, x in c["arms"].items() if x["tail_mean"] is not None}
            others = [x for b, x in m.items() if b != a]  # an arm that always diverged: none
            if a in m and others:
                leads.append(1.0 - m[a] / min(others))
        lead = (f", ahead of the next arm by a median {100 * float(np.median(leads)):.1f} % of "
                f"its mean (range {100 * min(leads):.1f}-{100 * max(leads):.1f} %)"
                if leads else "")  # fmt: skip
        parts.append(f"{controllers.label(a)} in {len(won)} cells (mechanism: "
                     f"{_by(won, 'mechanism')}; trajectory: {_by(won, 'trajectory')}){lead}")
    return "Where each arm has the lowest mean: " + "; ".join(parts) + "."


def _cell_name(c: dict) -> str:
    return (f"{c['mechanism']} / {c['trajectory']} / rate {c['rate']} / {c['gains']} gains / "
            f"process noise {c['process_std']:g}")


def notes(record: dict) -> list[str]:
    """The answer, in sentences computed from the record."""
    v, cs = record["verdict"], record["cells"]
    ia, ap = "iapid-nn-dekf - adaptive-pid", "adaptive-pid - pid"
    pays = [c for c in cs if classify(c) == "better" and c["tests"]["iapid-nn-dekf - pid"]
            ["significant"] and c["tests"]["iapid-nn-dekf - pid"]["mean_diff"] < 0]  # fmt: skip
    apid_div = [c for c in pays if c["arms"]["adaptive-pid"]["diverged"] > 0]
    worse = [c for c in cs if classify(c) == "worse"]
    out = [
        f"{v['cells']} cells ({' x '.join(f'{len(x)} {k}' for k, x in record['factors'].items())}"
        f"), {record['seeds']} seeds each with common random numbers; outcome: position RMSE "
        f"after the transient (a diverged run counts as {DIVERGED:g} m); tests: paired Wilcoxon, "
        f"Holm over the {len(PAIRS)} tested pairs of a cell (alpha {record['alpha']:g}), TOST of "
        f"IAPID vs APID at ±{1e3 * record['margin']:g} mm.",
        f"IAPID-NN-DEKF vs APID (the same PID and SGD, the identified instead of the model "
        f"Jacobian): better in {v['iapid_better_than_apid']} cells, equivalent within the margin "
        f"in {v['iapid_equivalent_to_apid']}, worse in {v['iapid_worse_than_apid']}, undecided in "
        f"{v['undecided']}.",
        f"The indirect scheme pays (IAPID significantly better than both APID and the fixed PID) "
        f"in {len(pays)} of {v['cells']} cells; by mechanism: {_by(pays, 'mechanism')}; by SGD "
        f"rate: {_by(pays, 'rate')}; by initial gains: {_by(pays, 'gains')}."
        + (f"  In {len(apid_div)} of them APID diverged "
           f"({sum(c['arms']['adaptive-pid']['diverged'] for c in apid_div)} of their "
           f"{sum(c['arms']['adaptive-pid']['n'] for c in apid_div)} runs) and IAPID in "
           f"none: there IAPID pays by staying stable where the model-Jacobian step does not."
           if apid_div and all(c["arms"]["iapid-nn-dekf"]["diverged"] == 0 for c in apid_div)
           else f"  In {len(apid_div)} of them APID diverged in some seeds." if apid_div
           else ""),
        f"Where IAPID is worse than APID ({len(worse)} cells), by SGD rate: {_by(worse, 'rate')}; "
        f"median relative difference IAPID vs APID over those cells "
        f"{_pct(_median(c['tests'][ia]['rel_diff'] for c in worse))}.",
        f"Why, in the Jacobian the SGD step used against the true robot's one-step Jacobian "
        f"(median over the cells where IAPID pays / where it is worse): relative error IAPID "
        f"{_median_of(pays, 'iapid-nn-dekf', 'jac_rel_error_median')} / "
        f"{_median_of(worse, 'iapid-nn-dekf', 'jac_rel_error_median')}, APID "
        f"{_median_of(pays, 'adaptive-pid', 'jac_rel_error_median')} / "
        f"{_median_of(worse, 'adaptive-pid', 'jac_rel_error_median')}; norm ratio of IAPID's "
        f"Jacobian {_median_of(pays, 'iapid-nn-dekf', 'jac_norm_ratio_median')} / "
        f"{_median_of(worse, 'iapid-nn-dekf', 'jac_norm_ratio_median')} (a norm ratio scales the "
        "SGD step like the learning rate).",
        f"APID vs the fixed PID: better in {v['apid_better_than_pid']} cells, worse in "
        f"{v['apid_worse_than_pid']}; median relative difference by SGD rate: "
        + ", ".join(f"{r} {_pct(_median(c['tests'][ap]['rel_diff'] for c in cs if c['rate'] == r))}"
                    for r in record["factors"]["rate"]) + ".",
        f"The oracle identifier (trained on the true poses) vs IAPID: better in "
        f"{v['oracle_better_than_iapid']} cells, worse in {v['oracle_worse_than_iapid']}; its "
        f"Jacobian's median relative error {_median_of(cs, 'iapid-oracle', 'jac_rel_error_median')}"
        f" against IAPID's {_median_of(cs, 'iapid-nn-dekf', 'jac_rel_error_median')}.",
        "Lowest mean per cell: " + ", ".join(f"{controllers.label(a)} {k}"
                                             for a, k in v["best_arm"].items() if k) + ".",
        _where_each_arm_wins(cs),
    ]  # fmt: skip
    stable = [c for c in pays if all(c["arms"][a]["diverged"] == 0
                                     for a in ("iapid-nn-dekf", "adaptive-pid"))]
    best = sorted(stable, key=lambda c: c["tests"][ia]["rel_diff"])[:3]
    if best:
        out.append("Largest gains of IAPID over APID where neither diverged: " + "; ".join(
            f"{_cell_name(c)} ({_pct(t['rel_diff'])}, difference of the means "
            f"{1e3 * t['mean_diff']:.2f} mm, 95 % CI [{1e3 * t['ci_low']:.2f}, "
            f"{1e3 * t['ci_high']:.2f}] mm)"
            for c, t in ((c, c["tests"][ia]) for c in best)) + ".")  # fmt: skip
    c = record["cost"]
    out.append(f"Cost: {c['runs']:,} runs in {c['run_seconds_total']:.0f} s of running over "
               f"the invocations that filled the stores ({c['runs_this_time']:,} runs in the "
               f"last, {c['seconds']:.0f} s in all) on {c['engine']}.")
    return out


def render(record: dict) -> str:
    return common.section(TITLE, notes(record), table(record), record["figures"])


def _figure(record: dict):
    """The regime map: for each cell the arm with the lowest mean (hatched when its lead over
    the runner-up in IAPID-vs-APID terms is not significant)."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    f = record["factors"]
    rows = [(m, t) for m in f["mechanism"] for t in f["trajectory"]]
    cols = [(r, g, p) for r in f["rate"] for g in f["gains"] for p in f["process_std"]]
    grid = np.full((len(rows), len(cols)), np.nan)
    for c in record["cells"]:
        i = rows.index((c["mechanism"], c["trajectory"]))
        j = cols.index((c["rate"], c["gains"], c["process_std"]))
        grid[i, j] = ARMS.index(c["best"])
    fig, ax = plt.subplots(figsize=(max(6, 0.45 * len(cols) + 3), max(3, 0.35 * len(rows) + 2)),
                           layout="constrained")  # fmt: skip
    cmap = ListedColormap([controllers.colour(a) for a in ARMS])
    ax.imshow(grid, cmap=cmap, vmin=-0.5, vmax=len(ARMS) - 0.5, aspect="auto")
    ax.set_yticks(range(len(rows)), [f"{m} / {t}" for m, t in rows], fontsize=7)
    ax.set_xticks(range(len(cols)), [f"{r} {g} {p:g}" for r, g, p in cols], fontsize=7,
                  rotation=90)  # fmt: skip
    for a in ARMS:
        ax.plot([], [], "s", color=controllers.colour(a), label=controllers.label(a))
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    ax.set_title("lowest mean after-transient position RMSE per cell "
                 "(columns: SGD rate, initial gains, pose-EKF process noise)", fontsize=9)
    return fig


if __name__ == "__main__":
    sys.exit(common.main(sys.modules[__name__]))
