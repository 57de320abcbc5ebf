"""The registries' contracts, checked on every row (STYLE §17): controllers, reference kinds,
studies.  A new row that breaks a numbered rule of its registry fails here."""

from __future__ import annotations

import dataclasses
import importlib

import numpy as np
import pytest
from numpy.testing import assert_allclose

import analysis
from wmr import controllers
from wmr import scenario as scn
from wmr._settings import from_table
from wmr.closedloop.sim import simulate
from wmr.model import references

CONTROLLERS = list(controllers.REGISTRY.values())
KINDS = list(references.KINDS.values())


@pytest.fixture(scope="module")
def lemniscate():
    return scn.load(scn.builtin("lemniscate"))


@pytest.mark.parametrize("ctrl", CONTROLLERS, ids=lambda c: c.name)
def test_controller_settings_are_frozen_validated_dataclasses(ctrl):
    """Rule 1: defaults exist, the object is frozen, a TOML table of its own defaults converts
    back to an equal object, and an unknown key is rejected."""
    st = ctrl.Settings()
    assert dataclasses.is_dataclass(st)
    with pytest.raises(dataclasses.FrozenInstanceError):
        setattr(st, dataclasses.fields(st)[0].name, None)
    table = {f.name: (list(v) if isinstance(v := getattr(st, f.name), tuple) else v)
             for f in dataclasses.fields(st)}  # fmt: skip
    assert from_table(ctrl.Settings, table, f"controllers.{ctrl.name}") == st
    with pytest.raises(ValueError, match="unknown key"):
        from_table(ctrl.Settings, {"no_such_field": 1.0}, f"controllers.{ctrl.name}")


@pytest.mark.parametrize("ctrl", CONTROLLERS, ids=lambda c: c.name)
def test_controller_pack_law_and_final_state(ctrl, lemniscate):
    """Rules 2-5: pack gives (p, s, theta, P) of consistent shapes, draws only from its rng, the
    law writes a finite input for the reference's own pose, the logged names fit in s, and the
    final state is a dataclass holding the run's values (it is built once, when the run is over,
    so it may keep the run's arrays rather than copy them: rule 5), which later steps would
    change (so a state read from the wrong place fails)."""
    st = ctrl.Settings()
    rng = np.random.default_rng(5)
    p, s, theta, P = ctrl.pack(st, lemniscate, rng)
    assert s.ndim == 1 and theta.ndim == 1 and P.shape == (theta.size, theta.size)
    assert len(ctrl.state_names) <= s.size
    p2, s2, theta2, P2 = ctrl.pack(st, lemniscate, np.random.default_rng(5))
    assert np.array_equal(theta, theta2) and np.array_equal(s, s2)  # rng is the only randomness
    u = np.full(2, np.nan)
    ref = references.sample("lemniscate", lemniscate.reference.params, lemniscate.dt, 2)
    for k in range(2):
        ctrl.law(p, s, theta, P, ref[k, :3].copy(), ref[k], lemniscate.dt, u)
        assert np.all(np.isfinite(u))
    final = ctrl.final_state(p, s, theta, P)
    assert dataclasses.is_dataclass(final)
    kept = {f.name: np.array(getattr(final, f.name), copy=True) for f in dataclasses.fields(final)
            if isinstance(getattr(final, f.name), np.ndarray)}  # fmt: skip
    if hasattr(final, "theta"):  # a network's weights and covariance: the run's, as they are
        assert np.array_equal(final.theta, theta) and np.array_equal(final.P, P)
    ctrl.law(p, s, theta, P, ref[1, :3] + 0.1, ref[1], lemniscate.dt, u)  # the run goes on
    again = ctrl.final_state(p, s, theta, P)
    assert any(not np.array_equal(v, getattr(again, k)) for k, v in kept.items()) or not kept


