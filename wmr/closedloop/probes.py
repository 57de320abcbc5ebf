"""Per-step probes of a closed-loop run: the weight filter and the pose filter's consistency.

A probe is passed to ``wmr.closedloop.sim.simulate(scenario, controller, seed, probe=...)``: the run
goes through the loop's Python driver (``wmr.closedloop.step.python_step``, bit-identical to the
compiled kernel) and calls the probe's hooks ``after_estimate(k, q, q_hat, Pq, nis)``,
``before_law(k, p, s, theta, P, q_hat)`` and ``after_law(k, p, s, theta, P, q_hat, u)``.  The probes
here only read what the hooks hand them (by name: ``p.H``, ``p.q_diag``, ``p.R``, ``p.nn_n_h`` of
the iapid-nn-dekf parameters) and what they saw at the previous step; the law's own logged numbers
(``nn_error``, ``cov_repairs``) are read afterwards from the run's record (``RunResult.signal``,
``.final``).

- :class:`WeightProbe` reads the weight DEKF of ``iapid-nn-dekf`` (eqs. 25-31; §3.4.1-3.4.2 and
  errata E10): ``||H_k||``, the prior and posterior covariance's extreme eigenvalues, the achieved
  contraction of inequality (48) (``wmr.estimation.stability``), the filter's NIS, Theorem 1's noise
  term and the network's prediction error against the true pose increment;
- :class:`PoseProbe` reads the pose EKF (errata E9): NEES of the posterior and NIS of each
  update, and whether the weight covariance stays positive definite;
- :func:`identifier_pair` gives the identifier's training pair of a step (its input and target);
- :func:`target_noise` splits the identifier's targets along a run into the true velocity and
  the noise the pose estimate adds to it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from wmr.closedloop.result import RunResult
from wmr.controllers.iapid_nn_dekf import identifier_input
from wmr.estimation import nn
from wmr.estimation import stability as stab
from wmr.estimation.ekf import nees
from wmr.model.kinematics import wrap_angle

__all__ = ["identifier_pair", "target_noise", "WeightProbe", "PoseProbe", "identical_runs"]


def identifier_pair(u_prev: np.ndarray, q_hat_prev: np.ndarray, q_hat: np.ndarray,
                    dt: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """The weight filter's training pair at step ``k`` (errata E6, E8).

    Parameters
    ----------
    u_prev : ndarray, shape (2,)
        The input ``u_{k-1} = (v, w)`` [m/s, rad/s] the plant received at the previous step.
    q_hat_prev, q_hat : ndarray, shape (3,)
        The pose estimates ``q_hat_{k-1}``, ``q_hat_k`` [m, m, rad] the controller acted on.
    dt : float
        Sample period [s].

    Returns
    -------
    x : ndarray, shape (4,)
        The identifier's input ``(v_{k-1}, w_{k-1}, cos theta_{k-1}, sin theta_{k-1})``.
    d : ndarray, shape (3,)
        Its target, the observed increment ``(q_hat_k - q_hat_{k-1}) / dt``, heading difference
        wrapped to (-pi, pi]; the innovation of eq. (30) is ``d - NN(theta_{k|k-1}, x)``.
    """
    x = identifier_input(u_prev, q_hat_prev[2])
    d = np.empty(3)
    for i in range(2):
        d[i] = (q_hat[i] - q_hat_prev[i]) / dt
    d[2] = wrap_angle(q_hat[2] - q_hat_prev[2]) / dt
    return x, d


def target_noise(q: np.ndarray, q_hat: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The identifier's targets along a run, split into signal and noise.

    The target of the weight filter's update at step ``k`` is ``d_k = (q_hat_k - q_hat_{k-1})/dt``
    (:func:`identifier_pair`); what it should be is the true pose increment
    ``s_k = (q_k - q_{k-1})/dt`` (headings wrapped).  The difference
    ``v_k = d_k - s_k = ((q_hat_k - q_k) - (q_hat_{k-1} - q_{k-1}))/dt`` is the measurement noise
    of the filter's measurement equation ``d_k = f(x_{k-1}) + v_k``: the pose estimate's error,
    differenced and divided by ``dt``.

    Parameters
    ----------
    q : ndarray, shape (M', 3), M' >= M
        True poses [m, m, rad], rows ``t_0, t_1, ...`` (a run's ``q`` has one row more than its
        ``q_hat``: the pose after the last step); the first ``M`` rows are used.
    q_hat : ndarray, shape (M, 3)
        The estimates the controller acted on, rows ``t_0 .. t_{M-1}``.
    dt : float
        Sample period [s].

    Returns
    -------
    noise, signal : ndarray, shape (M - 1, 3)
        ``v_k`` and ``s_k`` for ``k = 1 .. M - 1`` [m/s, m/s, rad/s] (row ``i`` is step
        ``k = i + 1``: the filter updates of the run).
    """
    q_hat = np.asarray(q_hat, dtype=float)
    q = np.asarray(q, dtype=float)[: len(q_hat)]
    signal = np.diff(q, axis=0) / dt
    signal[:, 2] = _wrap(np.diff(q[:, 2])) / dt
    target = np.diff(q_hat, axis=0) / dt
    target[:, 2] = _wrap(np.diff(q_hat[:, 2])) / dt
    return target - signal, signal


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles [rad] wrapped to [-pi, pi] elementwise (``wrap_angle`` is scalar)."""
    return np.arctan2(np.sin(a), np.cos(a))


def identical_runs(a: RunResult, b: RunResult) -> bool:
    """Whether two runs are the same bit for bit: how they ended, their RMSE, every logged signal
    (poses, reference, estimates, inputs, controller state), the final controller state field by
    field and the pose filter's final estimate and covariance (NaN equals NaN)."""
    if (a.diverged, a.diverged_at, a.cause) != (b.diverged, b.diverged_at, b.cause):
        return False
    if type(a.final) is not type(b.final):
        return False
    pairs = [(list(a.rmse.values()), list(b.rmse.values())),
             (a.pose_estimate, b.pose_estimate), (a.pose_covariance, b.pose_covariance)]
    pairs += [(getattr(a, f), getattr(b, f)) for f in ("t", "q", "ref", "q_hat", "u", "state")]
    if a.final is not None:
        pairs += [(getattr(a.final, f.name), getattr(b.final, f.name))
                  for f in dataclasses.fields(a.final)]
    return all(_same(x, y) for x, y in pairs)  # fmt: skip


