"""Reproduction of Tables 1-3 and Figures 4-10, with statistics over seeds and ablations.

Runs the paper's 3 scenarios x the registered controllers x N seeds (common random numbers: every
controller sees the same noise for a seed), plus ablation variants, and writes into ``out``:

- ``results/rmse.csv`` — one row per run (columns of ``wmr.engine.study.ROW_HEADER``);
- ``results/reproduction.json`` — the record: means, stds, divergences, rankings, paired
  comparisons;
- ``tables/table{1,2,3}.{md,tex}`` — the paper's value beside ours (mean ± std) and the ratio;
- ``figures/reproduction_*.png`` — the equivalents of Figs. 4-10 and the ablations.

Nothing is tuned to make the paper's ranking appear; the verdict is computed, not written.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from analysis import common
from analysis.reproduction import figures, stats, views
from analysis.reproduction.ablations import (
    Variant,
    backstepping_damping,
    damping_phrase,
    noise_scaled,
    pose_source,
    pose_source_changes,
    scaled,
)
from analysis.reproduction.stats import ALPHA, AXES, EQUIVALENCE_METRICS, MARGIN, TAIL
from analysis.reproduction.views import REGIMES_SECTION, TABLE_NUMBER, gains_text
from wmr import controllers
from wmr import scenario as scn
from wmr.closedloop.metrics import TRANSIENT
from wmr.engine.study import ROW_HEADER, Job, Row, run_jobs
from wmr.io import atomic_write_text, write_csv

__all__ = ["STEM", "TITLE", "PAPER_RMSE", "VARIANTS", "REGIMES_SECTION", "NOT_IN_PAPER",
           "build_jobs", "summarise", "gain_excursions", "adaptation_defaults", "table_markdown",
           "table_latex", "run", "check", "render"]  # fmt: skip

STEM = "reproduction"
TITLE = "Tables 1–3: the paper beside this reproduction"

#: Tables 1-3 of the paper: RMSE (x, y, theta) per scenario and controller.
PAPER_RMSE = {
    "lemniscate": {
        "iapid-nn-dekf": (0.078769, 0.12086, 0.1672),
        "backstepping": (0.1139, 0.2066, 0.3409),
        "adaptive-nn": (0.1041, 0.1832, 0.2973),
        "adaptive-pid": (0.0917, 0.1523, 0.2375),
    },
    "sinusoid": {
        "iapid-nn-dekf": (0.01233, 0.015138, 0.088707),
        "backstepping": (0.0475, 0.0563, 0.1586),
        "adaptive-nn": (0.0319, 0.0380, 0.1134),
        "adaptive-pid": (0.0384, 0.0453, 0.1326),
    },
    "sinusoid-perturbed": {
        "iapid-nn-dekf": (0.021495, 0.016504, 0.090142),
        "backstepping": (0.0908, 0.1076, 0.1794),
        "adaptive-nn": (0.0617, 0.0739, 0.12512),
        "adaptive-pid": (0.0583, 0.0415, 0.1252),
    },
}

#: Seeds of a quick run (``run(..., quick=True)``).
QUICK_SEEDS = 3

#: Backstepping gains (k1, k2, k3): the default, and the two ablations.
_BSC_DEFAULT = controllers.get("backstepping").Settings().gains
_BSC_LOW = (0.5, 2.0, 1.4)
_BSC_KANAYAMA = (10.0, 64.0, 16.0)


#: The ablations, in report order.  Which controllers each applies to is derived from the
#: settings fields it names (``analysis.reproduction.ablations``).
VARIANTS: dict[str, Variant] = {v.name: v for v in (
    Variant("rotation-printed",
            "the paper's printed error matrix of eqs. 4/6 instead of the rotation",
            settings={"printed_rotation": True}),
    Variant("nn-jacobian-printed",
            "the printed network Jacobian of eqs. 22-24 instead of the chain rule",
            settings={"printed_jacobian": True}),
    Variant("feed-forward", "eq. 7 plus the feed-forward (v_r cos e3, w_r)",
            settings={"feed_forward": True}),
    Variant("pose-filtered", "every controller uses the pose-EKF estimate",
            scenario=pose_source("filtered"), affects=pose_source_changes),
    Variant("pose-raw", "iapid-nn-dekf uses the raw measured pose (no localisation filter)",
            scenario=pose_source("raw"), affects=pose_source_changes),
    Variant("bsc-gains-low", f"backstepping gains {gains_text(_BSC_LOW)}: "
            + damping_phrase(_BSC_LOW, _BSC_DEFAULT),
            settings={"gains": _BSC_LOW}, only=("backstepping",)),
    Variant("bsc-gains-kanayama", f"backstepping gains {gains_text(_BSC_KANAYAMA)} of "
            "Kanayama et al. (1990): " + damping_phrase(_BSC_KANAYAMA, _BSC_DEFAULT),
            settings={"gains": _BSC_KANAYAMA}, only=("backstepping",)),
    Variant("noise-free", "no pose-measurement noise", scenario=noise_scaled(0.0)),
    Variant("noise-x3", "pose-measurement noise std x3 (0.03 m, 0.03 rad)",
            scenario=noise_scaled(3.0)),
    Variant("mu-x0.1", "SGD learning rates mu scaled by 0.1", settings={"mu": scaled(0.1)},
            where={"adapt": True}),
    Variant("mu-x10", "SGD learning rates mu scaled by 10", settings={"mu": scaled(10.0)},
            where={"adapt": True}),
)}  # fmt: skip


def paper_scenarios() -> dict[str, scn.Scenario]:
    """The paper's three scenarios as shipped, by name."""
    return {name: scn.load(scn.builtin(name)) for name in scn.PAPER_SCENARIOS}


