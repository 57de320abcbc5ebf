"""Tests of the ``jacobians`` study (``analysis/jacobians/``,
``analysis/jacobians/points.py``).

The batched CasADi evaluation against single calls; the point comparisons at ~50 points with
the study's own thresholds (CasADi AD is the oracle); the printed network Jacobian failing at
every size; the along-run comparisons and the learned-Jacobian summary on a short run; the study
shape: ``run(tmp, quick=True)`` then ``check`` on the record and on the record loaded back, the
table and the report section rendered from it, and ``check``, the table and the section on the
committed ``paper/`` record.  The learned-vs-true metrics are tested in
``tests/test_identification.py``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from analysis import common
from analysis import jacobians as jac
from analysis.jacobians import points as pts
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.estimation.identification import jacobian_quality
from wmr.model import symbolic as sym

PAPER = Path(__file__).resolve().parents[1] / "paper"
needs_paper = pytest.mark.skipif(not (PAPER / "results" / "jacobians.json").exists(),
                                 reason="paper/ not generated yet (make reproduce)")  # fmt: skip
SMALL = 50  # random points per check in these tests
# Identical formulas evaluated twice differ by nothing; rounding-level agreement is a few ulp.
ROUNDING = 1e-14


@pytest.fixture(scope="module")
def small_study():
    return pts.point_study(points=SMALL, seed=1)


def _lemniscate(duration: float = 4.0) -> scn.Scenario:
    """The paper's lemniscate cut to ``duration`` [s]."""
    return dataclasses.replace(scn.load(scn.builtin("lemniscate")), duration=duration)


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("jacobians")
    return out, jac.run(out, quick=True)


# ---------------------------------------------------------------------------------------------
# Batched CasADi evaluation and the sampled points
# ---------------------------------------------------------------------------------------------


def test_ad_batch_equals_single_calls():
    rng = np.random.default_rng(1)
    p = pts.unicycle_points(rng, 5, edges=False)
    F, G = pts._ad_batch(sym.step_jacobian_function("rk4"), p.q, p.u, p.dt)
    assert F.shape == (5, 3, 3) and G.shape == (5, 3, 2)
    f = sym.step_jacobian_function("rk4")
    for i in range(5):
        Fi, Gi = f(p.q[i], p.u[i], p.dt[i])
        assert_array_equal(F[i], Fi.full())
        assert_array_equal(G[i], Gi.full())
    net = pts.network_points(rng, 4, 5, 3, edges=False)
    (H,) = pts._ad_batch(sym.network_weight_jacobian_function(4, 5, 3), net.theta, net.x)
    h = sym.network_weight_jacobian_function(4, 5, 3)
    for i in range(3):
        assert_array_equal(H[i], h(net.theta[i], net.x[i]).full())


def test_points_are_seeded_and_include_the_edges():
    a = pts.unicycle_points(np.random.default_rng(3), 10)
    b = pts.unicycle_points(np.random.default_rng(3), 10)
    assert_array_equal(a.q, b.q)
    assert_array_equal(a.u, b.u)
    assert len(a) > 10
    assert np.any(a.u[:, 0] == 0.0) and np.any(a.u[:, 1] == 0.0)
    assert np.any(a.q[:, 2] == np.pi) and np.any(a.q[:, 2] == -np.pi)
    assert set(np.unique(a.dt)) == set(pts.DTS)


# ---------------------------------------------------------------------------------------------
# The point comparisons at a few points, with the study's own thresholds
# ---------------------------------------------------------------------------------------------


def test_closed_forms_match_ad(small_study):
    summary, _ = small_study
    for name, e in summary["unicycle_step"].items():
        assert e["max_rel_error"] < jac.CLOSED_FORM_TOL, name
    assert summary["network_input"]["corrected_max_rel_error"] < jac.CLOSED_FORM_TOL
    assert summary["network_weights"]["max_rel_error"] < jac.CLOSED_FORM_TOL


def test_printed_network_jacobian_fails(small_study):
    summary, _ = small_study
    ni = summary["network_input"]
    assert ni["printed_median_rel_error"] > jac.PRINTED_MIN_ERROR
    assert ni["printed_max_rel_error"] > jac.PRINTED_MIN_ERROR
    for size, d in ni["by_size"].items():
        assert d["printed_median_rel_error"] > jac.PRINTED_MIN_ERROR, size


def test_rotation_and_error_dynamics(small_study):
    rot = small_study[0]["rotation"]
    assert rot["printed_det"] == "(sq(cos(theta))-sq(sin(theta)))"
    assert rot["corrected_det"] == "1"
    assert rot["max_abs_det_minus_cos_2theta"] < jac.DET_TOL
    assert rot["error_dynamics_max_residual"]["corrected"] < jac.IDENTITY_TOL
    assert rot["error_dynamics_median_residual"]["printed"] > jac.PRINTED_MIN_RESIDUAL


