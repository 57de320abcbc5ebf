"""Reliability checks of issue 7 at test size: bad inputs, long runs, seam, faults, determinism;
the study's run/check/render on a quick run and on the committed record."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from analysis import reliability
from wmr import controllers

PAPER = Path(__file__).resolve().parents[1] / "paper"
COMMITTED = PAPER / "results" / "reliability.json"
needs_paper = pytest.mark.skipif(not COMMITTED.exists(), reason="paper/ not generated yet")


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """One quick run of the whole study (its parts are the checks tested below)."""
    out = tmp_path_factory.mktemp("reliability")
    return out, reliability.run(out, quick=True)


def test_every_bad_input_exits_2_with_one_line_and_writes_nothing(quick):
    res = quick[1]["bad_inputs"]
    bad = [c for c in res["cases"] if not (c["exit_code"] == 2 and c["one_line"] and
           c["starts_with_error"] and not c["traceback"] and not c["wrote_output"])]  # fmt: skip
    assert res["tried"] == len(reliability.BAD_SCENARIOS) + len(reliability.BAD_OPTIONS)
    assert bad == []


@pytest.mark.slow
def test_long_runs_are_finite_and_memory_does_not_grow_with_length():
    res = reliability.long_runs(hours=0.25)  # 90,000 steps vs 16,384; the hour runs in reproduce
    for name in controllers.NAMES:
        v = res[name]
        assert v["finite"] and not v["diverged"], (name, v)
        assert v["peak_traced_mb_long"] < 1.5 * v["peak_traced_mb_short"] + 1.0, (name, v)


def test_heading_seam_is_crossed_every_turn_without_trouble(quick):
    res = quick[1]["seam"]
    assert res["turns"] == 6
    for name in controllers.NAMES:
        assert not res[name]["diverged"]
        assert res[name]["heading_seam_crossings"] == res["expected_seam_crossings"]
        assert res[name]["rmse_theta"] < 0.05


def test_faults_are_repaired_or_reported_and_saturation_holds(quick):
    res = quick[1]["faults"]
    expected = {"repaired": True, "positive_definite_after": True}
    assert res["negative_covariance_diagonal"] == expected
    assert res["overflowing_controller"]["diverged"]
    assert res["overflowing_controller"]["cause"] == "non-finite value"
    for name in controllers.NAMES:  # every run is reported; a divergence names its cause
        rec = res["huge_noise"][name]
        assert rec["cause"] in (None, "position error exceeded divergence_bound",
                                "non-finite value")
        assert rec["diverged"] == (rec["cause"] is not None)
    assert not res["huge_noise"]["control run"]["diverged"]  # the study went on
    assert all(res["saturation_respected"].values())


def test_serial_and_two_workers_give_bit_identical_rows(quick):
    res = quick[1]["determinism"]
    assert res["serial_equals_parallel"] and res["parallel_repeatable"]


def test_quick_run_is_stored_checked_and_rendered(quick):
    out, record = quick
    stored = json.loads((out / "results" / "reliability.json").read_text())
    assert stored == record
    reliability.check(stored)
    table = (out / "tables" / "reliability.md").read_text()
    assert table == reliability.table(record)
    text = reliability.render(record)
    assert text.startswith("## Reliability\n") and table.rstrip() in text
    assert "Long runs (0.05 simulated hours," in text  # the quick run's length, from the record


def test_check_rejects_a_failed_outcome(quick):
    broken = json.loads(json.dumps(quick[1]))
    broken["summary"]["serial_equals_parallel"] = False
    with pytest.raises(AssertionError):
        reliability.check(broken)
    broken = json.loads(json.dumps(quick[1]))
    name = controllers.NAMES[0]
    broken["long_runs"][name]["peak_traced_mb_long"] = 10 * (
        broken["long_runs"][name]["peak_traced_mb_short"] + 1.0)
    with pytest.raises(AssertionError, match=name):
        reliability.check(broken)


@needs_paper
def test_committed_record_passes_the_check_and_renders_as_the_committed_report():
    record = json.loads(COMMITTED.read_text())
    reliability.check(record)
    assert reliability.render(record) in (PAPER / "report.md").read_text()
