"""Shared test data: a valid scenario text and the catalogue of invalid ones.

Imported by ``test_scenario.py`` (the loader) and ``test_cli.py`` (the same cases through
``wmr run``), so both check one list.  Each invalid case is an edit of :data:`BASE_TOML` plus the
dotted key and the text of the value that the one-line error message must name.
"""

from __future__ import annotations

import copy
import datetime
import json
from dataclasses import dataclass

import pytest
from hypothesis import strategies as st

from wmr.model.kinematics import INTEGRATORS
from wmr.model.references import KINDS

#: Numbers recomputed here against a record committed from ANOTHER machine agree to this relative
#: tolerance, not to the bit: the records under paper/ were made on a CPU with AVX-512, where
#: numpy's float64 sin/cos (the reference sampler) use SVML; an AVX2 CPU uses libm, and the
#: last bits move (measured: 60 of 120 reproduction numbers differ, by <= 1.9e-14 relative).
#: Within one machine -- drivers, engines, workers, refactors -- results stay bit for bit (the
#: tests of those use exact equality).
CROSS_MACHINE_RTOL = 1e-12

#: A valid, short scenario exercising every section (2 s, 200 steps).
BASE_TOML = """\
name = "case"
duration = 2.0
dt = 0.01
initial_pose = [0.0, -0.7, 1.5707963267948966]
integrator = "exact"
seed = 0

[reference]
kind = "circle"
radius = 1.0
period = 20.0

[noise]
pose_std = [0.01, 0.01, 0.01]

[[disturbance]]
start = 0.5
stop = 1.0
velocity = [0.1, 0.3]

[limits]
v_max = 2.0
w_max = 5.0

[controllers.backstepping]
gains = [2.0, 10.0, 4.0]
"""


@dataclass(frozen=True)
class Invalid:
    """An invalid scenario: each ``(old, new)`` of ``edits`` is applied to the base text."""

    id: str
    edits: tuple[tuple[str, str], ...]
    key: str  # the dotted key the error must name
    value: str | None  # text that must appear in the message (the offending value), if any

    def text(self) -> str:
        text = BASE_TOML
        for old, new in self.edits:
            assert text.count(old) == 1, f"case {self.id}: {old!r} is not unique"
            text = text.replace(old, new)
        return text


def _case(id: str, old: str, new: str, key: str, value: str | None) -> Invalid:
    return Invalid(id, ((old, new),), key, value)


def _top(line: str) -> str:
    """Insert ``line`` among the top-level keys (before the first table header)."""
    return f'name = "case"\n{line}'


