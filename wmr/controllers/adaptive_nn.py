"""DA-NN: the direct adaptive neural-network baseline (a documented design; the paper gives none).

"Direct": the controller's parameters are adapted straight from the tracking error, with no plant
identification (reproduction-notes §4.2).  Design chosen here (Fierro & Lewis-style backstepping
plus an NN compensator, trained like the paper's DEKF)::

    u_k = u_bsc(e_k) + NN_c(phi_k; theta),   phi = (e1, e2, sin e3, cos e3 - 1, v_r, w_r)

with ``u_bsc`` the backstepping law (same default gains) and the network's output layer starting
at zero, so DA-NN starts as backstepping and differs only by what it learns.  The weights are the
state of an EKF with the paper's ``P0, Q, R`` (eq. 63): at step ``k`` the "measurement" is the
reference pose ``q_r,k`` the last input should have reached, the model is the pose it reached,
``h(theta) = q_hat_k`` with ``dh/dtheta = J_{k-1} dNN_c/dtheta(phi_{k-1})`` (``J`` the exact
ZOH plant Jacobian), and the innovation is ``q_r,k - q_hat_k`` (heading wrapped).

What it adapts to, read off these equations.  The network's input is ``phi_{k-1}`` (the tracking
error and the reference velocities at ``t_{k-1}``; not the measured velocity, nor the reference's
accelerations); its output is an additive correction ``z = NN_c(phi)`` of the velocity command
``(v, w)``; its target, through the EKF, is the correction ``dz`` that would have removed the
one-step tracking error through the *nominal* unicycle, ``q_r,k - q_hat_k ~ G_{k-1} dz``
(``G = dq_{k+1}/du_k`` of the kinematic ZOH step, ``wmr.model.kinematics.step_jacobians``).  So it
compensates the error the base backstepping law leaves, as a static function of
``(e, v_r, w_r)``, assuming a command changes the pose within one step as the kinematic model
says.

On the dynamic plant (``model = "dynamic"``, ``wmr.robots.plant``) the command ``a`` is a set-point
of an inner velocity loop: per channel ``mass v' = nominal_mass bw (a - v) - f v``, a first-order
lag with time constant ``tau = mass / (nominal_mass bw + f)`` and static gain
``g = nominal_mass bw / (nominal_mass bw + f)`` (likewise ``w`` with the inertia).  Hence:

- the command's effect within one step is ``d(int_0^dt v)/da = g (dt - tau (1 - exp(-dt/tau)))
  = rho g dt`` with ``rho = 1 - (tau/dt)(1 - exp(-dt/tau))``: the true one-step Jacobian's
  ``v`` column is ``g rho`` times ``G``'s on a straight line (and the ``w`` column's heading
  entry likewise), so the EKF's ``H`` has the right sign per channel but overstates the effect
  by ``1 / (g rho)`` (about 10 for ``tau = 50 ms``, ``dt = 10 ms``), and a correction keeps
  acting on later steps through the velocity state, which the one-step model does not see;
- a **static velocity deficit** (friction: ``v -> g a`` in steady state, so tracking ``v_r``
  needs ``a = v_r / g``) is a function of ``v_r`` and ``w_r``, which are inputs: the network can
  represent its compensation ``(1/g - 1) v_r``, and re-learn it after a payload change changes
  ``g``, at the pace its EKF allows;
- the **lag** itself cannot be cancelled: a command that leads the lag, ``a ~ (v_r + tau v_r')/g``,
  needs the reference's acceleration (or the measured velocity), neither of which is an input;
  the network can only reshape the feedback on ``e`` (in effect retune the backstepping gains)
  along the trajectory it is trained on.

It is therefore not the torque-level compensator of Fierro & Lewis (whose network sees the
velocities and the derivative of the kinematic command and outputs torques): on the dynamic
plant it compensates static gain errors and whatever part of the lag's effect is a function of
``(e, v_r, w_r)`` along the run.  ``analysis/report.py`` evaluates ``tau``, ``g`` and ``rho`` for
the shipped dynamic plant.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass

import numpy as np

from wmr._jit import njit
from wmr._settings import check, positive
from wmr._shared import SHARED
from wmr.controllers import backstepping
from wmr.estimation import nn
from wmr.estimation.ekf import repair_covariance, weight_update
from wmr.model.kinematics import INTEGRATORS, step_jacobians_into, tracking_error_parts, wrap_angle

__all__ = ["Settings", "State", "STATE_NAMES", "pack", "final_state", "law"]

N_IN = 6
N_OUT = 2
STATE_NAMES = ("nn_v", "nn_w", "cov_repairs")
_S_NN = 0  # 2: network contribution to (v, w)
_S_REPAIRS = 2
_S_PHI = 3  # 6: previous network input
_S_U = 9  # 2: previous input
_S_Q = 11  # 3: previous pose estimate
_S_STARTED = 14
_S_SAT = 15  # 2: whether v, w were saturated at the previous step
_S_SIZE = 17
P_FLOOR = 1e-12

Params = namedtuple(
    "Params", "gains printed_rotation integrator n_h q_diag R Hn H work v_max w_max scratch")
# The run's scratch (``Params.scratch``, overwritten by each step): the plant Jacobian G (3 x 2),
# the innovation, the weight filter's small matrices, the network's output, input and hidden
# activations (the last n_h entries).
_G, _NU, _SMALL, _Z, _PHI, _HID = 0, 6, 9, 36, 38, 44


@dataclass(frozen=True)
class Settings:
    """DA-NN settings.

    Attributes
    ----------
    gains : tuple of float [1/s, 1/m^2, 1/m]
        Backstepping gains ``(k1, k2, k3)`` of the base law (as ``backstepping``'s default).
    hidden : int [-]
        Hidden tanh units of the compensator network (not in the paper).
    p0, q, r : float [-]
        Weight-EKF ``P0 = p0 I``, ``Q = q I``, ``R = r I_3`` (the paper's eq. 63 values).
    printed_rotation : bool [-]
        Use the paper's printed error matrix of eqs. 4/6.
    """

    gains: tuple[float, ...] = (2.0, 10.0, 4.0)
    hidden: int = 8
    p0: float = 1000.0
    q: float = 1e-5
    r: float = 1000.0
    printed_rotation: bool = False

    def __post_init__(self):
        backstepping.Settings(self.gains)  # same checks as the base law
        check(1 <= self.hidden <= 1000, "hidden", self.hidden, "must be in 1..1000")
        for name in ("p0", "r"):
            positive(name, getattr(self, name))
        check(self.q >= 0 and math.isfinite(self.q), "q", self.q, "must be >= 0")


def pack(settings: Settings, scenario, rng):
    """``(p, s, theta, P)``: output layer of the compensator initialised to zero."""
    n = nn.n_weights(N_IN, settings.hidden, N_OUT)
    theta = nn.init_weights(rng, N_IN, settings.hidden, N_OUT, output_scale=0.0)

    def build():  # what the runs share (read only): gains, the filter's Q and R, P0
        return (np.array(settings.gains), np.full(n, settings.q), settings.r * np.eye(3),
                settings.p0 * np.eye(n))  # fmt: skip

    gains, q_diag, R, P0 = SHARED.get("adaptive-nn", (settings, scenario.limits),
                                      scenario.integrator, build)  # fmt: skip
    p = Params(gains, settings.printed_rotation, INTEGRATORS[scenario.integrator],
               settings.hidden, q_diag, R, np.zeros((N_OUT, n)), np.zeros((3, n)),
               np.zeros((3, 3, n)), scenario.limits.v_max, scenario.limits.w_max,
               np.zeros(_HID + settings.hidden))  # fmt: skip
    return p, np.zeros(_S_SIZE), theta, P0.copy()


@dataclass(frozen=True)
class State:
    """DA-NN's controller state (a run's final one: ``RunResult.final``).

    Attributes
    ----------
    theta : ndarray, shape (n,)
        The compensator's flat weight vector (``wmr.estimation.nn`` layout).
    P : ndarray, shape (n, n)
        Its covariance in the weight EKF.
    nn_output : ndarray, shape (2,)
        The compensator's last contribution to ``(v, w)``.
    previous_input : ndarray, shape (2,)
        ``u_{k-1}`` as the plant received it (saturated).
    cov_repairs : int
        Covariance repairs (and failed updates) so far.
    """

    theta: np.ndarray
    P: np.ndarray
    nn_output: np.ndarray
    previous_input: np.ndarray
    cov_repairs: int


def final_state(p, s, theta, P) -> State:
    """The controller state as a :class:`State`; it keeps the run's ``theta`` and ``P`` (the run
    is over and owns them alone)."""
    return State(theta=theta, P=P, nn_output=s[_S_NN : _S_NN + 2].copy(),
                 previous_input=s[_S_U : _S_U + 2].copy(), cov_repairs=int(s[_S_REPAIRS]))


@njit
def _features_into(e, ref, phi):
    """The compensator's input ``(e1, e2, sin e3, cos e3 - 1, v_r, w_r)`` into ``phi`` (6,)."""
    phi[0] = e[0]
    phi[1] = e[1]
    phi[2] = math.sin(e[2])
    phi[3] = math.cos(e[2]) - 1.0
    phi[4] = ref[3]
    phi[5] = ref[4]


