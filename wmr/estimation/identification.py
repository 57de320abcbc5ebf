"""How good is an identified plant Jacobian?  Quality metrics along a closed-loop run.

The SGD gain step of eqs. (9)-(17) needs the plant Jacobian ``J_{k-1} = dq_k/du_{k-1}`` (3, 2)
of the step from ``t_{k-1}`` to ``t_k``.  ``adaptive-pid`` takes it from the nominal unicycle
model; ``iapid-nn-dekf`` identifies it online, ``J_NN = dt dNN/d(v, w)`` (eqs. 20-24, corrected
by the chain rule: errata E7).  Both log the Jacobian they used (``RunResult.jacobian()``).
:func:`jacobian_quality` compares that logged Jacobian, step by step, with the *true* plant
Jacobian, and the SGD direction it produces with the one the true Jacobian would give.

The true Jacobian is a callable ``true_jacobian(k, q, u, dt) -> (3, 2)``: the Jacobian
``dq_{k+1}/du_k`` of the true plant's step ``k`` (from ``t_k = k dt``) at the pose ``q`` and the
applied input ``u``.  The default, :func:`nominal_jacobian`, is the nominal ZOH unicycle step's
``G`` (:func:`wmr.model.kinematics.step_jacobians`); a plant that differs from the nominal model
(input gains, coupling, a change at some ``t_k``) passes its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, fields

import numpy as np

from wmr.model import kinematics as kin

__all__ = [
    "TrueJacobian",
    "QUALITY_KEYS",
    "JacobianQuality",
    "rel_error",
    "nominal_jacobian",
    "plant_jacobian",
    "jacobian_quality",
]

#: ``true_jacobian(k, q, u, dt) -> ndarray (3, 2)``: ``dq_{k+1}/du_k`` of the true plant's step
#: ``k`` at pose ``q`` (3,) and input ``u`` (2,) [m/(m/s), rad/(rad/s), ...], ``dt`` [s].
TrueJacobian = Callable[[int, np.ndarray, np.ndarray, float], np.ndarray]

#: The per-step series of a :class:`JacobianQuality` (all but the time ``t``), in table order.
QUALITY_KEYS: tuple[str, ...] = (
    "rel_error",
    "rel_error_v",
    "rel_error_w",
    "norm_ratio",
    "matrix_cosine",
    "cosine",
    "sign_v",
    "sign_w",
)

_TINY = np.finfo(float).tiny


def rel_error(A, B) -> np.ndarray:
    """``||A - B||_F / max(||B||_F, tiny)`` over the last two axes.

    Parameters
    ----------
    A, B : array_like, shape (..., m, n)
        The tested value and the reference.  1-D inputs are treated as one row.

    Returns
    -------
    ndarray, shape (...)
        Relative Frobenius error; 0 where ``A == B`` (including both zero); ``inf`` only if
        ``B == 0`` and ``A != 0`` exceeds ~1e-308.  ``A = 0`` scores 1.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if A.shape != B.shape:
        raise ValueError(f"shapes differ: {A.shape} vs {B.shape}")
    if A.ndim == 1:
        A, B = A[None, :], B[None, :]
    d = np.sqrt(np.sum((A - B) ** 2, axis=(-2, -1)))
    nb = np.sqrt(np.sum(B**2, axis=(-2, -1)))
    with np.errstate(over="ignore"):
        return d / np.maximum(nb, _TINY)


