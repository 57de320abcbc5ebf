"""The MuJoCo differential-drive plant (wmr.robots.mujoco_robot, DESIGN §3.7), on real MuJoCo.

Oracles: the firmware's wheel-speed formula; the unicycle arc and the kinematics of unequal
wheels (closed forms); Newton's law at the torque limit (closed form); the pose's own finite
differences; two robots and a rerun (bit for bit); the unwrapped heading against its wrapped
quaternion heading and the integral of the measured yaw rate.
"""

from __future__ import annotations

import math
import pickle
from pathlib import Path

import mujoco
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from wmr.robots import mujoco_model as mm
from wmr.robots.mujoco_robot import CHANGEABLE, DIAGNOSTICS, MujocoRobot, MujocoSpec, heading
from wmr.scenario import ScenarioError

DT = 0.01
SOURCE = "robot.toml"
#: Index of the torque-limit flag in the diagnostics vector.
SAT = DIAGNOSTICS.index("saturated")
LAT = DIAGNOSTICS.index("lateral_velocity")
#: High friction and a stiff servo: the robot should follow its wheels (DESIGN §3.7).
STIFF = {"friction": 1.0, "motor_gain": 20.0, "torque_limit": 20.0}
#: [s] transient after a step command from rest with STIFF: the stiff servo spins the wheels up
#: faster than friction can accelerate the robot (a short wheel spin), then the chassis's
#: pitch and yaw settle; measured within 2e-5 of the command from 1.2 s on.
SETTLE = 1.5
#: Steady (v, w) against the command after SETTLE: the tyres roll on their loaded radius (the
#: contact's static penetration, 1.8e-5 m of 0.05 m: 3.6e-4 relative) and creep (~1e-5).
VELOCITY_TOL = 5e-4
#: [m] the pose against the unicycle arc over 3 s at (0.4 m/s, 0.8 rad/s): the soft friction
#: creeps outward by about v w tc / 2 (slip angle ~ w tc / 2 = 1.6 mrad with the tyres'
#: time constant tc = 4 ms), turning the path about its start by that angle: <= 1 mm on the
#: 1 m circle; a wrong mapping (e.g. track 5 % off) misses by centimetres.
ARC_TOL = 2e-3
#: [m], [rad]: a zero command from rest (the model is built at its static equilibrium).
REST_TOL = 1e-6


def spec_of(**table) -> MujocoSpec:
    return MujocoSpec.from_table(table, base_dir=None, source=SOURCE)


def drive(spec, commands, q0=(0.0, 0.0, 0.0), changes=(), robot=None):
    """Reset at ``q0`` and hold each command for one control step: the poses ``q_0 .. q_n``
    (n+1, 3), the measured ``(v, w)`` after each step (n, 2) and the diagnostics (n, 9)."""
    robot = robot or MujocoRobot(spec, DT, changes)
    robot.reset(q0)
    q, u, g = np.empty(3), np.empty(2), np.empty(len(DIAGNOSTICS))
    robot.pose(q)
    poses, vels, diags = [q.copy()], [], []
    for k, a in enumerate(commands):
        robot.advance(k, a)
        robot.pose(q)
        robot.velocity(u)
        robot.diagnostics(g)
        poses.append(q.copy())
        vels.append(u.copy())
        diags.append(g.copy())
    return np.array(poses), np.array(vels), np.array(diags)


def arc(q0, v, w, t):
    """The unicycle's pose after ``t`` [s] at constant (v, w) from ``q0`` (closed form, eq. 1)."""
    x, y, th = q0
    return np.column_stack([x + v / w * (np.sin(th + w * t) - np.sin(th)),
                            y - v / w * (np.cos(th + w * t) - np.cos(th)), th + w * t])  # fmt: skip


# -- the firmware ---------------------------------------------------------------------------------


@pytest.mark.parametrize("command", [(0.3, 0.0), (0.0, 1.5), (0.4, -0.7), (-0.2, 0.9)],
                         ids=["straight", "spin", "right-turn", "reverse-left"])  # fmt: skip