INVALID: tuple[Invalid, ...] = (
    _case("syntax", "dt = 0.01", "dt = = 0.01", "(syntax)", None),
    _case(
        "syntax-unclosed-array", "gains = [2.0, 10.0, 4.0]", "gains = [2.0, 10.0", "(syntax)", None
    ),
    _case("missing-name", 'name = "case"\n', "", "name", None),
    _case("missing-dt", "dt = 0.01\n", "", "dt", None),
    _case("missing-reference-param", "radius = 1.0\n", "", "reference.radius", None),
    _case(
        "missing-reference",
        '[reference]\nkind = "circle"\nradius = 1.0\nperiod = 20.0\n',
        "",
        "reference",
        None,
    ),
    _case("missing-disturbance-stop", "stop = 1.0\n", "", "disturbance[0].stop", None),
    _case("type-dt-string", "dt = 0.01", 'dt = "0.01"', "dt", "'0.01'"),
    _case("type-duration-bool", "duration = 2.0", "duration = true", "duration", "True"),
    _case("type-name-number", 'name = "case"', "name = 3", "name", "3"),
    _case(
        "type-pose-table",
        "initial_pose = [0.0, -0.7, 1.5707963267948966]",
        "initial_pose = {x = 0.0}",
        "initial_pose",
        "{'x': 0.0}",
    ),
    _case(
        "type-pose-element",
        "initial_pose = [0.0, -0.7, 1.5707963267948966]",
        'initial_pose = [0.0, "a", 1.0]',
        "initial_pose[1]",
        "'a'",
    ),
    _case(
        "type-noise-element",
        "pose_std = [0.01, 0.01, 0.01]",
        'pose_std = [0.01, "x", 0.01]',
        "noise.pose_std[1]",
        "'x'",
    ),
    _case(
        "type-integrator-array",
        'integrator = "exact"',
        'integrator = ["exact"]',
        "integrator",
        "['exact']",
    ),
    _case(
        "type-kind-array", 'kind = "circle"', 'kind = ["circle"]', "reference.kind", "['circle']"
    ),
    _case("type-kind-table", 'kind = "circle"', "kind = {a = 1}", "reference.kind", "{'a': 1}"),
    _case("type-seed-float", "seed = 0", "seed = 1.5", "seed", "1.5"),
    _case(
        "type-gains-bool",
        "gains = [2.0, 10.0, 4.0]",
        "gains = [2.0, true, 4.0]",
        "controllers.backstepping.gains[1]",
        "True",
    ),
    Invalid(
        "type-noise-not-table",
        (
            ("[noise]\npose_std = [0.01, 0.01, 0.01]\n", ""),
            ('name = "case"\n', _top("noise = 0.01\n")),
        ),
        "noise",
        "0.01",
    ),
    _case("nan-dt", "dt = 0.01", "dt = nan", "dt", "nan"),
    _case("inf-duration", "duration = 2.0", "duration = inf", "duration", "inf"),
    _case(
        "nan-pose",
        "initial_pose = [0.0, -0.7, 1.5707963267948966]",
        "initial_pose = [0.0, nan, 1.0]",
        "initial_pose[1]",
        "nan",
    ),
    _case("inf-radius", "radius = 1.0", "radius = -inf", "reference.radius", "-inf"),
    _case("inf-v_max", "v_max = 2.0", "v_max = inf", "limits.v_max", "inf"),
    _case(
        "nan-gain",
        "gains = [2.0, 10.0, 4.0]",
        "gains = [2.0, nan, 4.0]",
        "controllers.backstepping.gains[1]",
        "nan",
    ),
    _case("zero-dt", "dt = 0.01", "dt = 0.0", "dt", "0.0"),
    _case("negative-dt", "dt = 0.01", "dt = -0.01", "dt", "-0.01"),
    _case("zero-duration", "duration = 2.0", "duration = 0", "duration", "0.0"),
    _case("negative-duration", "duration = 2.0", "duration = -2.0", "duration", "-2.0"),
    _case("dt-above-duration", "dt = 0.01", "dt = 3.0", "dt", "3.0"),
    _case("duration-not-whole-steps", "duration = 2.0", "duration = 2.005", "duration", "2.005"),
    _case("too-many-steps", "duration = 2.0", "duration = 1e7", "duration", "10000000.0"),
    _case("too-many-steps-tiny-dt", "dt = 0.01", "dt = 1e-300", "duration", "2.0"),
    _case(
        "pose-length-2",
        "initial_pose = [0.0, -0.7, 1.5707963267948966]",
        "initial_pose = [0.0, -0.7]",
        "initial_pose",
        "[0.0, -0.7]",
    ),
    _case(
        "pose-length-4",
        "initial_pose = [0.0, -0.7, 1.5707963267948966]",
        "initial_pose = [0.0, -0.7, 1.0, 2.0]",
        "initial_pose",
        "[0.0, -0.7, 1.0, 2.0]",
    ),
    _case(
        "noise-length",
        "pose_std = [0.01, 0.01, 0.01]",
        "pose_std = [0.01, 0.01]",
        "noise.pose_std",
        "[0.01, 0.01]",
    ),
    _case(
        "velocity-length",
        "velocity = [0.1, 0.3]",
        "velocity = [0.1]",
        "disturbance[0].velocity",
        "[0.1]",
    ),
    _case(
        "gains-length",
        "gains = [2.0, 10.0, 4.0]",
        "gains = [2.0, 10.0]",
        "controllers.backstepping.gains",
        "[2.0, 10.0]",
    ),
    _case("unknown-kind", 'kind = "circle"', 'kind = "spiral"', "reference.kind", "'spiral'"),
    _case(
        "unknown-integrator",
        'integrator = "exact"',
        'integrator = "midpoint"',
        "integrator",
        "'midpoint'",
    ),
    _case("unknown-key-top", 'name = "case"\n', _top("colour = 'red'\n"), "colour", "'red'"),
    _case(
        "unknown-key-reference",
        "radius = 1.0",
        "radius = 1.0\nwidth = 3.0",
        "reference.width",
        "3.0",
    ),
    _case("key-of-other-kind", "radius = 1.0", "radius = 1.0\nsize = 2.0", "reference.size", "2.0"),
    _case("unknown-key-noise", "[noise]\n", "[noise]\nbias = 0.5\n", "noise.bias", "0.5"),
    _case(
        "unknown-key-backstepping",
        "[controllers.backstepping]\n",
        "[controllers.backstepping]\nk4 = 1.0\n",
        "controllers.backstepping.k4",
        "1.0",
    ),
    _case("unknown-key-limits", "[limits]\n", "[limits]\na_max = 1.0\n", "limits.a_max", "1.0"),
    _case(
        "unknown-key-disturbance",
        "start = 0.5",
        "start = 0.5\nkind = 'step'",
        "disturbance[0].kind",
        "'step'",
    ),
    _case(
        "unknown-controller",
        "[controllers.backstepping]",
        "[controllers.lqr]",
        "controllers.lqr",
        None,
    ),
    _case(
        "negative-noise",
        "pose_std = [0.01, 0.01, 0.01]",
        "pose_std = [0.01, -0.01, 0.01]",
        "noise.pose_std",
        "-0.01",
    ),
    _case("reversed-window", "stop = 1.0", "stop = 0.4", "disturbance[0].stop", "0.4"),
    _case("empty-window", "stop = 1.0", "stop = 0.5", "disturbance[0].stop", "0.5"),
    _case("negative-window-start", "start = 0.5", "start = -0.5", "disturbance[0].start", "-0.5"),
    _case(
        "window-after-run",
        "start = 0.5\nstop = 1.0",
        "start = 2.0\nstop = 3.0",
        "disturbance[0].start",
        "2.0",
    ),
    _case("disturbance-not-array", "[[disturbance]]", "[disturbance]", "disturbance", None),
    _case(
        "zero-gain",
        "gains = [2.0, 10.0, 4.0]",
        "gains = [0.0, 10.0, 4.0]",
        "controllers.backstepping.gains",
        "0.0",
    ),
    _case(
        "negative-gain",
        "gains = [2.0, 10.0, 4.0]",
        "gains = [2.0, 10.0, -4.0]",
        "controllers.backstepping.gains",
        "-4.0",
    ),
    _case("zero-v_max", "v_max = 2.0", "v_max = 0.0", "limits.v_max", "0.0"),
    _case("zero-radius", "radius = 1.0", "radius = 0.0", "reference.radius", "0.0"),
    _case("negative-period", "period = 20.0", "period = -20.0", "reference.period", "-20.0"),
    _case("negative-seed", "seed = 0", "seed = -1", "seed", "-1"),
    _case(
        "zero-divergence-bound",
        "seed = 0",
        "seed = 0\ndivergence_bound = 0.0",
        "divergence_bound",
        "0.0",
    ),
    _case("empty-name", 'name = "case"', 'name = "  "', "name", "'  '"),
    _case("name-with-slash", 'name = "case"', 'name = "../escape"', "name", "'../escape'"),
    _case("name-dotdot", 'name = "case"', 'name = ".."', "name", "'..'"),
    *(
        _case(id, "[controllers.backstepping]", f"{plant}\n\n[controllers.backstepping]", key,
              value)
        for id, plant, key, value in (
            ("plant-unknown-key", "[plant]\nv_gian = 0.8", "plant.v_gian", "0.8"),
            ("plant-wrong-type", '[plant]\nv_gain = "big"', "plant.v_gain", "'big'"),
            ("plant-nan-gain", "[plant]\nv_gain = nan", "plant.v_gain", "nan"),
            ("plant-inf-slip", "[plant]\nslip = inf", "plant.slip", "inf"),
            ("plant-negative-lag", "[plant]\nactuator_tau = -0.1", "plant.actuator_tau", "-0.1"),
            ("plant-fractional-delay", "[plant]\ndelay_steps = 1.5", "plant.delay_steps", "1.5"),
            ("plant-negative-delay", "[plant]\ndelay_steps = -1", "plant.delay_steps", "-1"),
            ("plant-unknown-model", '[plant]\nmodel = "bicycle"', "plant.model", "'bicycle'"),
            ("plant-renamed-model", '[plant]\nmodel = "dynamic"\n[plant.lagged-velocity]',
             "plant.model", "lagged-velocity"),
            ("plant-renamed-table", '[plant]\nmodel = "lagged-velocity"\n[plant.dynamic]\n'
             "mass = 10.0", "plant.dynamic", "plant.lagged-velocity"),
            ("plant-table-without-model", "[plant]\n[plant.lagged-velocity]\nmass = 10.0",
             "plant.lagged-velocity", "10.0"),
            ("plant-model-without-table", '[plant]\nmodel = "lagged-velocity"',
             "plant.lagged-velocity", None),
            ("plant-lagged-unknown-key",
             '[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\nmas = 10.0',
             "plant.lagged-velocity.mas", "10.0"),
            ("plant-zero-mass",
             '[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\nmass = 0.0',
             "plant.lagged-velocity.mass", "0.0"),
            ("plant-negative-inertia",
             '[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\ninertia = -0.5',
             "plant.lagged-velocity.inertia", "-0.5"),
            ("plant-zero-bandwidth",
             '[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\n'
             "bandwidth = [0.0, 20.0]", "plant.lagged-velocity.bandwidth", "0.0"),
            ("plant-negative-friction",
             '[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\n'
             "friction = [-1.0, 0.0]", "plant.lagged-velocity.friction", "-1.0"),
            ("plant-lag-on-lagged-velocity",
             '[plant]\nmodel = "lagged-velocity"\nactuator_tau = 0.1\n[plant.lagged-velocity]',
             "plant.actuator_tau", "0.1"),
            ("plant-change-lag-on-lagged-velocity",
             '[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\n[[plant.change]]\n'
             "at = 1.0\nactuator_tau = 0.1", "plant.change[0].actuator_tau", "0.1"),
            ("plant-change-unknown-key", "[plant]\n[[plant.change]]\nat = 1.0\nfoo = 1.0",
             "plant.change[0].foo", "1.0"),
            ("plant-change-fixed-key", "[plant]\n[[plant.change]]\nat = 1.0\ndelay_steps = 2",
             "plant.change[0].delay_steps", "2"),
            ("plant-change-at-duration", "[plant]\n[[plant.change]]\nat = 2.0\nv_gain = 0.5",
             "plant.change[0].at", "2.0"),
            ("plant-change-negative-at",
             "[plant]\n[[plant.change]]\nat = -1.0\nv_gain = 0.5", "plant.change[0].at",
             "-1.0"),
            ("plant-change-nan-value", "[plant]\n[[plant.change]]\nat = 1.0\nslip = nan",
             "plant.change[0].slip", "nan"),
            ("plant-change-negative-value",
             "[plant]\n[[plant.change]]\nat = 1.0\nactuator_tau = -1.0",
             "plant.change[0].actuator_tau", "-1.0"),
            ("plant-change-lagged-key-on-kinematic",
             "[plant]\n[[plant.change]]\nat = 1.0\nmass = 15.0", "plant.change[0].mass",
             "15.0"),
            ("plant-change-missing-at", "[plant]\n[[plant.change]]\nv_gain = 0.5",
             "plant.change[0].at", None),
            ("plant-change-nothing", "[plant]\n[[plant.change]]\nat = 1.0",
             "plant.change[0]", None),
        )
    ),
    *(
        _case(id, 'kind = "circle"\nradius = 1.0\nperiod = 20.0', f'kind = "waypoints"\n{ref}',
              key, value)
        for id, ref, key, value in (
            ("waypoints-five-rows",
             "points = [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [2.0, 2.0, 0.0], [3.0, 3.0, 0.0], "
             "[4.0, 4.0, 0.0]]", "reference.points", "5"),
            ("waypoints-t-not-increasing",
             "points = [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 2.0, 0.0], [3.0, 3.0, 0.0], "
             "[4.0, 4.0, 0.0], [5.0, 5.0, 0.0]]", "reference.points row 2", "1.0"),
            ("waypoints-duration-beyond-last-t",
             "points = [[0.0, 0.0, 0.0], [0.3, 1.0, 0.0], [0.6, 2.0, 0.0], [0.9, 3.0, 0.0], "
             "[1.2, 4.0, 0.0], [1.5, 5.0, 0.0]]", "duration", "2.0"),
            ("waypoints-standing-still",
             "points = [[0.0, 1.0, 1.0], [1.0, 1.0, 1.0], [2.0, 1.0, 1.0], [3.0, 1.0, 1.0], "
             "[4.0, 1.0, 1.0], [5.0, 1.0, 1.0]]", "reference", "speed"),
            ("waypoints-file-and-points", 'file = "a.csv"\npoints = []', "reference", None),
            ("waypoints-missing-file", 'file = "no-such-path.csv"', "reference.file",
             "no-such-path.csv"),
            ("waypoints-unknown-key", "size = 1.0", "reference.size", "1.0"),
            ("waypoints-bad-cell",
             'points = [[0.0, 0.0, 0.0], [1.0, "x", 0.0], [2.0, 2.0, 0.0], [3.0, 3.0, 0.0], '
             "[4.0, 4.0, 0.0], [5.0, 5.0, 0.0]]", "reference.points[1][1]", "'x'"),
        )
    ),
)