def build_jobs(scenarios: dict, seeds: int, names=None, variants=VARIANTS) -> list[Job]:
    """Default runs of every controller plus each variant of the controllers it applies to."""
    names = list(names or controllers.NAMES)
    jobs = []
    for sc in scenarios.values():
        for name, seed in itertools.product(names, range(seeds)):
            jobs.append(Job(sc, name, seed))
        for variant in variants.values():
            for name in (n for n in variant.targets(sc) if n in names):
                sc_v, st_v = variant.apply(sc, name)
                jobs.extend(Job(sc_v, name, seed, variant.name, st_v) for seed in range(seeds))
    return jobs


def _scenario_summary(table: dict, sc: str) -> dict:
    names = [n for n in controllers.NAMES if (sc, n, "default") in table]
    paper_names = [n for n in controllers.PAPER_NAMES if n in names]
    paper = PAPER_RMSE[sc]
    complete = set(paper_names) == set(paper)
    entry: dict = {"runs": {}, "paired": {}, "ranking": {}, "paper_ranking": {}}
    for (s, n, v), d in table.items():
        if s == sc:
            rec = {a: stats.describe(d[a]) for a in (*AXES, "position", *TAIL)}
            rec["n_seeds"] = int(len(d["seed"]))
            rec["n_diverged"] = int(np.sum(d["diverged"]))
            entry["runs"].setdefault(n, {})[v] = rec
    entry["ranking"]["default"] = stats.ranking(table, sc, paper_names)
    entry["paper_ranking"] = {
        axis: sorted(paper, key=lambda n: paper[n][i]) for i, axis in enumerate(AXES)
    }
    entry["paper_ranking_reproduced"] = {
        axis: entry["ranking"]["default"][axis] == entry["paper_ranking"][axis]
        for axis in AXES if complete
    }  # fmt: skip
    for a, b in itertools.combinations(paper_names, 2):
        entry["paired"][f"{a} vs {b}"] = {
            axis: stats.paired(table[(sc, a, "default")][axis], table[(sc, b, "default")][axis])
            for axis in (*AXES, "position", "tail_position")
        }
    if complete:
        entry["paper_ranking_contradicted"] = {
            axis: stats.contradictions(entry["paper_ranking"][axis], entry["paired"], axis)
            for axis in AXES
        }
    for variant in VARIANTS:
        changed = {n: variant for n in paper_names if (sc, n, variant) in table}
        if changed:
            entry["ranking"][variant] = stats.ranking(table, sc, paper_names, changed)
    return entry


