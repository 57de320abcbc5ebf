"""Could any setting give the paper's tables?  Calibration, global sensitivity and fair tuning
(issue 15).

The paper leaves most of its simulation unsaid (dt, run length, trajectories, gains, noise, the
nature of the perturbation...).  This study writes those settings down as a **prior** (ranges
with their provenance, ``analysis._calibration_prior``), then asks:

1. **Screening** (Morris): which settings matter at all; the inert ones are fixed.
2. **A space-filling design** (scrambled Sobol, ``2 x 2**11 = 4096`` points x 2 seeds with common
   random numbers, run through ``wmr.study.engine``): does any point reproduce all 36 numbers
   of Tables 1-3 within their tolerance (the printed digits' rounding plus the seed-to-seed
   spread of one run)?  Which numbers are never reached, and what range does each span?
3. **The closest fit** (differential evolution of the rms log ratio, several starts): its
   settings, written as labelled scenario files (``wmr/scenarios/paper-fit/``; the defaults do
   not move), and its residual profile.
4. **Robustness of the ranking** over the prior x seeds: P(the paper's order), pairwise win
   probabilities, Kendall tau; Sobol indices (bootstrap intervals) of each controller's RMSE and
   of the ranking margins; convergence at N and N/2.
5. **Fair tuning**: each controller's free gains tuned with the same budget on training
   trajectories, evaluated on the paper's (held out); RMSE against control effort.

Nothing is tuned to make a controller win; the fit is a separate, labelled result.

Commands: ``wmr analyze calibration`` (and ``wmr reproduce``) re-render the committed record
(``paper/results/calibration.json`` and its points file); without one they compute it.
``python -m analysis.calibration --full [--workers N]`` recomputes it: about 45 minutes
of runs on two cores, in a resumable store ``calibration/`` under ``$WMR_STORES`` (default
``~/.cache/wmr/stores``; a store of other sources is set aside and rebuilt).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from analysis import _calibration_figures as figures
from analysis import _calibration_prior as prior
from analysis import _calibration_stages as stages
from analysis import common
from analysis._calibration_fair import fair_tuning
from analysis._calibration_store import Evaluator, store_digest
from analysis.common import fmt
from wmr import controllers

__all__ = ["STEM", "TITLE", "run", "check", "render", "table", "toml_text", "fit_scenarios",
           "read_points", "POINTS_FILE", "FIT_DIR", "main"]  # fmt: skip

STEM = "calibration"
TITLE = "Could any setting give the paper's tables? Calibration, sensitivity and fair tuning"
#: Where the fitted settings go (a separate, labelled scenario set; the defaults do not move).
FIT_DIR = Path(__file__).resolve().parent.parent / "wmr" / "scenarios" / "paper-fit"


def _store(out: Path, quick: bool) -> Path:
    """The study's store: beside the quick record, else the studies' folder's ``calibration/``
    (its manifest's digest decides whether it is resumed or set aside)."""
    from wmr.engine.store import studies_folder

    return Path(out) / ".calibration-store" if quick else studies_folder() / STEM


# ---------------------------------------------------------------------------------------------
# The fitted settings as scenario files


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")


def toml_text(doc: dict, header: str = "") -> str:
    """A TOML document (scalars, arrays, tables, arrays of tables, nested) as text."""
    lines = [f"# {h}" if h else "#" for h in header.splitlines()] if header else []

    def emit(table: dict, path: str) -> None:
        subs = []
        for k, v in table.items():
            if isinstance(v, dict):
                subs.append((k, v, False))
            elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
                subs.append((k, v, True))
            else:
                lines.append(f"{_key(k)} = {_toml_value(v)}")
        for k, v, many in subs:
            name = f"{path}.{_key(k)}" if path else _key(k)
            for item in (v if many else [v]):
                lines.extend(["", f"[[{name}]]" if many else f"[{name}]"])
                emit(item, name)

    emit(doc, "")
    return "\n".join(lines) + "\n"


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() else json.dumps(k)


def fit_scenarios(settings: dict, rms: float, folder: Path) -> list[str]:
    """Write the fitted ``settings`` as the three paper scenarios (with every controller's
    settings) into ``folder``; their file names."""
    folder.mkdir(parents=True, exist_ok=True)
    names = []
    for sc in prior.SCENARIOS:
        doc = prior.scenario_doc(sc, settings)
        doc["name"] = f"paper-fit-{sc}"
        doc["controllers"] = {}
        for c in prior.CONTROLLERS:
            st = prior.settings(c, settings)
            cls = controllers.get(c).Settings
            default = cls()
            doc["controllers"][c] = {f: list(getattr(st, f)) if isinstance(getattr(st, f), tuple)
                                     else getattr(st, f) for f in st.__dataclass_fields__
                                     if getattr(st, f) != getattr(default, f)}  # fmt: skip
        header = (f"A FIT, not the suite's defaults: the settings of the prior closest to the "
                  f"paper's Tables 1-3 (rms log ratio {rms:.3f} over the 36 numbers),\nfound by "
                  "analysis/calibration.py (`python -m analysis.calibration --full`); see "
                  "paper/report.md.\nOne value for all four controllers wherever a setting is "
                  "shared; mu, P0, Q, R and the initial pose as the paper gives them.")
        path = folder / f"{sc}.toml"
        from wmr.io import atomic_write_text

        atomic_write_text(path, toml_text(doc, header))
        names.append(path.name)
    return names


# ---------------------------------------------------------------------------------------------
# Run


#: The design's points beside the record (one row each: too many for the JSON).
POINTS_FILE = f"{STEM}_points.csv"


def _g(x) -> str:
    """A number of the points file: 7 significant digits (booleans and levels as they are)."""
    if isinstance(x, bool) or isinstance(x, str):
        return str(x).lower() if isinstance(x, bool) else x
    return f"{float(x):.7g}"


def _points(des: dict, space: stages.Space, out: Path) -> dict:
    """Write the design's points (``results/calibration_points.csv``: each varied setting's
    value, the rms and max |log ratio|, the numbers within tolerance, the diverged runs) and
    return the record's summary of them."""
    from wmr.io import write_csv

    values = [space.values(u) for u in des["u"]]
    n_within = des["within"].sum(axis=1)
    n_div = np.sum(des["status"] != 0, axis=(1, 2))
    header = ["point", *space.names, "rms_log_ratio", "max_abs_log_ratio", "n_within",
              "n_diverged"]  # fmt: skip
    rows = [[i, *(_g(v[n]) for n in space.names), _g(des["rms_log_ratio"][i]),
             _g(des["max_abs_log_ratio"][i]), int(n_within[i]), int(n_div[i])]
            for i, v in enumerate(values)]  # fmt: skip
    write_csv(Path(out) / "results" / POINTS_FILE, header, rows)
    return {"n": int(len(des["u"])), "file": f"results/{POINTS_FILE}", "columns": header,
            "design": "scrambled Sobol (scipy.stats.qmc.Sobol, seed "
            f"{stages.DESIGN_SEED}): A and B, {len(des['A'])} points each, the halves of a "
            f"sequence in 2 x {len(space.names)} dimensions", "varied": list(space.names),
            "min_rms_log_ratio": float(des["rms_log_ratio"].min()),
            "n_diverged_points": int(np.sum(n_div > 0)),
            "n_within_histogram": np.bincount(n_within, minlength=37).tolist()}  # fmt: skip


def read_points(out, record: dict) -> dict:
    """The points file of ``record`` under ``out`` as columns (floats, or strings for levels)."""
    import csv

    with open(Path(out) / record["points"]["file"], newline="") as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    cols = {}
    for j, name in enumerate(header):
        raw = [r[j] for r in body]
        try:
            cols[name] = [float(x) for x in raw]
        except ValueError:
            cols[name] = raw
    return cols


def _feasible_json(des: dict) -> dict:
    n_within = des["within"].sum(axis=1)
    cov = stages.coverage(des)
    lr = np.abs(np.log(des["mean"] / prior.PAPER))
    best = int(np.argmin(des["rms_log_ratio"]))
    w = des["within"].reshape(-1, 3, 4, 3)  # point, scenario, controller, axis
    n_per = des["within_per_number"].sum(axis=1)
    return {"count": int(np.sum(n_within == 36)),
            "points": [int(i) for i in np.flatnonzero(n_within == 36)],
            "count_per_number_bands": int(np.sum(n_per == 36)),
            "best_n_within_per_number_bands": int(n_per.max()),
            "per_table": {s: int(np.sum(w[:, i].all(axis=(1, 2))))
                          for i, s in enumerate(prior.SCENARIOS)},
            "per_controller": {c: int(np.sum(w[:, :, j].all(axis=(1, 2))))
                               for j, c in enumerate(prior.CONTROLLERS)},
            "per_row": {f"{s}/{c}": int(np.sum(w[:, i, j].all(axis=1)))
                        for i, s in enumerate(prior.SCENARIOS)
                        for j, c in enumerate(prior.CONTROLLERS)},
            "best_n_within": int(n_within.max()),
            "numbers": cov,
            "never_reached": [n for n, c in cov.items() if c["n_reached"] == 0],
            "never_spanned": [n for n, c in cov.items() if not c["spanned"]],
            "all_within_factor": {str(f): int(np.sum(np.all(lr <= math.log(f), axis=1)))
                                  for f in (1.1, 1.25, 1.5, 2.0, 3.0)},
            "best_point": {"index": best, "rms_log_ratio": float(des["rms_log_ratio"][best]),
                           "n_within": int(n_within[best])}}  # fmt: skip


def _tolerance_json(des: dict, n_seeds: int) -> dict:
    return {"rule": "|mean - paper| <= rounding + z sd sqrt(1 + 1/n): the rounding of the "
                    "printed digits (half a unit in the last place) plus z seed standard "
                    "deviations of one run (the paper's tables are single runs) around our "
                    "n-seed mean; sd = max(the point's sample sd, pooled cv x mean); a number "
                    "with a diverged seed is not matched",
            "z": prior.Z_JOINT, "joint_level": prior.JOINT_LEVEL,
            "z_rule": "Sidak: each band at joint_level**(1/36), so a setting that is the "
                      "paper's passes all 36 at once with probability joint_level",
            "z_per_number": prior.Z_SEED, "seeds": n_seeds,
            "rounding": dict(zip(prior.NUMBER_NAMES, map(float, prior.ROUNDING), strict=True)),
            "pooled_cv": dict(zip(prior.NUMBER_NAMES, map(float, des["cv"]), strict=True)),
            "median": dict(zip(prior.NUMBER_NAMES, map(float, np.median(des["tol"], axis=0)),
                               strict=True))}  # fmt: skip


def compute(out: Path, quick: bool, workers: int | None, progress=None) -> dict:
    """Run every stage (resuming the store) and assemble the record (no files but the store
    and, in the full study, the paper-fit scenarios)."""
    level = stages.QUICK if quick else stages.FULL
    digest = store_digest(level.name)
    t0 = time.perf_counter()
    with Evaluator(_store(out, quick), digest, workers, progress=progress) as ev:
        scr = stages.screening(ev, level)
        space = stages.Space.of(level, scr["active"], scr["fixed_at"])
        des = stages.design(ev, level, space)
        sens = stages.sensitivity(ev, level, space, des)
        rank = stages.ranking(des, level)
        best = stages.fit(ev, level, space, des)
        fair = fair_tuning(ev, level.fair)
        cost = {"runs_in_store": ev.runs_in_store(), "runs_this_time": ev.runs_this_time,
                "seconds_running": round(ev.seconds, 1), "engine": ev.engine_name,
                "seconds": round(time.perf_counter() - t0, 1),
                "runs_total": ev.totals["runs"],
                "seconds_running_total": round(ev.totals["seconds_running"], 1)}  # fmt: skip
    folder = Path(out) / "paper-fit" if quick else FIT_DIR
    files = fit_scenarios(best["settings"], best["rms_log_ratio"], folder)
    return {"level": level.name, "digest": digest,
            "prior": prior.prior_json(scr["active"], scr["fixed_at"]),
            "fixed": prior.FIXED, "held": prior.HELD,
            "paper": {n: {"value": float(v), "printed": p, "rounding": float(r)}
                      for n, v, p, r in zip(prior.NUMBER_NAMES, prior.PAPER,
                                            [prior.PAPER_PRINTED[s][c][i] for s in prior.SCENARIOS
                                             for c in prior.CONTROLLERS for i in range(3)],
                                            prior.ROUNDING, strict=True)},
            "screening": scr, "seeds": list(level.seeds),
            "points": _points(des, space, out),
            "tolerance": _tolerance_json(des, len(level.seeds)),
            "feasible": _feasible_json(des),
            "best_fit": {**best, "scenario_files": [f"wmr/scenarios/paper-fit/{f}" if not quick
                                                    else f"paper-fit/{f}" for f in files]},
            "p_paper_order": rank,
            "sensitivity": {"sobol": sens, "morris": {"importance": scr["importance"]}},
            "fair_tuning": fair, "cost": cost}  # fmt: skip


#: The repository's results (the committed record of the full study).
COMMITTED = Path(__file__).resolve().parent.parent / "paper"


def _committed(out: Path) -> tuple[Path, dict] | tuple[None, None]:
    """A full record (and its points file) in ``out``, else the repository's committed one."""
    for base in (out, COMMITTED):
        rec = common.load_record(base, STEM)
        if rec and rec.get("level") == "full" and (base / rec["points"]["file"]).exists():
            return base, rec
    return None, None


def run(out, *, quick: bool = False, workers: int | None = None, full: bool = False,
        progress: bool | None = None) -> dict:  # fmt: skip
    """The study into ``out``: ``quick`` a few points on short runs (tests); ``full``
    recomputes everything (about 45 minutes on two cores; the store resumes);
    otherwise the full record in ``out`` or, failing that, the repository's committed one is
    re-rendered (figures, table; ``wmr reproduce`` stays short), and only without any record is
    the study computed."""
    import shutil

    out = Path(out)
    base, record = (None, None) if (quick or full) else _committed(out)
    if record is None:
        record = compute(out, quick, workers, progress)
    elif base.resolve() != out.resolve():
        (out / "results").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(base / record["points"]["file"], out / record["points"]["file"])
    record["figures"] = figures.all_figures(record, read_points(out, record), out)
    common.write_record(out, STEM, record)
    common.write_table(out, STEM, table(record))
    return record


# ---------------------------------------------------------------------------------------------
# Check


def check(record: dict) -> None:
    """The record is whole and consistent: the prior shares >= 8 settings across all four
    controllers; the design is complete (>= 4096 points in the full study); the feasible set,
    the unreached numbers and the best fit's summary agree with their parts; the fit is no worse
    than the best design point it started from; probabilities lie in their intervals; every
    controller was tuned with the same budget."""
    shared = [n for n, p in record["prior"].items() if p["group"] == "shared"]
    assert len(shared) >= 8, shared
    pts = record["points"]
    n = pts["n"]
    assert record["level"] != "full" or n >= 4096, n
    hist = pts["n_within_histogram"]
    assert len(hist) == 37 and sum(hist) == n, hist
    feas = record["feasible"]
    assert feas["count"] == len(feas["points"]) == hist[36]
    assert feas["best_n_within"] == max(k for k, c in enumerate(hist) if c)
    for part in ("per_table", "per_controller", "per_row"):
        assert all(k >= feas["count"] for k in feas[part].values()), part
    nums = feas["numbers"]
    assert list(nums) == list(prior.NUMBER_NAMES)
    assert feas["never_reached"] == [k for k, c in nums.items() if c["n_reached"] == 0]
    for c in nums.values():
        assert c["min"] <= c["q05"] <= c["median"] <= c["q95"] <= c["max"], c
        assert c["spanned"] == (c["min"] <= c["paper"] <= c["max"]), c
    fit = record["best_fit"]
    res = fit["residuals"]
    assert list(res) == list(prior.NUMBER_NAMES)
    lr = np.array([r["log_ratio"] for r in res.values()])
    assert math.isclose(fit["rms_log_ratio"], float(np.sqrt(np.mean(lr**2))), rel_tol=1e-9)
    assert math.isclose(fit["max_abs_log_ratio"], float(np.max(np.abs(lr))), rel_tol=1e-9)
    for r in res.values():
        assert math.isclose(r["log_ratio"], math.log(r["mean"] / r["paper"]), abs_tol=1e-9), r
        assert r["within"] == (abs(r["mean"] - r["paper"]) <= r["tolerance"]
                               and r["diverged_seeds"] == 0), r
        assert r["within_per_number"] <= r["within"], r  # the per-number bands are narrower
    assert fit["n_within"] == sum(r["within"] for r in res.values())
    assert fit["feasible"] == (fit["n_within"] == 36)
    assert fit["rms_log_ratio_at_design_seeds"] <= fit["best_design_rms_log_ratio"] + 1e-12, fit
    assert math.isclose(fit["best_design_rms_log_ratio"], pts["min_rms_log_ratio"])
    po = record["p_paper_order"]
    for p in _probabilities(po):
        assert -1e-12 <= p["ci_low"] <= p["p"] + 1e-12, p
        assert p["p"] <= p["ci_high"] + 1e-12 <= 1.0 + 2e-12, p
    assert feas["count_per_number_bands"] <= feas["count"]
    cost = record["cost"]
    assert cost["runs_total"] >= cost["runs_this_time"], cost
    fair = record["fair_tuning"]
    budget = fair["budget"]["evaluations"]
    for c, t in fair["controllers"].items():
        assert t["nfev"] == budget, (c, t["nfev"], budget)
    assert sorted(fair["ranking_held_out"]) == sorted(prior.CONTROLLERS)


def _probabilities(po: dict):
    yield po["all_nine"]
    yield po["iapid_first_all"]
    yield po["iapid_first_any"]
    yield from po["per_table"].values()
    yield from po["pairwise"].values()


# ---------------------------------------------------------------------------------------------
# Render (from the record only)


def _label(name: str) -> str:
    s, c, a = name.split("/")
    return f"{s} {controllers.label(c)} {a}"


def _pct(p: dict) -> str:
    return f"{100 * p['p']:.1f} % [{100 * p['ci_low']:.1f}, {100 * p['ci_high']:.1f}]"


def _apart(feas: dict) -> str:
    """Which parts alone are matched more often than all 36 with shared settings."""
    more = [name for name, part in (("one table", feas["per_table"]),
                                    ("one controller's row", feas["per_controller"]))
            if max(part.values()) > feas["count"]]  # fmt: skip
    if not more:
        return "."
    return (": " + " and ".join(more) + " alone " + ("is" if len(more) == 1 else "are")
            + " matched more often than all 36 with shared settings.")


def _answer_tables(r: dict) -> list[str]:
    feas, fit, pts, tol = r["feasible"], r["best_fit"], r["points"], r["tolerance"]
    worst = sorted(fit["residuals"].items(), key=lambda kv: -abs(kv[1]["log_ratio"]))[:5]
    wf = feas["all_within_factor"]
    lines = [
        "**Does any plausible setting reproduce Tables 1-3?** "
        + ("No." if feas["count"] == 0 else f"Yes: {feas['count']} points.")
        + f"  Of {pts['n']} design points ({len(pts['varied'])} settings varied over the prior, "
        f"{len(r['seeds'])} seeds each), {feas['count']} match all 36 numbers within their "
        f"tolerance (bands at a joint {100 * tol['joint_level']:.0f} % level, z = "
        f"{tol['z']:.2f}; no diverged seed); the best matches {feas['best_n_within']} of 36.  "
        f"With the narrower per-number bands (z = {tol['z_per_number']:g}), "
        f"{feas['count_per_number_bands']} points match all 36 and the best "
        f"{feas['best_n_within_per_number_bands']}.  Loosening the test to a "
        "ratio band, all 36 lie within a factor " + ", ".join(
            f"{f}: {k} points" for f, k in wf.items()) + ".  Taken apart, the 12 numbers of "
        "one table are matched at " + ", ".join(
            f"{k} point{'s' if k != 1 else ''} ({s})" for s, k in feas["per_table"].items())
        + "; the 9 numbers of one controller at " + ", ".join(
            f"{k} ({controllers.label(c)})" for c, k in feas["per_controller"].items())
        + _apart(feas),
        "Numbers never reached within tolerance at any design point: "
        + (", ".join(_label(n) for n in feas["never_reached"]) or "none")
        + ".  Numbers outside the range the design spans: "
        + (", ".join(f"{_label(n)} (paper {fmt(feas['numbers'][n]['paper'])}, design "
                     f"{fmt(feas['numbers'][n]['min'])}-{fmt(feas['numbers'][n]['max'])})"
                     for n in feas["never_spanned"]) or "none") + ".",
        f"**How close is the best fit, and where does it miss?** rms log ratio "
        f"{fit['rms_log_ratio']:.3f} (a typical factor {math.exp(fit['rms_log_ratio']):.2f}), "
        f"largest |log ratio| {fit['max_abs_log_ratio']:.3f} (factor "
        f"{math.exp(fit['max_abs_log_ratio']):.2f}), over {len(fit['seeds'])} seeds; "
        f"{fit['n_within']} of 36 within tolerance ({fit['n_within_per_number']} with the "
        "per-number bands).  Largest misses: " + "; ".join(
            f"{_label(n)} {fmt(x['mean'])} vs {fmt(x['paper'])} (x{x['ratio']:.2f})"
            for n, x in worst) + ".  Differential evolution from "
        f"{len(fit['starts'])} starts reached " + ", ".join(
            f"{s['rms_log_ratio']:.3f}" for s in fit["starts"])
        + f" (best design point {fit['best_design_rms_log_ratio']:.3f}).",
    ]  # fmt: skip
    return lines


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
        f"{po['n_seeds']} seeds (single runs, as the paper's tables): all nine (scenario, axis) "
        f"orders as printed {_pct(po['all_nine'])}; IAPID-NN-DEKF lowest on all nine "
        f"{_pct(po['iapid_first_all'])}, on at least one {_pct(po['iapid_first_any'])}; mean "
        f"Kendall tau against the paper's orders {po['kendall_tau']['mean']:.3f} "
        f"[{po['kendall_tau']['ci'][0]:.3f}, {po['kendall_tau']['ci'][1]:.3f}].  Pairwise, "
        f"share of the 9 (scenario, axis) comparisons IAPID wins: {beats}.  "
        f"At half the design (nested in the whole) the same probabilities agree within their "
        f"intervals for {conv['agreeing']} of {conv['compared']}; between the design's two "
        f"independent halves (A and B) for {ind['agreeing']} of {ind['compared']}.",
    ]  # fmt: skip