def test_wheel_speed_setpoints_follow_the_nominal_mapping(command):
    """The actuators get omega_L = (v - w b_n/2)/r_n, omega_R = (v + w b_n/2)/r_n with the
    *nominal* radius and track (here 4 % and 5 % off the true ones)."""
    spec = spec_of(nominal_wheel_radius=0.052, nominal_track=0.315)
    robot = MujocoRobot(spec, DT)
    robot.reset((0.0, 0.0, 0.0))
    robot.advance(0, command)
    v, w = command
    left = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "left_motor")
    right = mujoco.mj_name2id(robot.model, mujoco.mjtObj.mjOBJ_ACTUATOR, "right_motor")
    # 0.315 / 2 is computed as 0.5 * 0.315 in the firmware: rounding only
    assert_allclose(robot.data.ctrl[left], (v - w * 0.315 / 2) / 0.052, rtol=1e-14, atol=1e-14)
    assert_allclose(robot.data.ctrl[right], (v + w * 0.315 / 2) / 0.052, rtol=1e-14, atol=1e-14)


# -- the physics against closed forms ------------------------------------------------------------


def test_constant_command_gives_the_unicycle_arc():
    """High friction, stiff servos: after the servo transient the measured (v, w) equal the
    command and the pose follows the unicycle arc; the side slip is the soft contact's creep
    (outward, below v w tc), and the measured velocity is the pose's own chord velocity."""
    v, w = 0.4, 0.8
    n = 450
    q, u, g = drive(spec_of(**STIFF), [(v, w)] * n, q0=(1.0, -0.5, 3.0))
    k0 = round(SETTLE / DT)
    assert_allclose(u[k0:], np.tile([v, w], (n - k0, 1)), atol=VELOCITY_TOL)
    expected = arc(q[k0], v, w, DT * np.arange(n + 1 - k0))
    assert np.max(np.hypot(*(q[k0:, :2] - expected[:, :2]).T)) < ARC_TOL
    assert np.max(np.abs(q[k0:, 2] - expected[:, 2])) < ARC_TOL
    lateral = g[k0:, LAT]
    tc = mm.SOLREF[0]
    assert np.all(lateral < 0) and np.all(lateral > -v * w * tc)  # outward, of the creep's size
    # the measured velocity against the chord of the pose over the last control step
    chord = np.diff(q, axis=0)[k0:]
    mid = q[k0:-1, 2] + chord[:, 2] / 2
    side = (-np.sin(mid) * chord[:, 0] + np.cos(mid) * chord[:, 1]) / DT
    assert_allclose(side, lateral, atol=1e-7)


def test_unequal_wheels_follow_the_kinematic_prediction():
    """True radii r_L != r_R with the firmware's nominal r_n: each wheel rolls r_i omega_i, so
    v = (r_L omega_L + r_R omega_R)/2 and w = (r_R omega_R - r_L omega_L)/b."""
    r_left, r_right, r_n, b = 0.048, 0.052, 0.05, 0.30
    v, w = 0.4, 0.5
    spec = spec_of(**STIFF, wheel_radius=[r_left, r_right], nominal_wheel_radius=r_n, track=b)
    _, u, _ = drive(spec, [(v, w)] * 200)
    om_left, om_right = (v - w * b / 2) / r_n, (v + w * b / 2) / r_n
    predicted = ((r_left * om_left + r_right * om_right) / 2,
                 (r_right * om_right - r_left * om_left) / b)
    assert_allclose(u[-1], predicted, atol=VELOCITY_TOL)
    assert abs(predicted[1] - w) > 100 * VELOCITY_TOL  # the test can tell the two apart


