"""Linearised sampled-data loops of the fixed PID (eq. 7) and backstepping (python-control).

Linearisation.  About perfect tracking of a reference with constant ``(v_r, w_r)`` (an
:class:`OperatingPoint`) the error dynamics of one sample period are ``de_{k+1} = E de_k + B du_k``
with ``E = de_next/de`` (3, 3) and ``B = de_next/du`` (3, 2) from CasADi's AD of the exact ZOH step
(:func:`wmr.model.symbolic.error_step_jacobian_function` at ``e = 0``, ``u = u_r``; never finite
differences).  :func:`error_plant` is the one place that builds the plant of every loop here.

Controllers.  The PID of eq. (7), discretised as in ``wmr.controllers.pid`` (``I[x]_k =
I[x]_{k-1} + dt x_k``, ``D[x]_k = (x_k - x_{k-1})/dt``, ``e1`` drives ``v``, ``s = e3 + e2``
drives ``w``), is linear: a discrete LTI system from ``e`` to ``u`` with states ``(I[e1], I[s],
e1_prev, s_prev)`` (:func:`pid_controller`).  Without feed-forward (the literal eq. 7) the nominal
input ``u_r`` is carried by the integrals, ``I* = (v_r/Kiv, w_r/Kiw)`` (:func:`pid_equilibrium`);
the deviations from that equilibrium obey the same LTI model (and with feed-forward too:
``d(v_r cos e3)/de3 = 0`` at ``e3 = 0``).  Backstepping linearises to the static gain
``du = [[k1, 0, 0], [0, v_r k2, v_r k3]] de`` (:func:`backstepping_controller`, CasADi AD).

Loops.  Plant and controller are joined with ``control.interconnect`` and analysed **one loop at
a time**: broken at the plant input ``v`` with the ``w`` loop closed (``L_v``), and at ``w`` with
``v`` closed (``L_w``), in the negative-feedback convention (closed loop ``1 + L``):
:func:`loop_transfer`.  Every closed-loop state vector is the plant's states, then the
controller's.

Closed forms, stability regions in gain space and the delay and rotation sweeps of these loops:
``wmr.linear.loop_regions`` (its names stay reachable as ``wmr.linear.loops.<name>``).

All functions are analysis-time numpy / python-control / CasADi (the closed loop never calls them);
``wmr.model.symbolic`` (CasADi) is imported when a plant or backstepping gain is built, so that
importing this module does not load it.  Margins of these loops: ``wmr.linear.margins``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import control as ct
import numpy as np
from scipy import optimize

from wmr import scenario as scn
from wmr._settings import check as _check
from wmr.controllers import backstepping as bsc_mod
from wmr.controllers import pid as pid_mod
from wmr.model.kinematics import INTEGRATORS
from wmr.model.references import sample

__all__ = [
    "CHANNELS",
    "PID_GAINS",
    "BSC_GAINS",
    "OperatingPoint",
    "operating_point",
    "constant_reference_scenario",
    "error_plant",
    "pid_controller",
    "backstepping_controller",
    "loop_transfer",
    "pid_loops",
    "backstepping_loops",
    "closed_loop_matrix",
    "spectral_radius",
    "frequency_response",
    "eigenvalue_distance",
    "pid_equilibrium",
    "pid_closed_loop_matrix",
    "start_state_map",
    "slow_mode_error",
]

#: The two loops (plant inputs) of the unicycle: linear velocity ``v``, angular velocity ``w``.
CHANNELS = ("v", "w")
#: Default gains of the fixed PID (Kpv, Kiv, Kdv, Kpw, Kiw, Kdw) and of backstepping (k1, k2, k3).
PID_GAINS: tuple[float, ...] = pid_mod.Settings().gains
BSC_GAINS: tuple[float, ...] = bsc_mod.Settings().gains


# ---------------------------------------------------------------------------------------------
# Operating point
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class OperatingPoint:
    """Perfect tracking of a reference with constant ``v_r`` [m/s] and ``w_r`` [rad/s].

    A straight line (``w_r = 0``) or a circle; ``dt`` [s] and the robot's ``integrator`` as in a
    scenario.  ``label`` says where it comes from.  The input dynamics of the true robot
    (DESIGN §3.3) that :func:`error_plant` models: ``actuator_tau`` [s], a first-order lag of both
    channels (0: none), and ``delay_steps``, a delay line of whole samples before it.
    """

    v_r: float
    w_r: float
    dt: float
    integrator: str = "exact"
    label: str = ""
    actuator_tau: float = 0.0
    delay_steps: int = 0

    def __post_init__(self):
        _check(math.isfinite(self.v_r), "v_r", self.v_r, "must be finite")
        _check(math.isfinite(self.w_r), "w_r", self.w_r, "must be finite")
        _check(math.isfinite(self.dt) and self.dt > 0, "dt", self.dt, "must be > 0")
        _check(self.integrator in INTEGRATORS, "integrator", self.integrator, "unknown")
        _check(math.isfinite(self.actuator_tau) and self.actuator_tau >= 0, "actuator_tau",
               self.actuator_tau, "must be >= 0")  # fmt: skip
        _check(int(self.delay_steps) == self.delay_steps and self.delay_steps >= 0,
               "delay_steps", self.delay_steps, "must be an integer >= 0")  # fmt: skip

    @property
    def u_r(self) -> np.ndarray:
        """The nominal input ``(v_r, w_r)``, shape (2,)."""
        return np.array([self.v_r, self.w_r])

    def to_json(self) -> dict:
        """``{"label", "v_r", "w_r", "dt", "integrator"}``, plus ``actuator_tau`` and
        ``delay_steps`` when the plant has them."""
        out = {"label": self.label, "v_r": self.v_r, "w_r": self.w_r, "dt": self.dt,
               "integrator": self.integrator}  # fmt: skip
        if self.actuator_tau:
            out["actuator_tau"] = self.actuator_tau
        if self.delay_steps:
            out["delay_steps"] = int(self.delay_steps)
        return out


def operating_point(sc: scn.Scenario, where: str = "mean") -> OperatingPoint:
    """An operating point of scenario ``sc``.

    ``where="mean"``: the time-mean ``v_r`` of the reference with ``w_r = 0`` (the straight line;
    the sinusoid's and lemniscate's mean curvature is zero).  ``where="max-curvature"``: the
    ``(v_r, w_r)`` of the reference sample with the largest ``|w_r|``.  Labelled
    ``"<scenario>:<where>"``.
    """
    ref = sample(sc.reference.kind, sc.reference.params, sc.dt, sc.n_steps + 1)
    if where == "mean":
        v_r, w_r = float(np.mean(ref[:, 3])), 0.0
    elif where == "max-curvature":
        i = int(np.argmax(np.abs(ref[:, 4])))
        v_r, w_r = float(ref[i, 3]), float(ref[i, 4])
    else:
        raise ValueError(f"where must be 'mean' or 'max-curvature', got {where!r}")
    return OperatingPoint(v_r, w_r, sc.dt, sc.integrator, f"{sc.name}:{where}",
                          sc.plant.actuator_tau, sc.plant.delay_steps)


def constant_reference_scenario(op: OperatingPoint, duration: float, e0) -> scn.Scenario:
    """A noise-free scenario whose reference has constant ``(v_r, |w_r|)``, started at error ``e0``.

    A straight line (sinusoid of zero amplitude) if ``w_r = 0``, else a counter-clockwise circle of
    radius ``v_r/|w_r|`` (the loop at ``-w_r`` is its mirror image, with the same eigenvalues).
    The initial pose is the one whose corrected error (eq. 6) to the first reference pose is
    ``e0`` (3,); ``duration`` [s] is rounded to whole steps; the plant has ``op``'s actuator lag
    and delay.  For comparing the simulator (``wmr.closedloop.sim.simulate``) with the linearised
    loop.
    """
    if op.w_r == 0.0:
        ref = {"kind": "sinusoid", "speed": op.v_r, "amplitude": 0.0, "omega": 1.0}
    else:
        R = op.v_r / abs(op.w_r)
        ref = {"kind": "circle", "radius": R, "period": 2 * math.pi / abs(op.w_r)}
    r0 = sample(ref["kind"], {k: v for k, v in ref.items() if k != "kind"}, op.dt, 1)[0]
    e0 = np.asarray(e0, dtype=float)
    th = r0[2] - e0[2]
    c, s = math.cos(th), math.sin(th)
    q0 = [r0[0] - (c * e0[0] - s * e0[1]), r0[1] - (s * e0[0] + c * e0[1]), th]
    n = round(duration / op.dt)
    plant = {k: v for k, v in (("actuator_tau", op.actuator_tau),
                               ("delay_steps", int(op.delay_steps))) if v}  # fmt: skip
    return scn.from_dict({"name": f"constant-{op.label or 'op'}", "duration": n * op.dt,
                          "dt": op.dt, "initial_pose": q0, "integrator": op.integrator,
                          "reference": ref, "noise": {"pose_std": [0.0, 0.0, 0.0]},
                          **({"plant": plant} if plant else {})})  # fmt: skip


# ---------------------------------------------------------------------------------------------
# Plant, controllers, loops
# ---------------------------------------------------------------------------------------------


def error_plant(op: OperatingPoint) -> ct.StateSpace:
    """The plant of the linearised loop at ``op``: inputs ``(v, w)``, outputs ``(e1, e2, e3)``.

    Without input dynamics, the kinematic error step: ``de_{k+1} = E de_k + B du_k``,
    ``y_k = de_k`` (states ``e``, ``C = I``), with ``E`` (3, 3) and ``B`` (3, 2) by CasADi AD of
    :func:`wmr.model.symbolic.error_step_function` at ``e = 0``, ``u = u_r`` (exact, no finite
    differences).

    With ``op.actuator_tau > 0`` the applied velocities ``u_a`` lag the command,
    ``u_a' = (u - u_a) / tau``, and the error moves with them, ``e' = A e + B_c u_a`` (``A``,
    ``B_c`` the continuous linearisation,
    :func:`wmr.model.symbolic.error_dynamics_jacobian_function`);
    the step of the joint ``(e, u_a)`` with ``u`` held is exact: the matrix exponential of
    ``[[A, B_c, 0], [0, -I/tau, I/tau], [0, 0, 0]] dt`` (as ``wmr.robots.plant`` integrates the true
    robot: exactly).  With ``op.delay_steps = d > 0`` a shift register of ``d`` past commands
    comes first: the plant receives ``u_{k-d}``.  States ``(e, u_a, z_1 .. z_d)`` (``z_j`` the
    command of ``j`` steps ago), inputs ``(v, w)``, outputs ``(e1, e2, e3)``.

    This is the one place where the plant is built: every loop, closed-loop matrix and gain grid
    of this module takes it from here, and handles any number of plant states through the output
    map ``C`` (the error is ``C x``; states are ordered error first).
    """
    core = _kinematic_error_step(op) if op.actuator_tau == 0 else _lagged_error_step(op)
    if op.delay_steps == 0:
        return core
    return _with_delay_line(core, int(op.delay_steps))


def pid_controller(gains, dt: float) -> ct.StateSpace:
    """Eq. (7) as a discrete LTI system from ``e = (e1, e2, e3)`` to ``u = (v, w)``.

    States ``x_k = (I[e1]_{k-1}, I[s]_{k-1}, e1_{k-1}, s_{k-1})`` with ``s = e3 + e2``; with
    ``I_k = I_{k-1} + dt x_k`` and ``D_k = (x_k - x_{k-1})/dt`` (``wmr.controllers.pid``)::

        v_k = Kiv I[e1]_{k-1} - (Kdv/dt) e1_{k-1} + (Kpv + Kiv dt + Kdv/dt) e1_k
        w_k = Kiw I[s]_{k-1}  - (Kdw/dt) s_{k-1}  + (Kpw + Kiw dt + Kdw/dt) s_k

    and ``x_{k+1} = diag(1, 1, 0, 0) x_k + [[dt e1], [dt s], [e1], [s]]``.  ``gains`` is
    ``(Kpv, Kiv, Kdv, Kpw, Kiw, Kdw)``, ``dt`` [s].
    """
    Kpv, Kiv, Kdv, Kpw, Kiw, Kdw = (float(g) for g in gains)
    A = np.diag([1.0, 1.0, 0.0, 0.0])
    # fmt: off
    B = np.array([[dt, 0.0, 0.0],
                  [0.0, dt, dt],
                  [1.0, 0.0, 0.0],
                  [0.0, 1.0, 1.0]])
    C = np.array([[Kiv, 0.0, -Kdv / dt, 0.0],
                  [0.0, Kiw, 0.0, -Kdw / dt]])
    gv, gw = Kpv + Kiv * dt + Kdv / dt, Kpw + Kiw * dt + Kdw / dt
    D = np.array([[gv, 0.0, 0.0],
                  [0.0, gw, gw]])
    # fmt: on
    return ct.ss(A, B, C, D, dt, inputs=("e1", "e2", "e3"), outputs=("v", "w"),
                 states=("I_e1", "I_s", "e1_prev", "s_prev"), name="controller")  # fmt: skip


def backstepping_controller(gains, op: OperatingPoint) -> ct.StateSpace:
    """Linearised backstepping: the static gain ``du/de`` (2, 3) at ``e = 0``, by CasADi AD of
    :func:`wmr.model.symbolic.backstepping_law_function`; ``gains`` is ``(k1, k2, k3)``."""
    from wmr.model import symbolic as sym  # on use: see _kinematic_error_step

    law = sym.backstepping_law_function()
    jac = law.factory("backstepping_gain", ["e", "u_r", "k"], ["jac:u:e"])
    D = np.asarray(jac(np.zeros(3), op.u_r, np.asarray(gains, dtype=float)))
    return ct.ss(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((2, 0)), D, op.dt,
                 inputs=("e1", "e2", "e3"), outputs=("v", "w"), name="controller")  # fmt: skip


def loop_transfer(plant: ct.StateSpace, controller: ct.StateSpace, channel: str) -> ct.StateSpace:
    """The SISO loop broken at plant input ``channel`` (``"v"`` or ``"w"``), the other closed.

    The controller's output ``channel`` in response to the plant input ``channel`` is ``-L``:
    ``L`` is in the negative-feedback convention (closed loop ``1 + L``).  States: the plant's,
    then the controller's.
    """
    if channel not in CHANNELS:
        raise ValueError(f"channel must be 'v' or 'w', got {channel!r}")
    other = "w" if channel == "v" else "v"
    connections = [[f"controller.{e}", f"plant.{e}"] for e in ("e1", "e2", "e3")]
    connections.append([f"plant.{other}", f"controller.{other}"])
    T = ct.interconnect([plant, controller], connections=connections,
                        inplist=[f"plant.{channel}"], outlist=[f"controller.{channel}"],
                        name=f"T_{channel}")  # fmt: skip
    return ct.ss(T.A, T.B, -T.C, -T.D, T.dt, name=f"L_{channel}")


def pid_loops(op: OperatingPoint, gains=PID_GAINS) -> dict[str, ct.StateSpace]:
    """``{"v": L_v, "w": L_w}`` of the PID loop at ``op`` (plant states + 4 each)."""
    P, C = error_plant(op), pid_controller(gains, op.dt)
    return {ch: loop_transfer(P, C, ch) for ch in CHANNELS}


def backstepping_loops(op: OperatingPoint, gains=BSC_GAINS) -> dict[str, ct.StateSpace]:
    """``{"v": L_v, "w": L_w}`` of the backstepping loop at ``op`` (the plant's states each)."""
    P, C = error_plant(op), backstepping_controller(gains, op)
    return {ch: loop_transfer(P, C, ch) for ch in CHANNELS}


# ---------------------------------------------------------------------------------------------
# Closed loops, spectra, frequency response
# ---------------------------------------------------------------------------------------------


def closed_loop_matrix(L: ct.StateSpace, f: complex = 1.0) -> np.ndarray:
    """State matrix of ``L`` closed through ``f`` (``u = -f y``): ``A - f B (1 + f D)^-1 C``.

    ``f = 1`` gives the nominal closed loop (every loop of :func:`pid_loops` has the same one).
    """
    d = complex(L.D[0, 0]) if np.iscomplexobj(f) else float(L.D[0, 0])
    return L.A - (f / (1.0 + f * d)) * (L.B @ L.C)


def spectral_radius(A: np.ndarray) -> float:
    """``max |eig(A)|`` (0 for an empty matrix): the loop is stable iff it is < 1."""
    return float(np.max(np.abs(np.linalg.eigvals(A)))) if A.size else 0.0


def frequency_response(L: ct.StateSpace, omega) -> np.ndarray:
    """``L(exp(j omega dt))`` of a SISO discrete ``L`` at ``omega`` [rad/s], vectorised.

    Solved on the state space, ``C (zI - A)^-1 B + D``, not through a transfer function (whose
    polynomial coefficients lose the poles clustered at ``z = 1``).
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    n = L.A.shape[0]
    z = np.exp(1j * omega * L.dt)
    if n == 0:
        return np.full(z.shape, complex(L.D[0, 0]))
    M = z[:, None, None] * np.eye(n) - L.A
    X = np.linalg.solve(M, np.broadcast_to(L.B.astype(complex), (z.size, n, 1)))
    return (L.C @ X)[:, 0, 0] + L.D[0, 0]


def eigenvalue_distance(a, b) -> float:
    """Largest distance between two eigenvalue sets of equal size after optimal pairing."""
    a, b = np.asarray(a, dtype=complex), np.asarray(b, dtype=complex)
    cost = np.abs(a[:, None] - b[None, :])
    r, c = optimize.linear_sum_assignment(cost)
    return float(cost[r, c].max())


# ---------------------------------------------------------------------------------------------
# The PID loop without python-control (gain grids), equilibrium, initial states
# ---------------------------------------------------------------------------------------------


def pid_equilibrium(op: OperatingPoint, gains, feed_forward: bool = False) -> np.ndarray:
    """Equilibrium ``x*`` (7,) of :func:`wmr.model.symbolic.pid_closed_loop_step_function`.

    ``(0, 0, 0, v_r/Kiv, w_r/Kiw, 0, 0)`` without feed-forward (the integrals carry ``u_r``;
    ``Kiv, Kiw > 0`` needed unless ``u_r`` is 0), zero with it.
    """
    x = np.zeros(7)
    if not feed_forward:
        x[3] = op.v_r / gains[1] if op.v_r else 0.0
        x[4] = op.w_r / gains[4] if op.w_r else 0.0
    return x


def pid_closed_loop_matrix(plant: ct.StateSpace, gains) -> np.ndarray:
    """The closed loop of :func:`pid_controller` on ``plant`` (:func:`error_plant`).

    ``[[A + B D_c C, B C_c], [B_c C, A_c]]`` with the plant's ``(A, B, C)`` and the controller's
    ``(A_c, B_c, C_c, D_c)`` at ``plant.dt``: states the plant's, then the controller's.  The
    same matrix as ``closed_loop_matrix(pid_loops(op, gains)["v"])`` without interconnecting
    (for gain grids).
    """
    c = pid_controller(gains, plant.dt)
    top = np.hstack((plant.A + plant.B @ c.D @ plant.C, plant.B @ c.C))
    return np.vstack((top, np.hstack((c.B @ plant.C, c.A))))


def start_state_map(controller: str, plant: ct.StateSpace) -> np.ndarray:
    """``M`` (n, 3): the closed-loop state at which the simulator starts from an error ``e0``.

    The plant's states are ``(e0, 0)`` (its extra states, if any, at rest at the operating
    point); the PID (``controller="pid"``) starts with zero integral deviations and previous
    signals equal to the current ones (``D = 0`` at ``k = 0``: ``e1_prev = e1``, ``s_prev = e2 +
    e3``); backstepping has no state.  ``x0 = M e0``.
    """
    top = np.vstack((np.eye(3), np.zeros((plant.nstates - 3, 3))))
    if controller == "backstepping":
        return top
    if controller == "pid":
        return np.vstack((top, np.zeros((2, 3)), [[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]))
    raise ValueError(f"controller must be 'pid' or 'backstepping', got {controller!r}")


def slow_mode_error(A: np.ndarray, M: np.ndarray, size: float = 1e-3) -> np.ndarray:
    """An initial error ``e0`` (3,) that excites the slowest mode of ``x+ = A x`` and not the next.

    ``x0 = M e0`` (``M`` (n, 3) maps the error to the initial state, :func:`start_state_map`).
    With left eigenvectors ``w_i``, the modal coefficients are ``w_i^H M e0``: ``e0`` cancels
    those of the next-slowest mode (one real constraint, or two for a complex pair) and, in what
    remains, maximises the slowest one's.  Normalised to ``|e0| = size``.
    """
    z, V = np.linalg.eig(A)
    W = np.linalg.inv(V)  # rows: left eigenvectors
    order = np.argsort(-np.abs(z), kind="stable")
    slow = order[0]
    rest = [i for i in order if abs(z[i] - z[slow]) > 1e-9 and abs(z[i] - np.conj(z[slow])) > 1e-9]
    cons = []
    if rest:
        g = W[rest[0]] @ M
        cons = [g.real] + ([g.imag] if abs(z[rest[0]].imag) > 1e-12 else [])
    N = _null_space(np.array(cons)) if cons else np.eye(3)
    g = W[slow] @ M @ N
    _, _, vt = np.linalg.svd(np.vstack((g.real, g.imag)))
    e0 = N @ vt[0]
    return size * e0 / np.linalg.norm(e0)


# ---------------------------------------------------------------------------------------------
# Private helpers
# ---------------------------------------------------------------------------------------------


def _kinematic_error_step(op: OperatingPoint) -> ct.StateSpace:
    """``de_{k+1} = E de_k + B du_k``, ``y_k = de_k``: the unicycle's error step (no input
    dynamics), by CasADi AD at ``e = 0``, ``u = u_r``."""
    # CasADi is imported here, on use, so that importing wmr never loads it (the oracle stays
    # out of the simulator's import graph: tests/test_symbolic.py).
    from wmr.model import symbolic as sym

    E, B = sym.error_step_jacobian_function(op.integrator)(np.zeros(3), op.u_r, op.u_r, op.dt)
    return ct.ss(np.asarray(E), np.asarray(B), np.eye(3), np.zeros((3, 2)), op.dt,
                 inputs=("v", "w"), outputs=("e1", "e2", "e3"), name="plant")  # fmt: skip


def _lagged_error_step(op: OperatingPoint) -> ct.StateSpace:
    """The exact sampled step of ``(e, u_a)`` with a first-order lag ``tau`` (see
    :func:`error_plant`)."""
    from scipy.linalg import expm

    from wmr.model import symbolic as sym

    A, Bc = (np.asarray(m) for m in sym.error_dynamics_jacobian_function()(np.zeros(3), op.u_r,
                                                                            op.u_r))
    tau = op.actuator_tau
    M = np.zeros((7, 7))
    M[:3, :3], M[:3, 3:5] = A, Bc
    M[3:5, 3:5], M[3:5, 5:7] = -np.eye(2) / tau, np.eye(2) / tau
    Phi = expm(M * op.dt)
    C = np.hstack((np.eye(3), np.zeros((3, 2))))
    return ct.ss(Phi[:5, :5], Phi[:5, 5:], C, np.zeros((3, 2)), op.dt, inputs=("v", "w"),
                 outputs=("e1", "e2", "e3"), states=("e1", "e2", "e3", "v_a", "w_a"),
                 name="plant")  # fmt: skip


def _with_delay_line(core: ct.StateSpace, d: int) -> ct.StateSpace:
    """``core`` fed through a delay of ``d`` whole samples: states ``(core, z_1 .. z_d)`` with
    ``z_1 <- u``, ``z_{j+1} <- z_j`` and ``core`` driven by ``z_d``."""
    n = core.nstates
    N = n + 2 * d
    A = np.zeros((N, N))
    A[:n, :n] = core.A
    A[:n, N - 2 :] = core.B  # the core is driven by the oldest command z_d
    for j in range(1, d):  # z_{j+1} <- z_j
        A[n + 2 * j : n + 2 * j + 2, n + 2 * (j - 1) : n + 2 * j] = np.eye(2)
    B = np.zeros((N, 2))
    B[n : n + 2] = np.eye(2)  # z_1 <- u
    C = np.hstack((core.C, np.zeros((core.noutputs, 2 * d))))
    states = [*core.state_labels, *(f"{c}_{j}" for j in range(1, d + 1) for c in ("v", "w"))]
    return ct.ss(A, B, C, np.zeros((core.noutputs, 2)), core.dt, inputs=("v", "w"),
                 outputs=("e1", "e2", "e3"), states=states, name="plant")  # fmt: skip


def _null_space(C: np.ndarray) -> np.ndarray:
    _, sv, vt = np.linalg.svd(C)
    rank = int(np.sum(sv > 1e-12 * max(sv.max(), 1.0)))
    return vt[rank:].T


def _sym():
    from wmr.model import symbolic

    return symbolic


def __getattr__(name: str):
    # the closed forms, regions and sweeps moved to wmr.linear.loop_regions: still reachable here
    from wmr.linear import loop_regions

    if name in loop_regions.__all__:
        return getattr(loop_regions, name)
    raise AttributeError(f"module 'wmr.linear.loops' has no attribute {name!r}")

