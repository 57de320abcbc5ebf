"""The PID of eq. (7) and its SGD gain adaptation, eqs. (8)-(17): the ``pid`` and ``adaptive-pid``.

Control law (eq. 7), with ``e = (e1, e2, e3)`` of eq. (6) (corrected rotation by default) and
``s = e3 + e2`` the signal of the angular loop::

    v = Kpv e1 + Kiv I[e1] + Kdv D[e1]            (+ v_r cos e3 with feed_forward)
    w = Kpw s  + Kiw I[s]  + Kdw D[s]             (+ w_r        with feed_forward)

discretised as ``I[x]_k = I[x]_{k-1} + dt x_k`` and ``D[x]_k = (x_k - x_{k-1}) / dt``
(``D = 0`` at ``k = 0``).  The paper's eq. (7) has no feed-forward; it is off by default.

Gain adaptation (eqs. 8-17, errata E5): with ``F = e^T Gamma e / 2`` and the regressor
``phi = dU/dK`` of eq. (15), one SGD step per sample is::

    K <- clip(K + mu o (dU/dK_{k-1})^T (J_{k-1}^T T_e(theta_k)^T Gamma e_k - h_k J_{k-1}[2, :]^T),
              K_min, K_max)

where ``J_{k-1} = dq_k/du_{k-1}`` is the plant Jacobian (causal indices, E5b) and
``h_k = e_k^T Gamma dT_e/dtheta (q_r,k - q_k)`` the heading's effect on the error frame, which the
paper drops (E5a; ``gradient = "approximate"``); with the rotation ``h = (alpha1 - alpha2) e1 e2``
(:func:`sgd_gain_step` derives it).  ``adaptive-pid`` uses the exact ZOH Jacobian of the unicycle
model; ``iapid-nn-dekf`` (``wmr.controllers.iapid_nn_dekf``) uses the one identified by the
network; ``jacobian_scale`` reads either per step (default) or per second.

State vector ``s`` (shared by the PID family, see ``S_*`` indices): gains, Jacobian estimate,
diagnostics, integrals, previous error signals and regressor, previous input and pose.
"""

from __future__ import annotations

import math
from collections import namedtuple
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from wmr._jit import njit
from wmr._settings import check
from wmr._shared import SHARED
from wmr.model.kinematics import INTEGRATORS, step_jacobians_into, tracking_error_parts

__all__ = [
    "Settings",
    "FixedSettings",
    "Params",
    "State",
    "JacobianSource",
    "STATE_NAMES",
    "GAIN_NAMES",
    "J_NAMES",
    "pack",
    "final_state",
    "make_params",
    "law",
    "pid_output",
    "heading_term",
    "sgd_gain_step",
    "adapt_gains",
    "GRADIENTS",
    "JACOBIAN_SCALES",
]

# Layout of the PID-family state vector s.
S_K = 0  # 6 gains (Kpv, Kiv, Kdv, Kpw, Kiw, Kdw)
S_J = 6  # 6 entries of the 3x2 Jacobian estimate J_{k-1}, row-major
S_NN_ERR = 12  # network prediction error norm (iapid only)
S_REPAIRS = 13  # covariance repairs so far (iapid only)
S_INT = 14  # 2 integrals (I[e1], I[s])
S_PREV = 16  # 2 previous signals (e1, s) for the derivative
S_PHI = 18  # 6 regressor entries dU/dK of the previous step
S_U = 24  # 2 previous input
S_Q = 26  # 3 previous pose estimate
S_STARTED = 29  # 0 before the first step
S_SIZE = 30

GAIN_NAMES = ("Kpv", "Kiv", "Kdv", "Kpw", "Kiw", "Kdw")
J_NAMES = ("J_xv", "J_xw", "J_yv", "J_yw", "J_thv", "J_thw")
#: Logged along a run by ``adaptive-pid`` (``pid`` logs the same; its gains stay constant).
STATE_NAMES = GAIN_NAMES + J_NAMES
#: Values of ``Settings.gradient``: the SGD direction with or without the ``dT_e/dtheta`` term.
GRADIENTS = ("exact", "approximate")
#: Values of ``Settings.jacobian_scale``: the plant Jacobian per sample or per second.
JACOBIAN_SCALES = ("step", "second")



