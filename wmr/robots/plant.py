"""The true robot (DESIGN §3.3): input gains and coupling, actuator lag, delay, slip, and the
lagged velocity loop.

Every controller and the pose EKF keep their *nominal* model (eq. 1, unit gains, no lag), as a
controller on a real robot would; this module is the one place that knows how the robot really
moves.  One step, after the command ``u_k`` is saturated (``wmr.closedloop.step``):

1. **delay** -- the command applied now is ``u_{k-d}`` (``d = delay_steps``; zero before the
   first one arrives), from a ring buffer;
2. the disturbance of the window containing ``t_k`` is added (``wmr.closedloop.step.actuate``);
3. **input map** (the parameters in force at ``t_k``)::

       a_v = v_gain v + v_from_w w,    a_w = w_gain w + w_from_v v

   (wheel radius and axle errors; unequal wheels of radii ``r (1 +- eps)`` and half-axle ``b``
   give ``v_from_w = eps b``, ``w_from_v = eps / b``);
4. **actuation and pose** over ``[t_k, t_k + dt]`` with ``a`` held:

   - kinematic, ``actuator_tau = 0``: ``(v, w) = a``;
   - kinematic, ``actuator_tau > 0``: ``v' = (a_v - v) / tau``, ``w' = (a_w - w) / tau``;
   - lagged-velocity: ``mass v' = nominal_mass bw_v (a_v - v) - f_v v`` and
     ``inertia w' = nominal_inertia bw_w (a_w - w) - f_w w`` (an inner proportional velocity loop
     tuned with the nominal mass and inertia, ``bw`` its bandwidth, ``f`` viscous friction: a
     first-order lag whose time constant follows the mass);
   - pose: ``x' = v cos(theta) - v_s sin(theta)``, ``y' = v sin(theta) + v_s cos(theta)``,
     ``theta' = w`` with the lateral skid velocity ``v_s = -slip v w`` (robot frame, left +):
     ``slip > 0`` skids outward of the turn (to the right in a left turn), as a centrifugal skid
     does;
   - with a lag or the velocity loop the robot starts at rest (``v = w = 0`` at ``t = 0``).

``[[plant.change]]`` events switch parameters mid-run: from the first step with ``t_k >= at``
the row of the parameter table for that event is in force (:func:`segment`).

Integration.  The ideal plant (``wmr.robots.plantspec.Plant.ideal``: every field at its ideal value,
no change) takes the scenario's ``integrator`` path of ``wmr.model.kinematics.step``, exactly as
before. Otherwise: without actuator dynamics the velocities are constant over the step and the
motion is integrated exactly (:func:`crab_arc`: the arc of a body moving with constant body-frame
velocity ``(v, v_s)`` and turn rate ``w``).  With actuator dynamics (lag, or the lagged-velocity
model) each channel is first order with the command held, so the velocities and the heading are
exact and only the position needs quadrature (:func:`lagged_step`: 3-point Gauss-Legendre, order 6),
in ``n_sub`` substeps chosen per parameter row so that a substep is at most :data:`SUBSTEP_FRACTION`
of the fastest actuator time constant.  Tests check the order and that a run's RMSE moves by < 1e-6
(relative) when the plant integration is refined 10x.

The parameter table's columns (:data:`PARAMS`) are those the specification declares
(``wmr.robots.plantspec.COLUMNS``, from its fields' metadata) plus ``substeps``; the physics below
reads them by name.
"""

from __future__ import annotations

import math

import numpy as np

from wmr._jit import njit
from wmr.model.kinematics import sinc_and_derivative
from wmr.robots.plantspec import COLUMNS

__all__ = [
    "KINEMATIC",
    "LAGGED_VELOCITY",
    "MODEL_CODES",
    "PARAMS",
    "N_PARAMS",
    "SUBSTEP_FRACTION",
    "time_constants",
    "substeps",
    "segment",
    "delayed",
    "apply",
    "arrays",
    "crab_arc",
    "first_order",
    "first_order_decayed",
    "finish_row",
    "table_row",
    "channels",
    "lagged_step",
]