def test_torque_limit_saturates_and_bounds_the_acceleration():
    """A step to 1 m/s needs more than the 0.3 N m limit: the flag is up, no torque exceeds the
    limit, and the robot accelerates at Newton's 2 tau / (r m_eff), m_eff = mass + 2 m_w + 2
    I_w / r^2 (the wheels' spin inertia I_w = m_w r^2 / 2; frictionless casters, no drag)."""
    tau, r, mass = 0.3, 0.05, 10.0
    _, u, g = drive(spec_of(torque_limit=tau, motor_gain=20.0, mass=mass), [(1.0, 0.0)] * 60)
    assert np.all(g[:, SAT] == 1.0)
    assert np.max(np.abs(g[:, 6:8])) <= tau * (1 + 1e-12)
    m_eff = mass + 2 * mm.WHEEL_MASS + 2 * (mm.WHEEL_MASS * r * r / 2) / r**2
    accel = np.diff(u[:, 0]) / DT
    assert_allclose(accel[5:], 2 * tau / (r * m_eff), rtol=1e-3)
    # a command within reach: the flag drops once the servo has caught up
    _, _, g = drive(spec_of(torque_limit=tau, motor_gain=20.0), [(0.05, 0.0)] * 100)
    assert g[0, SAT] == 1.0 and g[-1, SAT] == 0.0


def test_heading_unwraps_across_pi_over_ten_turns():
    """Ten turns on the spot: theta grows monotonically past 20 pi, equals the quaternion's
    heading modulo 2 pi, and the integral of the measured yaw rate."""
    w = 3.0
    n = round(2 * math.pi * 10.2 / w / DT)
    robot = MujocoRobot(spec_of(**STIFF), DT)
    q, u, _ = drive(None, [(0.0, w)] * n, q0=(0.0, 0.0, 3.0), robot=robot)
    assert np.all(np.diff(q[:, 2]) > 0)
    assert q[-1, 2] > 3.0 + 20 * math.pi
    qa = robot._qa
    wrapped = heading(robot.data.qpos[qa + 3:qa + 7])
    assert abs(math.remainder(q[-1, 2] - wrapped, 2 * math.pi)) < 1e-12
    integral = 3.0 + DT * np.sum(u[:, 1])  # rectangle rule of the measured rates
    assert abs(q[-1, 2] - integral) < 0.02


@pytest.mark.parametrize("table", [{}, {"com_offset": [0.05, 0.03], "wheel_radius": [0.049, 0.051],
                                        "mass": 14.0}],
                         ids=["default", "offset-and-unequal"])  # fmt: skip
def test_rests_at_t0_without_settling(table):
    """A zero command for 1 s leaves the pose where it was put, to 1e-6 m and rad."""
    q, _, _ = drive(spec_of(**table), [(0.0, 0.0)] * 100, q0=(0.3, -0.2, 2.0))
    assert_allclose(q, np.tile([0.3, -0.2, 2.0], (101, 1)), atol=REST_TOL)


def test_same_inputs_same_numbers_bit_for_bit():
    """Two robots, one robot reset and rerun, and a robot built from the spec after a trip
    through pickle (as to a worker) give identical poses for the same commands."""
    rng = np.random.default_rng(7)
    commands = np.column_stack([rng.uniform(-0.3, 0.6, 300), rng.uniform(-2.0, 2.0, 300)])
    spec = spec_of(friction=0.4, com_offset=[0.02, -0.01])
    changes = [(1.0, {"mass": 12.0, "com_offset": [0.04, 0.0]})]
    first, _, _ = drive(spec, commands, changes=changes)
    robot = MujocoRobot(spec, DT, changes)
    second, _, _ = drive(None, commands, robot=robot)
    third, _, _ = drive(None, commands, robot=robot)  # reset undoes the change of the run before
    shipped, _, _ = drive(pickle.loads(pickle.dumps(spec)), commands, changes=changes)
    assert_array_equal(first, second)
    assert_array_equal(first, third)
    assert_array_equal(first, shipped)


@pytest.mark.parametrize("table", [{}, {"friction": 0.1}, {"friction": 0.4,
                                                          "com_offset": [0.02, -0.01]}])
