"""Tests of wmr/linear/margins.py (margins of the linearised loops) and of the study
analysis/margins/.

Oracles: margins of loops computed by hand (an integrator, a two-step delay, the PI on a double
integrator), the same margins from closed-loop eigenvalues only, python-control's own disk
margin, the mirror symmetry of the plane, the nonlinear simulation (decay rates, gain limits),
and the committed record ``paper/results/margins.json`` for the study's check and report text.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path

import control as ct
import numpy as np
import pytest

from analysis import margins as study
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.controllers import pid
from wmr.linear import loops as lp
from wmr.linear import margins as mg

DT = 0.01
# Margins from the refined frequency response vs closed forms: limited by brentq/minimize
# tolerances (~1e-10 relative) and by round-off in (zI - A)^-1 near z = 1.
MARGIN_TOL = 1e-8
# Frequency-domain vs eigenvalue margins: the eigenvalue scans bisect to ~1e-11..1e-13, the
# disk-margin search over psi to xatol 1e-9; 1e-6 leaves room for both.
EIGEN_TOL = 1e-6
PAPER = Path(__file__).resolve().parents[1] / "paper"

OPS = [lp.OperatingPoint(0.61, 0.0, DT, label="straight"),
       lp.OperatingPoint(0.5, 0.5, DT, label="left turn"),
       lp.OperatingPoint(0.21, -0.5, DT, label="slow right turn")]  # fmt: skip
OP_IDS = [op.label for op in OPS]


# ---- margins of hand-computable loops ------------------------------------------------------


def _check_against_eigen(L, m):
    e = mg.eigen_margins(L)
    assert e["gain_margin"] == pytest.approx(m.gain_margin, rel=EIGEN_TOL)
    assert e["phase_margin_deg"] == pytest.approx(m.phase_margin_deg, rel=EIGEN_TOL)
    assert e["disk_margin"] == pytest.approx(m.disk_margin, rel=EIGEN_TOL)


@pytest.mark.parametrize("a", [0.05, 0.5, 1.2])
def test_margins_of_an_integrator_loop(a):
    """L(z) = a/(z - 1) (a = K dt: proportional control of e_{k+1} = e_k - dt u_k), 0 < a < 2.

    By hand, with z = exp(j theta), theta = w dt:
    - z - 1 = 2j sin(theta/2) exp(j theta/2), so arg L = -(pi/2 + theta/2): L is real negative
      only at theta = pi (z = -1), L(-1) = -a/2, hence GM = 2/a at the Nyquist frequency
      (closed-loop pole 1 - g a leaves the unit disc at g = 2/a); no lower gain margin.
    - |L| = a/(2 sin(theta/2)) = 1 at sin(theta_c/2) = a/2; PM = 180 + arg L = 90 - theta_c/2,
      i.e. PM = 90 deg - asin(a/2).
    - S - T = (1 - L)/(1 + L) = (z - 1 - a)/(z - 1 + a), the ratio of the distances from z to
      1 + a and to 1 - a, largest on the circle at z = -1: (2 + a)/(2 - a).  So
      alpha = 2/max|S - T| = 2(2 - a)/(2 + a), the disk gain margin (1 + alpha/2)/(1 - alpha/2)
      = 2/a equals the classical one (the worst point is on the real axis), and the disk phase
      margin is 2 atan(alpha/2) = 2 atan((2 - a)/(2 + a)).
    """
    L = ct.ss([[1.0]], [[1.0]], [[a]], [[0.0]], DT)
    m = mg.loop_margins(L)
    assert m.stable
    assert m.gain_margin == pytest.approx(2 / a, rel=MARGIN_TOL)
    assert m.phase_crossover_rad_s == pytest.approx(math.pi / DT, rel=1e-12)
    assert m.gain_margin_lower == 0.0 and m.gain_margin_lower_db == -math.inf
    assert m.phase_margin_deg == pytest.approx(90 - math.degrees(math.asin(a / 2)), rel=MARGIN_TOL)
    alpha = 2 * (2 - a) / (2 + a)
    assert m.disk_margin == pytest.approx(alpha, rel=MARGIN_TOL)
    assert m.disk_gain_margin_db == pytest.approx(20 * math.log10(2 / a), rel=MARGIN_TOL)
    assert m.disk_phase_margin_deg == pytest.approx(
        math.degrees(2 * math.atan((2 - a) / (2 + a))), rel=MARGIN_TOL)  # fmt: skip
    assert mg.disk_gain_phase_margins(alpha) == pytest.approx(
        (m.disk_gain_margin_db, m.disk_phase_margin_deg), rel=MARGIN_TOL)  # fmt: skip
    _check_against_eigen(L, m)


def test_margins_of_a_two_step_delay():
    """L(z) = k z^-2, k = 1/2.  arg L = -2 theta = -pi at theta = pi/2 (z = j), L(j) = -k, so
    GM = 1/k = 2 at w = pi/(2 dt) (closed loop z^2 + g k: |z| = sqrt(g k) = 1 at g = 1/k);
    |L| = k < 1 everywhere, so no gain crossover: PM = inf.  S - T = (z^2 - k)/(z^2 + k) is
    largest at z^2 = -1: (1 + k)/(1 - k), so alpha = 2(1 - k)/(1 + k) = 2/3, disk GM = 1/k
    (6.02 dB) and disk PM = 2 atan(1/3) = 36.87 deg."""
    k = 0.5
    L = ct.ss([[0.0, 0.0], [1.0, 0.0]], [[1.0], [0.0]], [[0.0, k]], [[0.0]], DT)  # k z^-2
    m = mg.loop_margins(L)
    assert m.gain_margin == pytest.approx(1 / k, rel=MARGIN_TOL)
    assert m.phase_crossover_rad_s == pytest.approx(math.pi / (2 * DT), rel=1e-9)
    assert m.phase_margin_deg == math.inf
    assert m.disk_margin == pytest.approx(2 * (1 - k) / (1 + k), rel=MARGIN_TOL)
    assert m.disk_gain_margin_db == pytest.approx(20 * math.log10(1 / k), rel=MARGIN_TOL)
    assert m.disk_phase_margin_deg == pytest.approx(
        math.degrees(2 * math.atan(1 / 3)), rel=MARGIN_TOL
    )
    assert m.to_json()["phase_margin_deg"] == "inf"
    e = mg.eigen_margins(L)
    assert e["gain_margin"] == pytest.approx(1 / k, rel=EIGEN_TOL)
    assert e["phase_margin_deg"] == math.inf
    assert e["disk_margin"] == pytest.approx(m.disk_margin, rel=EIGEN_TOL)


@pytest.mark.parametrize(("Kp", "Ki"), [(5.0, 5.0), (50.0, 1.0), (1.0, 200.0)])
def test_gain_margin_of_the_pi_double_integrator(Kp, Ki):
    """The v loop on a straight line: e1_{k+1} = e1_k - dt dv_k with the PI of eq. (7) gives
    L(z) = dt((Kp + Ki dt) z - Kp)/(z - 1)^2 =: a (z - b)/(z - 1)^2.  With gain g the closed
    loop is z^2 + (g a - 2) z + (1 - g a b); Jury: g a b < 2, g a (1 - b) > 0 and
    4 - g a (1 + b) > 0.  Since b < 1 the last binds: GM = 4/(a (1 + b)) = 1/|L(-1)|; there is
    no lower gain margin (the phase tends to -180 deg only as w -> 0, where python-control
    0.10.2's polynomial method reports a spurious crossover)."""
    a = DT * (Kp + Ki * DT)
    b = Kp / (Kp + Ki * DT)
    L = ct.ss([[2.0, -1.0], [1.0, 0.0]], [[1.0], [0.0]], [[a, -a * b]], [[0.0]], DT)
    m = mg.loop_margins(L)
    assert m.gain_margin == pytest.approx(4 / (a * (1 + b)), rel=MARGIN_TOL)
    assert m.gain_margin_lower == 0.0
    _check_against_eigen(L, m)
    # The same loop from the library: the v loop of the PID on a straight line.
    Lv = lp.pid_loops(OPS[0], (Kp, Ki, 0.0, 10.0, 2.0, 0.0))["v"]
    assert mg.loop_margins(Lv, python_control=False).gain_margin == pytest.approx(
        m.gain_margin, rel=1e-9
    )


@pytest.mark.parametrize("op", OPS, ids=OP_IDS)
@pytest.mark.parametrize("which", ["pid", "backstepping"])
def test_frequency_margins_agree_with_closed_loop_eigenvalues(op, which):
    loops = lp.pid_loops(op) if which == "pid" else lp.backstepping_loops(op)
    res = mg.analyse_loops(loops)
    assert res["same_closed_loop"] < 1e-12
    for ch in lp.CHANNELS:
        m = res[ch]
        checks = mg.compare_margins(m, res[f"{ch}_eigen"])
        assert checks["gain_margin_rel_diff"] < EIGEN_TOL, checks
        assert checks["gain_margin_lower_rel_diff"] < EIGEN_TOL, checks
        assert checks["phase_margin_abs_diff_deg"] < EIGEN_TOL, checks
        assert checks["disk_margin_rel_diff"] < EIGEN_TOL, checks
        assert checks["disk_gm_below_classical"] and checks["disk_pm_below_classical"]
        # python-control's own disk margin and the formula used along runs agree.
        fast = mg.loop_margins(loops[ch], python_control=False)
        assert fast.disk_margin == pytest.approx(m.disk_margin, rel=1e-9)
        assert fast.disk_phase_margin_deg == pytest.approx(m.disk_phase_margin_deg, rel=1e-9)


def test_margins_are_mirror_symmetric_in_w_r():
    """Reflecting the plane (y -> -y) maps (v_r, w_r) to (v_r, -w_r), e2, e3, w to their negatives
    and s = e3 + e2 to -s: same loops, same margins."""
    op = OPS[1]
    for ch in lp.CHANNELS:
        a = mg.loop_margins(lp.pid_loops(op)[ch], python_control=False)
        b = mg.loop_margins(
            lp.pid_loops(dataclasses.replace(op, w_r=-op.w_r))[ch], python_control=False
        )
        assert a.phase_margin_deg == pytest.approx(b.phase_margin_deg, rel=1e-9)
        assert a.disk_margin == pytest.approx(b.disk_margin, rel=1e-9)


def test_an_unstable_loop_gets_zero_margins():
    L = ct.ss([[1.0]], [[1.0]], [[2.5]], [[0.0]], DT)  # closed-loop pole 1 - 2.5 = -1.5
    m = mg.loop_margins(L)
    assert not m.stable and m.disk_margin == 0.0 and m.gain_margin_db == 0.0


def test_json_numbers():
    assert mg.json_number(math.inf) == "inf" and mg.json_number(-math.inf) == "-inf"
    assert mg.json_number(math.nan) is None
    assert mg.json_number(np.float64(1.5)) == 1.5


def test_margins_along_a_fixed_pid_run_on_a_straight_line_are_those_of_the_operating_point():
    """Along a fixed-PID run on a straight line the gains and (v_r, w_r) never change: every
    frozen-time loop is the one at the operating point, read through RunResult.gains()."""
    op = OPS[0]
    sc = lp.constant_reference_scenario(op, 2.0, np.zeros(3))
    rec = mg.margins_along_run(simulate(sc, "pid", seed=0), every=40)
    assert rec["t"].tolist() == pytest.approx([0.0, 0.4, 0.8, 1.2, 1.6])
    assert np.all(rec["gains"] == np.array(lp.PID_GAINS))
    ref = mg.analyse_loops(lp.pid_loops(op), python_control=False, cross_check=False)
    assert np.all(rec["rho"] == ref["spectral_radius"])
    for ch in lp.CHANNELS:
        assert np.all(rec[f"{ch}_gm_db"] == ref[ch].gain_margin_db)
        assert np.all(rec[f"{ch}_pm_deg"] == ref[ch].phase_margin_deg)
        assert np.all(rec[f"{ch}_dm"] == ref[ch].disk_margin)


# ---- the study: simulator cross-checks, record, check, report text -------------------------


def test_decay_of_the_simulated_loop_follows_the_slowest_eigenvalue():
    """The nonlinear simulated loop from a small error follows its linearisation and decays at
    the rate of the slowest closed-loop eigenvalue."""
    d = study.decay_check("backstepping", OPS[1], lp.BSC_GAINS, decades=4.0)
    assert not d["diverged"]
    assert d["rate_rel_error"] < 1e-3, d
    assert d["max_deviation_from_linear_rel"] < 1e-2, d


@pytest.mark.parametrize("index", [2, 5], ids=["Kdv", "Kdw"])
def test_simulated_loop_crosses_the_derivative_gain_limit_where_the_eigenvalues_do(index):
    op = OPS[0]
    limit = lp.stable_gain_interval(op, index)[1]
    inside, outside = study.gain_limit_check(op, index, limit, steps=1500)
    assert inside["spectral_radius"] < 1 < outside["spectral_radius"]
    assert inside["diverged_at"] is None and inside["tail_over_initial"] < 1
    assert outside["diverged_at"] is not None or outside["peak_over_initial"] > 10


def test_printed_rotation_destabilises_both_loops_between_45_and_135_degrees():
    """With the printed matrix the lateral feedback is cos 2theta e2: it changes sign for
    45 < |theta| < 135 deg; at theta = 0 the printed loop is the corrected one."""
    sweep = lp.printed_rotation_sweep(OPS[0], np.array([0.0, 30.0, 90.0, -90.0, 180.0]))
    for name in ("pid", "bsc"):
        rho = sweep[f"{name}_rho"]
        assert rho[0] == pytest.approx(sweep[f"{name}_rho_corrected"], rel=1e-12)
        assert rho[1] < 1.0 and rho[4] < 1.0
        assert rho[2] > 1.0 and rho[3] > 1.0
    assert lp.unstable_intervals([0, 1, 2, 3, 4], [False, True, True, False, True]) == [
        [1.0, 2.0], [4.0, 4.0]]  # fmt: skip
    with pytest.raises(ValueError, match="straight line"):
        lp.printed_rotation_sweep(OPS[1], [0.0])


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """One ``--quick`` run of the study (its directory and returned record), shared."""
    out = tmp_path_factory.mktemp("margins")
    return out, study.run(out, quick=True)


@pytest.mark.slow
def test_quick_run_writes_its_files_and_passes_its_check(quick):
    tmp_path, record = quick
    study.check(record)
    stored = json.loads((tmp_path / "results" / "margins.json").read_text())
    study.check(stored)
    assert stored["notes"] == study.notes(stored)
    assert (tmp_path / "tables" / "margins.md").read_text() == study.table(stored)
    for name in stored["figures"]:
        assert name.startswith("margins_") and (tmp_path / "figures" / name).exists()
    assert stored["along_runs"]["every_steps"] == study.QUICK_EVERY
    committed = json.loads((PAPER / "results" / "margins.json").read_text())
    assert set(committed) <= set(stored) and "floquet" in stored  # issue 14 adds a key


@pytest.mark.slow
def test_quick_record_holds_the_floquet_multipliers_and_the_check_guards_them(quick):
    """The Floquet block (wmr.linear.floquet): both loops stable about both periodic references, the
    PID's slowest multiplier confirmed by the simulator on both, its table block rendered; the
    check rejects a failed closed form, a simulator disagreement and an unchecked PID."""
    tmp_path, _ = quick
    record = json.loads((tmp_path / "results" / "margins.json").read_text())
    fl = record["floquet"]
    for sc in study.FLOQUET_SCENARIOS:
        for name in ("pid", "backstepping"):
            r = fl[sc][name]
            assert r["stable"] and r["moduli"][0] < 1 and r["average_rate"] < 1
            assert r["frozen_rho_min"] <= r["frozen_rho_max"] < 1
        assert fl[sc]["pid"]["simulated"]["modal_ratio_rel_error"] < 1e-3
    assert "Floquet multipliers about the periodic references" in study.table(record)
    for path, value in ((("circle_closed_form", "pid", "monodromy_rel_diff"), 1e-6),
                        (("sinusoid", "backstepping", "simulated", "modal_ratio_rel_error"), 0.1),
                        (("lemniscate", "pid", "simulated"), {"skipped": "-"})):  # fmt: skip
        bad = copy.deepcopy(record)
        node = bad["floquet"]
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
        with pytest.raises(AssertionError):
            study.check(bad)


def test_committed_record_passes_the_check_and_renders_the_committed_report_text():
    """The committed record: its claims hold, its notes and table are what the study renders
    from it, and the report's section is :func:`render` of it."""
    record = json.loads((PAPER / "results" / "margins.json").read_text())
    study.check(record)
    assert record["notes"] == study.notes(record)
    assert (PAPER / "tables" / "margins.md").read_text() == study.table(record)
    report = (PAPER / "report.md").read_text()
    assert study.render(record) in report
    # The SGD clamp of the derivative gains lies below the limits the loop tolerates.
    iv = record["stability_region"]["stable_interval_one_gain_at_a_time"]
    clamp = pid.Settings().gain_max
    assert clamp[2] < iv["Kdv"][1] and clamp[5] < iv["Kdw"][1]


def test_check_rejects_a_failed_cross_check():
    record = json.loads((PAPER / "results" / "margins.json").read_text())
    record["cross_checks"]["region_v_agrees_with_jury"] = 0.99
    with pytest.raises(AssertionError):
        study.check(record)


def test_operating_points_of_the_paper_scenarios():
    sc = scn.load(scn.builtin("sinusoid"))
    op = lp.operating_point(sc, "mean")
    assert op.w_r == 0.0 and op.label == "sinusoid:mean" and op.dt == sc.dt
    curved = lp.operating_point(sc, "max-curvature")
    assert abs(curved.w_r) > 0.4 and curved.label == "sinusoid:max-curvature"