KINEMATIC, LAGGED_VELOCITY = 0, 1
#: The compiled models: ``[plant] model`` -> the code in ``ints[I_MODEL]``.
MODEL_CODES = {"kinematic": KINEMATIC, "lagged-velocity": LAGGED_VELOCITY}
#: Columns of a row of the plant's parameter table (one row per segment between changes): the
#: specification's (``wmr.robots.plantspec.COLUMNS``), then the substeps of the lagged integration
#: and the eight decays it reads, ``expm1(-t / tau)`` of each channel at the three quadrature nodes
#: and at the substep's end (:func:`finish_row`: they depend on the row alone, so they are
#: computed once per row, not per step).
DECAYS = ("decay_v0", "decay_v1", "decay_v2", "decay_vh", "decay_w0", "decay_w1", "decay_w2",
          "decay_wh")  # fmt: skip
PARAMS = (*COLUMNS, "substeps", *DECAYS)
V_GAIN, W_GAIN, V_FROM_W, W_FROM_V, TAU, SLIP = (PARAMS.index(c) for c in (
    "v_gain", "w_gain", "v_from_w", "w_from_v", "actuator_tau", "slip"))  # fmt: skip
MASS, INERTIA, F_V, F_W, M_NOM, I_NOM, BW_V, BW_W, N_SUB = (PARAMS.index(c) for c in (
    "mass", "inertia", "friction_v", "friction_w", "nominal_mass", "nominal_inertia",
    "bandwidth_v", "bandwidth_w", "substeps"))  # fmt: skip
D_V, D_W = PARAMS.index("decay_v0"), PARAMS.index("decay_w0")
N_PARAMS = len(PARAMS)
#: A substep of the lagged plant is at most this fraction of the fastest actuator time constant.
SUBSTEP_FRACTION = 0.5
# integer state of the plant (``ints``): ideal flag, model, delay steps, current segment, ring
# buffer head
I_IDEAL, I_MODEL, I_DELAY, I_SEG, I_HEAD = range(5)


def time_constants(row, model: int) -> tuple[float, float]:
    """The actuator time constants ``(tau_v, tau_w)`` [s] of a parameter row (inf: none).

    Kinematic: ``actuator_tau`` for both (0: none, returned as inf).  Lagged-velocity: the inner
    loop ``mass v' = m_hat bw (a - v) - f v`` has ``tau = mass / (m_hat bw + f)`` (and likewise
    for w).
    """
    if model == LAGGED_VELOCITY:
        return (row[MASS] / (row[M_NOM] * row[BW_V] + row[F_V]),
                row[INERTIA] / (row[I_NOM] * row[BW_W] + row[F_W]))  # fmt: skip
    tau = row[TAU]
    return (tau, tau) if tau > 0 else (math.inf, math.inf)


def substeps(row, model: int, dt: float) -> int:
    """Substeps per sample for a parameter row: 1 without actuator dynamics, else enough that a
    substep is at most ``SUBSTEP_FRACTION`` of the fastest time constant."""
    tau = min(time_constants(row, model))
    if not math.isfinite(tau):
        return 1
    return max(1, math.ceil(dt / (SUBSTEP_FRACTION * tau) - 1e-9))


@njit(inline="always")
def segment(table_at, ints, t):
    """The row of the parameter table in force at ``t``: advance ``ints[I_SEG]`` past every
    change with ``at <= t`` (changes are sorted by time; row 0 holds from ``t = 0``)."""
    seg = ints[I_SEG]
    while seg + 1 < table_at.size and t >= table_at[seg + 1]:
        seg += 1
    ints[I_SEG] = seg
    return seg


@njit(inline="always")
def delayed(ua, ints, buffer):
    """Replace ``ua`` (the command at step k) by the one of step ``k - d`` from the ring buffer
    (zeros until the first command arrives) and store ``ua`` in its place."""
    d = ints[I_DELAY]
    if d > 0:
        h = ints[I_HEAD]
        v = buffer[h, 0]
        w = buffer[h, 1]
        buffer[h, 0] = ua[0]
        buffer[h, 1] = ua[1]
        ints[I_HEAD] = (h + 1) % d
        ua[0] = v
        ua[1] = w


@njit(inline="always")
def first_order(x0, target, tau, t):
    """A first-order channel ``x' = (target - x) / tau`` from ``x0``: ``(x(t), integral of x over
    [0, t])``, exactly: ``x(t) = target + (x0 - target) e^(-t/tau)``, its integral
    ``target t - (x0 - target) tau expm1(-t/tau)`` (:func:`first_order_decayed` with the decay
    ``expm1(-t/tau)``)."""
    return first_order_decayed(x0, target, tau, t, math.expm1(-t / tau))


