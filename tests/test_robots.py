"""The robot ladder (issue 20, item 3): its physics checks against closed forms and planted
cases, its statistics on synthetic records, the quick study end to end, and the committed
record (checks, renders as in the report, a sample of its runs reruns to the same numbers)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from analysis import prose, robots
from analysis.robots import views
from wmr import scenario as scn
from wmr.closedloop.sim import simulate

PAPER = Path(__file__).resolve().parents[1] / "paper"
COMMITTED = PAPER / "results" / "robots.json"
needs_record = pytest.mark.skipif(not COMMITTED.exists(), reason="no committed robots record")


# --- physics ---------------------------------------------------------------------------------


def test_a_steady_circle_well_inside_the_coulomb_bound_rolls_without_slip():
    """True and nominal radii equal: the achieved (v, w) is the command, no side-slip."""
    p = robots.sliding_point(1.0, 0.5, 1.0)
    assert p["demand"] == pytest.approx(0.5 / 9.81)
    assert p["v_actual"] == pytest.approx(0.5, rel=1e-2) and p["w_actual"] == pytest.approx(
        1.0, rel=1e-2)
    assert p["slip_angle"] < 0.01 and not p["sliding"]


def test_a_circle_past_the_coulomb_bound_slides():
    """At twice the lateral acceleration friction can give, the robot slides outward and does
    not reach the commanded speed."""
    p = robots.sliding_point(0.1, 1.0, 2.0)
    assert p["demand"] > 2.0 and p["sliding"]
    assert p["v_actual"] < 0.9 * 1.0


def test_the_servo_lag_is_measured_unsaturated():
    """The small step keeps the servos below their torque limit and reaches the command; a
    large step saturates them (ratio 1) and rises more slowly: an acceleration limit, not the
    lag.  A stiffer servo has the shorter lag."""
    small, large = robots.servo_lag(), robots.servo_lag(v=0.5, w=0.5)
    stiff = robots.servo_lag(robots.STIFF)
    assert small["max_torque_ratio"] < 1.0 and stiff["max_torque_ratio"] < 1.0
    assert large["max_torque_ratio"] == pytest.approx(1.0, abs=1e-9)
    assert small["final"] == pytest.approx([0.005, 0.005], rel=2e-2)
    assert 0 < small["tau_v"] < large["tau_v"]
    assert stiff["tau_w"] < small["tau_w"]


# --- statistics on synthetic records -----------------------------------------------------------


def test_clopper_pearson_of_zero_events_has_the_closed_form_upper_bound():
    lo, hi = robots.clopper_pearson(0, 20)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 20), rel=1e-9)
    lo, hi = robots.clopper_pearson(20, 20)
    assert hi == 1.0 and lo == pytest.approx(0.025 ** (1 / 20), rel=1e-9)


def _pair(diff, significant, scale=10.0, equivalent=False):
    return {"n": 20, "mean_diff": diff, "p": 0.001, "p_holm": 0.001 if significant else 0.5,
            "significant": significant, "scale": scale, "equivalent": equivalent}


def test_order_changes_needs_significance_on_both_rungs_and_opposite_signs():
    a = {"x vs y": _pair(-1.0, True), "x vs z": _pair(-1.0, True), "y vs z": _pair(1.0, False)}
    b = {"x vs y": _pair(+1.0, True), "x vs z": _pair(-2.0, True), "y vs z": _pair(-1.0, True)}
    assert robots.order_changes(a, b) == ["x vs y"]
    b["x vs y"]["significant"] = False
    assert robots.order_changes(a, b) == []


def test_a_significant_reversal_smaller_than_the_margin_is_not_an_order_change():
    """With common random numbers a 0.1 mm gap is significant; below 5 % of the better mean it
    does not count as a reversal."""
    a = {"x vs y": _pair(-0.1, True, scale=10.0)}
    b = {"x vs y": _pair(+0.1, True, scale=10.0)}
    assert robots.order_changes(a, b) == []
    b["x vs y"]["mean_diff"] = 0.6
    assert robots.order_changes(a, b) == []  # both sides must exceed the margin
    a["x vs y"]["mean_diff"] = -0.6
    assert robots.order_changes(a, b) == ["x vs y"]


def test_a_tie_needs_equivalence_not_a_large_p_value():
    cells = {"pid": {"mean": 1.0}, "backstepping": {"mean": 1.1}, "adaptive-pid": {"mean": 2.0}}
    pairs = {"pid vs backstepping": _pair(-0.1, False, equivalent=True),
             "pid vs adaptive-pid": _pair(-1.0, False, equivalent=False),
             "backstepping vs adaptive-pid": _pair(-0.9, True)}  # fmt: skip
    lad = {"cells": cells, "ranking": ["pid", "backstepping", "adaptive-pid"], "pairs": pairs}
    rec = {"rungs": ["kinematic"], "ladder": {"t": {"kinematic": lad}, "u": {"kinematic": {
        **lad, "ranking": ["adaptive-pid", "pid", "backstepping"]}}}}
    best = views.best_per_rung(rec)
    assert best == {"kinematic": {"t": ["pid", "backstepping"], "u": ["adaptive-pid"]}}
    # the sentence names each trajectory's best: winners of different trajectories are not tied
    assert views._best_sentence(rec, "kinematic") == "t PID (fixed) ≈ BSC; u APID"


def test_the_agreement_rule_and_its_floor():
    kin = {"mean": 0.0015, "n": 3}
    near, far = {"mean": 0.0030, "n": 3}, {"mean": 0.0040, "n": 3}
    assert robots._agree(near, kin)["agrees"] and robots._agree(near, kin)["floor_dominates"]
    assert not robots._agree(far, kin)["agrees"]
    big = {"mean": 0.100, "n": 3}
    assert not robots._agree({"mean": 0.1052, "n": 3}, big)["agrees"]  # 5 % of 100 mm decides
    assert not robots._agree({"mean": 0.1052, "n": 3}, big)["floor_dominates"]


# --- the study ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    import matplotlib

    matplotlib.use("Agg")
    out = tmp_path_factory.mktemp("robots")
    return out, robots.run(out, quick=True, workers=1)


def test_the_quick_study_checks_renders_and_opens_with_its_answer(quick):
    out, record = quick
    robots.check(record)
    text = robots.render(record)
    opening = text.split("\n\n")[1]
    assert 1 <= len(prose.sentences(opening)) <= 5
    assert prose.long_sentences(text) == []
    for name in record["figures"]:
        assert (out / "figures" / name).stat().st_size > 10_000
    assert (out / "tables" / "robots.md").read_text() == robots.table(record)


def test_the_fitted_plant_is_a_scenario_table(quick):
    _, record = quick
    for traj, f in record["fitted"].items():
        sc = scn.loads(scn.builtin(traj).read_text() + "\n" + f["toml"], source="fitted")
        assert sc.plant.model == "kinematic"
        assert math.isfinite(f["values"]["v_gain"])


def test_a_diverged_run_is_counted_not_averaged():
    class R:
        def __init__(self, seed, x, diverged):
            self.seed, self.tail_position, self.diverged = seed, x, diverged

    cell = robots._cell([R(0, 0.01, False), R(1, math.nan, True), R(2, 0.03, False)])
    assert cell["diverged"] == 1 and cell["stable"] == 2
    assert cell["mean"] == pytest.approx(0.02) and set(cell["values"]) == {0, 2}


@needs_record
def test_the_committed_record_checks_and_renders_as_in_the_report():
    record = json.loads(COMMITTED.read_text())
    robots.check(record)
    assert not record["quick"] and record["seeds"] >= 20 and record["mj_seeds"] >= 10
    assert robots.render(record) in (PAPER / "report.md").read_text()
    assert robots.table(record) == (PAPER / "tables" / "robots.md").read_text()


@needs_record
@pytest.mark.parametrize("traj, rung, controller, seed", [
    ("lemniscate", "mujoco", "backstepping", 3),
    ("sinusoid", "lagged-velocity", "adaptive-pid", 7),
])  # fmt: skip
def test_a_sample_of_the_committed_runs_reruns_to_the_same_numbers(traj, rung, controller, seed):
    record = json.loads(COMMITTED.read_text())
    sc = robots._scenario(traj, rung, robots.RUNGS[rung], None)
    r = simulate(sc, controller, seed, keep_trajectory=False)
    assert r.rmse_after_transient["position"] == \
        record["ladder"][traj][rung]["cells"][controller]["values"][str(seed)]
    assert np.isfinite(r.rmse_after_transient["position"])


# --- the store: an interrupted ladder resumes, a changed input rebuilds -----------------------


def _same(a, b) -> bool:
    """Two stored values equal (NaN equal to NaN)."""
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a)
                      and math.isnan(b))  # fmt: skip


def _rows_by_id(folder) -> dict:
    from wmr.engine.store import ShardStore

    t = ShardStore(folder).read().to_pydict()
    return {i: {k: t[k][n] for k in t} for n, i in enumerate(t["job_id"])}


def _quick_jobs(record):
    return robots._jobs(robots._design(True), record["fitted"], record["servo_lag"]["stiff"])


def _without_cost(record):
    return {k: v for k, v in record.items() if k not in ("cost", "figures")}


def test_the_quick_ladders_rows_are_in_its_store_as_the_engine_ran_them(quick):
    """Every job of the quick ladder has one ``ok`` row in the store, and it is the row the
    engine's own run of that job gives now (``run_job``, no store): the store loses nothing
    (float64 columns, the seed, the divergence)."""
    from wmr.engine.jobs import RESULT_FIELDS, run_job

    out, record = quick
    jobs = _quick_jobs(record)
    stored = _rows_by_id(robots.store_folder(out, True))
    assert set(stored) == {j.job_id for j in jobs} and len(jobs) == record["cost"]["runs"]
    assert record["cost"]["runs_this_time"] == len(jobs)
    for j in jobs[::5]:
        row, direct = stored[j.job_id], run_job(j)
        assert row["status"] == "ok" and row["variant"] == j.variant == direct.variant
        assert row["seed"] == direct.seed and row["scenario"] == direct.scenario
        for name in RESULT_FIELDS:
            assert _same(row[name], getattr(direct, name)), (j.job_id, name)


def test_an_interrupted_ladder_resumes_to_the_uninterrupted_record(quick, tmp_path):
    """A store holding only the first half of the runs (as an interruption leaves it: the
    shards written so far) resumes: only the missing half runs, and the store's rows and the
    record equal those of the uninterrupted run."""
    import shutil

    from wmr.engine.store import MANIFEST, ShardStore

    out, record = quick
    full = robots.store_folder(out, True)
    rows = _rows_by_id(full)
    jobs = _quick_jobs(record)
    half = [rows[j.job_id] for j in jobs[: len(jobs) // 2]]
    cut = robots.store_folder(tmp_path, True)
    (cut / "rows").mkdir(parents=True)
    shutil.copy(full / MANIFEST, cut / MANIFEST)
    ShardStore(cut, robots._schema()).write(half)
    resumed = robots.run(tmp_path, quick=True, workers=1)
    assert resumed["cost"]["runs_this_time"] == len(jobs) - len(half)
    assert _without_cost(resumed) == _without_cost(record)
    again = _rows_by_id(cut)
    assert set(again) == set(rows)
    for i, row in rows.items():
        assert all(_same(row[k], again[i][k]) for k in row), i


def test_a_store_of_other_inputs_is_set_aside_and_rebuilt(quick, tmp_path, capsys):
    """The store's digests cover the code, the design and the scenario files: a changed design
    (one seed fewer) or a changed scenario file gives other digests; a store of other digests is
    set aside with one line and rebuilt, its runs not reused."""
    import shutil

    out, record = quick
    d = robots._design(True)
    base = robots.store_digests(d)
    assert robots.store_digests({**d, "seeds": 1})["design_digest"] != base["design_digest"]
    edited = tmp_path / "lemniscate.toml"
    edited.write_text(scn.builtin("lemniscate").read_text().replace("size = 2.0", "size = 2.5"))
    assert robots.store_digests(d, [edited])["scenario_digest"] != base["scenario_digest"]
    assert robots.store_digests(d, [scn.builtin("lemniscate")]) == base
    folder = tmp_path / "store"
    shutil.copytree(robots.store_folder(out, True), folder)
    jobs = _quick_jobs(record)[:2]
    capsys.readouterr()
    rows, manifest = robots.run_ladder(jobs, 1, folder, robots.store_digests({**d, "seeds": 1}))
    said = [line for line in capsys.readouterr().err.splitlines() if "set aside" in line]
    assert len(said) == 1 and "design_digest" in said[0] and str(folder) in said[0]
    assert manifest["runs_this_time"] == 2 and len(_rows_by_id(folder)) == 2
    assert len(list(tmp_path.glob("store.stale-*"))) == 1
    # the same digests again: resumed, nothing runs
    rows2, manifest = robots.run_ladder(jobs, 1, folder, robots.store_digests({**d, "seeds": 1}))
    assert manifest["runs_this_time"] == 0 and [r.job_id for r in rows2] == [j.job_id for j in jobs]
