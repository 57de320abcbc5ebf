"""IAPID-NN-DEKF: the paper's indirect adaptive PID (the proposed scheme).

Per step ``k`` (reproduction-notes §6), with the pose estimate ``q_hat_k`` of the pose EKF:

1. **Identify** (eqs. 25-31, errata E6, E8).  A series-parallel identifier
   ``q_{k+1} ~ q_k + dt NN([v_k, w_k, cos theta_k, sin theta_k])`` is trained by the weight EKF
   on the pair (input at ``k-1`` -> observed increment ``(q_hat_k - q_hat_{k-1}) / dt``, heading
   difference wrapped): ``P <- P + Q``, Joseph update with ``H = dNN/dtheta`` at the *current*
   input ``x_{k-1}`` and innovation ``d_k - NN(x_{k-1})``.  The paper's NN maps ``(v, w)`` to
   the absolute pose, which a static map cannot represent (E6); the targets here are O(1), which
   makes the paper's ``P0 = R = 1000 I`` meaningful (E11).
2. **Jacobian** (eqs. 20-24, corrected by the chain rule, E7): ``J_{k-1} = dt dNN/d(v, w)`` at
   ``x_{k-1}`` with the updated weights; the printed eqs. 22-24 behind ``printed_jacobian``.
3. **Tune** the PID gains by the SGD step of eqs. 8-17 with that Jacobian
   (:func:`wmr.controllers.pid.adapt_gains`: the exact gradient by default, read per step or per
   second as ``jacobian_scale`` says), then apply eq. (7).
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from wmr._jit import njit
from wmr._settings import check, positive
from wmr.controllers import pid
from wmr.controllers.pid import S_NN_ERR, S_Q, S_REPAIRS, S_STARTED, S_U
from wmr.estimation import nn
from wmr.estimation.ekf import repair_covariance, weight_update
from wmr.model.kinematics import tracking_error_parts, wrap_angle

__all__ = ["Settings", "State", "STATE_NAMES", "N_IN", "pack", "pack_oracle", "final_state", "law",
           "identifier_input", "identifier_input_into"]

#: Network inputs ``(v, w, cos theta, sin theta)``; outputs ``(x', y', theta')`` estimates.
N_IN = 4
N_OUT = 3
STATE_NAMES = pid.STATE_NAMES + ("nn_error", "cov_repairs")
#: Smallest allowed diagonal of the weight covariance before a repair is counted.
P_FLOOR = 1e-12

Params = namedtuple("Params", pid.Params._fields + ("H", "work", "oracle", "truth"))


@dataclass(frozen=True)
class Settings(pid.Settings):
    """IAPID-NN-DEKF settings: the PID/SGD ones plus the network and its weight filter.

    Attributes
    ----------
    hidden : int [-]
        Hidden tanh units (not in the paper; 10 gives n = 83 weights).
    p0, q, r : float [-]
        Weight-filter ``P0 = p0 I``, ``Q = q I``, ``R = r I_3``: the paper's eq. (63) values.
    output_scale : float [-]
        Std scale of the initial output weights (small: the network starts near zero).
    printed_jacobian : bool [-]
        Use the paper's printed eqs. 22-24 for the input Jacobian (errata E7).
    """

    hidden: int = 10
    p0: float = 1000.0
    q: float = 1e-5
    r: float = 1000.0
    output_scale: float = 0.1
    printed_jacobian: bool = False

    def __post_init__(self):
        super().__post_init__()
        check(1 <= self.hidden <= 1000, "hidden", self.hidden, "must be in 1..1000")
        for name in ("p0", "r"):
            positive(name, getattr(self, name))
        check(self.q >= 0 and math.isfinite(self.q), "q", self.q, "must be >= 0")
        check(self.output_scale >= 0, "output_scale", self.output_scale, "must be >= 0")


def pack(settings: Settings, scenario, rng, oracle: bool = False):
    """``(p, s, theta, P)``: PID parameters, network weights ``theta`` (n,) and covariance
    ``P0``.  ``oracle``: the identifier learns from the true poses (``p.truth``, written by the
    loop) instead of the estimates; the PID still acts on the estimate."""
    source = pid.JacobianSource.NETWORK if settings.adapt else pid.JacobianSource.NONE

    def build():  # what the runs share (read only): the parameters' arrays and P0
        n = nn.n_weights(N_IN, settings.hidden, N_OUT)
        base = pid.make_params(settings, source, scenario, n_h=settings.hidden,
                                printed_jacobian=settings.printed_jacobian,
                                q_diag=np.full(n, settings.q),
                                R=settings.r * np.eye(N_OUT),
                                scratch=_scratch_size(settings.hidden))  # fmt: skip
        return base, n, settings.p0 * np.eye(n)

    base, n, P0 = pid.shared("iapid", settings, scenario, source, build)
    p = Params(*base[:-1], np.zeros(base.scratch.size), H=np.zeros((N_OUT, n)),
               work=np.zeros((3, N_OUT, n)), oracle=bool(oracle),
               truth=np.zeros(6))  # (true pose at t_k, true pose at t_{k-1})
    theta = nn.init_weights(rng, N_IN, settings.hidden, N_OUT, settings.output_scale)
    return p, pid.initial_state(settings), theta, P0.copy()


def pack_oracle(settings: Settings, scenario, rng):
    """The ``iapid-oracle`` arm: :func:`pack` with the identifier trained on the true poses.

    It separates what the estimation noise costs the identifier from what its model class
    (a static network of ``(v, w, cos, sin)``) can learn: same network, same filter, same
    initial weights for a seed, same PID on the same estimate; only the targets differ."""
    return pack(settings, scenario, rng, oracle=True)


@dataclass(frozen=True)
class State(pid.State):
    """IAPID-NN-DEKF's controller state: the PID family's plus the identifier's.

    Attributes
    ----------
    theta : ndarray, shape (n,)
        The identifier's flat weight vector (``wmr.estimation.nn`` layout).
    P : ndarray, shape (n, n)
        Its covariance in the weight filter.
    nn_error : float
        Norm of the last innovation ``d_k - NN(x_{k-1})``.
    cov_repairs : int
        Covariance repairs (and failed updates) so far.
    """

    theta: np.ndarray
    P: np.ndarray
    nn_error: float
    cov_repairs: int


def final_state(p, s, theta, P) -> State:
    """The controller state as a :class:`State`; it keeps the run's ``theta`` and ``P`` (the run
    is over and owns them alone: a copy of ``P``, 55 kB at n = 83, was a tenth of a run's
    set-up)."""
    return State(**pid.state_fields(s), theta=theta, P=P,
                 nn_error=float(s[S_NN_ERR]), cov_repairs=int(s[S_REPAIRS]))


@njit
def identifier_input(u, theta):
    """The identifier's input ``(v, w, cos theta, sin theta)``."""
    x = np.empty(N_IN)
    identifier_input_into(u, theta, x)
    return x


