"""Reliability checks of issue 7 at test size: bad inputs, long runs, seam, faults, determinism."""

from __future__ import annotations

import pytest

from analysis import reliability
from wmr import controllers


def test_every_bad_input_exits_2_with_one_line_and_writes_nothing():
    res = reliability.bad_inputs()
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


def test_heading_seam_is_crossed_every_turn_without_trouble():
    res = reliability.seam_crossings(turns=6)
    for name in controllers.NAMES:
        assert not res[name]["diverged"]
        assert res[name]["heading_seam_crossings"] == res["expected_seam_crossings"]
        assert res[name]["rmse_theta"] < 0.05


def test_faults_are_repaired_or_reported_and_saturation_holds():
    res = reliability.fault_injection()
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


def test_serial_and_two_workers_give_bit_identical_rows():
    res = reliability.determinism()
    assert res["serial_equals_parallel"] and res["parallel_repeatable"]