@njit(inline="always")
def first_order_decayed(x0, target, tau, t, e):
    """:func:`first_order` with its decay ``e = expm1(-t/tau)`` given (read from the row)."""
    return target + (x0 - target) * (1.0 + e), target * t - (x0 - target) * tau * e


def table_row(values, model: int, dt: float, n_sub: int | None = None) -> np.ndarray:
    """A row of the parameter table (:data:`N_PARAMS` entries) from the specification's columns
    ``values`` (``wmr.robots.plantspec.Plant.row``): the integration's columns written by
    :func:`finish_row` with ``n_sub`` substeps (default :func:`substeps`)."""
    row = np.zeros(N_PARAMS)
    row[: len(COLUMNS)] = values
    finish_row(row, model, dt, substeps(row, model, dt) if n_sub is None else n_sub)
    return row


@njit
def finish_row(row, model, dt, n_sub):
    """Write the lagged integration's columns of a parameter ``row`` (in place): ``substeps =
    n_sub`` and the :data:`DECAYS` -- ``expm1(-t / tau)`` of the v and w channels
    (:func:`channels`) at ``t = node_j h`` and ``t = h``, ``h = dt / n_sub``, exactly as
    :func:`first_order` would compute them each step (0 without actuator dynamics: unused)."""
    row[N_SUB] = n_sub
    for c in range(8):
        row[D_V + c] = 0.0
    if not (model == LAGGED_VELOCITY or row[TAU] > 0.0):
        return
    _, tau_v, _, tau_w = channels(row, model, 0.0, 0.0)
    h = dt / n_sub
    for j in range(3):
        tj = _GL_NODES[j] * h
        row[D_V + j] = math.expm1(-tj / tau_v)
        row[D_W + j] = math.expm1(-tj / tau_w)
    row[D_V + 3] = math.expm1(-h / tau_v)
    row[D_W + 3] = math.expm1(-h / tau_w)


@njit
def channels(row, model, a_v, a_w):
    """``(target_v, tau_v, target_w, tau_w)`` of the two first-order actuator channels.

    Kinematic lag: the targets are the mapped command and ``tau = actuator_tau``.
    Lagged-velocity: ``mass v' = m_hat bw (a - v) - f v`` is first order with
    ``tau = mass / (m_hat bw + f)`` and target ``m_hat bw a / (m_hat bw + f)`` (likewise for ``w``).
    """
    if model == LAGGED_VELOCITY:
        gv = row[M_NOM] * row[BW_V]
        gw = row[I_NOM] * row[BW_W]
        return (gv * a_v / (gv + row[F_V]), row[MASS] / (gv + row[F_V]),
                gw * a_w / (gw + row[F_W]), row[INERTIA] / (gw + row[F_W]))  # fmt: skip
    return a_v, row[TAU], a_w, row[TAU]


# 3-point Gauss-Legendre on [0, 1]: nodes and weights
_GL_NODES = (0.5 - 0.5 * math.sqrt(0.6), 0.5, 0.5 + 0.5 * math.sqrt(0.6))
_GL_WEIGHTS = (5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0)


@njit
def lagged_step(row, model, q, vel, a_v, a_w, dt, n_sub):
    """Advance the pose ``q`` and the actual velocities ``vel`` over ``dt`` with actuator
    dynamics, in place, in ``n_sub`` equal substeps; ``row`` a row of the table, its decays
    written for this ``dt`` and ``n_sub`` (:func:`table_row`).

    Per substep of length ``h`` the velocities and the heading are exact (:func:`first_order`:
    ``theta(t) = theta_0 + integral of w``); the position increments ``integral of (v cos theta -
    v_s sin theta, v sin theta + v_s cos theta)`` with ``v_s = -slip v w`` are taken by 3-point
    Gauss-Legendre quadrature, exact for polynomials of degree 5: the local error is O(h^7), the
    method is of order 6 (a test checks it).
    """
    tv_target, tau_v, tw_target, tau_w = channels(row, model, a_v, a_w)
    slip = row[SLIP]
    h = dt / n_sub
    for _ in range(n_sub):
        v0 = vel[0]
        w0 = vel[1]
        th0 = q[2]
        fx = 0.0
        fy = 0.0
        for j in range(3):  # the decays expm1(-t/tau) at the nodes: the row's (finish_row)
            tj = _GL_NODES[j] * h
            v, _ = first_order_decayed(v0, tv_target, tau_v, tj, row[D_V + j])
            w, dth = first_order_decayed(w0, tw_target, tau_w, tj, row[D_W + j])
            th = th0 + dth
            vs = -slip * v * w  # outward of the turn for slip > 0 (DESIGN §3.3)
            c = math.cos(th)
            s = math.sin(th)
            fx += _GL_WEIGHTS[j] * (v * c - vs * s)
            fy += _GL_WEIGHTS[j] * (v * s + vs * c)
        q[0] += h * fx
        q[1] += h * fy
        vel[0], _ = first_order_decayed(v0, tv_target, tau_v, h, row[D_V + 3])
        vel[1], dth = first_order_decayed(w0, tw_target, tau_w, h, row[D_W + 3])
        q[2] = th0 + dth


