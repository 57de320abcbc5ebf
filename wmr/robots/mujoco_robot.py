"""A robot nobody here wrote: the MuJoCo differential-drive plant (DESIGN §3.7).

``[plant] model = "mujoco"`` drives a MuJoCo rigid-body model with wheel-ground contact: slip,
skid, load transfer and motor saturation come from the physics engine, not from a term chosen
here.  :class:`MujocoSpec` is the validated ``[plant.mujoco]`` table (the shipped robot of
``wmr.robots.mujoco_model``, or a user's MJCF); :class:`MujocoRobot` is the plant the loop's Python
driver calls once per control step.

One control step ``k`` (``t_k = k dt``): the command ``a = (v, w)`` [m/s, rad/s], already
saturated, delayed and disturbed by the loop, goes through the robot's firmware, which believes
the *nominal* radius ``r_n`` and track ``b_n``::

    omega_L = (v - w b_n / 2) / r_n,    omega_R = (v + w b_n / 2) / r_n     [rad/s]

These wheel-speed setpoints are written to the actuators ``left_motor`` / ``right_motor`` and
held for ``dt / timestep`` calls of ``mujoco.mj_step``.  The pose is the body ``base``'s: its
position in the plane and the heading of its x axis, unwrapped (continuous across +-pi).

>>> spec = MujocoSpec.from_table({"robot": "diff-drive"}, base_dir=None, source="demo")
>>> robot = MujocoRobot(spec, dt=0.01)
>>> robot.reset((0.0, 0.0, 0.0))
>>> for k in range(100):
...     robot.advance(k, (0.5, 0.0))
>>> q = np.empty(3); robot.pose(q); round(float(q[0]), 2)
0.47
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from wmr._settings import SettingError, check, number, one_line, positive
from wmr.robots import mujoco_model

__all__ = [
    "ROBOTS",
    "SHIPPED_ONLY",
    "CHANGEABLE",
    "DIAGNOSTICS",
    "MujocoSpec",
    "MujocoRobot",
    "heading",
]

#: Shipped robots (``[plant.mujoco] robot``).
ROBOTS: tuple[str, ...] = ("diff-drive",)
#: Keys of the shipped robot only (a user's MJCF describes its own robot).
SHIPPED_ONLY = ("mass", "com_offset", "wheel_radius", "track", "friction", "torque_limit",
                "motor_gain")  # fmt: skip
#: Keys a ``[[plant.change]]`` may set on this model (shipped robot only).
CHANGEABLE = ("mass", "com_offset", "friction")
#: Names of :meth:`MujocoRobot.diagnostics`'s entries, in order (units in its docstring).
DIAGNOSTICS = ("lateral_velocity", "slip_angle", "slip_ratio_left", "slip_ratio_right",
               "wheel_speed_left", "wheel_speed_right", "torque_left", "torque_right",
               "saturated")  # fmt: skip

_DEFAULTS = {"mass": 10.0, "com_offset": (0.0, 0.0), "wheel_radius": (0.05, 0.05),
             "track": 0.30, "friction": 1.0, "torque_limit": 2.0, "motor_gain": 2.0}  # fmt: skip
_KEYS = ("robot", "file", "timestep", *SHIPPED_ONLY, "nominal_wheel_radius", "nominal_track")
#: Relative tolerance on dt being a whole number of physics steps.
_STEP_TOL = 1e-9
#: [m/s] floor of the slip ratio's denominator (a wheel at rest has no defined slip).
_SLIP_SPEED_FLOOR = 0.01
#: 2 pi, once.
_TWO_PI = 2 * math.pi
#: A wheel axis counts as the base's +y axis when their cosine exceeds this.
_AXIS_COS = 0.99


def _error(source: str, key: str, value: Any, reason: str) -> Exception:
    # imported here: wmr.scenario may import this module to parse [plant.mujoco]
    from wmr.scenario import ScenarioError

    return ScenarioError(source, key, value, reason)


@dataclass(frozen=True)
class MujocoSpec:
    """The validated ``[plant.mujoco]`` table (DESIGN §3.7).

    Build it with :meth:`from_table`; vary it with ``dataclasses.replace`` (the shipped robot's
    MJCF is rewritten from the numbers).

    Attributes
    ----------
    robot : str or None
        ``"diff-drive"`` (the shipped model of ``wmr.robots.mujoco_model``), or None with ``file``.
    file : str or None
        The user's MJCF path as written in the scenario (relative to it), or None.
    xml : str
        The MJCF text, loaded once: a worker on another machine needs no file.
    timestep : float [s]
        Physics step (> 0); ``dt`` must be a whole multiple of it (:meth:`check_dt`).  It
        replaces the MJCF's own ``<option timestep>``.
    mass : float [kg] or None
        Chassis mass (> 0); shipped robot only (None with a file), as the next six.
    com_offset : tuple of 2 float [m] or None
        Centre of mass ahead of / left of the axle midpoint (inside the support: ``|ahead| <=
        CASTER_ARM / 2``, ``|left| <= track / 4``).
    wheel_radius : tuple of 2 float [m] or None
        True radii ``(left, right)`` (> 0); one number sets both.
    track : float [m] or None
        Distance between the wheels' contact points (> 0).
    friction : float [-] or None
        Wheel-ground sliding friction coefficient (> 0).
    torque_limit : float [N m] or None
        Per-wheel motor torque limit (> 0).
    motor_gain : float [N m s/rad] or None
        Wheel-speed servo: torque = gain (setpoint - speed), clipped (> 0).
    nominal_wheel_radius : float [m]
        What the firmware believes (> 0); required with a file, default: the mean true radius.
    nominal_track : float [m]
        What the firmware believes (> 0); required with a file, default: the true track.
    """

    robot: str | None
    file: str | None
    xml: str = field(default="", repr=False)
    timestep: float = 0.002
    mass: float | None = None
    com_offset: tuple[float, ...] | None = None
    wheel_radius: tuple[float, ...] | None = None
    track: float | None = None
    friction: float | None = None
    torque_limit: float | None = None
    motor_gain: float | None = None
    nominal_wheel_radius: float = 0.05
    nominal_track: float = 0.30

    def __post_init__(self):
        positive("timestep", self.timestep)
        if self.file is not None:
            check(self.robot is None, "robot", self.robot, "give robot or file, not both")
            for key in SHIPPED_ONLY:
                check(getattr(self, key) is None, key, getattr(self, key),
                      'is for the shipped robot only (robot = "diff-drive"); a file\'s robot '
                      "is described by its MJCF")  # fmt: skip
            self._check_nominal()
            _check_mjcf(self.xml, self.file)
            return
        check(self.robot in ROBOTS, "robot", self.robot,
              f"unknown robot (known: {', '.join(ROBOTS)}; or give file = \"my-robot.xml\")")
        for key in SHIPPED_ONLY:
            check(getattr(self, key) is not None, key, None, "required for the shipped robot")
        for key in ("mass", "track", "friction", "torque_limit", "motor_gain"):
            positive(key, getattr(self, key))
        check(len(self.wheel_radius) == 2, "wheel_radius", self.wheel_radius,
              "must be one number or [left, right]")  # fmt: skip
        for r in self.wheel_radius:
            positive("wheel_radius", r)
        _check_com(self.com_offset, self.track, "com_offset")
        self._check_nominal()
        object.__setattr__(self, "xml", mujoco_model.diff_drive_xml(
            mass=self.mass, com_offset=self.com_offset, wheel_radius=self.wheel_radius,
            track=self.track, friction=self.friction, torque_limit=self.torque_limit,
            motor_gain=self.motor_gain, timestep=self.timestep))  # fmt: skip

    def _check_nominal(self) -> None:
        positive("nominal_wheel_radius", self.nominal_wheel_radius)
        positive("nominal_track", self.nominal_track)

    @classmethod
    def from_table(cls, table: Mapping, *, base_dir: Path | None, source: str,
                   where: str = "plant.mujoco") -> MujocoSpec:  # fmt: skip
        """Validate the ``[plant.mujoco]`` ``table`` of the scenario ``source``.

        ``file`` is read relative to ``base_dir`` (the scenario's folder; None: the working
        directory).  Every problem raises ``wmr.scenario.ScenarioError`` with one line naming
        ``source``, the dotted key under ``where`` and the value: unknown keys, an unknown
        robot, both or a missing/unreadable/malformed MJCF, one without the body ``base`` (free),
        the hinges ``left_wheel``/``right_wheel`` or the servos ``left_motor``/``right_motor``,
        non-positive numbers, shipped-only keys with a file, missing nominal values with a file.
        """
        try:
            return cls._from_table(table, base_dir, source, where)
        except SettingError as err:
            key = err.key if err.key.startswith(where) else f"{where}.{err.key}"
            raise _error(source, key, err.value, err.reason) from None

    @classmethod
    def _from_table(cls, table, base_dir, source, where) -> MujocoSpec:
        check(isinstance(table, Mapping), where, table, "must be a table")
        for key in table:
            check(key in _KEYS, key, table[key], f"unknown key (known: {', '.join(_KEYS)})")
        kw: dict[str, Any] = {}
        for key in ("timestep", "mass", "track", "friction", "torque_limit", "motor_gain",
                    "nominal_wheel_radius", "nominal_track"):  # fmt: skip
            if key in table:
                kw[key] = number(key, table[key])
        if "com_offset" in table:
            kw["com_offset"] = _pair("com_offset", table["com_offset"], broadcast=False)
        if "wheel_radius" in table:
            kw["wheel_radius"] = _pair("wheel_radius", table["wheel_radius"], broadcast=True)
        file = table.get("file")
        robot = table.get("robot")
        if file is None:
            robot = "diff-drive" if robot is None else robot
            check(isinstance(robot, str), "robot", robot, "must be a string")
            check(robot in ROBOTS, "robot", robot,
                  f"unknown robot (known: {', '.join(ROBOTS)}; or give file = \"my-robot.xml\")")
            kw = {**{k: _DEFAULTS[k] for k in SHIPPED_ONLY}, **kw}
            kw.setdefault("nominal_wheel_radius", 0.5 * sum(kw["wheel_radius"]))
            kw.setdefault("nominal_track", kw["track"])
            return cls(robot=robot, file=None, **kw)
        check(isinstance(file, str) and file != "", "file", file, "must be a file name")
        check(robot is None, "robot", robot, "give robot or file, not both")
        for key in SHIPPED_ONLY:
            check(key not in table, key, table.get(key),
                  'is for the shipped robot only (robot = "diff-drive"); a file\'s robot is '
                  "described by its MJCF")  # fmt: skip
        for key in ("nominal_wheel_radius", "nominal_track"):
            check(key in table, key, None, "required with file (what the firmware believes)")
        path = Path(file) if base_dir is None else Path(base_dir) / file
        try:
            xml = path.read_text(encoding="utf-8")
        except OSError as err:
            raise SettingError(f"{where}.file", file,
                               f"cannot read {path}: {err.strerror or err}") from None
        except UnicodeDecodeError:
            raise SettingError(f"{where}.file", file, "not UTF-8 text") from None
        return cls(robot=None, file=file, xml=xml, **kw)

    def to_json(self) -> dict:
        """The table's values for ``summary.json`` (the MJCF's text replaced by its SHA-256)."""
        import hashlib

        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "xml"}
        out = {k: (list(v) if isinstance(v, tuple) else v) for k, v in out.items()}
        out["xml_sha256"] = hashlib.sha256(self.xml.encode("utf-8")).hexdigest()
        return out

    @property
    def shipped(self) -> bool:
        """True for the shipped robot (``robot = "diff-drive"``)."""
        return self.file is None

    def substeps(self, dt: float) -> int:
        """Physics steps per control step, ``dt / timestep`` (``ValueError`` unless whole)."""
        ratio = dt / self.timestep
        n = round(ratio)
        if n < 1 or abs(ratio - n) > _STEP_TOL * max(1.0, ratio):
            raise ValueError(f"dt = {dt!r} s is not a whole multiple of plant.mujoco.timestep "
                             f"= {self.timestep!r} s")  # fmt: skip
        return n

    def check_dt(self, dt: float, source: str) -> None:
        """ScenarioError (key ``dt``) unless ``dt`` [s] is a whole multiple of ``timestep``."""
        try:
            self.substeps(dt)
        except ValueError:
            raise _error(source, "dt", dt, "must be a whole multiple of plant.mujoco.timestep "
                         f"= {self.timestep!r} s") from None  # fmt: skip

    def change(self, key: str, value: Any, *, where: str, source: str) -> Any:
        """The validated value of a ``[[plant.change]]`` ``key`` (``CHANGEABLE``) at ``where``.

        ScenarioError naming ``where.key`` for another key, for a user's file (no known mass,
        centre of mass or tyres) or for a value this robot cannot take.
        """
        full = f"{where}.{key}"
        if key not in CHANGEABLE:
            raise _error(source, full, value, f"cannot change mid-run on model = \"mujoco\" "
                         f"(changeable: {', '.join(CHANGEABLE)})")  # fmt: skip
        if not self.shipped:
            raise _error(source, full, value, 'is for the shipped robot only (robot = '
                         '"diff-drive"); a file\'s robot cannot change mid-run')  # fmt: skip
        try:
            if key == "com_offset":
                new = _pair(key, value, broadcast=False)
                _check_com(new, self.track, key)
            else:
                new = number(key, value)
                positive(key, new)
        except SettingError as err:
            raise _error(source, full, err.value, err.reason) from None
        return new


class MujocoRobot:
    """The MuJoCo plant of one run: the Python-level plant the loop's driver calls.

    Parameters
    ----------
    spec : MujocoSpec
        The robot.
    dt : float [s]
        Control period, a whole multiple of ``spec.timestep``.
    changes : sequence of (at, values)
        ``[[plant.change]]`` events (``wmr.scenario.PlantChange`` or ``(at [s], {key:
        value})``, keys in :data:`CHANGEABLE`, shipped robot only), applied from the first
        control step with ``t_k >= at`` (a payload: ``mass`` and ``com_offset``; a floor:
        ``friction``).  The chassis inertia scales with its mass (a uniform box).

    Attributes
    ----------
    model, data : mujoco.MjModel, mujoco.MjData
        The live MuJoCo model and state (for diagnostics; the plant's methods are the API).
    n_sub : int
        Physics steps per control step.
    """

    def __init__(self, spec: MujocoSpec, dt: float, changes: Sequence = ()):
        self.spec, self.dt = spec, float(dt)
        self.n_sub = spec.substeps(self.dt)
        self.model = m = mujoco.MjModel.from_xml_string(spec.xml)
        m.opt.timestep = spec.timestep
        if spec.shipped:
            # one kinematic tree: one constraint island, whose discovery at every physics step
            # is pure cost (~4 % of a step); the solver's numbers are the same bits without it
            # (tests/test_mujoco_robot.py compares both on a run)
            m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_ISLAND)
        self.data = mujoco.MjData(m)
        ids = _names(m)
        self._base = ids["base"]
        joint = m.body_jntadr[self._base]
        self._qa, self._va = int(m.jnt_qposadr[joint]), int(m.jnt_dofadr[joint])
        self._wheel_dof = [int(m.jnt_dofadr[j]) for j in (ids["left_wheel"], ids["right_wheel"])]
        self._wheel_body = [int(m.jnt_bodyid[j]) for j in (ids["left_wheel"], ids["right_wheel"])]
        self._motor = (ids["left_motor"], ids["right_motor"])
        self._limit = [float(m.actuator_forcerange[i, 1]) if m.actuator_forcelimited[i]
                       else math.inf for i in self._motor]  # fmt: skip
        self._radius = (spec.wheel_radius if spec.shipped
                        else (spec.nominal_wheel_radius,) * 2)  # fmt: skip
        self._half_track = 0.5 * spec.nominal_track
        self._r_nominal = spec.nominal_wheel_radius
        self._changes = sorted(((float(at), dict(values)) for at, values in
                                (_event(c) for c in changes)), key=lambda c: c[0])  # fmt: skip
        for at, values in self._changes:
            for key, value in values.items():
                values[key] = spec.change(key, value, where=f"plant.change(at={at})",
                                          source="<MujocoRobot>")  # fmt: skip
        if self._changes:
            self._tyres = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, g)
                           for g in mujoco_model.TYRES]  # fmt: skip
            self._inertia_per_kg = m.body_inertia[self._base].copy() / spec.mass
            self._pristine = (m.body_mass.copy(), m.body_ipos.copy(), m.body_inertia.copy(),
                              m.geom_friction.copy())  # fmt: skip
        # views into mjData (stable buffers) for the per-step reads
        d = self.data
        self._qpos, self._qvel, self._ctrl, self._xmat = d.qpos, d.qvel, d.ctrl, d.xmat
        self._force = d.actuator_force
        qa = self._qa
        self._quat = d.qpos[qa + 3:qa + 7]  # the base's orientation (w, x, y, z), a view
        self._xy = d.qpos[qa:qa + 2]  # the base's position in the plane, a view
        self._motor_left, self._motor_right = self._motor
        self._n_changes = len(self._changes)
        self._step = functools.partial(mujoco.mj_step, m, d, self.n_sub)
        self._next_change = 0
        self._theta = 0.0
        self._yaw = 0.0
        self._offsets = (0.0, 0.0)

    def reset(self, q0) -> None:
        """Rest at ``q0 = (x, y, theta)`` [m, m, rad] on the ground, ``t = 0``, no settling.

        The base's free joint gets ``(x, y)`` and its MJCF orientation turned by ``theta`` about
        the vertical; its height is the MJCF's (the shipped robot is built to rest there).  Any
        mid-run change of an earlier run is undone.
        """
        m, d = self.model, self.data
        if self._changes:
            for target, saved in zip((m.body_mass, m.body_ipos, m.body_inertia, m.geom_friction),
                                     self._pristine, strict=True):  # fmt: skip
                target[...] = saved
            mujoco.mj_setConst(m, mujoco.MjData(m))
        mujoco.mj_resetData(m, d)
        x, y, theta = (float(c) for c in q0)
        qa = self._qa
        d.qpos[qa], d.qpos[qa + 1] = x, y
        turn = np.array([math.cos(theta / 2), 0.0, 0.0, math.sin(theta / 2)])
        quat = np.empty(4)
        mujoco.mju_mulQuat(quat, turn, m.qpos0[qa + 3:qa + 7])
        d.qpos[qa + 3:qa + 7] = quat
        mujoco.mj_forward(m, d)
        yaw = heading(d.qpos[qa + 3:qa + 7])
        self._yaw = yaw
        self._theta = yaw + 2 * math.pi * round((theta - yaw) / (2 * math.pi))
        self._next_change = 0
        R = d.xmat[self._base].reshape(3, 3)
        self._offsets = tuple(float((d.xpos[b] - d.xpos[self._base]) @ R[:, 1])
                              for b in self._wheel_body)  # fmt: skip

    def advance(self, k: int, a) -> None:
        """Hold the command ``a = (v, w)`` [m/s, rad/s] over ``[t_k, t_k + dt]``.

        Changes due at ``t_k = k dt`` are applied first; the firmware writes the wheel-speed
        setpoints ``omega_L = (v - w b_n / 2) / r_n``, ``omega_R = (v + w b_n / 2) / r_n``
        [rad/s] to the servos; ``n_sub`` physics steps follow (one ``mj_step`` call).

        Called once per control step: what it reads is bound once in ``__init__`` (the ctrl
        buffer, the orientation's view, the step with its model, data and count), so the
        Python around the physics is a handful of float operations.
        """
        if self._next_change < self._n_changes:
            self._apply_changes(k * self.dt)
        v, w = float(a[0]), float(a[1])
        half, r = self._half_track, self._r_nominal
        ctrl = self._ctrl
        ctrl[self._motor_left] = (v - w * half) / r
        ctrl[self._motor_right] = (v + w * half) / r
        self._step()
        yaw = _yaw(*self._quat.tolist())
        step = yaw - self._yaw
        # unwrap: a control step turns the robot by less than pi (|w| < pi / dt)
        self._theta += step - _TWO_PI * round(step / _TWO_PI)
        self._yaw = yaw

    def pose(self, out) -> None:
        """Write the base's ``(x, y, theta)`` [m, m, rad] into ``out`` (3,): position in the
        plane and the heading of its x axis, unwrapped (continuous across +-pi)."""
        out[0], out[1] = self._xy
        out[2] = self._theta

    def velocity(self, out) -> None:
        """Write the actual body-frame ``(v, w)`` [m/s, rad/s] into ``out`` (2,): forward speed of
        the base's origin and the yaw rate.

        The frame is the base's mean heading over the last physics step, the direction of the
        chord its pose moved along (MuJoCo's semi-implicit step moves the pose with the
        end-of-step velocity from the start-of-step configuration): in the end-of-step heading a
        robot rolling without slip would show a spurious side velocity of ``-v w timestep / 2``.
        """
        v, _, w = self._body_velocity()
        out[0] = v
        out[1] = w

    def diagnostics(self, out) -> None:
        """Write :data:`DIAGNOSTICS` of the last physics step into ``out`` (9,).

        ``lateral_velocity`` [m/s] of the base's origin (left +); ``slip_angle`` [rad] =
        ``atan2(lateral, |forward|)``; ``slip_ratio_left/right`` [-] = ``(r omega - v_wheel) /
        max(|r omega|, |v_wheel|, 0.01 m/s)`` with the wheel centre's forward speed ``v_wheel``
        and the true radius (the nominal one for a user's file); ``wheel_speed_left/right``
        [rad/s]; ``torque_left/right`` [N m] the servo torques; ``saturated`` 1.0 when a servo
        is at its torque limit, else 0.0.
        """
        v, lat, w = self._body_velocity()
        qv, f = self._qvel, self._force
        out[0] = lat
        out[1] = math.atan2(lat, abs(v))
        for i in range(2):
            spin = qv[self._wheel_dof[i]]
            roll = self._radius[i] * spin
            ground = v - w * self._offsets[i]
            out[2 + i] = (roll - ground) / max(abs(roll), abs(ground), _SLIP_SPEED_FLOOR)
            out[4 + i] = spin
            out[6 + i] = f[self._motor[i]]
        saturated = any(abs(f[u]) >= lim * (1 - 1e-12) for u, lim in
                        zip(self._motor, self._limit, strict=True))  # fmt: skip
        out[8] = 1.0 if saturated else 0.0

    # -- private ------------------------------------------------------------------------------

    def _body_velocity(self) -> tuple[float, float, float]:
        """(forward, lateral, yaw rate) [m/s, m/s, rad/s] of the base in its mean heading over
        the last physics step (the direction of the chord its pose moved along)."""
        va, qv, qa, qp = self._va, self._qvel, self._qa, self._qpos
        R = self._xmat[self._base]  # row-major 3x3 at the start of the last physics step
        start = math.atan2(R[3], R[0])  # heading of the x axis projected on the ground
        turn = heading((qp[qa + 3], qp[qa + 4], qp[qa + 5], qp[qa + 6])) - start
        mid = start + 0.5 * (turn - 2 * math.pi * round(turn / (2 * math.pi)))
        c, s = math.cos(mid), math.sin(mid)
        vx, vy = qv[va], qv[va + 1]
        # free joint: angular velocity in the body frame; world z component = R[2, :] . omega
        w = R[6] * qv[va + 3] + R[7] * qv[va + 4] + R[8] * qv[va + 5]
        return float(c * vx + s * vy), float(-s * vx + c * vy), float(w)

    def _apply_changes(self, t: float) -> None:
        m = self.model
        changed = False
        while self._next_change < len(self._changes) and t >= self._changes[self._next_change][0]:
            for key, value in self._changes[self._next_change][1].items():
                if key == "mass":
                    m.body_mass[self._base] = value
                    m.body_inertia[self._base] = self._inertia_per_kg * value
                elif key == "com_offset":
                    m.body_ipos[self._base, :2] = value
                else:  # friction of the two tyres (the floor's is zero: max rule)
                    m.geom_friction[self._tyres, 0] = value
            self._next_change += 1
            changed = True
        if changed:  # the solver's inverse-inertia scales follow the new mass (scratch data)
            mujoco.mj_setConst(m, mujoco.MjData(m))


def heading(quat) -> float:
    """Yaw [rad] in (-pi, pi] of a body's x axis projected on the ground, from its orientation
    quaternion ``(w, x, y, z)``: ``atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))``."""
    return _yaw(*(float(c) for c in quat))


def _yaw(qw: float, qx: float, qy: float, qz: float) -> float:
    """:func:`heading` of the quaternion's four floats (the one formula; the step calls it)."""
    return math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


# -- private helpers ------------------------------------------------------------------------------


def _pair(key: str, value: Any, *, broadcast: bool) -> tuple[float, float]:
    if broadcast and isinstance(value, int | float) and not isinstance(value, bool):
        value = [value, value]
    check(isinstance(value, list | tuple) and len(value) == 2, key, value,
          "must be one number or [left, right]" if broadcast else "must be [ahead, left]")
    return (number(f"{key}[0]", value[0]), number(f"{key}[1]", value[1]))


def _check_com(com, track: float, key: str) -> None:
    check(len(com) == 2, key, com, "must be [ahead, left]")
    ahead, left = com
    check(abs(ahead) <= mujoco_model.CASTER_ARM / 2 and abs(left) <= track / 4, key, list(com),
          f"must lie inside the support: |ahead| <= {mujoco_model.CASTER_ARM / 2:g} m (half the "
          f"caster arm), |left| <= track / 4 = {track / 4:g} m")  # fmt: skip


def _event(change) -> tuple[float, Mapping]:
    if hasattr(change, "at"):
        return change.at, change.values
    at, values = change
    return at, values


def _names(m) -> dict[str, int]:
    """Ids of the names of DESIGN §3.7 (KeyError text for a missing one)."""
    obj = mujoco.mjtObj
    out = {"base": mujoco.mj_name2id(m, obj.mjOBJ_BODY, "base")}
    for name in ("left_wheel", "right_wheel"):
        out[name] = mujoco.mj_name2id(m, obj.mjOBJ_JOINT, name)
    for name in ("left_motor", "right_motor"):
        out[name] = mujoco.mj_name2id(m, obj.mjOBJ_ACTUATOR, name)
    return out


def _check_mjcf(xml: str, file: str) -> None:
    """SettingError (key ``file``) unless ``xml`` compiles and has the names of DESIGN §3.7."""
    check(isinstance(xml, str) and xml.strip() != "", "file", file, "the MJCF is empty")
    try:
        m = mujoco.MjModel.from_xml_string(xml)
    except ValueError as err:
        text = "; ".join(line.strip() for line in str(err).splitlines() if line.strip())
        raise SettingError("file", file, f"not a valid MJCF: {one_line(text)}") from None
    ids = _names(m)
    kinds = {"base": "body", "left_wheel": "joint", "right_wheel": "joint",
             "left_motor": "actuator", "right_motor": "actuator"}  # fmt: skip
    for name, i in ids.items():
        check(i >= 0, "file", file, f"the MJCF has no {kinds[name]} named {name!r} (DESIGN §3.7)")
    base = ids["base"]
    free = mujoco.mjtJoint.mjJNT_FREE
    check(m.body_jntnum[base] == 1 and m.jnt_type[m.body_jntadr[base]] == free, "file", file,
          "body 'base' must be free-floating (one <freejoint/>)")
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    y_axis = d.xmat[base].reshape(3, 3)[:, 1]
    for side in ("left", "right"):
        j, u = ids[f"{side}_wheel"], ids[f"{side}_motor"]
        check(m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE, "file", file,
              f"joint '{side}_wheel' must be a hinge")  # fmt: skip
        check(float(d.xaxis[j] @ y_axis) > _AXIS_COS, "file", file,
              f"joint '{side}_wheel' must turn about the base's +y axis (a positive speed drives "
              "forward)")  # fmt: skip
        gain, bias = m.actuator_gainprm[u], m.actuator_biasprm[u]
        servo = (m.actuator_trntype[u] == mujoco.mjtTrn.mjTRN_JOINT and m.actuator_trnid[u, 0] == j
                 and m.actuator_gear[u, 0] == 1.0
                 and m.actuator_gaintype[u] == mujoco.mjtGain.mjGAIN_FIXED
                 and m.actuator_biastype[u] == mujoco.mjtBias.mjBIAS_AFFINE
                 and gain[0] > 0 and bias[0] == 0 and bias[1] == 0
                 and abs(gain[0] + bias[2]) <= 1e-12 * gain[0])  # fmt: skip
        check(servo, "file", file,
              f"actuator '{side}_motor' must be a wheel-speed servo on joint '{side}_wheel' "
              '(<velocity joint="..." kv="..."/>, or <general> with gainprm="kv" '
              'biastype="affine" biasprm="0 0 -kv", gear 1)')  # fmt: skip
