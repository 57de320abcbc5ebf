"""The true robot (wmr.robots.plant, DESIGN §3.3): each effect against a closed form, the
integration's order and accuracy, the ideal plant bit for bit, and the controllers' ignorance of the
plant."""

from __future__ import annotations

import csv
import dataclasses
import math
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest
from cases import CROSS_MACHINE_RTOL
from numpy.testing import assert_allclose, assert_array_equal
from scipy.integrate import solve_ivp

from wmr import scenario as scn
from wmr.closedloop import runsetup
from wmr.closedloop import step as loop
from wmr.closedloop.sim import simulate
from wmr.robots import plant, plantspec

DT = 0.01
PAPER = Path(__file__).resolve().parents[1] / "paper"
#: The exact closed forms are evaluated in a different order than the step: rounding only.
EXACT_RTOL = 1e-12


def drive(spec: scn.Plant, commands, q0=(0.0, 0.0, 0.0), dt=DT):
    """Drive the plant ``spec`` with the command sequence through the loop's plant half
    (``wmr.closedloop.step.plant_step``: delay, no disturbance, no pose filter); the poses ``q_0 ..
    q_n`` and the final actual velocities."""
    sc = scn.from_dict({"name": "p", "duration": len(commands) * dt, "dt": dt,
                        "initial_pose": list(q0), "reference": {"kind": "circle", "radius": 1.0,
                                                                "period": 10.0}})  # fmt: skip
    run = loop.prepare(dataclasses.replace(sc, plant=spec), "backstepping", 0)
    half = loop.plant_step(run)
    arrays = (run.plant_table, run.plant_at, run.plant_ints, run.plant_vel, run.plant_buffer)
    q, u, ua = run.q, np.zeros(2), np.zeros(2)
    poses = [q.copy()]
    for k, c in enumerate(commands):
        u[:] = c
        half(k, dt, run.integrator, u, ua, q, run.disturbance, arrays, None)
        poses.append(q.copy())
    return np.array(poses), run.plant_vel


def test_input_gain_on_a_straight_line():
    """v_gain scales the distance travelled: x = v_gain v t, exactly (the crab arc with w = 0)."""
    n = 500
    q, _ = drive(scn.Plant(v_gain=0.8), [(0.5, 0.0)] * n)
    t = np.arange(n + 1) * DT
    assert_allclose(q[:, 0], 0.8 * 0.5 * t, rtol=EXACT_RTOL, atol=1e-15)
    assert np.all(q[:, 1:] == 0.0)


@pytest.mark.parametrize(("spec", "command", "radius"), [
    (scn.Plant(w_from_v=0.5), (0.4, 0.0), 0.4 / 0.2),  # applied w = 0.5 * 0.4
    (scn.Plant(v_from_w=0.1), (0.0, 1.0), 0.1 / 1.0),  # applied v = 0.1 * 1
    (scn.Plant(v_gain=1.1, w_gain=0.9), (0.5, 0.5), 0.55 / 0.45),
], ids=["w_from_v", "v_from_w", "both-gains"])  # fmt: skip
def test_coupling_turns_a_straight_command_into_a_circle(spec, command, radius):
    """A constant applied (v, w) is a circle of radius v/w about (0, R) from the origin."""
    q, _ = drive(spec, [command] * 700)
    assert_allclose(np.hypot(q[:, 0], q[:, 1] - radius), radius, rtol=EXACT_RTOL)


def test_lag_step_response_is_the_first_order_closed_form():
    """From rest, v(t) = a (1 - e^{-t/tau}) and theta(t) = a_w (t - tau (1 - e^{-t/tau}))."""
    tau, a_v, a_w, n = 0.1, 1.0, 0.5, 60
    spec = scn.Plant(actuator_tau=tau)
    for k in (1, 7, n):
        q, vel = drive(spec, [(a_v, a_w)] * k)
        t = k * DT
        assert_allclose(vel, [a_v * -math.expm1(-t / tau), a_w * -math.expm1(-t / tau)],
                        rtol=EXACT_RTOL)  # fmt: skip
        assert_allclose(q[-1, 2], a_w * (t + tau * math.expm1(-t / tau)), rtol=EXACT_RTOL)
    q, _ = drive(spec, [(a_v, 0.0)] * n)  # straight: x = integral of v
    t = n * DT
    assert_allclose(q[-1, 0], a_v * (t + tau * math.expm1(-t / tau)), rtol=1e-10)