def _answer_sensitivity(r: dict) -> list[str]:
    sob = r["sensitivity"]["sobol"]
    ix = sob["N"]["indices"]
    parts, widths = [], []
    for o in sob["outputs"]:
        if not ix.get(o) or not o.startswith(("margin", "rms")):
            continue
        top = sorted(ix[o].items(), key=lambda kv: -kv[1]["total"])[:3]
        widths += [v["total_high"] - v["total_low"] for _, v in top]
        parts.append(f"{o}: " + ", ".join(f"{n} {v['total']:.2f} [{v['total_low']:.2f}, "
                                          f"{v['total_high']:.2f}]" for n, v in top))
    conv, ind = sob["convergence"], sob["independent_halves"]
    scr = r["screening"]
    fixed = [n for n in r["prior"] if not r["prior"][n].get("varied", True)]
    weakest = min(scr["importance"], key=scr["importance"].get)
    return [
        "**Which unstated settings decide it?** Morris screening "
        f"({scr['trajectories']} trajectories, {scr['points']} points; a setting is inert when "
        f"its mu* stays below {scr['threshold']:g} of the largest for every output) fixed "
        f"{len(fixed)} settings ({', '.join(fixed) or 'none'}); the weakest, {weakest}, still "
        f"moves some output by {scr['importance'][weakest]:.2f} of the largest effect.  "
        "Largest total Sobol "
        f"indices (N = {sob['N']['n']}; margins are log RMSE of X minus IAPID's): "
        + "; ".join(parts) + f".  Convergence: {conv['intervals_overlapping']} of "
        f"{conv['intervals']} intervals at N and N/2 overlap (nested samples: expected); "
        f"between two independent halves of N/2 = {sob['first half']['n']} rows, "
        f"{ind['intervals_overlapping']} of {ind['intervals']} overlap.  The median interval "
        f"width at N is {ind['median_interval_width_at_N']:.2f} over all indices "
        f"and {float(np.median(widths)):.2f} over the largest ones named here"
        + (", so these rank the settings only coarsely." if np.median(widths) > 0.2 else "."),
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
    return [
        f"**Who wins under fair tuning?** Each controller's free gains tuned by the same "
        f"optimiser with {f['budget']['evaluations']} evaluations on "
        f"{len(f['training'])} training trajectories, then run on the paper's three scenarios "
        f"(held out, seeds {f['budget']['test_seeds'][0]}-{f['budget']['test_seeds'][-1]}): "
        f"{lab(best)} is best by the tables' mean log RMSE; mean position RMSE: {rows}.  "
        f"Seeds on which {lab(best)} beats each other controller (mean position RMSE over the "
        f"three scenarios): {wins}.",
    ]  # fmt: skip


def notes(record: dict) -> list[str]:
    """The study's answers, in sentences computed from the record."""
    c = record["cost"]
    out = _answer_tables(record) + _answer_ranking(record) + _answer_sensitivity(record)
    out += _answer_fair(record)
    out.append(f"Cost: {c['runs_in_store']:,} runs in the store; {c['runs_total']:,} runs were "
               f"run for it in {c['seconds_running_total']:.0f} s of running over every "
               f"invocation ({c['runs_this_time']:,} runs and {c['seconds_running']:.0f} s in "
               f"the last, on {c['engine']}); the fitted "
               f"settings: {', '.join(record['best_fit']['scenario_files'])} (a fit, not the "
               "defaults).")  # fmt: skip
    if record["level"] != "full":
        out.insert(0, "A QUICK run (a few points, short runs): its numbers answer nothing.")
    return out


def table(record: dict) -> str:
    """The 36 numbers: paper, the range over the design, the best fit and its tolerance."""
    rows = []
    for n, x in record["best_fit"]["residuals"].items():
        cv = record["feasible"]["numbers"][n]
        rows.append([_label(n), record["paper"][n]["printed"], f"{fmt(cv['min'])}-"
                     f"{fmt(cv['max'])}", cv["n_reached"], fmt(x["mean"]), f"{x['ratio']:.2f}",
                     fmt(x["tolerance"], 5), "yes" if x["within"] else "no"])  # fmt: skip
    header = ["number", "paper", "design range", "points within tol.", "best fit", "ratio",
              "tolerance", "within"]  # fmt: skip
    return "\n".join(common.md_table(header, rows)) + "\n"


def render(record: dict) -> str:
    """The report's section of this study."""
    return common.section(TITLE, notes(record), table(record), record["figures"])


# ---------------------------------------------------------------------------------------------
# Command line: ``python -m analysis.calibration [--full]``


def main(argv: list[str] | None = None) -> int:
    """``python -m analysis.calibration [--out DIR] [--quick | --full] [--workers N]``."""
    import matplotlib

    matplotlib.use("Agg")
    parser = argparse.ArgumentParser(prog="python -m analysis.calibration",
                                     description=__doc__.strip().splitlines()[0])  # fmt: skip
    parser.add_argument("--out", default="paper")
    parser.add_argument("--quick", action="store_true", help="a short version (for tests)")
    parser.add_argument("--full", action="store_true",
                        help="recompute the whole study (resuming its store)")  # fmt: skip
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    record = run(args.out, quick=args.quick, workers=args.workers, full=args.full)
    try:
        check(record)
    except AssertionError as err:
        print(f"{STEM}: check failed: {err}", file=sys.stderr)
        return 1
    print(f"{STEM}: wrote {args.out}/results/{STEM}.json in {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