def _feed_forward_best(table: dict, sc: str) -> dict:
    """The controller with the lowest mean position RMSE on ``sc`` without and with the
    ``feed-forward`` variant (the controllers it applies to on its runs, the others on their
    default runs): :func:`analysis.reproduction.stats.lowest_mean`."""
    names = [n for n in controllers.NAMES if (sc, n, "default") in table]
    return {"without": stats.lowest_mean(table, sc, names),
            "with": stats.lowest_mean(table, sc, names, "feed-forward")}  # fmt: skip


def _damping() -> dict:
    """The lateral-loop damping of backstepping's default gains and of every variant that sets
    them (:func:`analysis.reproduction.ablations.backstepping_damping`)."""
    out = {"default": backstepping_damping(_BSC_DEFAULT)}
    for v in VARIANTS.values():
        if "gains" in v.settings and v.only == ("backstepping",):
            out[v.name] = backstepping_damping(v.settings["gains"])
    return out


def summarise(rows: list[Row]) -> dict:
    """Statistics, rankings and paired comparisons of ``rows``, as stored in the record; the
    equivalence tests of the PID family (:func:`analysis.reproduction.stats.equivalence`), the
    best controller without and with feed-forward, and backstepping's damping per gain set."""
    table = stats.by_run(rows)
    scenarios = sorted({k[0] for k in table}, key=list(PAPER_RMSE).index)
    out: dict = {"scenarios": {}, "variants": {k: v.description for k, v in VARIANTS.items()},
                 "alpha": ALPHA}  # fmt: skip
    for sc in scenarios:
        out["scenarios"][sc] = _scenario_summary(table, sc)
    out["equivalence"] = {
        "margin": MARGIN, "alpha": ALPHA, "metrics": list(EQUIVALENCE_METRICS),
        "definition": "paired-t TOST of a - b at the margin (each one-sided test at alpha: "
                      "ci_low, ci_high is the 1 - 2 alpha interval of the mean difference, m); "
                      "wilcoxon_p: two-sided signed-rank test of the same differences, p_holm: "
                      "Holm-adjusted over every (scenario, pair) of one metric",
        "scenarios": stats.equivalence(table, scenarios),
    }  # fmt: skip
    out["feed_forward_best"] = {sc: _feed_forward_best(table, sc) for sc in scenarios
                                if any(k[0] == sc and k[2] == "feed-forward" for k in table)}
    out["backstepping_damping"] = _damping()
    return out


def gain_excursions(scenarios: dict, seed: int = 0) -> dict:
    """How far SGD moves the PID gains: max over the run of |K - K0|, absolute and relative to
    max(|K0|, 0.1), per gain, for the adaptive controllers (seed ``seed``)."""
    from wmr.closedloop.sim import simulate
    from wmr.controllers.pid import GAIN_NAMES

    out: dict = {}
    for sc_name, sc in scenarios.items():
        for name in ("adaptive-pid", "iapid-nn-dekf"):
            K = simulate(sc, name, seed).gains()
            K0 = np.array(sc.settings(name).gains)
            dev = np.abs(K - K0).max(axis=0)
            out.setdefault(sc_name, {})[name] = {
                "max_abs": dict(zip(GAIN_NAMES, map(float, dev), strict=True)),
                "max_rel": dict(zip(GAIN_NAMES, map(float, dev / np.maximum(np.abs(K0), 0.1)),
                                    strict=True)),
            }  # fmt: skip
    return out


def adaptation_defaults(scenarios: dict) -> dict:
    """The settings at which the PID family's equivalence is measured, per scenario: APID's
    initial gains, its SGD rates and how the plant Jacobian is read (``jacobian_scale``)."""
    out = {}
    for name, sc in scenarios.items():
        st = sc.settings("adaptive-pid")
        out[name] = {"gains": list(st.gains), "mu": list(st.mu),
                     "jacobian_scale": st.jacobian_scale, "gradient": st.gradient}  # fmt: skip
    return out