def test_delay_shifts_the_applied_input_sequence():
    """With d steps of delay the plant sees u_{k-d} (zeros first): the same poses as the
    undelayed plant fed the shifted sequence, bit for bit."""
    rng = np.random.default_rng(3)
    commands = rng.uniform(-1.0, 1.0, (50, 2))
    base = scn.Plant(v_gain=1.05, actuator_tau=0.05)
    delayed, _ = drive(dataclasses.replace(base, delay_steps=3), commands)
    shifted = np.vstack((np.zeros((3, 2)), commands[:-3]))
    reference, _ = drive(base, shifted)
    assert_array_equal(delayed, reference)


@pytest.mark.parametrize(("slip", "w"), [(0.2, 0.5), (0.2, -0.5), (-0.2, 0.5)],
                         ids=["outward-left-turn", "outward-right-turn", "inward-left-turn"])
def test_slip_drifts_on_a_circle_of_the_body_velocity(slip, w):
    """DESIGN §3.3: v_s = -slip v w.  With constant (v, w) the body moves on a circle about its
    instantaneous centre (-v_s/w, v/w) (robot frame) with radius sqrt(v^2 + v_s^2)/|w|, and its
    velocity leads the heading by atan2(v_s, v): for slip > 0 away from the turn's centre (to the
    right in a left turn, w > 0; to the left in a right turn), for slip < 0 into it."""
    v = 0.5
    vs = -slip * v * w
    q, _ = drive(scn.Plant(slip=slip), [(v, w)] * 800, q0=(1.0, 2.0, 0.3))
    c, s = math.cos(0.3), math.sin(0.3)
    centre = np.array([1.0, 2.0]) + np.array([[c, -s], [s, c]]) @ [-vs / w, v / w]
    assert_allclose(np.hypot(*(q[:, :2] - centre).T), math.hypot(v, vs) / abs(w),
                    rtol=EXACT_RTOL)  # fmt: skip
    step = q[401, :2] - q[400, :2]
    drift = math.atan2(step[1], step[0]) - (q[400, 2] + q[401, 2]) / 2
    assert_allclose(drift, math.atan2(vs, v), rtol=1e-9)
    outward = -math.copysign(1.0, w)  # the side away from the centre of the no-slip turn
    assert math.copysign(1.0, drift) == (outward if slip > 0 else -outward)


def test_a_negative_slip_is_the_earlier_inward_drift_bit_for_bit():
    """The sign is the only change of DESIGN §3.3's fix: slip = -s now gives the poses that
    slip = s gave before (v_s = +s v w), here written out as the crab arc with that v_s."""
    rng = np.random.default_rng(5)
    commands = rng.uniform(-1.0, 1.0, (30, 2))
    q, _ = drive(scn.Plant(slip=-0.3), commands, q0=(0.2, -0.1, 0.4))
    ref = np.array([0.2, -0.1, 0.4])
    for k, (v, w) in enumerate(commands):
        plant.crab_arc(ref, v, 0.3 * v * w, w, DT)
        assert_array_equal(q[k + 1], ref)


def test_lagged_velocity_model_steady_state_and_time_constant():
    """m v' = m_hat bw (a - v) - f v: v -> bw m_hat a / (bw m_hat + f) with time constant
    m / (bw m_hat + f) (and the same for w with the inertia)."""
    d = scn.LaggedVelocity(mass=10.0, inertia=0.6, friction=(2.0, 0.1), nominal_mass=8.0,
                           nominal_inertia=0.5, bandwidth=(20.0, 15.0))  # fmt: skip
    spec = scn.Plant(model="lagged-velocity", model_table=d)
    a_v, a_w, n = 1.0, 0.4, 40
    _, vel = drive(spec, [(a_v, a_w)] * n)
    t = n * DT
    g_v, g_w = 8.0 * 20.0, 0.5 * 15.0
    ss = np.array([g_v * a_v / (g_v + 2.0), g_w * a_w / (g_w + 0.1)])
    tau = np.array([10.0 / (g_v + 2.0), 0.6 / (g_w + 0.1)])
    assert_allclose(vel, ss * -np.expm1(-t / tau), rtol=EXACT_RTOL)
    assert_allclose(plant.time_constants(spec.row(), plant.LAGGED_VELOCITY), tau,
                    rtol=EXACT_RTOL)  # fmt: skip