class JacobianSource(IntEnum):
    """Where the SGD step of eqs. (9)-(17) takes the plant Jacobian ``J_{k-1}`` from."""

    NONE = 0  # no adaptation: the fixed ``pid``
    MODEL = 1  # the exact ZOH Jacobian of the nominal unicycle (``adaptive-pid``)
    NETWORK = 2  # identified online by the network (``iapid-nn-dekf``)


#: Frozen parameters of the PID family inside jitted code.
Params = namedtuple(
    "Params",
    "K_min K_max mu alpha exact_gradient jacobian_per_second feed_forward printed_rotation "
    "jacobian_source integrator nn_n_h nn_printed_jacobian q_diag R v_max w_max scratch",
)
#: Entries of ``Params.scratch`` the PID family's SGD step uses (the per-second Jacobian, 3 x 2).
SCRATCH = 6


@dataclass(frozen=True)
class Settings:
    """PID (eq. 7) and SGD (eqs. 8-17) settings.  The paper gives only ``mu = 0.9``.

    Attributes
    ----------
    gains : tuple of float [SI]
        Initial ``(Kpv, Kiv, Kdv, Kpw, Kiw, Kdw)``.  Not in the paper; default
        ``(5, 5, 0, 10, 2, 0)``: a fixed PID that tracks the sinusoid to cm level with the literal
        eq. 7 (reproduction-notes §5.4).
    mu : tuple of float [-]
        SGD learning rates per gain (eq. 10); the paper's 0.9 for all.
    alpha : tuple of float [-]
        Cost weights ``(alpha1, alpha2, alpha3)`` of eq. (8); not in the paper, 1 each.  With the
        exact gradient ``alpha2`` enters the SGD step through ``(alpha1 - alpha2) e1 e2`` on the
        w-gains; it drops out only with ``gradient = "approximate"`` and the exact model Jacobian
        (notes §4.3).
    gradient : str [-]
        The SGD direction of eq. (17): ``"exact"`` (default), the gradient of ``F_k`` with respect
        to ``u_{k-1}`` through the plant, heading term ``-h J[2, :]`` included (derived in
        ``sgd_gain_step``); ``"approximate"``: the paper's ``J^T T_e^T Gamma e``, which drops
        ``dT_e/dtheta`` (errata E5a) and is exact only when ``alpha1 = alpha2`` (with the
        rotation; never with ``printed_rotation``).
    jacobian_scale : str [-]
        Time scale of the plant Jacobian in the SGD step: ``"step"`` (default) uses
        ``J_{k-1} = dq_k/du_{k-1}`` of the sampled plant, ``~ dt G(theta)``, so the step is
        ``~ mu dt e phi``; ``"second"`` uses ``J_{k-1} / dt`` (per second, ``~ G``), which
        multiplies the effective learning rate by ``1/dt`` (x100 at ``dt = 0.01`` s).  Applies to
        the model's Jacobian (``adaptive-pid``) and the identified one (``iapid-nn-dekf``); the
        logged ``J_*`` signals stay per step.
    gain_min, gain_max : tuple of float [SI]
        Clamp of each gain during adaptation (errata E5d).  Not in the paper.  ``Kd <= 0.5``: noise
        on the measured pose drives the derivative gains up (DESIGN §5), and the linearised loop
        at the default gains is unstable beyond ``Kdv ~ 0.98``, ``Kdw ~ 0.95``
        (``analysis/margins/``); 0.5 keeps a factor of ~2 of margin.
    feed_forward : bool [-]
        Add ``(v_r cos e3, w_r)`` to eq. 7 (not in the paper).
    printed_rotation : bool [-]
        Use the paper's printed error matrix of eqs. 4/6 (errata E3) instead of the rotation.
    adapt : bool [-]
        Adapt the gains (``adaptive-pid``); False gives the fixed ``pid`` (and an
        ``iapid-nn-dekf`` that identifies the plant but does not tune its gains).
    """

    gains: tuple[float, ...] = (5.0, 5.0, 0.0, 10.0, 2.0, 0.0)
    mu: tuple[float, ...] = (0.9, 0.9, 0.9, 0.9, 0.9, 0.9)
    alpha: tuple[float, ...] = (1.0, 1.0, 1.0)
    gradient: str = "exact"
    jacobian_scale: str = "step"
    gain_min: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    gain_max: tuple[float, ...] = (50.0, 50.0, 0.5, 50.0, 50.0, 0.5)
    feed_forward: bool = False
    printed_rotation: bool = False
    adapt: bool = True

    def __post_init__(self):
        for name in ("mu", "alpha", "gain_min"):
            for x in getattr(self, name):
                check(x >= 0, name, getattr(self, name), "entries must be >= 0")
        check(self.gradient in GRADIENTS, "gradient", self.gradient,
              f"must be one of {', '.join(GRADIENTS)}")  # fmt: skip
        check(self.jacobian_scale in JACOBIAN_SCALES, "jacobian_scale", self.jacobian_scale,
              f"must be one of {', '.join(JACOBIAN_SCALES)}")  # fmt: skip
        for lo, hi, k in zip(self.gain_min, self.gain_max, self.gains, strict=True):
            check(lo <= hi, "gain_max", self.gain_max, "must be >= gain_min entrywise")
            check(lo <= k <= hi, "gains", self.gains, "must lie within [gain_min, gain_max]")


