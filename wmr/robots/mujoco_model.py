"""The shipped MuJoCo differential-drive robot (DESIGN §3.7, ``robot = "diff-drive"``), as MJCF.

:func:`diff_drive_xml` writes the model from the true parameters of ``[plant.mujoco]``; the
firmware (``wmr.robots.mujoco_robot``) maps commands with the *nominal* radius and track.

The robot
---------
- ``base``: the chassis, a free body.  Its frame sits at the axle midpoint, x forward, y left,
  z up; the chassis mass ``mass`` has its centre of mass ``com_offset`` ahead of / left of that
  point and :data:`COM_HEIGHT` above it, with the inertia of a uniform box
  (:data:`CHASSIS_LENGTH` x ``0.8 track`` x :data:`CHASSIS_HEIGHT`).
- ``left_wheel`` / ``right_wheel``: hinge joints about the base's +y axis (a positive speed
  drives the robot forward), wheel centres at ``y = +-track / 2`` at the height of their own
  radius, so both touch the ground with the chassis level even with unequal radii.  The tyre's
  collision shape is a sphere of the true radius (see below), drawn as a cylinder.
- two passive casters, frictionless balls fixed to the chassis :data:`CASTER_ARM` ahead of and
  behind the axle, with compliant tyres (contact time constant :data:`CASTER_SOLREF`, ten times
  the drive tyres'): the chassis rests on four contacts, and the casters' softer contacts leave
  most of the weight on the drive wheels (92 % for the default robot, the centre of mass on the
  axle).  The axle takes no pitch
  moment, so a centre of mass ``ahead`` loads the front caster by ``mass g ahead / CASTER_ARM``
  (the rear one lifts when it would pull).
- ``left_motor`` / ``right_motor``: wheel-speed servos, MuJoCo ``<velocity>`` actuators:
  torque = ``motor_gain (setpoint - wheel speed)``, clipped to ``+-torque_limit``.

Resting at t = 0 without a settling phase
------------------------------------------
At rest MuJoCo's soft contact is a linear spring (:func:`contact_stiffness`, read from MuJoCo's
own constraint rows).  Four springs under a rigid chassis are a plate on springs: the loads
follow from the weight and the spring stiffnesses (:func:`rest_loads`, a 3x3 linear solve;
a caster that would pull is lifted instead).  Each contact is then built sunk into the floor by
its static penetration (load / stiffness, ~1e-6 m), so the first step's contact forces balance
the weight exactly: a zero command leaves the pose still to ~1e-11 m over a second.

Why these contact settings
--------------------------
- *Point contact, condim 3.*  A cylinder lying on a plane gets MuJoCo's two rim contacts; with
  friction they forbid the wheel to pivot about the vertical, so the robot scrubs: measured on a
  draft of this model at ``friction = 1``, ``(v, w) = (0.5, 1.0)`` turned at 0.55 rad/s.  A
  sphere of the tyre's radius touches at one point below the wheel centre, at exactly the true
  radius in every rolling position: the textbook thin wheel, with sliding friction in both
  tangent directions (condim 3) and no torsional or rolling friction (no scrub torque, no
  rolling resistance: every departure from the unicycle comes from slip, load and torque).
- *Elliptic friction cones.*  The default pyramidal cone is anisotropic (its friction bound
  depends on the direction of sliding relative to the contact frame), the kind of artefact
  behind the sideways crabbing of wheeled models at low friction (google-deepmind/mujoco#57,
  where the fix was also centred primitive wheels and even load); the elliptic cone is
  Coulomb's isotropic bound ``|f_t| <= friction * f_n``.  ``impratio`` :data:`IMPRATIO` makes
  friction stiffer than the normal direction, which reduces MuJoCo's soft-constraint creep (a
  small slip velocity under a tangential load).
- *Stiff tyres, constant impedance*: ``solimp`` :data:`SOLIMP` has dmin = dmax, so a contact's
  stiffness does not depend on its penetration (the rest state above is exact); the tyres'
  time constant is twice the default 2 ms step (MuJoCo raises a smaller one to that), their
  damping ratio 3 (overdamped, as rubber: the static penetration is 1.8e-5 m, the loaded
  radius 3.6e-4 below the true one).  With damping ratio 1 a sliding tyre hopped (see below)
  and kept sliding after a brief overload at 0.8 of the friction bound; at 3 it grips again.
- *What the contact model cannot do*: beyond the Coulomb bound MuJoCo's soft elliptic cone
  raises the sliding tyres' normal force (the casters unload: sliding sets in at ~1.0 mu g
  rather than at the 0.92 mu g the tyres' share of the weight allows) and the sliding tyres
  hop (~0.1 mm, a wheel off the floor in most physics steps).  Softer friction (``pair``
  ``solreffriction``) removes the hop but lets the tyres creep sideways at a few cm/s well
  inside the bound, which is worse for the high-friction regime the ladder starts from.  In
  the sliding regime the side slip is physical in sign and order (outward, ~0.1 m/s at
  0.95 mu g and 1 m/s) but its size moved by ~50 % across the contact settings tried, and
  its vertical dynamics are not physics.  The
  casters' rigid mounting with softer contacts replaced sprung casters (slide joints), whose
  light caster bodies chattered on the stiff floor contact in a draft.
- *implicitfast integrator*: the servo's velocity gain is integrated implicitly (stable for
  stiff servos at the 2 ms step); a servo at its torque limit is left out of the implicit term
  by MuJoCo, so saturation bounds the torque exactly.
- Only robot-floor pairs collide (contype/conaffinity bits 2 and 1).  The floor has zero
  friction and condim 1: MuJoCo combines two geoms' friction and condim by their maximum, so
  each wheel-floor contact takes the tyre's ``friction`` and the casters stay frictionless; a
  ``[[plant.change]]`` of ``friction`` writes the two tyres only.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

__all__ = [
    "GRAVITY",
    "CHASSIS_LENGTH",
    "CHASSIS_HEIGHT",
    "COM_HEIGHT",
    "WHEEL_MASS",
    "WHEEL_WIDTH",
    "CASTER_ARM",
    "CASTER_RADIUS",
    "SOLREF",
    "CASTER_SOLREF",
    "SOLIMP",
    "IMPRATIO",
    "TYRES",
    "CONTACTS",
    "box_inertia",
    "contact_stiffness",
    "rest_loads",
    "diff_drive_xml",
]

#: [m/s^2] gravity (MuJoCo's default, written into the model).
GRAVITY = 9.81
#: [m] chassis box length (x) and height (z); its width is 0.8 track.
CHASSIS_LENGTH = 0.40
CHASSIS_HEIGHT = 0.10
#: [m] height of the chassis's centre of mass above the axle.
COM_HEIGHT = 0.05
#: [kg] mass of one wheel (a uniform disc) and [m] its width.
WHEEL_MASS = 0.2
WHEEL_WIDTH = 0.025
#: [m] distance of each caster ahead of / behind the axle; [m] caster ball radius.
CASTER_ARM = 0.15
CASTER_RADIUS = 0.02
#: Contact softness of the drive tyres and the floor (time constant [s], damping ratio [-]):
#: stiff; and the impedance (dmin, dmax, width [m]) of every contact.
SOLREF = (0.004, 3.0)
SOLIMP = (0.99, 0.99, 0.001)
#: Contact softness of the casters: compliant (their static stiffness is ~1/11 of a tyre's).
CASTER_SOLREF = (0.04, 3.0)
#: [-] ratio of friction to normal constraint impedance (elliptic cones).
IMPRATIO = 10.0
#: Names of the two tyre geoms (their friction is the wheel-ground friction).
TYRES = ("left_tyre", "right_tyre")
#: The four contact geoms: the drive tyres (at ``(0, +-track / 2)`` in the base frame) and the
#: casters (at ``(+-CASTER_ARM, 0)``).
CONTACTS = ("left_tyre", "right_tyre", "caster_front", "caster_rear")


def box_inertia(mass: float, track: float) -> tuple[float, float, float]:
    """Principal moments [kg m^2] of the chassis box (uniform density) of ``mass`` [kg].

    ``I_xx = m (W^2 + H^2) / 12``, ``I_yy = m (L^2 + H^2) / 12``, ``I_zz = m (L^2 + W^2) / 12``
    with ``L = CHASSIS_LENGTH``, ``W = 0.8 track``, ``H = CHASSIS_HEIGHT``.
    """
    L, W, H = CHASSIS_LENGTH, 0.8 * track, CHASSIS_HEIGHT
    return (mass * (W * W + H * H) / 12, mass * (L * L + H * H) / 12, mass * (L * L + W * W) / 12)


def contact_stiffness(xml: str) -> dict[str, float]:
    """Static stiffness [N/m] of each floor contact of the model ``xml``, keyed by geom name.

    At rest MuJoCo's soft contact is a linear spring: the constraint force is ``f = aref / R``
    with the reference acceleration ``aref = -k d r`` (``r`` the signed distance, ``k`` from
    ``solref``, the impedance ``d`` from ``solimp``, constant since dmin = dmax) and the
    regulariser ``R = (1 - d) / d diagApprox``, so ``f = -(k d / R) r``.  Read from MuJoCo's own
    constraint rows (``efc_KBIP``, ``efc_R``) at the model's initial configuration, where every
    contact must penetrate (a contact gets constraint rows only then).
    """
    import mujoco

    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    out = {}
    for i in range(d.ncon):
        row = d.contact.efc_address[i]  # the normal row comes first (elliptic cones)
        name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(d.contact.geom[i, 1]))
        k, _, imp, _ = d.efc_KBIP[row]
        out[name] = float(k * imp / d.efc_R[row])
    return out


def rest_loads(mass: float, com_offset: Sequence[float], track: float,
               stiffness: Mapping[str, float]) -> dict[str, float]:  # fmt: skip
    """Normal loads [N] of the four contacts (:data:`CONTACTS`) at rest: a rigid plate on springs.

    The chassis of ``mass`` [kg] with its centre of mass at ``com_offset = (ahead, left)`` [m]
    and the two wheels (:data:`WHEEL_MASS` each, on the axle) rest on contact springs of
    ``stiffness`` [N/m] at ``(x_i, y_i)`` (wheels ``(0, +-track/2)``, casters
    ``(+-CASTER_ARM, 0)``).  The penetration is a plane, ``p_i = h + a x_i + b y_i``, the load
    ``N_i = K_i p_i``; force and moment balance about the axle midpoint::

        sum N_i = (mass + 2 WHEEL_MASS) g,   sum N_i x_i = mass g ahead,
        sum N_i y_i = mass g left

    give ``(h, a, b)``.  A caster whose load comes out negative is lifted: it carries nothing and
    the other three are solved again; the result then also holds ``"gap:<name>"``, the lifted
    caster's height [m] above the floor.
    """
    ahead, left = (float(c) for c in com_offset)
    pos = {"left_tyre": (0.0, track / 2), "right_tyre": (0.0, -track / 2),
           "caster_front": (CASTER_ARM, 0.0), "caster_rear": (-CASTER_ARM, 0.0)}  # fmt: skip
    rhs = np.array([(mass + 2 * WHEEL_MASS) * GRAVITY, mass * GRAVITY * ahead,
                    mass * GRAVITY * left])  # fmt: skip
    active = list(CONTACTS)
    while True:
        A = np.zeros((3, 3))
        for name in active:
            phi = np.array([1.0, *pos[name]])
            A += stiffness[name] * np.outer(phi, phi)
        plane = np.linalg.solve(A, rhs)
        pen = {name: float(plane @ np.array([1.0, *pos[name]])) for name in CONTACTS}
        lifted = [n for n in active if pen[n] < 0 and n.startswith("caster")]
        if not lifted:
            break
        active.remove(min(lifted, key=lambda n: pen[n]))
    out = {name: (stiffness[name] * pen[name] if name in active else 0.0) for name in CONTACTS}
    for name in CONTACTS:
        if name not in active:
            out[f"gap:{name}"] = -pen[name]
    return out


def diff_drive_xml(*, mass: float, com_offset: Sequence[float], wheel_radius: Sequence[float],
                   track: float, friction: float, torque_limit: float, motor_gain: float,
                   timestep: float) -> str:  # fmt: skip
    """The MJCF text of the shipped robot with these true parameters (units as in DESIGN §3.7:
    kg, m, -, N m, N m s/rad, s); ``wheel_radius`` is ``(left, right)``.

    Built to rest at t = 0 (module docstring): a first model with every contact sunk by 1 um
    gives the contact stiffnesses, :func:`rest_loads` the loads, and the returned model has each
    contact sunk by its static penetration (load / stiffness) or lifted by its gap.
    """
    params = dict(mass=float(mass), com_offset=tuple(float(c) for c in com_offset),
                  wheel_radius=tuple(float(r) for r in wheel_radius), track=float(track),
                  friction=float(friction), torque_limit=float(torque_limit),
                  motor_gain=float(motor_gain), timestep=float(timestep))  # fmt: skip
    # the stiffness does not depend on the penetration (dmin = dmax): probe it at 1 um
    stiffness = contact_stiffness(_xml(**params, sink=dict.fromkeys(CONTACTS, 1e-6)))
    loads = rest_loads(params["mass"], params["com_offset"], params["track"], stiffness)
    sink = {n: loads[n] / stiffness[n] if loads[n] > 0 else -loads[f"gap:{n}"] for n in CONTACTS}
    return _xml(**params, sink=sink)


def _xml(*, mass, com_offset, wheel_radius, track, friction, torque_limit, motor_gain, timestep,
         sink) -> str:  # fmt: skip
    """The MJCF with each contact geom sunk into the floor by ``sink[name]`` [m] (negative: a
    gap), the chassis level."""
    r_left, r_right = wheel_radius
    ahead, left = com_offset
    centres = (r_left - sink["left_tyre"], r_right - sink["right_tyre"])
    z0 = 0.5 * (centres[0] + centres[1])
    ixx, iyy, izz = box_inertia(mass, track)

    def soft(ref):
        return (f'solref="{ref[0]!r} {ref[1]!r}" '
                f'solimp="{SOLIMP[0]!r} {SOLIMP[1]!r} {SOLIMP[2]!r}"')  # fmt: skip

    wheels = []
    for side, r, zc, y in (("left", r_left, centres[0], track / 2),
                           ("right", r_right, centres[1], -track / 2)):  # fmt: skip
        i_axle = WHEEL_MASS * r * r / 2
        i_perp = WHEEL_MASS * (3 * r * r + WHEEL_WIDTH**2) / 12
        wheels.append(f"""
      <body name="{side}_wheel_body" pos="0 {y!r} {zc - z0!r}">
        <joint name="{side}_wheel" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 0" mass="{WHEEL_MASS!r}" diaginertia="{i_perp!r} {i_axle!r} {i_perp!r}"/>
        <geom name="{side}_tyre" type="sphere" size="{r!r}" condim="3" contype="2"
              conaffinity="1" friction="{friction!r} 0 0" {soft(SOLREF)} rgba="0 0 0 0"/>
        <geom type="cylinder" size="{r!r} {WHEEL_WIDTH / 2!r}" zaxis="0 1 0" contype="0"
              conaffinity="0" mass="0" rgba="0.15 0.15 0.15 1"/>
      </body>""")
    casters = []
    for side, x in (("front", CASTER_ARM), ("rear", -CASTER_ARM)):
        name = f"caster_{side}"
        casters.append(f"""
      <geom name="{name}" type="sphere" size="{CASTER_RADIUS!r}" condim="1" contype="2"
            conaffinity="1" friction="0 0 0" mass="0" {soft(CASTER_SOLREF)}
            pos="{x!r} 0 {CASTER_RADIUS - sink[name] - z0!r}" rgba="0.7 0.7 0.7 1"/>""")
    return f"""<mujoco model="wmr-diff-drive">
  <!-- written by wmr.robots.mujoco_model.diff_drive_xml: see its module docstring for each choice
  --> <option timestep="{timestep!r}" gravity="0 0 {-GRAVITY!r}" integrator="implicitfast"
          cone="elliptic" impratio="{IMPRATIO!r}"/>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 1" friction="0 0 0" condim="1" contype="1"
          conaffinity="2" {soft(SOLREF)} rgba="0.8 0.8 0.8 1"/>
    <body name="base" pos="0 0 {z0!r}">
      <freejoint name="base_free"/>
      <inertial pos="{ahead!r} {left!r} {COM_HEIGHT!r}" mass="{mass!r}"
                diaginertia="{ixx!r} {iyy!r} {izz!r}"/>
      <geom name="chassis" type="box" contype="0" conaffinity="0" mass="0"
            size="{CHASSIS_LENGTH / 2!r} {0.4 * track!r} {CHASSIS_HEIGHT / 2!r}"
            pos="0 0 {COM_HEIGHT!r}" rgba="0.2 0.4 0.8 1"/>{"".join(casters)}{"".join(wheels)}
    </body>
  </worldbody>
  <actuator>
    <velocity name="left_motor" joint="left_wheel" kv="{motor_gain!r}" forcelimited="true"
              forcerange="{-torque_limit!r} {torque_limit!r}"/>
    <velocity name="right_motor" joint="right_wheel" kv="{motor_gain!r}" forcelimited="true"
              forcerange="{-torque_limit!r} {torque_limit!r}"/>
  </actuator>
</mujoco>
"""