@njit
def identifier_input_into(u, theta, x):
    """:func:`identifier_input` written into ``x`` (4,)."""
    x[0] = u[0]
    x[1] = u[1]
    x[2] = math.cos(theta)
    x[3] = math.sin(theta)


# The run's scratch (``Params.scratch``, overwritten by each step): after the PID family's own
# entries, the identifier's input, output, hidden activations, innovation, input Jacobian and the
# weight filter's small matrices (wmr.estimation.ekf.joseph_update).
_X = pid.SCRATCH
_Z = _X + N_IN
_HID = _Z + N_OUT


def _scratch_size(n_h: int) -> int:
    return _HID + n_h + N_OUT + N_OUT * N_IN + 3 * N_OUT * N_OUT


@njit
def _buffers(p):
    """Views of the identifier's scratch: ``x, z, h, innovation, Jx, small``."""
    n_h = p.nn_n_h
    b = p.scratch
    nu = _HID + n_h
    jx = nu + N_OUT
    small = jx + N_OUT * N_IN
    return (b[_X:_Z], b[_Z:_HID], b[_HID:nu], b[nu:jx], b[jx:small].reshape((N_OUT, N_IN)),
            b[small : small + 3 * N_OUT * N_OUT].reshape((3, N_OUT, N_OUT)))  # fmt: skip


@njit
def identify(p, s, theta, P, q_hat, dt):
    """Steps 1-2: weight-EKF update on the last transition, then the identified ``J_{k-1}``,
    written into the state (``wmr.controllers.pid.jacobian_slot``) and returned (a view).

    The transition is the pose estimates' ``(q_hat_{k-1}, q_hat_k)``, or the true poses'
    (``p.truth``) for the oracle arm."""
    if p.oracle:
        now, before = p.truth[0:3], p.truth[3:6]
    else:
        now, before = q_hat, s[S_Q : S_Q + 3]
    x, z, h, innovation, Jx, small = _buffers(p)
    identifier_input_into(s[S_U : S_U + 2], before[2], x)
    nn.forward_into(theta, x, p.nn_n_h, N_OUT, z, h)
    for i in range(2):
        innovation[i] = (now[i] - before[i]) / dt - z[i]
    innovation[2] = wrap_angle(now[2] - before[2]) / dt - z[2]
    s[S_NN_ERR] = math.sqrt(innovation[0] ** 2 + innovation[1] ** 2 + innovation[2] ** 2)
    nn.weight_jacobian(theta, x, p.nn_n_h, N_OUT, h, p.H)
    nis = weight_update(theta, P, p.H, innovation, p.q_diag, p.R, p.work, small)
    # a failed update (S not positive definite: NaN NIS, nothing changed) counts like a repair
    if repair_covariance(P, P_FLOOR) or not math.isfinite(nis):
        s[S_REPAIRS] += 1.0
    if p.nn_printed_jacobian:
        Jx[:, :] = nn.input_jacobian_printed(theta, x, p.nn_n_h, N_OUT)
    else:
        nn.forward_into(theta, x, p.nn_n_h, N_OUT, z, h)
        nn.input_jacobian_into(theta, x, p.nn_n_h, N_OUT, h, Jx)
    J = pid.jacobian_slot(s)
    for i in range(3):
        for j in range(2):
            J[i, j] = dt * Jx[i, j]
    return J


@njit
def law(p, s, theta, P, q_hat, ref, dt, u):
    """One IAPID-NN-DEKF step: identify, tune the gains (SGD), apply eq. (7)."""
    e = tracking_error_parts(q_hat, ref, p.printed_rotation)
    if s[S_STARTED] != 0.0:
        J = identify(p, s, theta, P, q_hat, dt)
        if p.jacobian_source != pid.JacobianSource.NONE:  # adapt = false: identify only
            pid.adapt_gains(p, s, J, e, q_hat, ref, dt)
    pid.pid_output(p, s, e, ref, dt, u)
    pid.remember(s, q_hat, u)
    if p.oracle:
        p.truth[3:6] = p.truth[0:3]