def make_params(settings: Settings, source: JacobianSource, scenario, **nn) -> Params:
    """Jitted-side parameters: the Jacobian ``source`` of the SGD step, the scenario's
    integrator and actuator limits; ``nn`` holds the network size and weight-filter matrices for
    ``iapid-nn-dekf`` (and the size of its ``scratch``: the run's buffers, overwritten by each
    step, so the law allocates nothing)."""
    return Params(
        K_min=np.array(settings.gain_min),
        K_max=np.array(settings.gain_max),
        mu=np.array(settings.mu),
        alpha=np.array(settings.alpha),
        exact_gradient=settings.gradient == "exact",
        jacobian_per_second=settings.jacobian_scale == "second",
        feed_forward=settings.feed_forward,
        printed_rotation=settings.printed_rotation,
        jacobian_source=int(source),
        integrator=INTEGRATORS[scenario.integrator],
        nn_n_h=nn.get("n_h", 0),
        nn_printed_jacobian=nn.get("printed_jacobian", False),
        q_diag=nn.get("q_diag", np.zeros(0)),
        R=nn.get("R", np.zeros((0, 0))),
        v_max=scenario.limits.v_max,
        w_max=scenario.limits.w_max,
        scratch=np.zeros(nn.get("scratch", SCRATCH)),
    )


def initial_state(settings: Settings) -> np.ndarray:
    s = np.zeros(S_SIZE)
    s[S_K : S_K + 6] = settings.gains
    return s


@dataclass(frozen=True)
class FixedSettings(Settings):
    """Settings of the fixed-gain ``pid``: those of :class:`Settings` with ``adapt = false``."""

    adapt: bool = False


def shared(kind: str, settings, scenario, source, build):
    """``build()`` made once per ``kind`` of pack, settings, Jacobian ``source`` and the scenario's
    limits and integrator (what :func:`make_params` reads), and shared by the runs
    (``wmr._shared``): the laws only read the arrays of the parameters; each run gets its own
    ``scratch`` and whatever else a law writes."""
    return SHARED.get(kind, (settings, scenario.limits), (int(source), scenario.integrator), build)


def pack(settings: Settings, scenario, rng):
    """``(p, s, theta, P)`` for ``pid``/``adaptive-pid``: no network, so ``theta`` and ``P`` are
    empty."""
    source = JacobianSource.MODEL if settings.adapt else JacobianSource.NONE
    p = shared("pid", settings, scenario, source, lambda: make_params(settings, source, scenario))
    p = Params(*p[:-1], np.zeros(SCRATCH))  # the run's own scratch (the last field)
    return p, initial_state(settings), np.zeros(0), np.zeros((0, 0))


pack.uses_rng = False  # it draws nothing: the loop need not make the initialisation stream