def test_the_shipped_robot_skips_island_discovery_with_the_same_bits(table):
    """The shipped robot is one kinematic tree, so MujocoRobot turns MuJoCo's island discovery
    off (a cost, no physics); the poses, velocities and diagnostics are bit for bit those of
    the same robot with islands on (MuJoCo's default), sliding (low friction) or not, with a
    mid-run change; the unwrapped heading is ``heading`` of the orientation up to whole turns."""
    rng = np.random.default_rng(11)
    commands = np.column_stack([rng.uniform(-0.3, 0.8, 400), rng.uniform(-2.5, 2.5, 400)])
    spec = spec_of(**table)
    changes = [(2.0, {"mass": 13.0})]
    off = MujocoRobot(spec, DT, changes)
    assert off.model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_ISLAND
    on = MujocoRobot(spec, DT, changes)
    on.model.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
    for a, b in zip(drive(None, commands, robot=off), drive(None, commands, robot=on),
                    strict=True):  # fmt: skip
        assert_array_equal(a, b)
    qa = off._qa
    wrapped = heading(off.data.qpos[qa + 3:qa + 7])
    q = np.empty(3)
    off.pose(q)
    assert abs(math.remainder(q[2] - wrapped, 2 * math.pi)) < 1e-9


# -- [[plant.change]] -----------------------------------------------------------------------------


@pytest.mark.parametrize(("change", "command"), [
    ({"mass": 16.0}, (0.5, 1.2)),
    ({"com_offset": [0.06, 0.02]}, (0.5, 1.2)),
    ({"friction": 0.05}, (0.5, 1.2)),  # 0.6 m/s^2 > 0.05 g: the robot slides from then on
], ids=["mass", "com_offset", "friction"])  # fmt: skip
def test_change_takes_effect_at_the_first_step_at_or_after_at(change, command):
    """A change at 0.995 s applies from step 100 (t = 1.0 s): the poses equal the unchanged run's
    through q_100 (bit for bit) and differ from q_101 on."""
    spec = spec_of(friction=0.3)
    commands = [command] * 150
    plain, _, _ = drive(spec, commands)
    changed, _, g = drive(spec, commands, changes=[(0.995, change)])
    assert_array_equal(changed[:101], plain[:101])
    assert np.all(np.any(changed[101:] != plain[101:], axis=1))
    if "friction" in change:  # sliding sets in: the side slip grows far beyond the creep
        assert np.min(np.abs(g[110:, LAT])) > 0.01 > 0.001 > np.max(np.abs(g[60:100, LAT]))


def test_heavier_payload_accelerates_slower_at_the_torque_limit():
    """A mass change is a real mass: Newton's acceleration at the limit drops as 1 / m_eff."""
    tau, r = 0.3, 0.05
    spec = spec_of(torque_limit=tau, motor_gain=20.0)
    _, u, _ = drive(spec, [(2.0, 0.0)] * 60, changes=[(0.3, {"mass": 20.0})])
    accel = np.diff(u[:, 0]) / DT
    m_eff = 20.0 + 2 * mm.WHEEL_MASS + mm.WHEEL_MASS
    assert_allclose(accel[40:], 2 * tau / (r * m_eff), rtol=1e-3)


# -- a user's own MJCF ----------------------------------------------------------------------------

USER_MJCF = """<mujoco model="user-robot">
  <option timestep="0.005" integrator="implicitfast" cone="elliptic"/>
  <worldbody>
    <geom name="ground" type="plane" size="5 5 0.1" friction="0 0 0"/>
    <body name="base" pos="0 0 0.06">
      <freejoint/>
      <geom type="box" size="0.12 0.08 0.03" pos="-0.04 0 0.03" mass="4"/>
      <geom type="sphere" size="0.02" pos="-0.1 0 -0.04" friction="0" condim="1" mass="0.01"/>
      <body name="lw" pos="0 0.11 0">
        <joint name="left_wheel" type="hinge" axis="0 1 0"/>
        <geom type="sphere" size="0.06" mass="0.2" friction="0.9"/>
      </body>
      <body name="rw" pos="0 -0.11 0">
        <joint name="right_wheel" type="hinge" axis="0 1 0"/>
        <geom type="sphere" size="0.06" mass="0.2" friction="0.9"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <velocity name="left_motor" joint="left_wheel" kv="5" forcerange="-0.5 0.5"
              forcelimited="true"/>
    <general name="right_motor" joint="right_wheel" gainprm="5" biastype="affine" biasprm="0 0 -5"
             forcerange="-0.5 0.5" forcelimited="true"/>
  </actuator>
</mujoco>
"""