def test_check_passes_and_fails_loudly(small_study):
    summary = small_study[0]
    jac.check(summary)
    broken = {
        **summary,
        "network_input": {**summary["network_input"], "printed_median_rel_error": 0.01},
    }
    with pytest.raises(AssertionError, match="printed eqs. 22-24"):
        jac.check(broken)
    broken = {**summary, "unicycle_step": {"rk4": {"max_rel_error": 1e-6}}}
    with pytest.raises(AssertionError, match="step rk4"):
        jac.check(broken)
    rot = {**summary["rotation"], "max_abs_corrected_det_minus_1": 1e-3}
    with pytest.raises(AssertionError, match="corrected det T_e"):
        jac.check({**summary, "rotation": rot})


def test_printed_network_jacobian_is_zero_only_where_the_network_is_constant():
    """All-zero weights: both Jacobians are exactly zero, so the printed form 'agrees' there."""
    p = pts.network_points(np.random.default_rng(2), 4, 5, 0)
    errs = pts.network_errors(p)
    zero = np.all(p.theta == 0.0, axis=1)
    assert zero.sum() == 1
    assert errs["input_printed"][zero] == 0.0
    assert np.all(errs["input_printed"][~zero] > jac.PRINTED_MIN_ERROR)


def test_rolling_mean_has_no_zero_padding_and_skips_nan():
    x = np.full(20, 0.7)
    x[5] = np.nan
    assert_allclose(jac._rolling_mean(x, 7), 0.7, rtol=0, atol=ROUNDING)


# ---------------------------------------------------------------------------------------------
# Along runs and the learned-Jacobian summary
# ---------------------------------------------------------------------------------------------


def test_along_run_and_learned_summary():
    sc = _lemniscate()
    r = simulate(sc, jac.CONTROLLER, seed=0)
    a = pts.along_run(r, max_points=100)
    assert a["steps"] == 100
    for e in a["unicycle_step"].values():
        assert e["max_rel_error"] < jac.CLOSED_FORM_TOL
    assert a["network_input"]["corrected_max_rel_error"] < jac.CLOSED_FORM_TOL
    assert a["network_weights"]["max_rel_error"] < jac.CLOSED_FORM_TOL
    assert a["error_dynamics_max_residual"]["corrected"] < jac.IDENTITY_TOL
    q = jacobian_quality(r, integrator=sc.integrator)
    s = jac.summarise_learned([q, q])
    assert s["seeds"] == 2
    assert set(jac.LEARNED_KEYS) <= set(s)
    for key in jac.LEARNED_KEYS:  # the same run twice: its last-half mean, no spread
        assert s[key] == {"mean": q.tail_mean(key), "std": 0.0}, key
    assert s["rel_error_whole_run"]["mean"] == q.tail_mean("rel_error", start=0.0)
    assert s["rel_error_final"] == [float(q.rel_error[-1])] * 2
    assert -1.0 <= s["cosine"]["mean"] <= 1.0
    assert 0.0 <= s["sign_w"]["mean"] <= 1.0


def test_along_run_reads_the_network_size_from_the_settings():
    """A 7-unit identifier: the weights and the size come from the run's record."""
    sc = _lemniscate(1.0)
    settings = dataclasses.replace(sc.settings(jac.CONTROLLER), hidden=7)
    r = simulate(sc, jac.CONTROLLER, seed=0, settings=settings)
    assert r.settings.hidden == 7
    a = pts.along_run(r, max_points=20)
    assert a["network_input"]["corrected_max_rel_error"] < jac.CLOSED_FORM_TOL
    assert a["network_weights"]["max_rel_error"] < jac.CLOSED_FORM_TOL


def test_without_noise_zeroes_only_the_noise():
    sc = scn.load(scn.builtin("sinusoid"))
    q = jac.without_noise(sc)
    assert q.noise.pose_std == (0.0, 0.0, 0.0)
    assert q.reference == sc.reference and q.dt == sc.dt


def test_with_process_std_changes_only_the_pose_filters_process_noise():
    sc = scn.load(scn.builtin("sinusoid"))
    v = jac.with_process_std(sc, 0.003)
    assert v.estimator.process_std == (0.003, 0.003, 0.003)
    assert dataclasses.replace(v, estimator=sc.estimator) == sc


def test_target_noise_summary_is_the_pose_filters_differenced_error():
    """Oracle: the pose filter's exact-model steady state (wmr.estimation.stability.
    random_walk_increment_noise) gives the std of the targets' noise; a smaller process noise
    smooths more and leaves less noise on the targets."""
    from wmr.estimation import stability as stab

    sc = _lemniscate(10.0)
    got = {}
    for std in jac.PROCESS_STD:
        runs = [simulate(jac.with_process_std(sc, std), jac.CONTROLLER, seed) for seed in (0, 1)]
        got[std] = jac.target_noise_summary(runs)
        var, _ = stab.random_walk_increment_noise(std**2, sc.noise.pose_std[0] ** 2)
        want = np.sqrt(var) * sc.noise.pose_std[0] / sc.dt
        # 2 runs x 999 steps: the std of a std estimate ~2 %; the heading coupling ~1 %
        assert_allclose(got[std]["noise_std"]["mean"], [want] * 3, rtol=0.06)
        assert_allclose(got[std]["noise_rms_xy"]["mean"], np.sqrt(2) * want, rtol=0.06)
    assert got[0.003]["noise_rms"]["mean"] < got[0.01]["noise_rms"]["mean"]
    # the signal is the true velocity: a process-noise setting barely moves it (same reference)
    assert_allclose(got[0.003]["signal_rms_xy"]["mean"], got[0.01]["signal_rms_xy"]["mean"],
                    rtol=0.05)  # fmt: skip