@njit
def crab_arc(q, v, vs, w, dt):
    """Exact motion over ``dt`` with constant body-frame velocity ``(v, vs)`` and turn rate ``w``,
    in place.  With ``a = w dt / 2``, ``s = sin(a)/a`` and ``phi = theta + a``, the integral of the
    rotation ``R(theta + w t)`` over the step is ``dt s R(phi)``, so::

        x+ = x + dt s (v cos(phi) - vs sin(phi)),   y+ = y + dt s (v sin(phi) + vs cos(phi)),
        theta+ = theta + w dt

    (``vs = 0`` is the unicycle's exact arc of ``wmr.model.kinematics.step``).
    """
    a = 0.5 * w * dt
    s, _ = sinc_and_derivative(a)
    phi = q[2] + a
    c = math.cos(phi)
    sn = math.sin(phi)
    q[0] += dt * s * (v * c - vs * sn)
    q[1] += dt * s * (v * sn + vs * c)
    q[2] += w * dt


@njit(inline="always")
def apply(k, dt, ua, q, table, table_at, ints, vel):
    """Drive the (non-ideal) true robot over ``[t_k, t_k + dt]`` with the command ``ua`` (delayed
    and disturbed), in place: ``q`` the pose, ``vel`` the actual ``(v, w)``.  The ideal plant
    is ``wmr.model.kinematics.step`` with the scenario's integrator
    (``wmr.closedloop.step.actuate``)."""
    row = table[segment(table_at, ints, k * dt)]
    a_v = row[V_GAIN] * ua[0] + row[V_FROM_W] * ua[1]
    a_w = row[W_GAIN] * ua[1] + row[W_FROM_V] * ua[0]
    model = ints[I_MODEL]
    if model == LAGGED_VELOCITY or row[TAU] > 0.0:
        lagged_step(row, model, q, vel, a_v, a_w, dt, int(row[N_SUB]))
    else:
        vel[0] = a_v
        vel[1] = a_w
        crab_arc(q, a_v, -row[SLIP] * a_v * a_w, a_w, dt)  # v_s = -slip v w: outward


def arrays(spec, dt: float):
    """The plant's arrays for the loop from a validated ``wmr.scenario.Plant`` ``spec``:
    ``(table (n_seg, N_PARAMS), table_at (n_seg,), ints (5,), vel (2,), buffer (max(d, 1), 2))``.

    Row 0 holds the parameters at ``t = 0``; row ``j`` those from the ``j``-th change on (each
    change applies its keys on top of the row before it); the last column, ``substeps``, is
    :func:`substeps` of the row.
    """
    if spec.model not in MODEL_CODES:
        raise ValueError(f"model {spec.model!r} is not a compiled plant (compiled: "
                         f"{', '.join(MODEL_CODES)})")  # fmt: skip
    model = MODEL_CODES[spec.model]
    rows, at = [spec.row()], [0.0]
    for change in spec.changes:
        rows.append(spec.row(rows[-1], change.values))
        at.append(change.at)
    table = np.array([table_row(r, model, dt) for r in rows])
    ints = np.array([int(spec.ideal), model, spec.delay_steps, 0, 0], dtype=np.int64)
    return (table, np.array(at, dtype=float), ints, np.zeros(2),
            np.zeros((max(spec.delay_steps, 1), 2)))