def invalid_params():
    """``pytest.param`` per invalid case, with its id."""
    return [pytest.param(c, id=c.id) for c in INVALID]


def assert_names(message: str, case: Invalid, filename: str) -> None:
    """The message is one line naming the file, the key and (if any) the value."""
    assert "\n" not in message.rstrip("\n"), message
    assert filename in message, message
    assert case.key in message, message
    if case.value is not None:
        assert case.value in message, message


# --- random mutations of a valid scenario (property tests, issue 7) -----------------------------

#: Numbers a careless or hostile file may hold: signs, zeros, NaN/inf, extremes, subnormals.
_NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),  # TOML integers are 64-bit
    st.sampled_from([0, 0.0, -0.0, -1, -1e-9, 1e-300, 5e-324, 1e300, 1.7976931348623157e308]),
)
_SCALARS = st.one_of(_NUMBERS, st.booleans(), st.text(max_size=6), st.dates())
#: Any TOML value (nested arrays and tables of the scalars above).
TOML_VALUES = st.recursive(
    _SCALARS,
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=3)
    ),
    max_leaves=5,
)


def _paths(node, prefix=()):
    """Every path (tuple of keys/indices) into a parsed TOML document."""
    items = node.items() if isinstance(node, dict) else enumerate(node)
    for key, child in items:
        yield (*prefix, key)
        if isinstance(child, dict | list):
            yield from _paths(child, (*prefix, key))