def test_a_change_applies_from_the_first_step_with_t_k_at_or_after_at():
    """v_gain 1 -> 0.5 at 0.105 s: steps 0..10 (t_k <= 0.10) move 0.01, steps from 11 on 0.005."""
    spec = scn.Plant(changes=(scn.PlantChange(0.105, {"v_gain": 0.5}),))
    q, _ = drive(spec, [(1.0, 0.0)] * 20)
    dx = np.diff(q[:, 0])
    assert_allclose(dx[:11], DT, rtol=EXACT_RTOL)
    assert_allclose(dx[11:], 0.5 * DT, rtol=EXACT_RTOL)
    exact = scn.Plant(changes=(scn.PlantChange(0.1, {"v_gain": 0.5}),))  # t_10 = 10 * 0.01
    dx = np.diff(drive(exact, [(1.0, 0.0)] * 20)[0][:, 0])
    assert np.sum(np.isclose(dx, DT)) == 10  # k * dt >= at at k = 10 (0.1 == 10 * 0.01)


def _reference_step(spec, q0, vel0, a, dt):
    """One step of the 5-state ODE of DESIGN §3.3 by scipy's DOP853 at tolerance 1e-13 (the
    oracle; the side velocity v_s = -slip v w written here, not taken from wmr.robots.plant)."""
    row = spec.row()
    model = plant.MODEL_CODES[spec.model]
    tv, tau_v, tw, tau_w = plant.channels(np.array(row), model, *a)

    def f(t, x):
        vs = -spec.slip * x[3] * x[4]
        c, s = math.cos(x[2]), math.sin(x[2])
        return [x[3] * c - vs * s, x[3] * s + vs * c, x[4], (tv - x[3]) / tau_v,
                (tw - x[4]) / tau_w]

    sol = solve_ivp(f, (0.0, dt), [*q0, *vel0], method="DOP853", rtol=1e-13, atol=1e-15)
    return sol.y[:, -1]


def test_lagged_step_is_of_order_six():
    """One step against a tight ODE solution: the local error falls as h^7 (GL3 quadrature on
    exact channels), so halving h divides it by ~128; and it is tiny at the scenario's dt."""
    spec = scn.Plant(actuator_tau=0.05, slip=0.3)
    q0, vel0, a = np.array([0.1, -0.2, 0.7]), np.array([0.3, -0.8]), (1.2, 1.5)
    errors = []
    for h in (0.04, 0.02, 0.01):
        q, vel = q0.copy(), vel0.copy()
        plant.lagged_step(plant.table_row(spec.row(), plant.KINEMATIC, h, 1), plant.KINEMATIC, q,
                          vel, *a, h, 1)  # fmt: skip
        errors.append(np.max(np.abs(np.concatenate((q, vel)) - _reference_step(spec, q0, vel0,
                                                                                a, h))))
    assert errors[0] / errors[1] > 64.0 and errors[1] / errors[2] > 64.0, errors
    assert errors[2] < 1e-10, errors  # h = dt of the paper's scenarios


@pytest.fixture(scope="module")
def lemniscate():
    return scn.load(scn.builtin("lemniscate"))


@pytest.mark.parametrize("controller", ["backstepping", "iapid-nn-dekf"])
@pytest.mark.parametrize("section", [
    "[plant]\nactuator_tau = 0.1\ndelay_steps = 2\nslip = 0.1\n",
    "[plant]\nmodel = 'lagged-velocity'\n[plant.lagged-velocity]\nmass = 10.0\n[[plant.change]]\n"
    "at = 20.0\nmass = 15.0\ninertia = 0.75\n",
], ids=["lag-delay-slip", "lagged-velocity-payload"])  # fmt: skip
def test_rmse_is_converged_under_tenfold_refinement(controller, section, lemniscate, monkeypatch):
    """DESIGN §3.3: refining the plant's integration 10x moves a run's RMSE by < 1e-6 (relative)."""
    sc = scn.loads(Path(scn.builtin("lemniscate")).read_text() + section)
    coarse = simulate(sc, controller, 0, keep_trajectory=False).rmse
    n_coarse = plant.arrays(sc.plant, sc.dt)[0][:, plant.N_SUB]
    default = plant.substeps
    monkeypatch.setattr(plant, "substeps", lambda row, model, dt: 10 * default(row, model, dt))
    runsetup.SHARED.clear()  # the plant's table is scenario set-up shared by its runs: rebuild it
    assert np.array_equal(plant.arrays(sc.plant, sc.dt)[0][:, plant.N_SUB], 10 * n_coarse)
    fine = simulate(sc, controller, 0, keep_trajectory=False).rmse
    assert coarse != fine  # the finer integration did run
    for key in ("x", "y", "theta", "position"):
        assert abs(coarse[key] - fine[key]) < 1e-6 * fine[key], (key, coarse, fine)


