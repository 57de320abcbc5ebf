"""Floquet multipliers of the sampled closed loops linearised about a periodic reference orbit.

The frozen-time view (``wmr.linear.margins.margins_along_run``) relinearises the loop at each
``(v_r(t_k), w_r(t_k))`` as if it stayed there; on a reference whose curvature changes within
the slowest mode's time (~5 s here) it does not by itself say how the time-varying loop behaves.
This module linearises the loop **about the reference orbit** and follows it for one period.

Linearisation.  Along perfect tracking of a reference the per-step closed-loop Jacobian at
``t_k`` is ``A_k = dx_{k+1}/dx_k`` at ``e = 0`` with ``u_r = (v_r(t_k), w_r(t_k))``, by CasADi
AD of the whole nonlinear sampled loop: :func:`wmr.model.symbolic.pid_closed_loop_jacobian_function`
(the fixed PID of eq. 7, state ``(e1, e2, e3, I[e1], I[s], e1_prev, s_prev)``, 7) and
:func:`wmr.model.symbolic.backstepping_closed_loop_jacobian_function` (state ``e``, 3).  The PID's
is taken with feed-forward at ``x = 0``, whose orbit is the reference's; without feed-forward at
``x* = (0, 0, 0, v_r/Kiv, w_r/Kiw, 0, 0)`` it is the same matrix (``d(v_r cos e3)/de3 = 0`` at
``e3 = 0``), but the literal eq. 7 does not keep ``e = 0`` when ``u_r`` varies (its integrals
must move), so its orbit is only near this one.  Like every Jacobian of ``wmr.model.symbolic``, the
reference is moved over a step along its arc with ``u_r(t_k)`` held; the simulator moves it
along the analytic path, a difference of ``O(dt^2)`` per step that keeps the noise-free loop
0.1-1 mm (mrad) off ``e = 0``.

Floquet theory (discrete).  If ``A_{k+N} = A_k`` (the reference's ``(v_r, w_r)`` has period
``T = N dt``), the monodromy matrix ``Phi = A_{N-1} ... A_1 A_0`` maps a perturbation over one
period; its eigenvalues, the Floquet multipliers ``mu_i``, do not depend on the starting phase,
and the linearised time-varying loop is asymptotically stable iff every ``|mu_i| < 1``.
``|mu|^(1/N)`` is the average per-step rate of a mode (compare the frozen-time spectral radius
``max|eig(A_k)|``); ``-dt / ln |mu|^(1/N)`` its time constant.  For a constant ``(v_r, w_r)``
(a circle) ``Phi = A^N`` and ``mu = eig(A)^N``.

Periods: lemniscate and circle, their ``period``; sinusoid, ``2 pi / omega`` (``x_r = speed t``
is not periodic, but the error dynamics depend on ``(v_r, w_r)`` only, which are).  When
``T / dt`` is not a whole number (the sinusoid: 1256.6 steps) the orbit has
``N = round(T / dt)`` steps and ``Phi`` is the map over ``N dt`` from ``t_0``; the mismatch
``N dt - T`` is reported (:attr:`Orbit.mismatch`).

Accuracy.  The product of thousands of contracting, strongly non-normal matrices resolves only
the largest multipliers: each multiplier carries a first-order round-off bound, its condition
number times the error of ``Phi`` (the product's round-off, measured against an
extended-precision product, plus ``eig``'s backward error ``n eps |Phi|``)
(:attr:`Floquet.error_bound`).

All analysis-time numpy / CasADi; the simulator never calls this module.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from wmr import scenario as scn
from wmr.controllers import pid as pid_mod
from wmr.linear.loops import (
    BSC_GAINS,
    PID_GAINS,
    OperatingPoint,
    error_plant,
    slow_mode_error,
    start_state_map,
)
from wmr.model.kinematics import tracking_error
from wmr.model.references import ReferenceSampler

__all__ = [
    "CONTROLLERS",
    "HOW",
    "SIM_SIZE",
    "SIM_FLOOR",
    "SIM_TOL",
    "reference_period",
    "Orbit",
    "orbit",
    "step_jacobians",
    "monodromy",
    "Floquet",
    "floquet",
    "floquet_of",
    "perturbed_scenario",
    "simulator_check",
    "summary",
    "analyse",
    "circle_check",
]

#: The loops analysed: the fixed PID of eq. (7) and backstepping, with their default gains.
CONTROLLERS = ("pid", "backstepping")
#: How the loops are linearised (for records).
HOW = ("closed loop linearised about the periodic reference orbit (e = 0 at the reference's "
       "(v_r(t_k), w_r(t_k)), every step of one period; CasADi AD of the sampled nonlinear "
       "loop), default gains of the fixed PID (eq. 7) and of backstepping, the PID's Jacobian "
       "identical with and without feed-forward; "
       "monodromy = product of the per-step Jacobians over one period, multipliers = its "
       "eigenvalues (stable iff all |mu| < 1); average_rate = |mu_1|^(1/N) per step")
#: Size [m, m, rad] of the initial error of :func:`simulator_check`: small enough that the
#: loop's quadratic terms are ~1e-4 of the linear ones.
SIM_SIZE = 1e-4
#: Smallest perturbation after one period [m, rad] the simulator check can resolve: the poses
#: (O(1) m) of the two runs carry round-off of ~1e-16 per step, ~1e-14 after thousands of
#: steps; below 1e-13 the difference of the runs is not the perturbation.
SIM_FLOOR = 1e-13
#: Largest relative error of the simulated slowest multiplier.  The Jacobians are taken on
#: ``e = 0``; the noise-free loop runs 0.1-0.9 mm (mrad) off it (the reference's O(dt^2)
#: arc-vs-path difference per step), which changes each step's Jacobian by ~1e-4..1e-3
#: relative, and the 1e-4 start adds nonlinear terms of ~1e-4 relative; over a period they move
#: ``ln mu_1`` (-2.5 .. -25 here) by up to ~1e-3 of itself.  Measured: 1e-6 (PID), 1e-3
#: (backstepping, 0.6 mm off the orbit); 1e-2 leaves a factor ~10.
SIM_TOL = 1e-2


def reference_period(kind: str, params: Mapping[str, float]) -> float:
    """The period [s] of the reference's ``(v_r, w_r)``: ``period`` of a lemniscate or circle,
    ``2 pi / omega`` of a sinusoid; ValueError for a kind that is not periodic (waypoints)."""
    if kind in ("lemniscate", "circle"):
        return float(params["period"])
    if kind == "sinusoid":
        return 2.0 * math.pi / float(params["omega"])
    raise ValueError(f"reference kind {kind!r} is not periodic (lemniscate, circle, sinusoid)")


@dataclass(frozen=True)
class Orbit:
    """One period of a periodic reference sampled every ``dt`` [s] from step ``start``.

    ``kind``, ``params`` as in a scenario's ``[reference]``; ``integrator`` the robot's step
    (``"exact"``, ``"euler"``, ``"rk4"``); ``start`` the first step (``t_0 = start dt``).
    """

    kind: str
    params: Mapping[str, float]
    dt: float
    integrator: str = "exact"
    start: int = 0

    @property
    def period(self) -> float:
        """``T`` [s] (:func:`reference_period`)."""
        return reference_period(self.kind, self.params)

    @property
    def n_steps(self) -> int:
        """``N = round(T / dt)``."""
        return round(self.period / self.dt)

    @property
    def mismatch(self) -> float:
        """``N dt - T`` [s]: 0 when the period is a whole number of steps."""
        return self.n_steps * self.dt - self.period

    def samples(self) -> np.ndarray:
        """The reference rows ``(x_r, y_r, theta_r, v_r, w_r)`` at ``t_k = (start + k) dt``,
        ``k = 0 .. N``, shape (N + 1, 5)."""
        sampler = ReferenceSampler(self.kind, self.params, self.dt)
        if self.start:
            sampler.rows(0, self.start)
        return sampler.rows(self.start, self.start + self.n_steps + 1)


def orbit(sc: scn.Scenario, start: int = 0) -> Orbit:
    """The periodic orbit of scenario ``sc``'s reference (its ``dt`` and integrator).

    The Jacobians model the paper's robot: a scenario with a non-ideal ``[plant]`` is refused
    (ValueError), as is a reference that is not periodic.
    """
    if not sc.plant.ideal:
        raise ValueError(f"scenario {sc.name!r}: Floquet analysis models the ideal plant only")
    reference_period(sc.reference.kind, sc.reference.params)
    return Orbit(sc.reference.kind, dict(sc.reference.params), sc.dt, sc.integrator, start)


def step_jacobians(controller: str, u_r: np.ndarray, dt: float, integrator: str = "exact",
                   gains=None) -> np.ndarray:  # fmt: skip
    """The closed loop's Jacobians ``A_k`` at ``e = 0`` along a reference, by CasADi AD.

    Parameters
    ----------
    controller : {"pid", "backstepping"}
        The fixed PID of eq. (7) with feed-forward (state 7, at ``x = 0``) or backstepping
        (state 3).
    u_r : ndarray, shape (N, 2)
        ``(v_r, w_r)`` [m/s, rad/s] at each step.
    dt : float
        Sample period [s].
    integrator : str
        The robot's step.
    gains : sequence of float, optional
        ``(Kpv, Kiv, Kdv, Kpw, Kiw, Kdw)`` or ``(k1, k2, k3)``; the defaults otherwise.

    Returns
    -------
    ndarray, shape (N, n, n)
        ``A_k = dx_{k+1}/dx_k`` (``n`` = 7 or 3).
    """
    from wmr.model import symbolic as sym  # on use: importing wmr never loads CasADi

    u_r = np.asarray(u_r, dtype=float).reshape(-1, 2)
    if controller == "pid":
        f, n = sym.pid_closed_loop_jacobian_function(integrator, feed_forward=True), 7
        gains = PID_GAINS if gains is None else gains
    elif controller == "backstepping":
        f, n = sym.backstepping_closed_loop_jacobian_function(integrator), 3
        gains = BSC_GAINS if gains is None else gains
    else:
        raise ValueError(f"controller must be 'pid' or 'backstepping', got {controller!r}")
    N = u_r.shape[0]
    # one call of the mapped function: the outputs side by side, (n, N n)
    A = np.asarray(f.map(N)(np.zeros(n), u_r.T, np.asarray(gains, dtype=float), dt))
    return np.ascontiguousarray(A.reshape(n, N, n).transpose(1, 0, 2))


def monodromy(jacobians: np.ndarray, dtype=float) -> np.ndarray:
    """``Phi = A_{N-1} ... A_1 A_0`` (later steps on the left) of ``jacobians`` (N, n, n),
    accumulated in ``dtype`` (``numpy.longdouble`` for the extended-precision reference)."""
    Phi = np.eye(jacobians.shape[1], dtype=dtype)
    for A in jacobians.astype(dtype, copy=False):
        Phi = A @ Phi
    return Phi


@dataclass(frozen=True)
class Floquet:
    """The Floquet analysis of one loop over one period.

    Attributes
    ----------
    multipliers : ndarray, shape (n,), complex
        Eigenvalues of :attr:`monodromy`, largest modulus first.
    error_bound : ndarray, shape (n,)
        First-order round-off bound of each multiplier: condition number ``1/|w^H v|`` (unit
        left and right eigenvectors) times ``|Phi - Phi_ext|_2 + n eps |Phi|_2``.
    right, left : ndarray, shape (n, n), complex
        Right eigenvectors (columns, unit) and left eigenvectors (rows ``w^H`` scaled so that
        ``w^H v = 1``) in the order of :attr:`multipliers`.
    monodromy : ndarray, shape (n, n)
    frozen_rho : ndarray, shape (N,)
        ``max|eig(A_k)|`` of each step's Jacobian (the frozen-time spectral radius).
    n_steps : int
        ``N``.
    """

    multipliers: np.ndarray
    error_bound: np.ndarray
    right: np.ndarray
    left: np.ndarray
    monodromy: np.ndarray
    frozen_rho: np.ndarray
    n_steps: int

    @property
    def moduli(self) -> np.ndarray:
        """``|mu_i|``, largest first, shape (n,)."""
        return np.abs(self.multipliers)

    @property
    def resolved(self) -> np.ndarray:
        """Multipliers whose modulus exceeds 1000 times its round-off bound (known to better
        than 1e-3 relative), shape (n,) of bool."""
        return self.moduli > 1e3 * self.error_bound

    @property
    def stable(self) -> bool:
        """All multipliers inside the unit circle: the loop about the orbit is asymptotically
        stable."""
        return bool(self.moduli[0] < 1.0)

    @property
    def average_rate(self) -> float:
        """``|mu_1|^(1/N)``: the slowest mode's average per-step rate."""
        return float(self.moduli[0] ** (1.0 / self.n_steps))