@dataclass(frozen=True)
class State:
    """The PID family's controller state (a run's final one: ``RunResult.final``).

    Attributes
    ----------
    gains : ndarray, shape (6,)
        ``(Kpv, Kiv, Kdv, Kpw, Kiw, Kdw)``.
    jacobian : ndarray, shape (3, 2)
        The plant Jacobian ``J_{k-1}`` the last SGD step used (zero for the fixed ``pid``).
    integrals : ndarray, shape (2,)
        ``I[e1]``, ``I[s]`` of eq. (7).
    previous_input : ndarray, shape (2,)
        ``u_{k-1}`` as the plant received it (saturated).
    """

    gains: np.ndarray
    jacobian: np.ndarray
    integrals: np.ndarray
    previous_input: np.ndarray


def state_fields(s) -> dict:
    """The named fields of :class:`State` read from the state vector ``s`` (copies)."""
    return {"gains": s[S_K : S_K + 6].copy(), "jacobian": s[S_J : S_J + 6].reshape(3, 2).copy(),
            "integrals": s[S_INT : S_INT + 2].copy(), "previous_input": s[S_U : S_U + 2].copy()}


def final_state(p, s, theta, P) -> State:
    """The controller state as a :class:`State`."""
    return State(**state_fields(s))


@njit(inline="always")
def pid_output(p, s, e, ref, dt, u):
    """Eq. (7): update integrals/derivatives in ``s``, write ``u``, store the regressor of eq. (15).

    ``e`` is the error of eq. (6), an array (3,) or the tuple of
    ``wmr.model.kinematics.tracking_error_parts`` (the laws' allocation-free form).

    The regressor ``dU/dK = [[e1, I[e1], D[e1], 0, 0, 0], [0, 0, 0, s, I[s], D[s]]]`` is kept in
    ``s[S_PHI:S_PHI+6]`` as ``(e1, I[e1], D[e1], s, I[s], D[s])`` for the next SGD step.
    """
    ex = e[0]
    sw = e[2] + e[1]
    s[S_INT] += dt * ex
    s[S_INT + 1] += dt * sw
    if s[S_STARTED] != 0.0:
        dx = (ex - s[S_PREV]) / dt
        dw = (sw - s[S_PREV + 1]) / dt
    else:
        dx = 0.0
        dw = 0.0
    s[S_PREV] = ex
    s[S_PREV + 1] = sw
    phi = s[S_PHI : S_PHI + 6]
    phi[0] = ex
    phi[1] = s[S_INT]
    phi[2] = dx
    phi[3] = sw
    phi[4] = s[S_INT + 1]
    phi[5] = dw
    K = s[S_K : S_K + 6]
    u[0] = K[0] * phi[0] + K[1] * phi[1] + K[2] * phi[2]
    u[1] = K[3] * phi[3] + K[4] * phi[4] + K[5] * phi[5]
    if p.feed_forward:
        u[0] += ref[3] * math.cos(e[2])
        u[1] += ref[4]
    # Saturate here (the simulator's clip is then a no-op) so the controller remembers the input
    # the plant receives; a saturated channel does not depend on its gains: regressor zero.
    for c, limit in ((0, p.v_max), (1, p.w_max)):
        if abs(u[c]) > limit:
            u[c] = min(max(u[c], -limit), limit)
            phi[3 * c : 3 * c + 3] = 0.0