def _learned(**changes):
    """A learned-Jacobian record whose rel. errors are ``changes`` (per entry: 3 values)."""
    def entry(vals):
        return {sc: {k: {"mean": v, "std": 0.0} for k in jac.LEARNED_KEYS}
                for sc, v in zip(("a", "b", "c"), vals, strict=True)}

    tn = {std: {sc: {"noise_rms_xy": {"mean": n}, "signal_rms_xy": {"mean": 0.5}}
                for sc in ("a", "b", "c")} for std, n in (("0.01", 1.0), ("0.003", 0.4))}
    return {"scenarios": entry(changes["default"]), "noise_free": entry(changes["quiet"]),
            "process_noise": {"0.01": entry(changes["default"]), "0.003": entry(changes["low"])},
            "oracle": entry(changes["oracle"]), "target_noise": tn,
            "default_process_std": [[0.01] * 3] * 3}  # fmt: skip


def test_the_explanation_is_chosen_by_the_numbers():
    follows = jac._explanation(_learned(default=(2.5, 2.7, 2.7), low=(0.9, 0.5, 0.5),
                                        oracle=(0.7, 0.4, 0.5), quiet=(0.9, 0.6, 0.7)))
    assert "So most of the error at the defaults comes with the noise" in follows
    assert "72–85 % of the default's error goes" in follows
    assert "(the default)" in follows
    partly = jac._explanation(_learned(default=(1.0, 1.0, 1.0), low=(0.9, 0.9, 0.9),
                                       oracle=(0.7, 0.8, 0.6), quiet=(0.9, 0.6, 0.7)))
    assert "So part of the error" in partly
    against = jac._explanation(_learned(default=(1.0, 1.0, 1.0), low=(1.2, 0.5, 0.5),
                                        oracle=(0.7, 0.4, 0.5), quiet=(0.9, 0.6, 0.7)))
    assert "These numbers do not show the error following the noise" in against
    assert "So most" not in against


# ---------------------------------------------------------------------------------------------
# The study shape
# ---------------------------------------------------------------------------------------------


def test_quick_run_writes_its_files_and_checks(quick):
    out, record = quick
    jac.check(record)
    loaded = common.load_record(out, jac.STEM)
    assert loaded == json.loads(json.dumps(record))
    jac.check(loaded)
    assert record["points"] == jac.QUICK_POINTS
    assert record["learned_jacobian"]["seeds"] == jac.QUICK_SEEDS
    assert list(record["along_runs"]["scenarios"]) == list(scn.PAPER_SCENARIOS)
    assert record["figures"] == ["jacobians_errors.png", "jacobians_learned.png"]
    learned = record["learned_jacobian"]
    assert list(learned["process_noise"]) == [f"{s:g}" for s in jac.PROCESS_STD]
    assert learned["process_noise"]["0.01"] == learned["scenarios"]  # same seeds, same runs
    assert list(learned["oracle"]) == list(scn.PAPER_SCENARIOS)
    assert set(learned["target_noise"]["0.003"]["sinusoid"]) >= {"noise_std", "signal_rms_xy"}
    for name in record["figures"]:
        assert (out / "figures" / name).is_file()
    assert (out / "tables" / "jacobians.md").read_text() == jac.table(loaded)
    assert record["notes"] == jac.notes(loaded)
    section = jac.render(loaded)
    assert section.startswith(f"## {jac.TITLE}\n")
    assert jac.table(loaded).rstrip() in section
    assert "![jacobians_learned.png](figures/jacobians_learned.png)" in section


def test_check_fails_on_a_broken_along_run(quick):
    _, record = quick
    along = json.loads(json.dumps(record["along_runs"]))
    along["scenarios"]["sinusoid"]["error_dynamics_max_residual"]["corrected"] = 1e-6
    with pytest.raises(AssertionError, match="sinusoid: corrected error-dynamics"):
        jac.check({**record, "along_runs": along})


def test_check_fails_when_the_default_process_noise_is_not_the_default_runs(quick):
    _, record = quick
    learned = json.loads(json.dumps(record["learned_jacobian"]))
    learned["process_noise"]["0.01"]["sinusoid"]["rel_error"]["mean"] += 1.0
    with pytest.raises(AssertionError, match="default process noise 0.01"):
        jac.check({**record, "learned_jacobian": learned})


@needs_paper
def test_committed_record_checks_and_renders_the_committed_table_and_section():
    record = common.load_record(PAPER, jac.STEM)
    jac.check(record)
    assert jac.table(record) == (PAPER / "tables" / "jacobians.md").read_text()
    assert jac.notes(record) == record["notes"]
    report = (PAPER / "report.md").read_text()
    start = report.index(f"## {jac.TITLE}\n")
    end = report.index("\n## ", start)
    assert jac.render(record).rstrip("\n") == report[start:end].rstrip("\n")