def floquet_of(jacobians: np.ndarray) -> Floquet:
    """The Floquet analysis of a periodic sequence of Jacobians ``A_0 .. A_{N-1}`` (N, n, n)."""
    J = np.asarray(jacobians, dtype=float)
    n = J.shape[1]
    Phi = monodromy(J)
    err = float(np.linalg.norm((Phi - monodromy(J, np.longdouble)).astype(float), 2))
    err += n * np.finfo(float).eps * float(np.linalg.norm(Phi, 2))
    mu, wl, vr = scipy.linalg.eig(Phi, left=True, right=True)
    order = np.argsort(-np.abs(mu), kind="stable")
    mu, wl, vr = mu[order], wl[:, order], vr[:, order]
    dots = np.einsum("ij,ij->j", wl.conj(), vr)  # w_i^H v_i, unit vectors
    with np.errstate(divide="ignore"):
        cond = 1.0 / np.abs(dots)
    left = wl.conj().T / dots[:, None]  # rows w_i^H with w_i^H v_i = 1
    frozen = np.max(np.abs(np.linalg.eigvals(J)), axis=1)
    return Floquet(mu, cond * err, vr, left, Phi, frozen, J.shape[0])


def floquet(controller: str, orb: Orbit, gains=None) -> Floquet:
    """The Floquet multipliers of ``controller``'s loop (:data:`CONTROLLERS`) about ``orb``."""
    ref = orb.samples()
    return floquet_of(step_jacobians(controller, ref[:-1, 3:5], orb.dt, orb.integrator, gains))