class WeightProbe:
    """Reads the weight filter of ``iapid-nn-dekf`` around each ``law`` call.

    Per filter update (every step but the first: the law identifies from the second step on,
    once a transition has been seen) it records, in arrays ``a[field]`` of length ``n_steps``
    (NaN where not computed): ``norm_H = ||H_k||_2``; the innovation norm and the filter's NIS
    ``nu^T (H P_{k|k-1} H^T + R)^-1 nu``; ``spd`` (Cholesky of ``P_{k|k}`` succeeds: 1); the
    network's prediction error after the update against the true increment (``pred_error``);
    ``trace = tr P_{k|k}`` at every step.  Every ``every`` steps also the O(n^3) ones: extreme
    eigenvalues of the prior ``P_{k|k-1} = P + Q`` (eq. 28, ``A = I``) and of the posterior; the
    achieved contraction ``alpha_k`` of (48) and ``||M_k||``
    (``wmr.estimation.stability.kalman_contraction``);
    ``direct_gap = 1 - lambda_k`` from the stored ``P_{k|k}`` (``contraction_direct``); Theorem 1's
    ``mu_k`` (``wmr.estimation.stability.noise_term``) and its parts ``mu_q = tr(Pi_{k+1} Q)`` and
    ``ktpik[k] = K^T Pi_{k+1} K`` (3, 3) (``wmr.estimation.stability.noise_term_parts``), from which
    ``mu_k`` follows for any measurement-noise covariance. ``theta[k]`` holds the weights after the
    law at ``k``; ``nu[k]`` the innovation vector (3,).

    The identifier's innovation is rebuilt from what the probe saw at the previous step
    (:func:`identifier_pair`); the law's own norm of it is its logged signal ``nn_error``, to
    compare with ``a["innovation"]`` after the run.

    Parameters
    ----------
    n_steps : int
        Steps of the run (the arrays' length).
    n_weights : int
        Length ``n`` of the flat weight vector ``theta``.
    dt : float
        Sample period [s].
    every : int
        Compute the O(n^3) quantities every ``every`` steps (all steps with 1).
    """

    FIELDS = ("norm_H", "lmin_prior", "lmax_prior", "lmin_post", "lmax_post", "alpha_k", "norm_M",
              "direct_gap", "nis", "innovation", "mu", "pred_error", "spd", "trace",
              "mu_q")  # fmt: skip

    def __init__(self, n_steps: int, n_weights: int, dt: float, every: int = 1):
        self.every = max(1, int(every))
        self.dt = dt
        self.a = {f: np.full(n_steps, np.nan) for f in self.FIELDS}
        self.theta = np.full((n_steps, n_weights), np.nan)
        self.q_true = np.full((n_steps, 3), np.nan)
        self.nu = np.full((n_steps, 3), np.nan)  # the innovation vectors
        self.ktpik = np.full((n_steps, 3, 3), np.nan)  # K^T Pi_{k+1} K (noise_term_parts)
        self._previous = None  # (u_{k-1}, q_hat_{k-1}) as the law remembered them
        self._active = False

    def after_estimate(self, k, q, q_hat, Pq, nis):
        self.q_true[k] = q

    def before_law(self, k, p, s, theta, P, q_hat):
        self._active = self._previous is not None
        if not self._active:
            return
        self._x, d = identifier_pair(*self._previous, q_hat, self.dt)
        z, _ = nn.forward(theta, self._x, p.nn_n_h, p.H.shape[0])  # H: (outputs, weights)
        self._nu = d - z
        self._P_prior = P + np.diag(p.q_diag)  # eq. (28) with A = I

    def after_law(self, k, p, s, theta, P, q_hat, u):
        self.theta[k] = theta
        self.a["trace"][k] = np.trace(P)
        self._previous = (u.copy(), q_hat.copy())
        if self._active:
            self._every_update(k, p, theta, P)
            if k % self.every == 0:
                self._instrumented(k, p, P)

    def _every_update(self, k, p, theta, P):
        """The cheap quantities, at every filter update."""
        a = self.a
        self._H = H = p.H.copy()  # H_k: weight Jacobian at theta_{k|k-1} (scratch of the law)
        a["norm_H"][k] = np.linalg.norm(H, 2)
        nu = self._nu
        self.nu[k] = nu
        a["innovation"][k] = math.sqrt(nu @ nu)
        S = H @ self._P_prior @ H.T + p.R
        a["nis"][k] = nu @ np.linalg.solve(S, nu)
        try:
            np.linalg.cholesky(P)
            a["spd"][k] = 1.0
        except np.linalg.LinAlgError:
            a["spd"][k] = 0.0
        # function-space error: prediction at x_{k-1} after the update vs the true increment
        z, _ = nn.forward(theta, self._x, p.nn_n_h, H.shape[0])
        dq = (self.q_true[k] - self.q_true[k - 1]) / self.dt
        dq[2] = wrap_angle(self.q_true[k, 2] - self.q_true[k - 1, 2]) / self.dt
        a["pred_error"][k] = np.linalg.norm(z - dq)

    def _instrumented(self, k, p, P):
        """The O(n^3) quantities of Assumption 1, (48) and Theorem 1 at step ``k``."""
        a, H, R, Pp = self.a, self._H, p.R, self._P_prior
        Q = np.diag(p.q_diag)
        lp = np.linalg.eigvalsh(Pp)
        a["lmin_prior"][k], a["lmax_prior"][k] = lp[0], lp[-1]
        P_post = 0.5 * (P + P.T)
        lq = np.linalg.eigvalsh(P_post)
        a["lmin_post"][k], a["lmax_post"][k] = lq[0], lq[-1]
        c = stab.kalman_contraction(Pp, H, R, Q)
        a["alpha_k"][k] = c["alpha"]
        a["norm_M"][k] = c["norm_M"]
        K = c["K"]
        M = np.eye(Pp.shape[0]) - K @ H
        P_next = P_post + Q  # the filter's own next prior, eq. (28) at k + 1
        a["direct_gap"][k] = 1.0 - stab.contraction_direct(M, Pp, P_next)
        a["mu"][k] = stab.noise_term(P_next, K, p.q_diag, R)
        a["mu_q"][k], self.ktpik[k] = stab.noise_term_parts(P_next, K, p.q_diag)