@njit
def _buffers(p):
    """Views of the run's scratch: ``G, innovation, small, z, phi, h``."""
    b = p.scratch
    return (b[_G:_NU].reshape((3, 2)), b[_NU:_SMALL], b[_SMALL:_Z].reshape((3, 3, 3)),
            b[_Z:_PHI], b[_PHI:_HID], b[_HID : _HID + p.n_h])  # fmt: skip


@njit
def adapt(p, s, theta, P, q_hat, ref, dt):
    """EKF step on the compensator weights from the error the last input left (see module doc)."""
    G, innovation, small, z, _, h = _buffers(p)
    phi = s[_S_PHI : _S_PHI + N_IN]  # the previous network input (read only here)
    nn.forward_into(theta, phi, p.n_h, N_OUT, z, h)
    nn.weight_jacobian(theta, phi, p.n_h, N_OUT, h, p.Hn)
    for c in range(N_OUT):  # a saturated input did not depend on the weights
        if s[_S_SAT + c] != 0.0:
            p.Hn[c, :] = 0.0
    step_jacobians_into(s[_S_Q : _S_Q + 3], s[_S_U : _S_U + 2], dt, p.integrator, None, G)
    for i in range(3):  # H = G Hn, written out (no BLAS call in the loop)
        for b in range(p.H.shape[1]):
            p.H[i, b] = G[i, 0] * p.Hn[0, b] + G[i, 1] * p.Hn[1, b]
    innovation[0] = ref[0] - q_hat[0]
    innovation[1] = ref[1] - q_hat[1]
    innovation[2] = wrap_angle(ref[2] - q_hat[2])
    nis = weight_update(theta, P, p.H, innovation, p.q_diag, p.R, p.work, small)
    # a failed update (S not positive definite: NaN NIS, nothing changed) counts like a repair
    if repair_covariance(P, P_FLOOR) or not math.isfinite(nis):
        s[_S_REPAIRS] += 1.0