def perturbed_scenario(sc: scn.Scenario, e0, periods: int = 1) -> scn.Scenario:
    """``sc`` without noise or disturbance, every controller on the raw (here exact) pose,
    ``periods`` periods long, started at the corrected error ``e0`` (3,) [m, m, rad] from its
    reference at ``t = 0`` (eq. 6 inverted): the loop the linearisation describes."""
    orb = orbit(sc)
    r0 = orb.samples()[0]
    e0 = np.asarray(e0, dtype=float)
    th = r0[2] - e0[2]
    c, s = math.cos(th), math.sin(th)
    q0 = (r0[0] - (c * e0[0] - s * e0[1]), r0[1] - (s * e0[0] + c * e0[1]), th)
    return dataclasses.replace(sc, name=f"{sc.name}-floquet", initial_pose=q0,
                               duration=periods * orb.n_steps * sc.dt, noise=scn.Noise(),
                               disturbances=(),
                               estimator=scn.Estimator(pose_source="raw"))  # fmt: skip


def simulator_check(sc: scn.Scenario, controller: str, result: Floquet | None = None,
                    size: float = SIM_SIZE) -> dict:  # fmt: skip
    """The slowest multiplier against the nonlinear loop (``wmr.closedloop.sim.simulate``).

    Two noise-free runs of one period (:func:`perturbed_scenario`): on the reference (``e0 =
    0``) and started at an error of norm ``size`` along the slowest Floquet mode
    (``wmr.linear.loops.slow_mode_error`` on ``Phi``: the next mode cancelled; the PID, with
    feed-forward so that its orbit is the reference's, starts with zero integrals,
    ``x_0 = M e0``, ``wmr.linear.loops.start_state_map``).  Their difference ``dx`` is the
    perturbation; its coordinate on the slowest mode, ``w_1^H dx``, is multiplied by ``mu_1``
    over the period in the linearised loop, whatever the other modes do.

    Returns ``{"controller", "mu_1" [re, im], "modal_ratio" [re, im]`` (simulated ``w_1^H dx_N /
    w_1^H dx_0``), ``"modal_ratio_rel_error"``, ``"prediction_rel_error"`` (``|dx_N - Phi dx_0|
    / |Phi dx_0|``), ``"perturbation_after_period"`` (``|dx_N|``), ``"nominal_max_error"``
    (largest ``|e|`` entry of the unperturbed run: its distance from the orbit)``}``.
    """
    from wmr.closedloop.sim import (
        simulate,  # on use: the study imports this module without running loops
    )

    orb = orbit(sc)
    fl = floquet(controller, orb) if result is None else result
    r0 = orb.samples()[0]
    M = start_state_map(controller, error_plant(OperatingPoint(r0[3], r0[4], sc.dt,
                                                               sc.integrator)))  # fmt: skip
    e0 = slow_mode_error(fl.monodromy, M, size)
    settings = pid_mod.FixedSettings(feed_forward=True) if controller == "pid" else None
    runs = [simulate(perturbed_scenario(sc, e), controller, seed=0, settings=settings)
            for e in (np.zeros(3), e0)]  # fmt: skip
    dx0, dxN = M @ e0, _loop_state(runs[1], controller) - _loop_state(runs[0], controller)
    ratio = (fl.left[0] @ dxN) / (fl.left[0] @ dx0)
    pred = fl.monodromy @ dx0
    nominal = np.array([tracking_error(q, r, False) for q, r in zip(runs[0].q, runs[0].ref,
                                                                     strict=True)])  # fmt: skip
    mu = fl.multipliers[0]
    return {"controller": controller, "e0": [float(x) for x in e0],
            "mu_1": [float(mu.real), float(mu.imag)],
            "modal_ratio": [float(ratio.real), float(ratio.imag)],
            "modal_ratio_rel_error": float(abs(ratio - mu) / abs(mu)),
            "prediction_rel_error": float(np.linalg.norm(dxN - pred) / np.linalg.norm(pred)),
            "perturbation_after_period": float(np.linalg.norm(dxN)),
            "nominal_max_error": float(np.max(np.abs(nominal))),
            "diverged": bool(runs[0].diverged or runs[1].diverged)}  # fmt: skip


