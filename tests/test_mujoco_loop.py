"""The MuJoCo robot in the loop (DESIGN §3.7): ``model = "mujoco"`` from a scenario file, a
user's MJCF through ``wmr run``, sweeps on every engine, and the loop's side of the contract --
delay, disturbance and saturation before the robot, the pose measured at the control instants --
checked against the robot driven directly with the commands the loop logged (an independent
replay), bit for bit."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from cases import rows_on_every_engine
from numpy.testing import assert_array_equal
from test_mujoco_robot import USER_MJCF

from wmr import cli
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.engine import sweep
from wmr.robots.mujoco_robot import MujocoRobot

SCENARIO = """\
name = "mj"
duration = 2.0
dt = 0.01
initial_pose = [0.0, -0.2, 1.5707963267948966]
seed = 3

[reference]
kind = "lemniscate"
size = 1.0
period = 20.0

[noise]
pose_std = [0.01, 0.01, 0.01]

[[disturbance]]
start = 0.5
stop = 1.0
velocity = [0.1, 0.3]

[limits]
v_max = 0.6
w_max = 1.5

[plant]
model = "mujoco"
delay_steps = 2

[plant.mujoco]
{robot}

[[plant.change]]
at = 1.2
{change}
"""
SHIPPED = SCENARIO.format(robot='robot = "diff-drive"\nfriction = 0.8', change="mass = 13.0")
USER = SCENARIO.format(robot='file = "me.xml"\nnominal_wheel_radius = 0.06\nnominal_track = 0.22',
                       change="").replace("[[plant.change]]\nat = 1.2\n", "")


def _user_scenario(folder: Path) -> Path:
    (folder / "me.xml").write_text(USER_MJCF)
    (folder / "user.toml").write_text(USER)
    return folder / "user.toml"


def test_the_loop_drives_the_robot_as_the_contract_says():
    """Replay the logged commands through a fresh robot: the delay (zeros, then the command of
    two steps before), the disturbance inside its window and the change at 1.2 s are the loop's;
    the poses are the robot's at the control instants."""
    sc = scn.loads(SHIPPED)
    r = simulate(sc, "backstepping", 3)
    assert sc.plant.model == "mujoco" and not sc.plant.ideal and not r.diverged
    robot = MujocoRobot(sc.plant.model_table, sc.dt, [(c.at, c.values) for c in sc.plant.changes])
    robot.reset(np.array(sc.initial_pose))
    q, poses = np.empty(3), [np.array(sc.initial_pose)]
    for k in range(sc.n_steps):
        a = (r.u[k - 2] if k >= 2 else np.zeros(2)) + r.disturbance[k]
        robot.advance(k, a)
        robot.pose(q)
        poses.append(q.copy())
    assert_array_equal(np.array(poses), r.q)
    assert np.all(np.abs(r.u) <= [0.6, 1.5])  # the command is saturated before the robot
    assert r.plant_velocity.shape == (sc.n_steps, 2)
    assert simulate(sc, "backstepping", 3).rmse == r.rmse  # deterministic


@pytest.mark.parametrize(("key", "away", "default"), [
    ("mass", "13.0", "10.0"), ("com_offset", "[0.05, 0.02]", "[0.0, 0.0]"),
    ("friction", "0.3", "0.8"),
], ids=["mass", "com_offset", "friction"])  # fmt: skip
def test_each_changeable_key_takes_effect_at_its_time(key, away, default):
    """Every key a [[plant.change]] may set on the MuJoCo robot (plantspec.MODELS["mujoco"]):
    the same run up to the change, another after (``default``: the value in force before)."""
    from wmr.robots import plantspec

    assert set(plantspec.changeable("mujoco")) >= {"mass", "com_offset", "friction"}
    sc = scn.loads(SHIPPED.replace("mass = 13.0", f"{key} = {away}"))
    light = scn.loads(SHIPPED.replace("mass = 13.0", f"{key} = {default}"))
    a, b = simulate(sc, "pid", 0), simulate(light, "pid", 0)
    k = round(1.2 / sc.dt)
    assert_array_equal(a.q[: k + 1], b.q[: k + 1])
    assert not np.array_equal(a.q[k + 1 :], b.q[k + 1 :])