def test_ideal_plant_is_bit_identical_to_the_committed_results(lemniscate):
    """An explicit ideal [plant] changes nothing (bit for bit: the same run without ``[plant]``),
    and runs equal paper/results/rmse.csv (made before the plant existed) to the cross-machine
    tolerance (``cases.CROSS_MACHINE_RTOL``: the file was made on another CPU)."""
    rows = {}
    with open(PAPER / "results" / "rmse.csv") as fh:
        for r in csv.DictReader(fh):
            if r["variant"] == "default" and r["seed"] in ("0", "3"):
                rows[(r["scenario"], r["controller"], int(r["seed"]))] = r
    for name in scn.PAPER_SCENARIOS:
        text = Path(scn.builtin(name)).read_text() + "\n[plant]\nv_gain = 1.0\nslip = 0.0\n"
        sc = scn.loads(text)
        assert sc.plant.ideal
        for (scenario, controller, seed), r in rows.items():
            if scenario != name:
                continue
            got = simulate(sc, controller, seed, keep_trajectory=False).rmse
            plain = simulate(scn.load(scn.builtin(name)), controller, seed,
                             keep_trajectory=False).rmse  # fmt: skip
            assert got == plain, (name, controller, seed)
            for axis in ("x", "y", "theta", "position"):
                assert got[axis] == pytest.approx(float(r[f"rmse_{axis}"]),
                                                  rel=CROSS_MACHINE_RTOL), (name, controller, seed)


@pytest.mark.parametrize("controller", ["iapid-nn-dekf", "adaptive-nn", "adaptive-pid",
                                        "backstepping"])  # fmt: skip
def test_no_controller_sees_the_true_plant(controller, lemniscate):
    """Changing only the plant leaves the controller's packed model and state, the pose filter
    and the first command unchanged: nothing but the plant reads [plant]."""
    d = scn.LaggedVelocity(mass=13.0, inertia=0.9, nominal_mass=7.0)
    true = dataclasses.replace(lemniscate, plant=scn.Plant(
        model="lagged-velocity", v_gain=0.7, w_from_v=0.3, delay_steps=2, slip=0.2,
        model_table=d))
    a, b = loop.prepare(lemniscate, controller, 0), loop.prepare(true, controller, 0)
    for x, y in ((a.s, b.s), (a.theta, b.theta), (a.P, b.P), (a.Qp, b.Qp), (a.Rp, b.Rp)):
        assert_array_equal(x, y)
    pa = a.p._asdict().values() if hasattr(a.p, "_asdict") else [a.p]
    pb = b.p._asdict().values() if hasattr(b.p, "_asdict") else [b.p]
    for x, y in zip(pa, pb, strict=True):
        assert_array_equal(x, y)
    ra, rb = simulate(lemniscate, controller, 0), simulate(true, controller, 0)
    assert_array_equal(ra.u[0], rb.u[0]) and assert_array_equal(ra.q_hat[0], rb.q_hat[0])
    assert not np.array_equal(ra.q[5], rb.q[5])  # while the robots themselves differ


def test_with_lag_the_robot_starts_at_rest():
    q, vel = drive(scn.Plant(actuator_tau=0.2), [(1.0, 0.0)])
    assert 0.0 < q[1, 0] < 0.1 * DT  # well below the commanded 1 m/s x dt
    assert 0.0 < vel[0] < 0.1


# --- The plant from its fields' metadata (issue 19 item 4) ---------------------------------------

_DEFAULT_MODEL = next(iter(plantspec.MODELS))


def _away(f: dataclasses.Field):
    """A valid value of field ``f`` away from its default: its ``example``, else derived."""
    if f.metadata["example"] is not None:
        return f.metadata["example"]
    d = f.default
    if isinstance(d, tuple):
        return tuple(1.5 * x + 0.1 for x in d)
    if isinstance(d, int) and not isinstance(d, bool):
        return d + 1
    if isinstance(d, float):
        return 1.5 * d + 0.1
    raise TypeError(f"give {f.name} an example value (param(..., example=...))")