def _parent(doc, path):
    node = doc
    for key in path[:-1]:
        node = node[key]
    return node


@st.composite
def mutated_scenarios(draw, base: dict, values=TOML_VALUES, max_mutations: int = 3):
    """A deep copy of ``base`` with 1..max_mutations random mutations.

    Mutations: set any key or element to a random value, or any number to a random finite
    float (often still valid, but extreme: 1e-200, 1e300); delete a key or element (wrong
    lengths, missing keys); add a random key to any table or element to any array; set the
    reference kind or the integrator to a random string or to another valid name.
    """
    doc = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, max_mutations))):
        paths = list(_paths(doc))
        op = draw(st.sampled_from(["set", "number", "delete", "add", "kind", "integrator"]))
        numbers = [p for p in paths if isinstance(_parent(doc, p)[p[-1]], float)]
        if op == "number" and numbers:
            path = draw(st.sampled_from(numbers))
            _parent(doc, path)[path[-1]] = draw(st.floats(allow_nan=False, allow_infinity=False))
        elif op in ("set", "delete") and paths:
            path = draw(st.sampled_from(paths))
            parent = _parent(doc, path)
            if op == "set":
                parent[path[-1]] = draw(values)
            else:
                del parent[path[-1]]
        elif op == "add":
            containers = [p for p in paths if isinstance(_parent(doc, p)[p[-1]], dict | list)]
            target = doc
            if containers and draw(st.booleans()):
                p = draw(st.sampled_from(containers))
                target = _parent(doc, p)[p[-1]]
            if isinstance(target, dict):
                target[draw(st.text(max_size=8))] = draw(values)
            else:
                target.append(draw(values))
        elif op == "kind" and isinstance(doc.get("reference"), dict):
            doc["reference"]["kind"] = draw(st.text(max_size=10) | st.sampled_from(sorted(KINDS)))
        elif op == "integrator":
            doc["integrator"] = draw(st.text(max_size=8) | st.sampled_from(sorted(INTEGRATORS)))
    return doc