def test_a_users_mjcf_runs_through_wmr_run(tmp_path, capsys):
    path = _user_scenario(tmp_path)
    outs = []
    for tag in ("a", "b"):
        code = cli.main(["run", str(path), "--controller", "backstepping", "iapid-nn-dekf",
                         "--out", str(tmp_path / tag)])  # fmt: skip
        assert code == 0, capsys.readouterr().err
        outs.append(json.loads((tmp_path / tag / "summary.json").read_text()))
    assert outs[0] == outs[1]  # same seed, same numbers
    assert outs[0]["plant"]["model"] == "mujoco"
    assert len(outs[0]["plant"]["mujoco"]["xml_sha256"]) == 64
    assert all(not run["diverged"] for run in outs[0]["runs"])


@pytest.mark.parametrize(("text", "key"), [
    (SHIPPED.replace("delay_steps = 2", "delay_steps = 2\nv_gain = 0.9"), "plant.v_gain"),
    (SHIPPED.replace("delay_steps = 2", "delay_steps = 2\nslip = 0.1"), "plant.slip"),
    (SHIPPED.replace("dt = 0.01", "dt = 0.003"), "dt"),
    (SHIPPED.replace("mass = 13.0", "v_gain = 0.8"), "plant.change[0].v_gain"),
    (SHIPPED.replace('robot = "diff-drive"', 'robot = "tank"'), "plant.mujoco.robot"),
    (SHIPPED.replace("[plant.mujoco]", "[plant.lagged-velocity]"), "plant.lagged-velocity"),
    (SHIPPED.replace('[plant.mujoco]\nrobot = "diff-drive"\nfriction = 0.8\n', ""),
     "plant.mujoco"),
], ids=["v_gain", "slip", "dt", "change-v_gain", "robot", "other-table", "no-table"])  # fmt: skip
def test_bad_mujoco_scenarios_are_one_line_errors(text, key):
    with pytest.raises(scn.ScenarioError) as info:
        scn.loads(text)
    assert key in str(info.value) and "\n" not in str(info.value)


SPEC = """\
name = "mj-sweep"
scenarios = ["user.toml"]
controllers = ["backstepping", "pid"]
seeds = 2

[factors]
"plant.delay_steps" = [0, 1]
"""


def test_a_users_robot_sweeps_on_every_engine_with_the_serial_rows(tmp_path_factory):
    folder = tmp_path_factory.mktemp("mj-sweep")
    _user_scenario(folder)
    (folder / "spec.toml").write_text(SPEC)
    spec = sweep.load_spec(folder / "spec.toml")

    rows_on_every_engine(spec, folder, tmp_path_factory.mktemp("elsewhere"),
                         before_workers=lambda: (folder / "me.xml").unlink())  # fmt: skip


MUJOCO_SHIPPED = sorted(p.stem for p in (Path(scn.builtin("lemniscate")).parent / "mujoco")
                        .glob("*.toml"))  # fmt: skip


def _saturated_share(sc, r) -> float:
    """The share of steps at which a servo was at its torque limit: the run's commands replayed
    through a fresh robot (the loop's contract, checked above) with its diagnostics read."""
    from wmr.robots.mujoco_robot import DIAGNOSTICS

    robot = MujocoRobot(sc.plant.model_table, sc.dt, [(c.at, c.values) for c in sc.plant.changes])
    robot.reset(np.array(sc.initial_pose))
    d, hit = np.empty(len(DIAGNOSTICS)), 0
    for k in range(len(r.u)):
        robot.advance(k, r.u[k] + r.disturbance[k])  # no delay in the shipped scenarios
        robot.diagnostics(d)
        hit += d[DIAGNOSTICS.index("saturated")] > 0
    return hit / len(r.u)


@pytest.mark.parametrize("name", MUJOCO_SHIPPED)
def test_the_shipped_mujoco_scenarios_run(name):
    sc = scn.load(scn.builtin(f"mujoco/{name}"))
    assert sc.plant.model == "mujoco" and sc.plant.delay_steps == 0
    r = simulate(sc, "backstepping", 0)
    assert not r.diverged, (name, r.cause)
    if name == "lemniscate-torque-limit":  # stated in the scenario file: about a tenth
        share = _saturated_share(sc, r)
        assert 0.05 <= share <= 0.2, share
        assert _saturated_share(scn.load(scn.builtin("mujoco/lemniscate")),
                                simulate(scn.load(scn.builtin("mujoco/lemniscate")),
                                         "backstepping", 0)) < share  # fmt: skip


def test_seven_mujoco_scenarios_ship():
    assert MUJOCO_SHIPPED == ["lemniscate", "lemniscate-low-friction", "lemniscate-payload",
                              "lemniscate-torque-limit", "lemniscate-unequal-wheels",
                              "sinusoid", "sinusoid-perturbed"]  # fmt: skip