def summary(fl: Floquet, dt: float, shown: int = 3) -> dict:
    """JSON-able summary of ``fl`` (sample period ``dt`` [s]).

    ``moduli`` and ``moduli_error_bound``: the ``shown`` largest ``|mu_i|`` and their round-off
    bounds (a modulus below its bound is not resolved); ``n_multipliers``; ``stable``;
    ``average_rate`` ``|mu_1|^(1/N)`` and ``time_constant_s`` ``-dt / ln(average_rate)``; the
    frozen-time spectral radius along the orbit: ``frozen_rho_min``, ``frozen_rho_max`` and
    ``frozen_rho_geometric_mean`` (``exp(mean ln rho_k)``: the per-step rate a frozen-time view
    would predict for the period).
    """
    rate = fl.average_rate
    return {"moduli": [float(x) for x in fl.moduli[:shown]],
            "moduli_error_bound": [float(x) for x in fl.error_bound[:shown]],
            "n_multipliers": int(fl.moduli.size), "stable": fl.stable,
            "average_rate": rate,
            "time_constant_s": -dt / math.log(rate) if 0 < rate < 1 else None,
            "frozen_rho_min": float(fl.frozen_rho.min()),
            "frozen_rho_max": float(fl.frozen_rho.max()),
            "frozen_rho_geometric_mean": float(np.exp(np.mean(np.log(fl.frozen_rho))))}  # fmt: skip