@pytest.mark.parametrize("ctrl", CONTROLLERS, ids=lambda c: c.name)
def test_controller_runs_and_its_record_names_its_signals(ctrl, lemniscate):
    """Every logged signal is reachable by name and equals the logged column; label, colour and
    the pose rule are set; the run's settings are the scenario's."""
    sc = dataclasses.replace(lemniscate, duration=2.0)
    r = simulate(sc, ctrl.name, 0)
    assert not r.diverged and r.settings == sc.settings(ctrl.name)
    for i, name in enumerate(ctrl.state_names):
        assert np.array_equal(r.signal(name), r.state[:, i])
    assert np.array_equal(r.signal("v"), r.u[:, 0])
    with pytest.raises(KeyError, match="no signal"):
        r.signal("no-such-signal")
    assert ctrl.label and ctrl.colour
    assert sc.estimator.filters(ctrl.name) == ctrl.uses_estimator  # pose_source = "paper"


def test_gains_and_jacobian_views_of_the_pid_family(lemniscate):
    sc = dataclasses.replace(lemniscate, duration=1.0)
    r = simulate(sc, "adaptive-pid", 0)
    assert r.gains().shape == (sc.n_steps, 6) and r.jacobian().shape == (sc.n_steps, 3, 2)
    assert np.array_equal(r.gains()[-1], r.final.gains)
    assert np.array_equal(r.jacobian()[-1], r.final.jacobian)
    with pytest.raises(KeyError, match="PID gains"):
        simulate(sc, "backstepping", 0).gains()


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.name)
def test_reference_kind_derivatives_match_finite_differences(kind):
    """The path's analytic first and second derivatives against central differences."""
    params = kind.example
    t = np.linspace(0.3, 9.7, 23)
    h = 1e-5
    x, y, xd, yd, xdd, ydd = references.path_derivatives(kind.name, params, t)
    xp, yp, xdp, ydp, _, _ = references.path_derivatives(kind.name, params, t + h)
    xm, ym, xdm, ydm, _, _ = references.path_derivatives(kind.name, params, t - h)
    # central differences: error O(h^2) ~ 1e-10 times the third derivative, plus rounding 1e-11/h
    for got, plus, minus in ((xd, xp, xm), (yd, yp, ym), (xdd, xdp, xdm), (ydd, ydp, ydm)):
        assert_allclose(got, (plus - minus) / (2 * h), rtol=1e-6, atol=1e-6)
    assert len(kind.units) == len(kind.params) and set(kind.positive) <= set(kind.params)


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k.name)
def test_reference_kind_example_loads_and_positivity_is_enforced(kind):
    table = {k: ([list(r) for r in v] if isinstance(v, tuple) else v)
             for k, v in kind.example.items()}  # fmt: skip
    base = {"name": "r", "duration": 1.0, "dt": 0.1, "initial_pose": [0.0, 0.0, 0.0],
            "reference": {"kind": kind.name, **table}}  # fmt: skip
    assert scn.from_dict(base).reference.params == kind.example
    for p in kind.positive:
        bad = {**base, "reference": {**base["reference"], p: 0.0}}
        with pytest.raises(scn.ScenarioError, match=f"reference.{p}"):
            scn.from_dict(bad)


@pytest.mark.parametrize("name", analysis.STUDIES)
def test_every_study_has_the_study_shape(name):
    """DESIGN §3.6: STEM (the registry name), TITLE, run, check, render; runnable as a module."""
    study = analysis.get(name)
    assert study.STEM == name and isinstance(study.TITLE, str) and study.TITLE
    assert callable(study.run) and callable(study.check)
    assert callable(study.render)
    assert importlib.util.find_spec(f"analysis.{name}") is not None


def test_one_number_sets_every_entry_of_a_vector_setting():
    """``mu = 5.0`` means five for each of the six gains (issue 11); a wrong length still fails."""
    st = from_table(controllers.get("adaptive-pid").Settings, {"mu": 5.0}, "controllers.x")
    assert st.mu == (5.0,) * 6
    with pytest.raises(ValueError, match="must have 6 elements"):
        from_table(controllers.get("adaptive-pid").Settings, {"mu": [1.0, 2.0]}, "c")
    with pytest.raises(ValueError, match="must be an array of numbers or one number"):
        from_table(controllers.get("adaptive-pid").Settings, {"mu": "fast"}, "c")