@njit
def law(p, s, theta, P, q_hat, ref, dt, u):
    """One DA-NN step: adapt the compensator, then backstepping plus compensator."""
    if s[_S_STARTED] != 0.0:
        adapt(p, s, theta, P, q_hat, ref, dt)
    e1, e2, e3 = tracking_error_parts(q_hat, ref, p.printed_rotation)
    _, _, _, z, phi, h = _buffers(p)
    _features_into((e1, e2, e3), ref, phi)
    nn.forward_into(theta, phi, p.n_h, N_OUT, z, h)
    v_r = ref[3]
    u[0] = v_r * math.cos(e3) + p.gains[0] * e1 + z[0]
    u[1] = ref[4] + v_r * (p.gains[1] * e2 + p.gains[2] * math.sin(e3)) + z[1]
    # Saturate here (the simulator's clip is then a no-op) so the input remembered for the next
    # adaptation step is the one the plant receives.
    for c, limit in ((0, p.v_max), (1, p.w_max)):
        s[_S_SAT + c] = 1.0 if abs(u[c]) > limit else 0.0
        u[c] = min(max(u[c], -limit), limit)
    s[_S_NN] = z[0]
    s[_S_NN + 1] = z[1]
    s[_S_PHI : _S_PHI + N_IN] = phi
    s[_S_U] = u[0]
    s[_S_U + 1] = u[1]
    s[_S_Q : _S_Q + 3] = q_hat
    s[_S_STARTED] = 1.0