def analyse(sc: scn.Scenario, controllers=CONTROLLERS, shown: int = 3) -> dict:
    """The Floquet analysis of ``controllers`` about scenario ``sc``'s periodic reference.

    Returns ``{"period_s", "steps", "period_mismatch_s", <controller>: ...}``, each controller's
    entry :func:`summary` plus ``frozen_period_prediction`` (the geometric-mean frozen-time
    radius to the power ``N``, to set beside ``moduli[0]``), ``phase_shift_rel_diff`` (relative
    change of the ``shown`` largest moduli when the period starts at step ``N // 2`` instead of
    0: round-off for a whole-step period, else the effect of ``period_mismatch_s``) and
    ``simulated`` (:func:`simulator_check`, or ``{"skipped": reason}`` when
    ``|mu_1| SIM_SIZE`` is below :data:`SIM_FLOOR`).
    """
    orb = orbit(sc)
    out: dict = {"period_s": orb.period, "steps": orb.n_steps, "period_mismatch_s": orb.mismatch}
    for c in controllers:
        fl = floquet(c, orb)
        rec = summary(fl, sc.dt, shown)
        rec["frozen_period_prediction"] = rec["frozen_rho_geometric_mean"] ** orb.n_steps
        half = floquet(c, dataclasses.replace(orb, start=orb.n_steps // 2))
        k = min(shown, int(np.sum(fl.resolved)))
        rec["phase_shift_rel_diff"] = float(np.max(np.abs(half.moduli[:k] / fl.moduli[:k] - 1)))
        after = fl.moduli[0] * SIM_SIZE
        rec["simulated"] = (simulator_check(sc, c, fl) if after > SIM_FLOOR else {
            "skipped": f"|mu_1| x {SIM_SIZE:g} = {after:.2g} is below the simulator's "
                       f"resolution ({SIM_FLOOR:g})"})  # fmt: skip
        out[c] = rec
    return out


def circle_check(op: OperatingPoint, controllers=CONTROLLERS) -> dict:
    """The closed form for a circle, the constant ``(v_r, |w_r|)`` of ``op`` (``w_r != 0``; the
    loop at ``-w_r`` is its mirror image, ``wmr.linear.loops.constant_reference_scenario``): ``Phi =
    A^N`` and ``mu = eig(A)^N``, ``A`` the closed loop at ``op`` built independently by
    python-control (``wmr.linear.loops.pid_loops`` / ``backstepping_loops``,
    :func:`wmr.linear.loops.closed_loop_matrix`); ``N`` the steps of one turn, ``op``'s ``dt``.

    Returns ``{"v_r", "w_r", "steps", <controller>: {"monodromy_rel_diff" (max entry of
    ``|Phi - A^N|`` over that of ``A^N``), "multipliers_rel_diff" (largest relative distance
    from a resolved multiplier, :attr:`Floquet.resolved`, to the nearest ``eig(A)^N``),
    "multipliers_compared"}}``.
    """
    from wmr.linear.loops import backstepping_loops, closed_loop_matrix, pid_loops

    v_r, w_r = op.v_r, abs(op.w_r)
    orb = Orbit("circle", {"radius": v_r / w_r, "period": 2 * math.pi / w_r}, op.dt, op.integrator)
    op = OperatingPoint(v_r, w_r, op.dt, op.integrator)
    N = orb.n_steps
    out: dict = {"v_r": v_r, "w_r": w_r, "steps": N}
    for c in controllers:
        A = closed_loop_matrix((pid_loops if c == "pid" else backstepping_loops)(op)["v"])
        AN = np.linalg.matrix_power(A, N)
        fl = floquet(c, orb)
        lam = np.linalg.eigvals(A) ** N
        mu = fl.multipliers[fl.resolved]
        out[c] = {"monodromy_rel_diff": float(np.abs(fl.monodromy - AN).max() / np.abs(AN).max()),
                  "multipliers_rel_diff": float(max(np.min(np.abs(m - lam)) / abs(m) for m in mu)),
                  "multipliers_compared": int(mu.size)}  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------
# Private helpers
# ---------------------------------------------------------------------------------------------


def _loop_state(run, controller: str) -> np.ndarray:
    """The closed-loop state of the linearisation at the run's last instant ``N``: the
    corrected error ``e_N`` and, for the PID, the integrals after step ``N - 1`` and that step's
    signals ``e1``, ``s = e3 + e2`` (noise-free: the controller's error is the true one)."""
    e = tracking_error(run.q[-1], run.ref[-1], False)
    if controller != "pid":
        return e
    ep = tracking_error(run.q[-2], run.ref[-2], False)
    return np.concatenate((e, run.final.integrals, (ep[0], ep[2] + ep[1])))