#: The models of the compiled plant's parameter table.  A Python-level robot (a model with its
#: own ``parse_table``: the MuJoCo robot) has its own keys and physics, tested by its own tests
#: (tests/test_mujoco_robot.py, tests/test_mujoco_loop.py: each changeable key mid-run there).
_COMPILED_MODELS = [m for m in plantspec.MODELS.values() if m.parse_table is None]


def _each_key():
    """(model, field) for every key of [plant] and of every model's table, and (model, None) for
    every model but the default: read from the metadata, so a new field is covered."""
    out = [pytest.param(None, f, id=f.name) for f in plantspec.spec_fields(scn.Plant)
           if f.name != "model"]  # fmt: skip
    for m in _COMPILED_MODELS:
        if m.name != _DEFAULT_MODEL:
            out.append(pytest.param(m.name, None, id=f"model={m.name}"))
        for f in plantspec.spec_fields(m.table) if m.table is not None else ():
            out.append(pytest.param(m.name, f, id=f"{m.name}.{f.name}"))
    return out


@pytest.fixture(scope="module")
def short():
    """A 2 s lemniscate with noise: 200 steps, every effect shows in the poses."""
    text = Path(scn.builtin("lemniscate")).read_text().replace("duration = 40.0", "duration = 2.0")
    return scn.loads(text)


def _poses(sc, spec):
    return simulate(dataclasses.replace(sc, plant=spec), "backstepping", 1).q


def test_every_key_is_declared_with_its_metadata():
    """Every key of [plant] and of the models' tables is a param() field (a plain field would be
    left out of ideal, the table, to_json and describe), and wmr.robots.plant's columns are the
    specification's (a consistency check of the derivation)."""
    for cls in (scn.Plant, *(m.table for m in plantspec.MODELS.values() if m.table)):
        keys = {f.name for f in dataclasses.fields(cls) if f.metadata.get("toml", True)}
        assert keys == {f.name for f in plantspec.spec_fields(cls)}, cls
    assert plant.PARAMS == (*plantspec.COLUMNS, "substeps", *plant.DECAYS)


def _null_change(model: str, other_than: str | None) -> tuple:
    """A change that changes nothing (a changeable key, not ``other_than``, set to its default
    at t = 0): the plant takes the plant kernel with the model's default parameters."""
    key = next(k for k in plantspec.changeable(model) if k != other_than)
    owner = scn.Plant if key in {f.name for f in plantspec.spec_fields(scn.Plant)} else \
        plantspec.MODELS[model].table
    return (scn.PlantChange(0.0, {key: next(f.default for f in plantspec.spec_fields(owner)
                                            if f.name == key)}),)  # fmt: skip


@pytest.mark.parametrize(("model", "f"), _each_key())
def test_each_key_away_from_its_default_is_a_different_robot(model, f, short):
    """A key away from its default: the plant is not ideal, describe() and to_json() show it,
    and a short run's poses differ from the ideal plant's run and from the run of the same
    kernel without it (the model at its defaults, made non-ideal by a change that changes
    nothing; the kernels differ in rounding): nothing is left at the ideal kernel or unread by
    the physics."""
    if model is None:  # a key of [plant], on the first model it applies to
        model = next(m for m, row in plantspec.MODELS.items() if f.name not in row.excluded)
        base = scn.Plant(model=model)
        spec = dataclasses.replace(base, **{f.name: _away(f)})
        value = getattr(spec, f.name)
        assert spec.to_json()[f.name] == (list(value) if isinstance(value, tuple) else value)
    elif f is None:  # another model, at its defaults
        base, spec, value = scn.Plant(), scn.Plant(model=model), model
    else:  # a key of the model's table
        base = scn.Plant(model=model)
        spec = dataclasses.replace(base, model_table=dataclasses.replace(
            base.model_table, **{f.name: _away(f)}))  # fmt: skip
        value = getattr(spec.model_table, f.name)
        assert spec.to_json()[model][f.name] == (list(value) if isinstance(value, tuple)
                                                 else value)  # fmt: skip
    assert not spec.ideal
    if f is not None:
        assert f.metadata["label"].format(name=f.name, value=plantspec._fmt(value)) in \
            spec.describe()
    else:
        assert spec.describe().startswith(f"plant: {model}")
    changed = _poses(short, spec)
    assert not np.array_equal(changed, _poses(short, scn.Plant()))
    same_kernel = dataclasses.replace(base, changes=_null_change(base.model, f and f.name))
    assert not np.array_equal(_poses(short, dataclasses.replace(spec, changes=same_kernel.changes)),
                              _poses(short, same_kernel))  # fmt: skip