def run(out, *, quick: bool = False, workers: int | None = None, seeds: int = 20,
        progress: bool | None = None) -> dict:  # fmt: skip
    """Run the reproduction into ``out`` (``QUICK_SEEDS`` seeds at most when ``quick``), write
    ``results/rmse.csv``, the record, Tables 1-3 and the figures; return the record."""
    out = Path(out)
    seeds = min(seeds, QUICK_SEEDS) if quick else seeds
    scenarios = paper_scenarios()
    rows = run_jobs(build_jobs(scenarios, seeds), workers, progress=progress, desc=STEM)
    write_csv(out / "results" / "rmse.csv", ROW_HEADER, (r.csv_row() for r in rows))
    record = summarise(rows)
    record["seeds"] = seeds
    record["transient_s"] = TRANSIENT
    record["gain_excursion"] = gain_excursions(scenarios)
    record["adaptation_defaults"] = adaptation_defaults(scenarios)
    record["pose_source"] = {
        sc: {n: "filtered" if s.estimator.filters(n) else "raw" for n in controllers.NAMES}
        for sc, s in scenarios.items()
    }
    record["divergences"] = [
        {"scenario": r.scenario, "controller": r.controller, "variant": r.variant, "seed": r.seed,
         "diverged_at": r.diverged_at, "cause": r.cause}
        for r in rows if r.diverged
    ]  # fmt: skip
    record["figures"] = (figures.tracking_figures(scenarios, out)
                         + [figures.ablation_figure(record, out)])  # fmt: skip
    for sc in record["scenarios"]:
        num = TABLE_NUMBER[sc]
        atomic_write_text(out / "tables" / f"table{num}.md", table_markdown(record, sc))
        atomic_write_text(out / "tables" / f"table{num}.tex", table_latex(record, sc))
    common.write_record(out, STEM, record)
    return record


def check(record: dict) -> None:
    """Every run is present and accounted for: each scenario of the paper, every controller's
    default runs and each variant's runs of the controllers it applies to, over all the seeds;
    every run has a finite RMSE or is counted as diverged."""
    seeds = record["seeds"]
    assert list(record["scenarios"]) == list(PAPER_RMSE), list(record["scenarios"])
    n_diverged = 0
    for sc_name, sc in paper_scenarios().items():
        runs = record["scenarios"][sc_name]["runs"]
        expected = [(n, "default") for n in controllers.NAMES]
        expected += [(n, v.name) for v in VARIANTS.values() for n in v.targets(sc)]
        present = [(n, v) for n, d in runs.items() for v in d]
        assert sorted(present) == sorted(expected), (sc_name, sorted(set(present) ^ set(expected)))
        for n, v in expected:
            rec = runs[n][v]
            assert rec["n_seeds"] == seeds, f"{sc_name}/{n}/{v}: {rec['n_seeds']} of {seeds} seeds"
            assert rec["position"]["n"] + rec["n_diverged"] == seeds, (sc_name, n, v, rec)
            n_diverged += rec["n_diverged"]
    assert len(record["divergences"]) == n_diverged, (len(record["divergences"]), n_diverged)


# --- Rendering: the tables and the report's sections, from the record ------------------------


#: The mark of a table row whose controller is not in the paper (its "paper" cell is empty).
NOT_IN_PAPER = "†"
_NOT_IN_PAPER_NOTE = (f"{NOT_IN_PAPER} not in the paper: a controller this suite adds "
                      "(no published value to compare with)")  # fmt: skip


def _table_names(record: dict, scenario: str) -> list[str]:
    """The rows of Tables 1-3: the paper's controllers in table order, then the other
    registered controllers with runs in the record (marked :data:`NOT_IN_PAPER`)."""
    runs = record["scenarios"][scenario]["runs"]
    paper = [n for n in controllers.PAPER_NAMES if n in runs]
    return paper + [n for n in controllers.NAMES if n in runs and n not in paper]


