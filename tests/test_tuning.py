"""The shared tuning stage (analysis/tuning.py): the optimiser on planted optima, the budget
rule, the edge flag, the settings written into a scenario, and one arm tuned through the engine."""

from __future__ import annotations

import numpy as np
import pytest

from analysis import tuning
from wmr import controllers

#: A planted optimum recovered to this distance in unit coordinates: the quadratic's minimum
#: is 0 and CMA-ES with 60 evaluations per coordinate reaches a value < 1e-4, i.e. a distance
#: < 1e-2 per coordinate on a unit-curvature bowl (measured: < 2e-3).
RECOVER_TOL = 2e-2


def _bowl(centre, floor: float = 0.0):
    centre = np.asarray(centre)
    calls = []

    def f(xs):
        calls.append(len(xs))
        return [floor + float(np.sum((x - centre) ** 2)) for x in xs]

    return f, calls


@pytest.mark.parametrize("centre", [(0.3, 0.7, 0.55), (0.8, 0.2, 0.4, 0.65, 0.1)])
def test_cma_es_recovers_a_planted_optimum(centre):
    f, _ = _bowl(centre)
    dim = len(centre)
    res = tuning.minimise(f, dim, 60 * dim, seed=0)
    assert np.max(np.abs(np.array(res["x"]) - centre)) < RECOVER_TOL, res["x"]
    assert res["f"] == pytest.approx(float(np.sum((np.array(res["x"]) - centre) ** 2)), abs=1e-12)


def test_restarts_are_independent_agree_on_a_bowl_and_not_on_two_wells():
    f, _ = _bowl((0.4, 0.6, 0.5), floor=0.2)  # a floor as the objective's (RMSE > 0)
    runs = [tuning.minimise(f, 3, 150, seed=s, x0=np.random.default_rng(s).random(3))
            for s in range(2)]  # fmt: skip
    assert runs[0]["x"] != runs[1]["x"]  # different seeds, different paths
    ag = tuning.agreement(runs)
    assert ag["agree"] and ag["spread"] < 1e-3 and ag["max_coordinate_distance"] < 0.05
    # two restarts ending in wells of value 0.2 and 0.3: they disagree (0.1 > 5 % of 0.2)
    far = tuning.agreement([{"f": 0.2, "x": [0.1, 0.1]}, {"f": 0.3, "x": [0.9, 0.9]}])
    assert not far["agree"] and far["spread"] == pytest.approx(0.1)
    assert far["max_coordinate_distance"] == pytest.approx(0.8)


@pytest.mark.parametrize("dim", [3, 6, 11])
def test_the_budget_gives_every_setting_the_same_evaluations(dim):
    """Exactly ``per_setting * dim`` evaluations per restart, whatever the population (CMA-ES's
    default 4 + floor(3 ln d) does not divide it)."""
    f, calls = _bowl(np.full(dim, 0.5))
    budget = tuning.Budget(per_setting=7, seeds=(0,))
    res = tuning.minimise(f, dim, budget.evaluations(dim), seed=1)
    assert sum(calls) == res["evaluations"] == 7 * dim
    assert res["population"] == 4 + int(3 * np.log(dim))
    assert res["evaluations"] / dim == 7


def test_an_optimum_on_the_box_edge_is_flagged():
    """The bowl's centre outside the box (x0 < 0): the optimum sits at the low edge of x0 and is
    flagged; the interior coordinate is not, nor is a categorical setting."""
    a = tuning.Arm("t", "adaptive-pid", (tuning.FREE["adaptive-pid"][0],
                                         tuning.FREE["adaptive-pid"][7],
                                         tuning.FREE["adaptive-pid"][3]))  # fmt: skip
    f, _ = _bowl((-0.3, 0.5, 0.5))
    res = tuning.minimise(f, 3, 90, seed=0)
    flagged = tuning.edges(a, res["x"])
    assert [e["setting"] for e in flagged] == ["Kpv"] and flagged[0]["edge"] == "low"
    assert flagged[0]["value"] == pytest.approx(0.5, rel=0.1)
    assert tuning.edges(a, [0.0, 0.5, 0.5]) == tuning.edges(a, [0.0, 0.99, 0.5])[:1]


def test_settings_land_in_the_scenario_each_run_is_made_from():
    """A free setting's value is the run's setting: element, multiplier, categorical, scalar; the
    defaults' unit coordinates map back to the defaults."""
    a = tuning.arm("iapid-nn-dekf", "filtered")
    u = np.linspace(0.05, 0.95, a.dim)
    vals = tuning.values_at(a, u)
    from analysis.regimes import design

    sc = tuning.scenario(design.document("lemniscate"), a, tuning.settings_table(a, vals))
    st = sc.settings("iapid-nn-dekf")
    assert st.gains[0] == pytest.approx(0.5 * 100 ** 0.05) and st.gains[1] == vals["Kiv"]
    assert st.mu == pytest.approx(tuple(0.9 * vals["mu x"] for _ in range(6)))
    assert st.jacobian_scale == vals["jacobian_scale"] and st.alpha[2] == vals["alpha3"]
    assert sc.estimator.pose_source == "filtered" and sc.estimator.filters("iapid-nn-dekf")
    d = tuning.values_at(a, tuning.unit_of_defaults(a))
    ref = controllers.get("iapid-nn-dekf").Settings()
    assert d["Kpv"] == pytest.approx(ref.gains[0]) and d["mu x"] == pytest.approx(1.0)
    assert d["jacobian_scale"] == ref.jacobian_scale


def test_the_bounded_objective_and_its_divergence_penalty():
    s = tuning.bounded([0.05, 0.0, 1e9, np.nan], [False, False, False, False])
    assert s.tolist() == [0.5, 0.0, pytest.approx(1.0), tuning.DIVERGED_SCORE]
    assert tuning.bounded([0.01], [True]).tolist() == [tuning.DIVERGED_SCORE]
    assert np.all(s <= tuning.DIVERGED_SCORE)


@pytest.mark.slow
def test_an_arm_tuned_through_the_engine(tmp_path):
    """BSC (3 gains) on one short training run: the tuned objective is no worse than at the
    defaults' coordinates (restart 0 starts there), the record says its budget, and the cache
    gives the same record back without running."""
    from analysis.regimes import design
    from wmr.engine import engine

    training = {"t": design.training_documents(duration=6.0)["train-lemniscate@ideal"]}
    a = tuning.arm("backstepping", "raw")
    budget = tuning.Budget(per_setting=2, seeds=(0,))
    with engine(1) as eng:
        rec = tuning.tune_arm(a, training, budget, eng, cache=tmp_path)
        again = tuning.tune_arm(a, training, budget, eng, cache=tmp_path)
    assert again == rec
    assert rec["evaluations"] == 2 * 3 * 2 and rec["runs_per_evaluation"] == 1
    assert rec["objective"] <= rec["objective_at_defaults"] + 1e-9  # x0 = defaults, evaluated
    assert 0 <= rec["objective"] < tuning.DIVERGED_SCORE
    assert len(rec["restarts"]) == 2 and "agree" in rec["agreement"]


@pytest.mark.parametrize("controller", tuning.ARMS)
def test_every_corner_of_an_arms_box_is_a_valid_scenario(controller):
    """A box reaching outside what the controller admits (a gain above ``gain_max``, say) would
    stop a tuning run mid-way with a ScenarioError: both corners must build."""
    from analysis.regimes import design

    a = tuning.arm(controller, "filtered")
    for u in (np.zeros(a.dim), np.ones(a.dim)):
        table = tuning.settings_table(a, tuning.values_at(a, u))
        tuning.scenario(design.document("lemniscate"), a, table)