# --- a small TOML writer (the test data must be files; the standard library only reads TOML) -----


def _toml_string(s: str) -> str:
    # json escapes quotes, backslash and C0 controls as TOML does; DEL must be escaped too
    return json.dumps(s, ensure_ascii=False).replace("\x7f", "\\u007f")


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v)  # 'nan', 'inf', '-inf', '1e+300' are TOML floats
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, datetime.date):
        return v.isoformat()
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_string(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"not a TOML value: {v!r}")


def to_toml(doc: dict) -> str:
    """TOML text of a document, every table written inline (``key = {...}``)."""
    return "".join(f"{_toml_string(k)} = {_toml_value(v)}\n" for k, v in doc.items())


#: A short lemniscate (the sweep and engine tests'), its duration a format field.
SHORT_LEMNISCATE = """\
name = "short"
duration = {duration}
dt = 0.01
initial_pose = [0.0, -0.2, 1.5707963267948966]
[reference]
kind = "lemniscate"
size = 2.0
period = 40.0
[noise]
pose_std = [0.01, 0.01, 0.01]
"""


def rows_on_every_engine(spec, folder, home, before_workers=None):
    """Run the sweep ``spec`` into ``folder/{serial,local,remote}``: serially, on a 2-worker
    LocalCluster, and on a scheduler with two worker processes started on 127.0.0.1 in ``home``
    (a folder that holds none of the spec's files); every run ok and the three stores' rows equal.
    ``before_workers`` runs after the serial sweep (e.g. to remove a file the workers must not
    need)."""
    from wmr.engine import study, sweep

    def rows(out):
        df = sweep.read_rows(out).to_pandas().sort_values("job_id").reset_index(drop=True)
        assert set(df.status) == {"ok"}, df.error.tolist()
        return df

    sweep.run_sweep(spec, folder / "serial", workers=1, progress=False)
    serial = rows(folder / "serial")
    if before_workers is not None:
        before_workers()
    sweep.run_sweep(spec, folder / "local", workers=2, progress=False, batch_seconds=0.001)
    assert rows(folder / "local").equals(serial)
    with study.LoopbackCluster(home / "cluster", workers=2, timeout=240) as c:
        sweep.run_sweep(spec, folder / "remote", scheduler=c.address, progress=False,
                        batch_seconds=0.001)  # fmt: skip
    assert rows(folder / "remote").equals(serial)
    return serial
