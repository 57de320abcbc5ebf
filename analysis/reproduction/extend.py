"""Extend the committed reproduction record with the runs of added controllers, the other
controllers' committed numbers kept byte for byte.

``make reproduce`` reruns everything; when a controller joins the registry (``adaptive-bsc``,
``nmpc``) only its runs are new, and a full rerun on another CPU moves the others' numbers in
their last bits (the committed record was made with AVX-512; an AVX2 machine's libm and BLAS round
differently, ``tests/cases.CROSS_MACHINE_RTOL``).  :func:`extend` runs only the new controllers'
jobs of :func:`analysis.reproduction.build_jobs` and merges them with the study's own functions:

- ``rmse.csv``: the committed rows kept as text, the new rows inserted, all in ``build_jobs``
  order (the order a full run writes);
- each scenario's ``runs`` gain the new controllers' entries (``summarise`` of their rows); the
  paired comparisons, rankings and equivalence tests are over the paper's four controllers
  (``controllers.PAPER_NAMES``) and stay as committed;
- ``feed_forward_best`` is recomputed over every controller from ``rmse.csv``'s position RMSEs
  (the metric it compares), ``pose_source`` from ``controllers.NAMES``, ``divergences`` in row
  order (the committed entries kept);
- Tables 1-3 and the ablation figure re-rendered from the record.

Usage: ``python -m analysis.reproduction.extend --out paper nmpc``.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

from analysis import common
from analysis import reproduction as rep
from analysis.reproduction import figures, stats
from analysis.reproduction.views import TABLE_NUMBER
from wmr import controllers
from wmr.closedloop.result import Row
from wmr.engine.study import ROW_HEADER, run_jobs
from wmr.io import atomic_write_text, write_csv

__all__ = ["extend", "read_rows", "main"]


def read_rows(path: Path) -> list[Row]:
    """The rows of an ``rmse.csv`` (its columns only: the tail RMSEs, ``diverged_at`` and
    ``cause`` are not in the file and are left at their defaults)."""
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        return [Row(d["scenario"], d["controller"], d["variant"], int(d["seed"]),
                    float(d["rmse_x"]), float(d["rmse_y"]), float(d["rmse_theta"]),
                    float(d["rmse_position"]), d["diverged"] == "true")
                for d in reader]  # fmt: skip


def _key(scenario: str, controller: str, variant: str, seed: int) -> tuple:
    return (scenario, controller, variant, seed)


def extend(out, names, *, workers: int | None = None, progress: bool | None = None) -> dict:
    """Add the runs of controllers ``names`` to the record in ``out`` (written back); return it.

    ``ValueError`` if a name is not registered or already has runs in the record.
    """
    out = Path(out)
    names = list(names)
    for n in names:
        controllers.get(n)
    record = common.load_record(out, rep.STEM)
    csv_path = out / "results" / "rmse.csv"
    old_rows = read_rows(csv_path)
    have = {r.controller for r in old_rows}
    if clash := sorted(set(names) & have):
        raise ValueError(f"{csv_path}: the record already has runs of {', '.join(clash)}")
    seeds = record["seeds"]
    scenarios = rep.paper_scenarios()
    new_rows = run_jobs(rep.build_jobs(scenarios, seeds, names=names), workers,
                        progress=progress, desc=f"{rep.STEM} +{'+'.join(names)}")  # fmt: skip
    new_summary = rep.summarise(new_rows)

    # rmse.csv in build_jobs order over every controller: committed text for the old rows
    with open(csv_path, newline="") as f:
        old_text = {_key(*r[:3], int(r[3])): r for r in list(csv.reader(f))[1:]}
    new_by_key = {_key(r.scenario, r.controller, r.variant, r.seed): r for r in new_rows}
    order = [_key(j.scenario.name, j.controller, j.variant, j.seed)
             for j in rep.build_jobs(scenarios, seeds)]  # fmt: skip
    missing = [k for k in order if k not in old_text and k not in new_by_key]
    assert not missing and len(order) == len(old_text) + len(new_by_key), missing[:5]
    write_csv(csv_path, ROW_HEADER,
              (old_text[k] if k in old_text else new_by_key[k].csv_row() for k in order))

    for sc, entry in record["scenarios"].items():
        runs = dict(entry["runs"])
        runs.update(new_summary["scenarios"][sc]["runs"])
        entry["runs"] = {n: runs[n] for n in controllers.NAMES if n in runs}
    table = stats.by_run(old_rows + new_rows)  # position RMSEs: in rmse.csv, exact
    for sc in record["feed_forward_best"]:
        record["feed_forward_best"][sc] = rep._feed_forward_best(table, sc)
    record["pose_source"] = {
        sc: {n: "filtered" if s.estimator.filters(n) else "raw" for n in controllers.NAMES}
        for sc, s in scenarios.items()
    }  # fmt: skip
    old_div = {_key(d["scenario"], d["controller"], d["variant"], d["seed"]): d
               for d in record["divergences"]}  # fmt: skip
    new_div = {k: {"scenario": r.scenario, "controller": r.controller, "variant": r.variant,
                   "seed": r.seed, "diverged_at": r.diverged_at, "cause": r.cause}
               for k, r in new_by_key.items() if r.diverged}  # fmt: skip
    record["divergences"] = [old_div.get(k) or new_div[k] for k in order
                             if k in old_div or k in new_div]  # fmt: skip
    ablation = figures.ablation_figure(record, out)
    record["figures"] = [f for f in record["figures"] if f != ablation] + [ablation]
    for sc in record["scenarios"]:
        num = TABLE_NUMBER[sc]
        atomic_write_text(out / "tables" / f"table{num}.md", rep.table_markdown(record, sc))
        atomic_write_text(out / "tables" / f"table{num}.tex", rep.table_latex(record, sc))
    common.write_record(out, rep.STEM, record)
    return record


def main(argv: list[str] | None = None) -> int:
    """``python -m analysis.reproduction.extend [--out paper] [--workers N] NAME...``."""
    parser = argparse.ArgumentParser(prog="python -m analysis.reproduction.extend",
                                     description=__doc__.strip().splitlines()[0])  # fmt: skip
    parser.add_argument("names", nargs="+", help="controllers to add")
    parser.add_argument("--out", default="paper")
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    record = extend(args.out, args.names, workers=args.workers)
    rep.check(record)
    print(f"{args.out}/results/{rep.STEM}.json: + {', '.join(args.names)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