@njit(inline="always")
def heading_term(p, e, q, q_r):
    """``h = e^T Gamma dT_e/dtheta (q_r - q)``: how the error frame's turn with the heading moves
    the cost ``F = e^T Gamma e / 2`` (the term of the exact SGD gradient the paper drops, E5a).

    Parameters
    ----------
    p : Params
        Uses ``alpha`` and ``printed_rotation``.
    e : ndarray, shape (3,)
        The tracking error of eq. (6) at ``q`` [m, m, rad].
    q : ndarray, shape (3,)
        Pose ``(x [m], y [m], theta [rad])`` the error was formed at.
    q_r : ndarray, shape (>= 2,)
        Reference sample; only ``(x_r, y_r)`` [m] is used.

    Returns
    -------
    float
        ``h`` [m^2/rad].  With the rotation ``dT_e/dtheta (q_r - q) = (e2, -e1, 0)``, so
        ``h = alpha1 e1 e2 - alpha2 e2 e1``, computed as ``alpha1 (e1 e2) - alpha2 (e1 e2)``:
        exactly ``0.0`` when ``alpha1 = alpha2`` (the product rounds once, then ``x - x = 0``).
        With the printed matrix ``[[c, s, 0], [s, c, 0], [0, 0, 1]]`` (E3) the derivative is
        ``(-s dx + c dy, c dx - s dy, 0)`` with ``(dx, dy) = (x_r - x, y_r - y)``, and ``h``
        does not vanish with equal weights (``2 cos(2 theta) dx dy`` at ``alpha = (1, 1, 1)``).
    """
    if p.printed_rotation:
        c = math.cos(q[2])
        s = math.sin(q[2])
        dx = q_r[0] - q[0]
        dy = q_r[1] - q[1]
        return p.alpha[0] * e[0] * (-s * dx + c * dy) + p.alpha[1] * e[1] * (c * dx - s * dy)
    e1e2 = e[0] * e[1]
    return p.alpha[0] * e1e2 - p.alpha[1] * e1e2


@njit(inline="always")
def sgd_gain_step(p, s, J, e, theta, h):
    """One SGD step of eqs. (9)-(17) on the gains in ``s``, with the Jacobian ``J`` (3, 2).

    ``K <- clip(K + mu o (dU/dK)^T (J^T T_e(theta)^T Gamma e - h J[2, :]^T), K_min, K_max)``
    with the regressor ``dU/dK`` of the previous step (stored by :func:`pid_output`).

    Derivation (errata E5, corrected rotation).  The cost of step ``k`` is
    ``F = e^T Gamma e / 2`` (eq. 8), ``Gamma = diag(alpha)``, with ``e = T_e(theta_k) (q_r - q_k)``
    (eq. 6), and ``q_k = f(q_{k-1}, u_{k-1})`` depends on the gains through
    ``u_{k-1} = U(K)`` (eq. 7, regressor ``dU/dK``).  ``J = dq_k/du_{k-1}`` (its row 2 is
    ``dtheta_k/du_{k-1}``), and ``T_e`` depends on ``theta_k``, so by the chain rule::

        de/du = -T_e J + (dT_e/dtheta (q_r - q)) J[2, :]      (3, 2), an outer product last
        dT_e/dtheta (q_r - q) = (-s dx + c dy, -c dx - s dy, 0) = (e2, -e1, 0)
        dF/du = e^T Gamma de/du = -(J^T T_e^T Gamma e)^T + h J[2, :]
        h = e^T Gamma (e2, -e1, 0) = alpha1 e1 e2 - alpha2 e2 e1 = (alpha1 - alpha2) e1 e2

    and ``dF/dK = dF/du dU/dK``; the step ``K <- K - mu o dF/dK^T`` is the update above (sign as
    in E5).  The paper's eq. (17) drops ``dT_e/dtheta`` (E5a): ``h = 0``, exact only when
    ``alpha1 = alpha2``.  With the exact ZOH Jacobian ``J[2, :] = (0, dt)``, so ``h`` moves the
    w-gains only: ``dK_w = mu dt (alpha3 e3 - (alpha1 - alpha2) e1 e2) phi_w``.

    Parameters
    ----------
    p : Params
        ``mu``, ``alpha``, ``K_min``, ``K_max``, ``printed_rotation``.
    s : ndarray, shape (S_SIZE,)
        The PID-family state; its gains are updated in place.
    J : ndarray, shape (3, 2)
        Plant Jacobian ``dq_k/du_{k-1}`` as the step should read it (per step or per second:
        :func:`adapt_gains`).
    e : ndarray, shape (3,)
        Tracking error ``e_k`` of eq. (6) [m, m, rad].
    theta : float
        Heading ``theta_k`` [rad] of ``T_e``.
    h : float
        The heading term of :func:`heading_term`; ``0.0`` gives the approximate gradient.  A zero
        ``h`` skips the term, so the exact gradient with ``alpha1 = alpha2`` is the approximate
        one bit for bit.
    """
    # T_e^T Gamma e with T_e = [[c, sn, 0], [+-sn, c, 0], [0, 0, 1]]
    # (wmr.model.kinematics.rotation), written out with every term of the 3 x 3 product (no
    # allocation, no BLAS call)
    c = math.cos(theta)
    sn = math.sin(theta)
    t10 = sn if p.printed_rotation else -sn
    ge0 = p.alpha[0] * e[0]  # Gamma e
    ge1 = p.alpha[1] * e[1]
    ge2 = p.alpha[2] * e[2]
    te0 = c * ge0 + t10 * ge1 + 0.0 * ge2
    te1 = sn * ge0 + c * ge1 + 0.0 * ge2
    te2 = 0.0 * ge0 + 0.0 * ge1 + 1.0 * ge2
    g0 = J[0, 0] * te0 + J[1, 0] * te1 + J[2, 0] * te2  # (J^T T_e^T Gamma e)_v
    g1 = J[0, 1] * te0 + J[1, 1] * te1 + J[2, 1] * te2  # (...)_w
    if h != 0.0:
        g0 -= h * J[2, 0]
        g1 -= h * J[2, 1]
    for i in range(6):
        g = g0 if i < 3 else g1
        k = s[S_K + i] + p.mu[i] * g * s[S_PHI + i]
        s[S_K + i] = min(max(k, p.K_min[i]), p.K_max[i])


