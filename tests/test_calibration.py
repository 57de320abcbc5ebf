"""The calibration study (issue 15): its prior, discrepancy, methods, store and record.

Oracles: the shipped scenarios (the prior's defaults must map back onto them bit for bit), the
reproduction's own copy of the paper's tables, closed forms (the lemniscate's peak speed, the
log ratios of a scaled table, Morris effects of a linear function, the Ishigami function's Sobol
indices), scipy (``sobol_indices``, ``kendalltau``), brute force (Pareto fronts), and the
committed record against the committed scenario files.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest

from analysis import _calibration_prior as prior
from wmr import scenario as scn
from wmr.sim import simulate

ROOT = Path(__file__).resolve().parent.parent


# ---------------------------------------------------------------------------------------------
# Step 1: the prior


def test_paper_numbers_are_the_reproductions_and_their_rounding():
    from analysis.reproduction import PAPER_RMSE

    table = np.array([PAPER_RMSE[s][c][i] for s in prior.SCENARIOS for c in prior.CONTROLLERS
                      for i in range(3)])  # fmt: skip
    assert np.array_equal(prior.PAPER, table)
    assert prior.NUMBER_NAMES[0] == "lemniscate/iapid-nn-dekf/x"
    assert len(set(prior.NUMBER_NAMES)) == 36
    # the printed digits set the rounding: "0.0380" keeps its trailing zero (4 decimals)
    assert prior.half_unit("0.0380") == pytest.approx(5e-5, rel=1e-12)
    assert prior.half_unit("0.078769") == pytest.approx(5e-7, rel=1e-12)
    assert prior.ROUNDING.shape == (36,)


def test_prior_is_written_down_with_provenance_and_shares_settings():
    shared = [s for s in prior.PRIOR if s.group == "shared"]
    assert len(shared) >= 8
    for s in prior.PRIOR:
        assert len(s.provenance) > 20, s.name
        f = s.factor
        if s.default is None:  # no saturation: beyond the range's top
            continue
        if f.levels is not None:
            assert s.default in f.levels, s.name
        else:
            assert f.low <= s.default <= f.high, s.name
            # the default's unit coordinate maps back onto it
            assert f.value(s.default_u()) == pytest.approx(s.default, rel=1e-9), s.name
    # what the paper gives is never varied
    assert not {"mu", "p0", "q", "r", "initial_pose"} & set(prior.NAMES)
    # dt divides every run length and the 15-20 s window
    dts = prior.PRIOR[prior.NAMES.index("dt")].factor.levels
    for dt, T in itertools.product(dts, prior.PRIOR[prior.NAMES.index("duration")].factor.levels):
        for t in (T, 15.0, 20.0):
            assert abs(t / dt - round(t / dt)) < 1e-9, (dt, t)
    record = prior.prior_json()
    assert set(record) == set(prior.NAMES)
    assert all("provenance" in r and ("levels" in r or "range" in r) for r in record.values())


@pytest.mark.parametrize("name", prior.SCENARIOS)
def test_defaults_map_back_onto_the_shipped_scenarios_bit_for_bit(name):
    v = prior.defaults()
    shipped = scn.load(scn.builtin(name))
    for sc, c, st in prior.cases(v, scenarios=(name,)):
        assert st == shipped.settings(c)
        a = simulate(sc, c, 3, settings=st)
        b = simulate(shipped, c, 3)
        assert np.array_equal(a.q, b.q), (name, c)


def test_settings_are_shared_across_the_controllers():
    v = {**prior.defaults(), "printed_rotation": True, "pid_scale_v": 0.5, "bsc_k1": 3.0,
         "dann_hidden": 12, "iapid_hidden": 5, "feed_forward": True}  # fmt: skip
    apid, iapid = prior.settings("adaptive-pid", v), prior.settings("iapid-nn-dekf", v)
    bsc, dann = prior.settings("backstepping", v), prior.settings("adaptive-nn", v)
    assert apid.gains == iapid.gains == (2.5, 2.5, 0.0, 10.0, 2.0, 0.0)
    assert apid.feed_forward and iapid.feed_forward and iapid.hidden == 5
    assert bsc.gains == dann.gains == (3.0, 10.0, 4.0) and dann.hidden == 12
    assert all(s.printed_rotation for s in (apid, iapid, bsc, dann))
    assert iapid.mu == (0.9,) * 6 and iapid.p0 == 1000.0 and iapid.q == 1e-5 and iapid.r == 1000.0


def test_saturation_is_relative_to_the_reference_peak():
    # Gerono: v_r = a W sqrt(cos^2 phi + cos^2 2 phi), largest at phi = 0: a W sqrt(2)
    a, period, h = 1.5, 30.0, 2.0
    lim = prior.limits("lemniscate", {"size": a, "period": period}, 0.01, 40.0, h)
    assert lim["v_max"] == pytest.approx(h * a * 2 * math.pi / period * math.sqrt(2), rel=1e-12)
    # sinusoid: v_r = sqrt(s^2 + (A w cos wt)^2), largest at t = 0
    lim = prior.limits("sinusoid", {"speed": 0.5, "amplitude": 1.0, "omega": 0.5}, 0.01, 40.0, 1)
    assert lim["v_max"] == pytest.approx(math.hypot(0.5, 0.5), rel=1e-12)


def test_perturbation_readings():
    assert prior.perturbation("velocity", math.log(2) / math.log(6)) == {
        "disturbance": [{"start": 15.0, "stop": 20.0, "velocity": [0.1, 0.3]}]}
    g = prior.perturbation("gain", 0.2)["plant"]["change"]
    assert [c["at"] for c in g] == [15.0, 20.0] and g[0]["v_gain"] == pytest.approx(0.7)
    assert g[1]["v_gain"] == g[1]["w_gain"] == 1.0
    s = prior.perturbation("slip", 1.0)["plant"]["change"]
    assert s[0]["slip"] == pytest.approx(0.5) and s[1]["slip"] == 0.0
    with pytest.raises(ValueError):
        prior.perturbation("wind", 0.5)


def test_a_unit_gain_change_is_no_perturbation():
    """The 'gain' reading at gain 1 is the unperturbed sinusoid (the non-ideal plant path is
    refined to 1e-6 of the RMSE, DESIGN §3.3)."""
    v = {**prior.defaults(), "perturbation": "gain", "perturbation_size": 0.5, "duration": 25.0}
    (sc_p, c, st), = prior.cases(v, scenarios=("sinusoid-perturbed",), names=("backstepping",))
    (sc_u, _, _), = prior.cases(v, scenarios=("sinusoid",), names=("backstepping",))
    assert not sc_p.plant.ideal and sc_u.plant.ideal
    a, b = simulate(sc_p, c, 0, settings=st), simulate(sc_u, c, 0, settings=st)
    for axis in ("x", "y", "theta"):
        assert a.rmse[axis] == pytest.approx(b.rmse[axis], rel=1e-6)


# ---------------------------------------------------------------------------------------------
# Step 2: the discrepancy and the tolerance


def test_discrepancy_closed_forms():
    d = prior.discrepancy(prior.PAPER)
    assert d["rms_log_ratio"] == 0.0 and d["max_abs_log_ratio"] == 0.0
    scale = np.where(np.arange(36) % 2 == 0, 2.0, 0.5)
    d = prior.discrepancy(prior.PAPER * scale)
    assert d["rms_log_ratio"] == pytest.approx(math.log(2), rel=1e-12)
    one_nan = prior.PAPER.copy()
    one_nan[5] = np.nan  # a diverged mean counts as DIVERGED_RMSE
    lr = prior.log_ratios(one_nan)
    assert lr[5] == pytest.approx(math.log(prior.DIVERGED_RMSE / prior.PAPER[5]))
    assert np.all(lr[np.arange(36) != 5] == 0.0)
    # batched: (..., 36)
    assert prior.discrepancy(np.stack([prior.PAPER, 2 * prior.PAPER]))["rms_log_ratio"][1] == \
        pytest.approx(math.log(2))


def test_tolerance_is_rounding_plus_seed_spread_of_one_run():
    tol = prior.tolerance(np.zeros(36), 2)
    assert np.array_equal(tol, prior.ROUNDING)
    sd = np.full(36, 0.01)
    tol = prior.tolerance(sd, 4)
    assert tol == pytest.approx(prior.ROUNDING + prior.Z_SEED * 0.01 * math.sqrt(1.25))