class PoseProbe:
    """Pose-filter consistency at every step, and whether the weight covariance stays SPD.

    ``n_steps``: steps of the run (the arrays' length).

    ``nees[k]``: NEES of the posterior at ``t_k`` against the true pose (``k = 0``: the first
    estimate is the measurement and ``P = R``); ``nis[k]``: NIS of the pose update at ``t_k``
    (NaN at ``k = 0``); ``spd_failures``: steps after which the controller's weight covariance
    ``P`` (if it has one) fails a Cholesky factorisation.
    """

    def __init__(self, n_steps: int):
        self.nees = np.full(n_steps, np.nan)
        self.nis = np.full(n_steps, np.nan)
        self.spd_failures = 0

    def after_estimate(self, k, q, q_hat, Pq, nis):
        self.nees[k] = nees(q, q_hat, Pq)
        self.nis[k] = nis

    def after_law(self, k, p, s, theta, P, q_hat, u):
        if P.size:
            try:
                np.linalg.cholesky(P)
            except np.linalg.LinAlgError:
                self.spd_failures += 1


def _same(x, y) -> bool:
    """Bit-for-bit equality of two arrays or numbers (NaN equals NaN; None only equals None)."""
    if x is None or y is None:
        return x is None and y is None
    return bool(np.array_equal(np.asarray(x, dtype=float), np.asarray(y, dtype=float),
                               equal_nan=True))  # fmt: skip