def user_spec(tmp_path: Path, xml: str = USER_MJCF, **extra) -> MujocoSpec:
    (tmp_path / "me.xml").write_text(xml, encoding="utf-8")
    table = {"file": "me.xml", "nominal_wheel_radius": 0.06, "nominal_track": 0.22, **extra}
    return MujocoSpec.from_table(table, base_dir=tmp_path, source=str(tmp_path / SOURCE))


def test_a_users_mjcf_loads_and_runs(tmp_path):
    """A file with the names of §3.7 (one <velocity>, one <general> servo) runs from its text
    alone: it drives the commanded speed and turn, and the spec's timestep replaces the file's."""
    spec = user_spec(tmp_path)
    assert spec.file == "me.xml" and spec.robot is None and spec.xml == USER_MJCF
    (tmp_path / "me.xml").unlink()  # the text travels with the spec, not the file
    robot = MujocoRobot(spec, DT)
    assert robot.model.opt.timestep == 0.002 and robot.n_sub == 5
    q, u, _ = drive(None, [(0.3, 0.0)] * 150 + [(0.3, 0.6)] * 150, q0=(2.0, 1.0, -1.0),
                    robot=robot)  # fmt: skip
    assert_allclose(u[140], [0.3, 0.0], atol=5e-3)
    assert_allclose(u[-1], [0.3, 0.6], atol=5e-3)
    assert abs(q[150, 2] - (-1.0)) < 0.01  # straight: heading kept
    assert np.hypot(q[150, 0] - 2.0, q[150, 1] - 1.0) == pytest.approx(0.3 * 1.5, abs=0.02)


# -- bad input: one line naming the file, key and value -------------------------------------------


def error_of(call) -> str:
    with pytest.raises(ScenarioError) as info:
        call()
    text = str(info.value)
    assert "\n" not in text
    return text


@pytest.mark.parametrize(("table", "key", "value"), [
    ({"robot": "tank"}, "plant.mujoco.robot", "'tank'"),
    ({"wheels": 3}, "plant.mujoco.wheels", "3"),
    ({"mass": 0.0}, "plant.mujoco.mass", "0.0"),
    ({"mass": -2.0}, "plant.mujoco.mass", "-2.0"),
    ({"wheel_radius": [0.05, -0.01]}, "plant.mujoco.wheel_radius", "-0.01"),
    ({"wheel_radius": 0.0}, "plant.mujoco.wheel_radius", "0.0"),
    ({"track": -0.3}, "plant.mujoco.track", "-0.3"),
    ({"friction": 0.0}, "plant.mujoco.friction", "0.0"),
    ({"torque_limit": -1.0}, "plant.mujoco.torque_limit", "-1.0"),
    ({"motor_gain": 0.0}, "plant.mujoco.motor_gain", "0.0"),
    ({"timestep": 0.0}, "plant.mujoco.timestep", "0.0"),
    ({"nominal_track": -1.0}, "plant.mujoco.nominal_track", "-1.0"),
    ({"com_offset": [0.2, 0.0]}, "plant.mujoco.com_offset", "[0.2, 0.0]"),
    ({"com_offset": 0.1}, "plant.mujoco.com_offset", "0.1"),
    ({"mass": "heavy"}, "plant.mujoco.mass", "'heavy'"),
], ids=lambda x: x if isinstance(x, str) and x.startswith("plant") else None)  # fmt: skip
def test_bad_shipped_table_is_one_line(table, key, value):
    text = error_of(lambda: spec_of(**table))
    assert text.startswith(f"{SOURCE}: {key} = ") and value in text


