"""Margins of adaptive-bsc frozen at its estimates (analysis/margins/adaptive.py): its frozen
law against backstepping's CasADi linearisation, a closed-form gain-margin shift, and the
committed record against BSC's margins."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from analysis import margins as study
from analysis.margins import adaptive as ma
from wmr import scenario as scn
from wmr.linear.loops import BSC_GAINS, backstepping_controller, backstepping_loops, operating_point
from wmr.linear.margins import analyse_loops

PAPER = Path(__file__).resolve().parents[1] / "paper"
#: Central differences of step 1e-6 on a smooth law: O(h^2) + round-off / h ~ 1e-10.
FD_TOL = 1e-8
#: Margins computed twice on loops equal to FD_TOL: their crossovers agree to ~1e-8 [dB, deg].
MARGIN_TOL = 1e-6


def _ops():
    sc = {n: scn.load(scn.builtin(n)) for n in ("sinusoid", "lemniscate")}
    return [operating_point(sc[n], w) for n in ("sinusoid", "lemniscate")
            for w in ("mean", "max-curvature")]  # fmt: skip


@pytest.mark.parametrize("op", _ops(), ids=lambda o: o.label)
def test_frozen_at_the_nominal_map_is_backsteppings_law(op):
    """adaptive_bsc.law (compiled, differenced) at the estimates (1, 0, 1, 0) equals
    backstepping's gain by CasADi AD of wmr.model.symbolic's law: two implementations of eq. 7."""
    D = ma.policy_gain(op, [1.0, 0.0, 1.0, 0.0])
    D_bsc = np.asarray(backstepping_controller(BSC_GAINS, op).D)
    np.testing.assert_allclose(D, D_bsc, rtol=0, atol=FD_TOL)


def test_a_frozen_gain_error_shifts_the_decoupled_v_margin_by_its_decibels():
    """On a straight line (w_r = 0) the v loop is decoupled (de1' = -dv, v = k1 e1): frozen at
    v_gain^ = a on the ideal plant its loop gain is BSC's / a, so its gain margin is BSC's plus
    20 log10(a) dB, and its phase margin is the one at that gain."""
    from analysis.margins.nmpc import nmpc_loops

    op = _ops()[0]
    assert op.w_r == 0.0
    bsc = analyse_loops(backstepping_loops(op), cross_check=False)
    for a in (0.8, 0.95, 1.2):
        D = ma.policy_gain(op, [a, 0.0, 1.0, 0.0])
        res = analyse_loops(nmpc_loops(op, D), cross_check=False)
        gm, gm_bsc = res["v"].gain_margin_db, bsc["v"].gain_margin_db
        assert gm == pytest.approx(gm_bsc + 20 * math.log10(a), abs=MARGIN_TOL)
        assert res["w"].gain_margin_db == pytest.approx(bsc["w"].gain_margin_db, abs=MARGIN_TOL)


def test_the_plants_input_map_undoes_matching_estimates():
    """Frozen at the wheel-radius plant's true map (0.8, 0, 0.8, 0) on that plant, the loop
    G D_law is BSC's on the ideal plant (G G^^-1 = I), and its margins are BSC's."""
    op = _ops()[3]
    G = ma.input_map(0.8, 0.0, 0.8, 0.0)
    D = G @ ma.policy_gain(op, [0.8, 0.0, 0.8, 0.0])
    np.testing.assert_allclose(D, np.asarray(backstepping_controller(BSC_GAINS, op).D),
                               rtol=0, atol=FD_TOL)  # fmt: skip


def test_committed_record_frozen_margins_equal_bscs_once_adapted():
    """The stored rows: the end-of-run estimates are within 0.03 of each plant's truth (0.8 on
    the wheel radius), and check() holds (BSC's margins within MATCH_DB / MATCH_DEG)."""
    record = json.loads((PAPER / "results" / "margins.json").read_text())
    rec = record["adaptive_bsc"]
    assert set(rec) == set(ma.PLANTS)
    assert rec["wheel-radius"]["truth"]["v_gain"] == 0.8
    for e in rec.values():
        for n, x in e["estimates"].items():
            assert abs(x - e["truth"][n]) <= 0.03, (e["scenario"], n, x)
        assert list(e["points"]) == list(record["operating_points"])
    study.check(record)
    ma.check(record)


def test_check_fails_on_an_unadapted_loop():
    """A planted fault: BSC's gain on the wheel-radius robot (estimates left at nominal) is not
    adapted, and check() says so."""
    record = json.loads((PAPER / "results" / "margins.json").read_text())
    record["adaptive_bsc"]["wheel-radius"]["estimates"].update(v_gain=1.0, w_gain=1.0)
    with pytest.raises(AssertionError, match="wheel-radius"):
        ma.check(record)
