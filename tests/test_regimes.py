"""The regime study (issue 14): a quick run through the engine, its statistics, its record."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from analysis import regimes

PAPER = Path(__file__).resolve().parents[1] / "paper"


def _cell(tost_equivalent: bool, significant: bool, diff: float) -> dict:
    return {"tests": {"iapid-nn-dekf - adaptive-pid": {"significant": significant,
                                                       "mean_diff": diff}},
            "tost_iapid_apid": {"equivalent": tost_equivalent}}  # fmt: skip


@pytest.mark.parametrize(("tost", "sig", "diff", "kind"), [
    (True, True, 0.0004, "equivalent"),  # a real but sub-millimetre difference: the same
    (False, True, -0.004, "better"), (False, True, 0.004, "worse"),
    (False, False, 0.004, "undecided"), (True, False, 0.0, "equivalent"),
])  # fmt: skip
def test_classification_of_iapid_vs_apid(tost, sig, diff, kind):
    assert regimes.classify(_cell(tost, sig, diff)) == kind


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("regimes")
    return regimes.run(out, quick=True, workers=1), out


@pytest.mark.slow
def test_quick_run_is_whole_consistent_and_renders(quick):
    record, out = quick
    regimes.check(record)
    stored = json.loads((out / "results" / "regimes.json").read_text())
    assert stored == json.loads(json.dumps(record))
    regimes.check(stored)
    n = len(record["factors"]["mechanism"]) * len(record["factors"]["trajectory"]) * len(
        record["factors"]["rate"]) * len(record["factors"]["gains"]) * len(
        record["factors"]["process_std"])  # fmt: skip
    assert record["verdict"]["cells"] == n == len(record["cells"])
    assert record["cost"]["runs"] == record["cost"]["runs_this_time"] > 0
    assert (out / "tables" / "regimes.md").read_text() == regimes.table(stored)
    assert regimes.render(stored).startswith(f"## {regimes.TITLE}\n")


@pytest.mark.slow
def test_a_cell_is_its_runs(quick):
    """A cell's numbers are the store's rows: the means, and the paired differences that the
    tests are made on (the same seeds, common random numbers)."""
    record, out = quick
    from wmr import sweep

    rows = sweep.read_rows(out / ".regimes-store" / "family").to_pandas()
    c = record["cells"][3]
    sel = rows[(rows.scenario == f"{c['trajectory']}@{c['mechanism']}")
               & (rows["estimator.process_std"] == c["process_std"])]  # fmt: skip
    rate = record["rates"][c["rate"]]
    sel = sel[(sel["controllers.*.mu"] == rate["mu"])
              & (sel["controllers.*.jacobian_scale"] == rate["jacobian_scale"])
              & (sel["controllers.*.gains"] == str(tuple(record["gain_sets"][c["gains"]])))]
    a = sel[sel.controller == "iapid-nn-dekf"].sort_values("seed").tail_position.to_numpy()
    b = sel[sel.controller == "adaptive-pid"].sort_values("seed").tail_position.to_numpy()
    assert len(a) == record["seeds"] and c["arms"]["iapid-nn-dekf"]["tail_mean"] == a.mean()
    assert c["tests"]["iapid-nn-dekf - adaptive-pid"]["mean_diff"] == np.mean(a - b)


@pytest.mark.skipif(not (PAPER / "results" / "regimes.json").exists(), reason="not generated")
def test_the_committed_record_passes_its_check_and_is_in_the_report():
    record = json.loads((PAPER / "results" / "regimes.json").read_text())
    regimes.check(record)
    assert regimes.render(record).rstrip() in (PAPER / "report.md").read_text()