MISSING = {
    "body": USER_MJCF.replace('name="base"', 'name="chassis"'),
    "joint": USER_MJCF.replace('name="left_wheel"', 'name="lw_joint"').replace(
        'joint="left_wheel"', 'joint="lw_joint"'),
    "actuator": USER_MJCF.replace('name="right_motor"', 'name="rm"'),
    "free base": USER_MJCF.replace("<freejoint/>", '<joint type="slide" axis="1 0 0"/>'),
    "backward axis": USER_MJCF.replace('name="left_wheel" type="hinge" axis="0 1 0"',
                                       'name="left_wheel" type="hinge" axis="0 -1 0"'),
    "torque motor": USER_MJCF.replace(
        '<velocity name="left_motor" joint="left_wheel" kv="5"',
        '<motor name="left_motor" joint="left_wheel"'),
    "malformed": "<mujoco><worldbody><body></mujoco>",
    "empty": "",
}  # fmt: skip


@pytest.mark.parametrize("case", list(MISSING))
def test_bad_user_mjcf_is_one_line(tmp_path, case):
    text = error_of(lambda: user_spec(tmp_path, MISSING[case]))
    assert "plant.mujoco.file = 'me.xml'" in text and str(tmp_path / SOURCE) in text


def test_user_file_errors_name_key_and_value(tmp_path):
    missing = error_of(lambda: MujocoSpec.from_table(
        {"file": "nope.xml", "nominal_wheel_radius": 0.05, "nominal_track": 0.3},
        base_dir=tmp_path, source=SOURCE))  # fmt: skip
    assert "plant.mujoco.file = 'nope.xml': cannot read" in missing
    shipped_only = error_of(lambda: user_spec(tmp_path, mass=3.0))
    assert "plant.mujoco.mass = 3.0: is for the shipped robot only" in shipped_only
    no_nominal = error_of(lambda: MujocoSpec.from_table({"file": "me.xml"}, base_dir=tmp_path,
                                                        source=SOURCE))  # fmt: skip
    assert "plant.mujoco.nominal_wheel_radius: required with file" in no_nominal
    both = error_of(lambda: user_spec(tmp_path, robot="diff-drive"))
    assert "plant.mujoco.robot = 'diff-drive': give robot or file, not both" in both


def test_dt_must_be_a_whole_multiple_of_the_timestep():
    spec = spec_of(timestep=0.004)
    spec.check_dt(0.012, SOURCE)  # three steps: fine
    text = error_of(lambda: spec.check_dt(0.01, SOURCE))
    assert text.startswith(f"{SOURCE}: dt = 0.01: must be a whole multiple") and "0.004" in text
    with pytest.raises(ValueError):
        MujocoRobot(spec, 0.01)


def test_change_values_are_validated(tmp_path):
    spec = spec_of()
    new = spec.change("com_offset", [0.01, 0], where="plant.change[0]", source=SOURCE)
    assert new == (0.01, 0.0)
    for key, value, reason in [("slip", 0.1, "cannot change mid-run"), ("mass", -1.0, "> 0"),
                               ("friction", 0.0, "> 0"), ("com_offset", [0.0, 0.2], "support")]:
        text = error_of(lambda k=key, v=value: spec.change(k, v, where="plant.change[0]",
                                                           source=SOURCE))  # fmt: skip
        assert f"plant.change[0].{key} = " in text and reason in text
    text = error_of(lambda: user_spec(tmp_path).change("mass", 5.0, where="plant.change[1]",
                                                       source=SOURCE))  # fmt: skip
    assert "plant.change[1].mass = 5.0: is for the shipped robot only" in text
    assert set(CHANGEABLE) == {"mass", "com_offset", "friction"}