def _each_changeable():
    return [pytest.param(m.name, k, id=f"{m.name}.{k}") for m in _COMPILED_MODELS
            for k in plantspec.changeable(m.name)]  # fmt: skip


@pytest.mark.parametrize(("model", "key"), _each_changeable())
def test_each_changeable_key_changes_the_robot_mid_run(model, key, short):
    """A [[plant.change]] of each changeable key at 1 s to a value away from its default gives
    the poses of the same change to the default value up to 1 s, bit for bit, and others after
    (both take the plant kernel: a change makes a plant non-ideal)."""
    table = plantspec.MODELS[model].table
    owner = scn.Plant if key in {f.name for f in plantspec.spec_fields(scn.Plant)} else table
    f = next(f for f in plantspec.spec_fields(owner) if f.name == key)
    base = scn.Plant(model=model, changes=(scn.PlantChange(1.0, {key: f.default}),))
    spec = dataclasses.replace(base, changes=(scn.PlantChange(1.0, {key: _away(f)}),))
    a, b = _poses(short, base), _poses(short, spec)
    k = round(1.0 / short.dt)
    assert_array_equal(a[:k + 1], b[:k + 1])
    assert not np.array_equal(a[k + 1:], b[k + 1:])


@pytest.mark.parametrize("name", ["lemniscate-payload", "lemniscate-lag-delay", "lemniscate-slip"])
def test_to_json_is_the_plant_table_of_the_file(name):
    """to_json() mirrors the scenario file: read back as a [plant] table it is the same plant."""
    sc = scn.load(scn.builtin(name))
    doc = sc.plant.to_json()
    doc["change"] = doc.pop("changes")
    assert plantspec.parse(doc, plantspec.Context(sc.duration, sc.dt, sc.source)) == sc.plant


def test_the_renamed_model_is_an_error_naming_the_new_name():
    for text, key in (('[plant]\nmodel = "dynamic"\n', "plant.model"),
                      ('[plant]\nmodel = "dynamic"\n[plant.dynamic]\nmass = 12.0\n',
                       "plant.dynamic")):  # fmt: skip
        with pytest.raises(scn.ScenarioError, match="lagged-velocity") as err:
            scn.loads(Path(scn.builtin("lemniscate")).read_text() + text, "f.toml")
        assert err.value.key == key and "\n" not in str(err.value)


def test_the_extending_recipes_plant_field_is_picked_up_everywhere():
    """docs/extending.md's example field, declared on a Plant (here a subclass, as the recipe
    adds it to Plant itself): ideal, the table's columns, the changeable keys, describe(),
    to_json(), the loader's rule and the settings reference follow from the declaration alone."""
    from wmr._settings import SettingError, from_table
    from wmr.settings_reference import attribute_docs

    doc = (PAPER.parent / "docs" / "extending.md").read_text()
    m = re.search(r"<!-- example: plant-field -->\n```python\n(.*?)```", doc, re.S)
    assert m, "no plant-field example in docs/extending.md"
    ns = {"Plant": scn.Plant, "dataclasses": dataclasses, "plantspec": plantspec,
          **{k: getattr(plantspec, k) for k in plantspec.__all__}}  # fmt: skip
    exec("@plantspec.plant_table\nclass Extended(Plant):\n"
         + textwrap.indent(m.group(1), "    "), ns)
    cls = ns["Extended"]
    (f,) = [f for f in plantspec.spec_fields(cls) if f.name not in
            {g.name for g in plantspec.spec_fields(scn.Plant)}]  # fmt: skip
    assert cls().ideal and not cls(**{f.name: _away(f)}).ideal
    assert f.name in plantspec.columns(cls) and f.name not in plantspec.COLUMNS
    assert cls(**{f.name: _away(f)}).row()[plantspec.columns(cls).index(f.name)] == _away(f)
    assert f.name in plantspec.changeable(_DEFAULT_MODEL, cls)
    assert f"{f.name} {plantspec._fmt(_away(f))}" in cls(**{f.name: _away(f)}).describe()
    assert cls(**{f.name: _away(f)}).to_json()[f.name] == _away(f)
    assert from_table(cls, {f.name: _away(f)}, "plant") == cls(**{f.name: _away(f)})
    with pytest.raises(SettingError, match=f"plant.{f.name}"):
        from_table(cls, {f.name: "fast"}, "plant")
    assert attribute_docs(cls)[f.name] == (f.metadata["unit"], f.metadata["doc"])