@njit(inline="always")
def adapt_gains(p, s, J, e, q_hat, ref, dt):
    """The SGD step of a law at step ``k``: settings applied, then :func:`sgd_gain_step`.

    ``J`` (3, 2) is ``dq_k/du_{k-1}`` per sample; with ``jacobian_scale = "second"`` the step reads
    ``J / dt`` [per second].  ``gradient = "exact"`` adds :func:`heading_term` at ``(e, q_hat,
    ref)``, ``"approximate"`` leaves it out.  ``e`` (3,) is the error of eq. (6) at ``q_hat`` (3,);
    ``ref`` (5,) the reference sample; ``dt`` [s].
    """
    h = heading_term(p, e, q_hat, ref) if p.exact_gradient else 0.0
    if p.jacobian_per_second:
        Js = p.scratch[0:6].reshape((3, 2))  # J / dt, in the run's scratch
        for i in range(3):
            for j in range(2):
                Js[i, j] = J[i, j] / dt
        sgd_gain_step(p, s, Js, e, q_hat[2], h)
    else:
        sgd_gain_step(p, s, J, e, q_hat[2], h)


@njit(inline="always")
def store_jacobian(s, J):
    for i in range(3):
        for j in range(2):
            s[S_J + 2 * i + j] = J[i, j]


@njit(inline="always")
def remember(s, q_hat, u):
    """Keep ``u_k`` and ``q_hat_k`` for the next step's causal Jacobian (E5b)."""
    s[S_U] = u[0]
    s[S_U + 1] = u[1]
    for i in range(3):
        s[S_Q + i] = q_hat[i]
    s[S_STARTED] = 1.0


@njit(inline="always")
def jacobian_slot(s):
    """The Jacobian estimate ``J_{k-1}`` (3, 2) in the state ``s``: a view, written in place."""
    return s[S_J : S_J + 6].reshape((3, 2))


@njit
def law(p, s, theta, P, q_hat, ref, dt, u):
    """``pid`` / ``adaptive-pid``: SGD step with the exact ZOH plant Jacobian, then eq. (7)."""
    e = tracking_error_parts(q_hat, ref, p.printed_rotation)
    if p.jacobian_source != JacobianSource.NONE and s[S_STARTED] != 0.0:
        J = jacobian_slot(s)  # G = dq_k/du_{k-1} of the ZOH step, written into the state
        step_jacobians_into(s[S_Q : S_Q + 3], s[S_U : S_U + 2], dt, p.integrator, None, J)
        adapt_gains(p, s, J, e, q_hat, ref, dt)
    pid_output(p, s, e, ref, dt, u)
    remember(s, q_hat, u)