def _table_cells(record: dict, scenario: str):
    """Per row of Tables 1-3: (controller, axis index, axis, paper's RMSE or None, our mean,
    our std, "diverged/seeds")."""
    entry = record["scenarios"][scenario]
    for name in _table_names(record, scenario):
        rec = entry["runs"][name]["default"]
        for i, axis in enumerate(AXES):
            p = PAPER_RMSE[scenario][name][i] if name in PAPER_RMSE[scenario] else None
            yield (name, i, axis, p, rec[axis]["mean"], rec[axis]["std"],
                   f"{rec['n_diverged']}/{rec['n_seeds']}")  # fmt: skip


def _row_label(name: str, scenario: str) -> str:
    mark = "" if name in PAPER_RMSE[scenario] else f" {NOT_IN_PAPER}"
    return controllers.label(name) + mark


def table_markdown(record: dict, scenario: str) -> str:
    """Table 1, 2 or 3 (``scenario``) in Markdown: the paper's RMSE beside ours and the ratio;
    the controllers the paper does not have below, marked."""
    md = [f"Table {TABLE_NUMBER[scenario]} ({scenario}): RMSE, paper vs this reproduction "
          f"(mean ± std over seeds, ratio = ours / paper)", "",
          "| controller | axis | paper | ours | ratio | diverged |", "|---|---|---|---|---|---|"]
    extra = False
    for name, _, axis, p, m, s, div in _table_cells(record, scenario):
        extra = extra or p is None
        ours = "—" if m is None else f"{m:.4f} ± {s:.4f}"
        ratio = "—" if m is None or p is None else f"{m / p:.2f}"
        paper = "—" if p is None else f"{p:.4f}"
        md.append(f"| {_row_label(name, scenario)} | {axis} | {paper} | {ours} | {ratio} "
                  f"| {div} |")  # fmt: skip
    if extra:
        md += ["", _NOT_IN_PAPER_NOTE + "."]
    return "\n".join(md) + "\n"


def table_latex(record: dict, scenario: str) -> str:
    """Table 1, 2 or 3 (``scenario``) as a LaTeX booktabs tabular (the controllers the paper
    does not have below, marked with a dagger)."""
    tex = [r"\begin{tabular}{llrrrr}", r"\toprule",
           r"Controller & Axis & Paper & Ours (mean $\pm$ std) & Ratio & Diverged \\",
           r"\midrule"]  # fmt: skip
    names = _table_names(record, scenario)
    for name, i, axis, p, m, s, div in _table_cells(record, scenario):
        ours = "--" if m is None else f"{m:.4f} $\\pm$ {s:.4f}"
        ratio = "--" if m is None or p is None else f"{m / p:.2f}"
        paper = "--" if p is None else f"{p:.4f}"
        mark = "" if p is not None else r"$^\dagger$"
        first = controllers.label(name) + mark if i == 0 else ""
        sym = "\\theta" if axis == "theta" else axis
        tex.append(f"{first} & ${sym}$ & {paper} & {ours} & {ratio} & {div} \\\\")
        if i == len(AXES) - 1:
            tex.append(r"\midrule" if name != names[-1] else r"\bottomrule")
    tex.append(r"\end{tabular}")
    if names[-1] not in PAPER_RMSE[scenario]:
        tex.append(r"$^\dagger$ " + _NOT_IN_PAPER_NOTE.split(" ", 1)[1] + ".")
    return "\n".join(tex) + "\n"


def render(record: dict) -> str:
    """The report's sections of this study: Tables 1-3, the ranking verdict, the ablations."""
    intro = (f"Mean ± std over {record['seeds']} seeds (common random numbers: all controllers "
             "see the same noise for a seed); RMSE of eq. 64 over the true poses, θ wrapped; "
             "ratio = ours / paper.  Pose each controller acts on (as in the paper, only the "
             "proposed scheme localises; the `pose-filtered` / `pose-raw` ablations give "
             "everyone the same): "
             + ", ".join(f"{controllers.label(n)} {src}" for n, src in
                         next(iter(record["pose_source"].values())).items()) + ".")  # fmt: skip
    tables = "\n".join(table_markdown(record, sc) for sc in record["scenarios"])
    return "\n".join([common.section(TITLE, intro, tables), views.ranking_section(record),
                      views.ablations_section(record)])  # fmt: skip