def nominal_jacobian(integrator: str | int = "exact") -> TrueJacobian:
    """The nominal plant's Jacobian: ``G = dq+/du`` of the ZOH unicycle step (eq. 1) with
    ``integrator`` (``"exact"``, ``"euler"``, ``"rk4"`` or its code), whatever ``k``."""
    code = kin.integrator_code(integrator)

    def true_jacobian(k: int, q: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        return kin.step_jacobians(q, u, dt, code)[1]

    return true_jacobian


#: Central-difference step [input units] of :func:`plant_jacobian`: the true plant's step is
#: smooth in the command, so the truncation error is O(h^2) ~ 1e-12 and rounding ~1e-16/h.
PLANT_FD_STEP = 1e-6


def plant_jacobian(scenario, run) -> TrueJacobian:
    """The true robot's Jacobian ``dq_{k+1}/du_k`` along ``run`` of ``scenario`` (DESIGN §3.3).

    The ideal plant: :func:`nominal_jacobian`.  Otherwise the step of ``wmr.robots.plant`` (the
    input map in force at ``t_k``, slip, lag or dynamics from the actual velocities
    ``run.plant_velocity[k]``, the disturbance of the window) differentiated in the command by
    central differences (:data:`PLANT_FD_STEP`); with an input delay of ``d >= 1`` samples the
    command of step ``k`` does not reach the robot within the step, and the Jacobian is zero.
    ``run`` must hold a trajectory.
    """
    from wmr.closedloop import step as loop
    from wmr.robots import plant

    spec = scenario.plant
    if spec.ideal:
        return nominal_jacobian(scenario.integrator)
    if run.plant_velocity is None:
        raise ValueError("plant_jacobian needs a run with its trajectory (keep_trajectory=True)")
    table, at, ints, _, _ = plant.arrays(spec, scenario.dt)
    dist = np.array([(d.start, d.stop, *d.velocity) for d in scenario.disturbances],
                    dtype=float).reshape(-1, 4)  # fmt: skip
    h = PLANT_FD_STEP

    def true_jacobian(k: int, q: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray:
        J = np.zeros((3, 2))
        if spec.delay_steps > 0:
            return J
        for j in range(2):
            out = []
            for sign in (1.0, -1.0):
                ua = np.array(u, dtype=float)
                ua[j] += sign * h
                loop.disturb(k * dt, ua, dist)
                qn, vel, state = np.array(q, dtype=float), run.plant_velocity[k].copy(), ints.copy()
                plant.apply(k, dt, ua, qn, table, at, state, vel)
                out.append(qn)
            J[:, j] = (out[0] - out[1]) / (2 * h)
        return J

    return true_jacobian


@dataclass(frozen=True)
class JacobianQuality:
    """Per-step quality of the Jacobian a run used, for the steps ``k = 1 .. n-1``.

    Every field is an ndarray of shape (n - 1,).

    Attributes
    ----------
    t : ndarray
        ``t_k`` [s].
    rel_error : ndarray
        ``||J_NN - J||_F / ||J||_F`` (:func:`rel_error`); ``J_NN = 0`` scores 1.
    rel_error_v, rel_error_w : ndarray
        The same per column (the ``v`` and the ``w`` column).
    norm_ratio : ndarray
        ``||J_NN||_F / ||J||_F`` (inf where ``J = 0``): a scale error acts on the SGD step as
        a learning-rate factor.
    matrix_cosine : ndarray
        Cosine of ``J_NN`` and ``J`` as 6-vectors (the error up to scale).
    cosine : ndarray
        Cosine of the SGD directions ``g_NN`` and ``g`` (2,), ``g = J^T T_e(theta_hat_k)^T
        Gamma e_k`` (eq. 17); NaN where either is 0.
    sign_v, sign_w : ndarray
        1.0 where ``g_NN`` and ``g`` have the same sign in that channel, 0.0 where not, NaN
        where either is 0.  ``mu`` and the regressor ``phi`` are common to both Jacobians, so
        the channel's three gains move the same way exactly when the signs agree.
    """

    t: np.ndarray
    rel_error: np.ndarray
    rel_error_v: np.ndarray
    rel_error_w: np.ndarray
    norm_ratio: np.ndarray
    matrix_cosine: np.ndarray
    cosine: np.ndarray
    sign_v: np.ndarray
    sign_w: np.ndarray

    def as_dict(self) -> dict[str, np.ndarray]:
        """The series by name (``t`` and :data:`QUALITY_KEYS`)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def tail_mean(self, key: str, start: float = 0.5) -> float:
        """Mean of series ``key`` over its steps from the fraction ``start`` of the run on
        (``0.5``: the last half, ``0``: the whole run), NaN entries skipped."""
        x = getattr(self, key)
        return float(np.nanmean(x[int(len(x) * start) :]))

    def tail_means(self, start: float = 0.5) -> dict[str, float]:
        """:meth:`tail_mean` of every series of :data:`QUALITY_KEYS`: one run's summary."""
        return {key: self.tail_mean(key, start) for key in QUALITY_KEYS}


def jacobian_quality(run, true_jacobian: TrueJacobian | None = None, *,
                     integrator: str | int = "exact",
                     every: int = 1) -> JacobianQuality:  # fmt: skip
    """Compare the Jacobian ``J_{k-1}`` a run used at each step with the true plant Jacobian.

    At step ``k >= 1`` the controller logs ``J_{k-1}`` (``run.jacobian()[k]``; for
    ``iapid-nn-dekf`` it is ``dt dNN/d(v, w)`` at ``(u_{k-1}, theta_hat_{k-1})``).  The true
    Jacobian is ``true_jacobian(k - 1, q_hat_{k-1}, u_{k-1}, dt)``, at the estimate, where the
    identifier is evaluated.  The SGD step (eqs. 9-17, :func:`wmr.controllers.pid.sgd_gain_step`)
    moves gain ``i`` of channel ``c`` by ``mu_i g_c phi_i`` with
    ``g = J^T T_e(theta_hat_k)^T Gamma e_k`` (2,), ``e_k`` the tracking error of eq. (6) at
    ``q_hat_k`` and ``Gamma = diag(alpha)`` (the run's settings, its rotation included).

    Parameters
    ----------
    run : wmr.closedloop.result.RunResult
        A run with its trajectory, of a controller that logs its plant Jacobian (the PID family).
    true_jacobian : callable, optional
        ``(k, q, u, dt) -> (3, 2)`` (:data:`TrueJacobian`); default: :func:`nominal_jacobian`
        of ``integrator``.
    integrator : str or int
        The nominal plant's integrator (the scenario's), used only by the default.
    every : int
        Evaluate every ``every``-th step only (``k = 1, 1 + every, ...``): a cheaper estimate of
        the run's averages for large sweeps.

    Returns
    -------
    JacobianQuality
        The per-step series of the steps ``k = 1 .. n-1`` (every ``every``-th).
    """
    if true_jacobian is None:
        true_jacobian = nominal_jacobian(integrator)
    n = len(run.u)
    ks = np.arange(1, n, max(1, int(every)))
    J_l = run.jacobian()[ks]
    J_t = np.empty_like(J_l)
    g_l = np.empty((len(ks), 2))
    g_t = np.empty((len(ks), 2))
    alpha = np.asarray(run.settings.alpha, dtype=float)
    printed = bool(run.settings.printed_rotation)
    for i, k in enumerate(ks):
        J_t[i] = true_jacobian(k - 1, run.q_hat[k - 1], run.u[k - 1], run.dt)
        e = kin.tracking_error(run.q_hat[k], run.ref[k], printed)
        te = kin.rotation(run.q_hat[k, 2], printed).T @ (alpha * e)  # T_e^T Gamma e
        g_l[i] = J_l[i].T @ te
        g_t[i] = J_t[i].T @ te
    norm_l = np.linalg.norm(J_l, axis=(1, 2))
    norm_t = np.linalg.norm(J_t, axis=(1, 2))
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero true J: inf (or NaN if both)
        norm_ratio = norm_l / norm_t
    return JacobianQuality(
        t=run.t[ks],
        rel_error=rel_error(J_l, J_t),
        rel_error_v=rel_error(J_l[:, :, :1], J_t[:, :, :1]),
        rel_error_w=rel_error(J_l[:, :, 1:], J_t[:, :, 1:]),
        norm_ratio=norm_ratio,
        matrix_cosine=np.sum(J_l * J_t, axis=(1, 2)) / np.maximum(norm_l * norm_t, _TINY),
        cosine=_cosine(g_l, g_t),
        sign_v=_same_sign(g_l[:, 0], g_t[:, 0]),
        sign_w=_same_sign(g_l[:, 1], g_t[:, 1]),
    )


def _cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cosine of ``a`` and ``b`` (m, 2); NaN where either row is 0."""
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    ok = (na > 0) & (nb > 0)
    out = np.full(len(a), np.nan)
    out[ok] = np.sum(a[ok] * b[ok], axis=1) / (na[ok] * nb[ok])
    return out


def _same_sign(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """1.0 where ``a`` and ``b`` have the same sign, 0.0 where opposite, NaN where either is 0."""
    prod = a * b
    return np.where(prod == 0, np.nan, (prod > 0).astype(float))
