"""Scenario files: the shipped scenarios' values, every kind of invalid file, and a property test.

Oracles: the paper's stated values (initial poses, perturbation window), the documented schema
(DESIGN §3.1), and the error contract: a :class:`ScenarioError` whose one-line message names the
file, the dotted key and the offending value.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib

import pytest
from cases import BASE_TOML, INVALID, assert_names, invalid_params, mutated_scenarios
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from wmr import scenario
from wmr._settings import SettingError, from_table
from wmr.controllers import backstepping
from wmr.scenario import ScenarioError

#: Poses X0 given in the caption of the paper's Fig. 4.
PAPER_INITIAL_POSE = {
    "lemniscate": (0.0, -0.7, math.pi / 2),
    "sinusoid": (0.0, 0.0, 0.0),
    "sinusoid-perturbed": (0.0, 0.0, 0.0),
}


@pytest.mark.parametrize("name", scenario.PAPER_SCENARIOS)
def test_shipped_scenarios_have_the_papers_values(name):
    sc = scenario.load(scenario.builtin(name))
    assert sc.name == name
    assert sc.initial_pose == PAPER_INITIAL_POSE[name]  # pi/2 is written with 17 digits: exact
    assert sc.dt == 0.01 and sc.duration == 40.0 and sc.n_steps == 4000
    assert sc.integrator == "exact"
    assert sc.noise.pose_std == (0.01, 0.01, 0.01)
    if name == "lemniscate":
        assert sc.reference.kind == "lemniscate"
        assert dict(sc.reference.params) == {"size": 2.0, "period": 40.0}
    else:
        assert sc.reference.kind == "sinusoid"
        assert dict(sc.reference.params) == {"speed": 0.5, "amplitude": 1.0, "omega": 0.5}
    if name == "sinusoid-perturbed":
        # the paper's perturbation from t = 15 s to t = 20 s, an additive (v, w) disturbance
        assert sc.disturbances == (scenario.Disturbance(15.0, 20.0, (0.1, 0.3)),)
    else:
        assert sc.disturbances == ()


def test_base_case_is_valid_and_complete():
    """The text every invalid case edits is itself valid, with every section read."""
    sc = scenario.loads(BASE_TOML, "base.toml")
    assert sc.source == "base.toml"
    assert sc.n_steps == 200
    assert sc.reference == scenario.ReferenceSpec("circle", {"radius": 1.0, "period": 20.0})
    assert sc.disturbances == (scenario.Disturbance(0.5, 1.0, (0.1, 0.3)),)
    assert sc.limits == scenario.Limits(2.0, 5.0)
    assert sc.settings("backstepping") == backstepping.Settings(gains=(2.0, 10.0, 4.0))
    assert sc.divergence_bound == 10.0  # the default


def test_defaults_of_optional_sections():
    text = "\n".join(
        line for line in BASE_TOML.splitlines() if not line.startswith(("integrator", "seed"))
    ).split("[noise]")[0]
    sc = scenario.loads(text)
    assert sc.integrator == "exact" and sc.seed == 0
    assert sc.noise.pose_std == (0.0, 0.0, 0.0)
    assert sc.disturbances == ()
    assert math.isinf(sc.limits.v_max) and math.isinf(sc.limits.w_max)
    assert sc.settings("backstepping") == backstepping.Settings()


def test_scenario_is_frozen():
    sc = scenario.loads(BASE_TOML)
    with pytest.raises(dataclasses.FrozenInstanceError):
        sc.dt = 0.1  # type: ignore[misc]
    with pytest.raises(TypeError):
        sc.reference.params["radius"] = 2.0  # type: ignore[index]


@pytest.mark.parametrize("case", invalid_params())
def test_invalid_scenario_error_names_file_key_value(case, tmp_path):
    path = tmp_path / f"{case.id}.toml"
    path.write_text(case.text(), encoding="utf-8")
    with pytest.raises(ScenarioError) as info:
        scenario.load(path)
    err = info.value
    assert err.key == case.key
    assert err.source == str(path)
    assert_names(str(err), case, path.name)


def test_every_invalid_case_has_a_unique_id():
    ids = [c.id for c in INVALID]
    assert len(ids) == len(set(ids))


def test_unreadable_files(tmp_path):
    with pytest.raises(ScenarioError, match=r"missing\.toml.*cannot read"):
        scenario.load(tmp_path / "missing.toml")
    with pytest.raises(ScenarioError, match="cannot read"):
        scenario.load(tmp_path)  # a directory
    latin1 = tmp_path / "latin1.toml"
    latin1.write_bytes(BASE_TOML.replace('"case"', '"caf\xe9"').encode("latin-1"))
    with pytest.raises(ScenarioError, match=r"latin1\.toml.*UTF-8"):
        scenario.load(latin1)


def test_from_dict_rejects_integers_beyond_float():
    """A Python caller may pass integers TOML cannot hold; they are invalid, not a crash."""
    doc = tomllib.loads(BASE_TOML)
    doc["duration"] = 10**400
    with pytest.raises(ScenarioError, match="duration"):
        scenario.from_dict(doc)
    doc = tomllib.loads(BASE_TOML)
    doc["limits"]["v_max"] = -(10**400)
    with pytest.raises(ScenarioError, match=r"limits\.v_max"):
        scenario.from_dict(doc)


def test_message_stays_one_line_for_keys_with_newlines():
    """TOML allows any character in a quoted key; the message escapes it."""
    with pytest.raises(ScenarioError) as info:
        scenario.loads('"bad\\nkey" = 1\n' + BASE_TOML, "nl.toml")
    assert info.value.key == "bad\nkey"
    assert str(info.value).startswith("nl.toml: bad\\nkey = 1: unknown key")
    assert "\n" not in str(info.value)


@dataclasses.dataclass(frozen=True)
class _Window:
    """A settings class whose __post_init__ raises a plain ValueError (not a SettingError)."""

    bounds: tuple[float, ...] = (0.0, 1.0)

    def __post_init__(self):
        if self.bounds[0] > self.bounds[1]:
            raise ValueError("bounds must increase\nsecond line")


def test_plain_value_error_of_a_settings_class_is_a_setting_error():
    with pytest.raises(SettingError) as info:
        from_table(_Window, {"bounds": [2.0, 1.0]}, "controllers.window")
    assert info.value.key == "controllers.window"
    assert info.value.reason == "bounds must increase"  # first line only: messages are one line
    assert from_table(_Window, {"bounds": [1.0, 2.0]}, "w") == _Window((1.0, 2.0))


# --- property: any mutation of a valid scenario is either valid or a ScenarioError --------------

_BASE = tomllib.loads(BASE_TOML)
#: from_dict also takes Python dicts: allow values TOML cannot hold (None, huge integers).
_PY_VALUES = st.one_of(st.none(), st.integers(), st.complex_numbers(), st.tuples(st.floats()))


def _check_valid(sc: scenario.Scenario) -> None:
    """Invariants of any scenario from_dict accepts."""
    assert isinstance(sc.name, str) and sc.name.strip()
    assert math.isfinite(sc.dt) and sc.dt > 0
    assert math.isfinite(sc.duration) and sc.duration >= sc.dt
    assert 1 <= sc.n_steps <= scenario.MAX_STEPS
    assert math.isclose(sc.n_steps * sc.dt, sc.duration, rel_tol=1e-8)
    assert len(sc.initial_pose) == 3 and all(math.isfinite(p) for p in sc.initial_pose)
    assert sc.reference.kind in ("lemniscate", "sinusoid", "circle")
    assert all(math.isfinite(v) for v in sc.reference.params.values())
    assert sc.integrator in ("exact", "euler", "rk4")
    assert all(s >= 0 and math.isfinite(s) for s in sc.noise.pose_std)
    for d in sc.disturbances:
        assert 0 <= d.start < d.stop and d.start < sc.duration and len(d.velocity) == 2
    assert sc.limits.v_max > 0 and sc.limits.w_max > 0
    for name in sc.controllers:
        sc.settings(name)


@settings(
    max_examples=400,
    derandomize=True,  # reproducible in CI
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(mutated_scenarios(_BASE) | mutated_scenarios(_BASE, values=_PY_VALUES))
def test_from_dict_returns_a_scenario_or_raises_scenario_error(doc):
    try:
        sc = scenario.from_dict(doc, "prop.toml")
    except ScenarioError as err:
        message = str(err)
        assert "\n" not in message
        assert message.startswith("prop.toml: ")
    else:
        _check_valid(sc)


_PLANT_BASE = tomllib.loads(
    BASE_TOML + '[plant]\nmodel = "lagged-velocity"\nv_gain = 0.9\ndelay_steps = 1\nslip = -0.1\n'
    "[plant.lagged-velocity]\nmass = 12.0\nfriction = [0.5, 0.02]\n"
    "[[plant.change]]\nat = 1.0\nmass = 15.0\nw_gain = 1.1\n")


@settings(max_examples=300, derandomize=True, database=None, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])  # fmt: skip
@given(mutated_scenarios(_PLANT_BASE) | mutated_scenarios(_PLANT_BASE, values=_PY_VALUES))
def test_any_mutation_of_a_plant_is_a_plant_or_a_scenario_error(doc):
    """The [plant] parser (wmr.robots.plantspec.parse) on mutations of a plant with a model table
    and a change: a valid plant whose parameter rows are finite, or a one-line ScenarioError."""
    try:
        sc = scenario.from_dict(doc, "prop.toml")
    except ScenarioError as err:
        assert "\n" not in str(err) and str(err).startswith("prop.toml: ")
    else:
        _check_valid(sc)
        rows = [sc.plant.row()]
        for change in sc.plant.changes:
            rows.append(sc.plant.row(rows[-1], change.values))
        assert all(math.isfinite(x) for r in rows for x in r)


# --- a new plant model is a row of wmr.robots.plantspec.MODELS (DESIGN §3.7 comes this way)
# ------------


def test_a_new_model_is_a_row_of_the_models_table(tmp_path, monkeypatch):
    """A model with its own table, excluded [plant] keys and a finish hook that reads a file
    relative to the scenario: the parser, the changeable keys, ideal, describe() and to_json()
    take it from the row alone."""
    from wmr._settings import positive
    from wmr.robots import plantspec

    @plantspec.plant_table
    class Toy:
        """A toy model's table."""

        file: str = plantspec.param("", unit="-", doc="A file, relative to the scenario.")
        mass: float = plantspec.param(10.0, unit="kg", doc="Mass (> 0).", rule=positive,
                                      changeable=True)  # fmt: skip

    def finish(table, context):
        path = tmp_path / table.file
        if not path.is_file():
            raise SettingError("plant.toy.file", table.file, "no such file")
        assert context.source.endswith("s.toml") and context.dt == 0.01
        return dataclasses.replace(table, file=path.read_text())

    monkeypatch.setitem(plantspec.MODELS, "toy", plantspec.Model(
        "toy", Toy, ("v_gain", "slip"), "the toy has its own wheels", "a toy", finish))
    (tmp_path / "robot.txt").write_text("<robot/>")

    def load(plant: str):
        path = tmp_path / "s.toml"
        path.write_text(BASE_TOML + plant)
        return scenario.load(path)

    sc = load('[plant]\nmodel = "toy"\ndelay_steps = 1\n[plant.toy]\nfile = "robot.txt"\n'
              "mass = 12.0\n[[plant.change]]\nat = 1.0\nmass = 15.0\n")
    p = sc.plant
    assert p.model_table == Toy("<robot/>", 12.0) and p.changes[0].values == {"mass": 15.0}
    assert not p.ideal and p.describe().startswith("plant: toy; delay 1 steps;")
    assert p.to_json()["toy"] == {"file": "<robot/>", "mass": 12.0} and "v_gain" not in p.to_json()
    assert plantspec.changeable("toy") == ("w_gain", "v_from_w", "w_from_v", "actuator_tau",
                                           "mass")  # fmt: skip
    for plant, key in (('[plant]\nmodel = "toy"\nv_gain = 0.9\n[plant.toy]\n', "plant.v_gain"),
                       ('[plant]\nmodel = "toy"\n', "plant.toy"),
                       ('[plant]\n[plant.toy]\nmass = 3.0\n', "plant.toy"),
                       ('[plant]\nmodel = "toy"\n[plant.toy]\nmass = 0.0\n', "plant.toy.mass"),
                       ('[plant]\nmodel = "toy"\n[plant.toy]\nfile = "none.txt"\n',
                        "plant.toy.file"),
                       ('[plant]\nmodel = "toy"\n[plant.toy]\nfile = "robot.txt"\n'
                        '[[plant.change]]\nat = 1.0\nslip = 0.1\n', "plant.change[0].slip"),
                       ('[plant]\n[[plant.change]]\nat = 1.0\nfile = "x"\n',
                        "plant.change[0].file")):  # fmt: skip
        with pytest.raises(ScenarioError) as err:
            load(plant)
        assert err.value.key == key and "\n" not in str(err.value), str(err.value)
