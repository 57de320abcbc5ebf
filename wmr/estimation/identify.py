"""``wmr identify``: the kinematic ``[plant]`` of DESIGN §3.3 fitted to a robot's log.

The log: a CSV with a header and one row per control step ``t_k`` -- ``t`` [s] (strictly
increasing, constant step ``dt``: the delay is in steps), ``v, w`` [m/s, rad/s] the saturated
command sent at ``t_k``, ``x_meas, y_meas, theta_meas`` [m, m, rad] the *measured* pose
``z_k = q_k + n_k`` (heading wrapped or not), optionally ``dv, dw`` the disturbance in force,
added to the delayed command before the plant (0 if absent).  Other columns -- ``wmr run``'s true
pose ``x, y, theta`` among them, which a real robot's log lacks -- are ignored; trailing rows with
empty per-step cells (``wmr run``'s last instant) are dropped.  The robot is at rest at the first
row with no command in its delay line (§3.3; what ``wmr run`` logs).

The model is ``wmr.robots.plant`` itself: :func:`replay` drives the loop's own plant half
(``wmr.closedloop.step.plant_half``: ``wmr.robots.plant.delayed``, the disturbance,
``wmr.robots.plant.apply``) with the logged commands (``PARAMETERS`` and ``delay_steps``; slip as
the plant defines it, §3.3: ``v_s = -slip v w``, signed, positive outward).  **Output error**: the
residual is the measured pose minus the simulated one (heading wrapped), each channel divided by its
noise level from second differences of the measured pose (``var(Δ²z) = 6 σ²``), minimised by
``scipy.optimize.least_squares`` (Levenberg-Marquardt) over the continuous parameters; the delay
by search over ``0 .. max_delay``.  Equation error on differenced poses would be biased, its
intervals wrong (the noise on increments is MA(1) and sits in the regressors).  With white
measurement noise the simulated pose at ``t_k`` depends on commands before ``t_k`` only, so the
fit stays consistent on closed-loop logs, whose commands depend on past noise.

Drift: **multiple shooting**.  The log is cut into segments of ``segment`` seconds (default
:data:`SEGMENT_SECONDS`), each restarted from its own initial pose, fitted with the rest; the lag
state and the delay line run on across the cuts (the commands fix them).  An open-loop
simulation of a plant the model does not quite contain (the MuJoCo robot) drifts from the
measured path over a long log; a cut bounds the drift to one segment, at the price of precision
(a gain error shows as a drift growing with the segment's length).  On a 40 s closed-loop log of
an exact model the intervals of 10 s segments are 1.0-3.6x those of one 40 s shot, of 5 s
segments 1.1-8.8x.  From the nominal plant a long shot can end in a local minimum (one 40 s shot:
s^2 = 7369), so every fit starts from a fit over :data:`WARM_SECONDS` segments.

Intervals: Gauss-Newton, ``cov = s^2 (J^T J)^-1`` with ``J`` the Jacobian of the weighted
residuals at the optimum (central differences of :func:`replay`) and ``s^2`` the weighted
residual variance (1: the model explains the log down to its noise; above 1 the residuals are
not white and the intervals too narrow); 95 % intervals ``+-1.96 se``, conditional on the chosen
delay.  The delay's 95 % set: the delays with ``Δχ² = (χ²_d - χ²_best) / s^2 <= 3.84``.  A lag
whose optimum is its bound 0 is written as 0 with a one-sided upper limit.

Identifiability, said not guessed: a parameter is *not identifiable from this log* -- left at its
default, out of the written table, the reason in a comment -- when (1) the commands rule it out
(:func:`structural`: ``w`` or ``v`` zero on every row, a command that never changes), (2) its
Jacobian column is zero, (3) it cannot be told from the others (variance inflation above
:data:`VIF_LIMIT`: the column-normalised Jacobian is rank deficient), or (4) its 95 % interval is
wider than :data:`RESOLUTION`.  Each is dropped in turn and the fit (and the delay search)
redone.  Nothing identifiable: :class:`LogError` (exit 2).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from wmr._jit import njit
from wmr._settings import one_line
from wmr.closedloop import step as loop
from wmr.estimation.robot_log import (
    MIN_ROWS,
    OPTIONAL,
    REQUIRED,
    Log,
    LogError,
    read_log,
)
from wmr.robots import plant
from wmr.scenario import Plant

__all__ = ["LogError", "PARAMETERS", "NOMINAL", "REQUIRED", "OPTIONAL", "MIN_ROWS",
           "SEGMENT_SECONDS", "WARM_SECONDS", "MAX_DELAY", "VIF_LIMIT", "RESOLUTION", "Log",
           "read_log", "structural", "replay", "noise_level", "Identification", "identify",
           "to_toml", "report"]  # fmt: skip

#: The continuous parameters fitted (DESIGN §3.3), in this order, and their nominal values.
PARAMETERS = ("v_gain", "w_gain", "v_from_w", "w_from_v", "actuator_tau", "slip")
NOMINAL = {"v_gain": 1.0, "w_gain": 1.0, "v_from_w": 0.0, "w_from_v": 0.0,
           "actuator_tau": 0.0, "slip": 0.0}  # fmt: skip
UNITS = {"v_gain": "-", "w_gain": "-", "v_from_w": "m/rad", "w_from_v": "rad/m",
         "actuator_tau": "s", "slip": "s"}  # fmt: skip
#: Default length of a multiple-shooting segment [s], and of the segments of the first fit.
SEGMENT_SECONDS, WARM_SECONDS = 10.0, 2.0
#: At most this many segments (the dense Jacobian takes 24 (6 + 3 segments) bytes a row).
MAX_SEGMENTS = 50
#: Default largest delay searched [steps].
MAX_DELAY = 10
#: A variance inflation factor above this: the parameter cannot be told from the others.
VIF_LIMIT = 1e8
#: The widest 95 % half-width counted as identified, for a robot of this suite's size (track
#: ~0.3 m, speeds ~0.5 m/s, turn rates ~1 rad/s): a gain known to +-0.5, a coupling to +-0.05
#: m/rad or +-0.5 rad/m (unequal wheels of +-17 % at b = 0.15 m), a lag or a slip to +-0.5 s
#: say nothing useful about the robot.
RESOLUTION = {"v_gain": 0.5, "w_gain": 0.5, "v_from_w": 0.05, "w_from_v": 0.5,
              "actuator_tau": 0.5, "slip": 0.5}  # fmt: skip
#: Two-sided 95 % normal quantile, and the chi-square (1 dof) 95 % quantile for the delay set.
Z95 = 1.959963984540054
CHI2_95 = 3.841458820694124
#: Starting lag [steps of dt]; lags below ``TAU_ZERO dt`` are written as 0 (no lag).
TAU_START, TAU_ZERO = 2.0, 1e-3
#: The fit integrates the lag with at most this many substeps: the plant's own rule
#: (``wmr.robots.plant.substeps``) for lags down to dt/4; below, a scenario with the written lag
#: integrates more finely (the difference: below ``tau |Δv|`` per command change).
MAX_FIT_SUBSTEPS = 8
#: Central-difference steps of the Jacobian (relative to max(1, |p|)).
FD_STEP = 1e-6
_COLS = [plant.PARAMS.index(p) for p in PARAMETERS]
_TAU = PARAMETERS.index("actuator_tau")


def structural(log: Log) -> dict[str, str]:
    """Parameters the log's commands rule out, ``{parameter: reason}``.  With ``c = u + dist``:
    ``w_gain``, ``v_from_w`` multiply ``w`` and ``v_gain``, ``w_from_v`` multiply ``v``; a factor
    zero on every row leaves the poses independent of them (``slip`` multiplies the *applied*
    ``v w``, which the coupling can make nonzero: the Jacobian decides).  A command that never
    changes informs the lag and the delay only through the assumed start from rest."""
    c, out = log.u + log.dist, {}
    for i, name, params in ((1, "w", ("w_gain", "v_from_w")), (0, "v", ("v_gain", "w_from_v"))):
        if not np.any(c[:, i]):
            out.update(dict.fromkeys(params, f"{name} (+ d{name}) is zero on every row"))
    if np.all(c == c[0]):
        for p, what in (("actuator_tau", "lag"), ("delay_steps", "delay")):
            out[p] = f"the command never changes (only the assumed start from rest would " \
                     f"inform the {what})"
    return out


# The loop's plant half with the parameter table (delay -> disturbance ->
# ``wmr.robots.plant.apply``).
_PLANT_HALF = loop.plant_half(loop.PLANT_TABLE)


@njit
def _replay(u, dist, dt, table, at, ints, buffer, starts, q0, out):
    """The plant half of ``wmr.closedloop.step`` (:data:`_PLANT_HALF`) driven by logged commands
    ``u`` and disturbances ``dist`` (n, 2) (row ``k`` a window ``[t_k, inf)`` of the half's
    disturbance table, so exactly ``dist[k]`` is added at ``t_k``); ``out[k]`` the pose at ``t_k``,
    reset to ``q0[j]`` at row ``starts[j]``."""
    vel, uk, ua, q, j = np.zeros(2), np.zeros(2), np.zeros(2), np.zeros(3), 0
    window, no_log = np.zeros((1, 4)), np.zeros((0, 2))
    window[0, 1] = np.inf
    arrays = (table, at, ints, vel, buffer)
    for k in range(u.shape[0]):
        if j < starts.size and k == starts[j]:
            q[:] = q0[j]
            j += 1
        out[k, :] = q
        uk[0] = u[k, 0]
        uk[1] = u[k, 1]
        window[0, 0] = k * dt  # the time the half computes, so the window contains it
        window[0, 2] = dist[k, 0]
        window[0, 3] = dist[k, 1]
        _PLANT_HALF(k, dt, 0, uk, ua, q, window, arrays, no_log)


def _table(values, dt: float, max_substeps: int | None = None) -> np.ndarray:
    """The one-row parameter table of ``wmr.robots.plant`` with ``values`` (6,) of
    :data:`PARAMETERS` (the other columns at ``wmr.scenario.Plant``'s defaults, substeps by
    ``wmr.robots.plant.substeps``,
    capped at ``max_substeps``)."""
    cols = np.array(Plant().row(), dtype=float)  # the specification's columns come first
    cols[_COLS] = values
    n = plant.substeps(cols, plant.KINEMATIC, dt)
    n = n if max_substeps is None else min(n, max_substeps)
    return plant.table_row(cols, plant.KINEMATIC, dt, n)[None, :]  # + the integration's columns


def replay(log: Log, values, delay: int, starts, q0, max_substeps: int | None = None):
    """The poses ``wmr.robots.plant`` gives over the log's commands, (n, 3) [m, m, rad]: a replay of
    the logged commands through the plant half of the step (``wmr.closedloop.step``: delayed by
    ``delay`` steps, zeros before the first; the logged disturbance added;
    ``wmr.robots.plant.apply``), not a copy of the closed loop (no sensing, no law).  ``values``
    (6,) are :data:`PARAMETERS`; the pose
    restarts from ``q0[j]`` (3,) at row ``starts[j]`` (``starts[0] = 0``) while the actual
    velocities and the delay line run on; the robot starts at rest."""
    _, at, ints, _, buffer = plant.arrays(Plant(delay_steps=int(delay)), log.dt)
    out = np.empty((log.n, 3))
    table = _table(np.asarray(values, dtype=float), log.dt, max_substeps)
    _replay(log.u, log.dist, log.dt, table, at, ints, buffer, np.asarray(starts, dtype=np.int64),
            np.asarray(q0, dtype=float).reshape(-1, 3), out)  # fmt: skip
    return out


def _wrap(a):
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def noise_level(z: np.ndarray) -> np.ndarray:
    """Per-channel noise level (3,) of a measured pose (n, 3): ``sqrt(mean(Δ²z²) / 6)`` (white
    noise; the true second difference ``~ a dt²`` is negligible), floored at 1e-9."""
    d = np.diff(z, axis=0)
    d[:, 2] = _wrap(d[:, 2])
    return np.maximum(np.sqrt(np.mean(np.diff(d, axis=0) ** 2, axis=0) / 6.0), 1e-9)


@dataclass
class _Problem:
    """The weighted output-error problem at one delay with the parameters ``free`` (mask (6,))
    fitted and the others at their nominal values; ``x = (free values, initial poses)``."""

    log: Log
    delay: int
    free: np.ndarray
    starts: np.ndarray
    sigma: np.ndarray
    max_substeps: int | None = MAX_FIT_SUBSTEPS

    def unpack(self, x):
        values = np.array([NOMINAL[p] for p in PARAMETERS])
        nf = int(self.free.sum())
        values[self.free] = x[:nf]
        return values, x[nf:].reshape(-1, 3)

    def simulate(self, x):
        values, q0 = self.unpack(x)
        return replay(self.log, values, self.delay, self.starts, q0, self.max_substeps)

    def residual(self, x):
        r = self.log.z - self.simulate(x)
        r[:, 2] = _wrap(r[:, 2])
        return (r / self.sigma).ravel()

    def jacobian(self, x):
        """Central differences of the weighted residual (forward at the lag's bound 0), shape
        (3 n, len(x)); a coordinate of every segment's initial pose is moved at once (each moves
        only its segment's rows)."""
        n, nf = self.log.n, int(self.free.sum())
        seg = np.searchsorted(self.starts, np.arange(n), side="right") - 1
        tau = int(self.free[:_TAU].sum()) if self.free[_TAU] else -1
        J = np.zeros((n, 3, len(x)))
        for cols in [[j] for j in range(nf)] + [list(range(nf + c, len(x), 3)) for c in range(3)]:
            h = FD_STEP * max(1.0, float(np.max(np.abs(x[cols]))))
            hi, lo = x.copy(), x.copy()
            hi[cols] += h
            forward = cols[0] == tau and x[tau] - h < 0.0
            if not forward:
                lo[cols] -= h
            d = (self.simulate(lo) - self.simulate(hi)) / ((1.0 if forward else 2.0) * h)
            where = np.asarray(cols)[seg] if len(cols) > 1 else np.full(n, cols[0])
            J[np.arange(n), :, where] = d / self.sigma
        return J.reshape(3 * n, len(x))


def _segments(log: Log, segment: float) -> np.ndarray:
    """First rows of the shooting segments of ``segment`` seconds (a short last one merged),
    at most :data:`MAX_SEGMENTS` (longer ones on a long log: the Jacobian is dense)."""
    length = max(1, round(segment / log.dt), math.ceil(log.n / MAX_SEGMENTS))
    starts = np.arange(0, log.n, length)
    if len(starts) > 1 and log.n - starts[-1] < length / 2:
        starts = starts[:-1]
    return starts


def _fit(problem: _Problem, x0: np.ndarray):
    """``least_squares`` (Levenberg-Marquardt, MINPACK) from ``x0``.  The lag is unbounded
    here: the plant treats ``actuator_tau <= 0`` as no lag, and :func:`identify` refits with
    the lag at its bound 0 when the optimum lies there."""
    return least_squares(problem.residual, x0, jac=problem.jacobian, method="lm",
                         x_scale="jac", ftol=1e-10, xtol=1e-10, gtol=1e-10,
                         max_nfev=200)  # fmt: skip


def _solve(problem: _Problem):
    """Fit ``problem`` from the nominal parameters (the lag at ``TAU_START dt``), each segment
    from its measured pose -- through a first fit over :data:`WARM_SECONDS` segments when the
    problem's are longer (short shots stay near the measured path from a poor start, so the
    long ones start near their optimum; a single 40 s shot from the nominal plant ends in a
    local minimum)."""
    log, free = problem.log, problem.free
    values = np.array([NOMINAL[p] for p in PARAMETERS])
    values[_TAU] = TAU_START * log.dt
    short = _segments(log, WARM_SECONDS)
    if len(short) > len(problem.starts):
        warm = dataclasses.replace(problem, starts=short)
        res = _fit(warm, np.concatenate((values[free], log.z[short].ravel())))
        values = warm.unpack(res.x)[0]
    return _fit(problem, np.concatenate((values[free], log.z[problem.starts].ravel())))


#: When parameters cannot be told apart, the first of this order is dropped (the gains last).
_DROP_ORDER = ("v_from_w", "w_from_v", "slip", "actuator_tau", "v_gain", "w_gain")


def _unresolved(J: np.ndarray, free: np.ndarray, s2: float
                ) -> tuple[dict[str, str], dict[str, float]]:  # fmt: skip
    """Free parameters the weighted Jacobian ``J`` (3 n, p; the free parameters' columns
    first) cannot resolve, as ``{parameter: reason}``, and the variance inflation factor of each
    free parameter.  In turn: every zero column; else the parameter (by ``_DROP_ORDER``) of a
    group whose VIF ``1 / (1 - R_j^2)`` exceeds :data:`VIF_LIMIT` (``R_j^2``: the share of column
    ``j`` explained by all the others, from the column-normalised normal matrix); else the one
    whose 95 % half-width (``s2`` the residual variance) most exceeds :data:`RESOLUTION`."""
    names = [p for p, f in zip(PARAMETERS, free, strict=True) if f]
    if not names:
        return {}, {}
    norms = np.linalg.norm(J, axis=0)
    zero = [p for j, p in enumerate(names) if norms[j] <= 1e-12 * norms.max()]
    if zero:
        return dict.fromkeys(zero, "the poses do not depend on it in this log (zero Jacobian "
                                   "column)"), dict.fromkeys(names, math.inf)  # fmt: skip
    F = (J / norms).T @ (J / norms)
    lam, V = np.linalg.eigh(F)
    lam = np.maximum(lam, 1e-16 * lam[-1])  # below rounding: numerically singular
    vif = {p: float(np.sum(V[j] ** 2 / lam)) for j, p in enumerate(names)}
    bad = [p for p in names if vif[p] > VIF_LIMIT]
    if bad:
        p = min(bad, key=_DROP_ORDER.index)
        j = names.index(p)
        others = [i for i in range(F.shape[0]) if i != j]
        beta = np.linalg.pinv(F[np.ix_(others, others)], rcond=1e-10) @ F[others, j]
        told = [names[i] for i, b in zip(others, beta, strict=True)
                if i < len(names) and abs(b) > 0.1]  # fmt: skip
        return {p: f"its effect on the poses cannot be told from that of "
                   f"{', '.join(told) or 'the initial poses'} (variance inflation "
                   f"{vif[p]:.2g} > {VIF_LIMIT:g})"}, vif  # fmt: skip
    half = Z95 * np.sqrt(s2 * np.diag(np.linalg.inv(J.T @ J)))
    ratio = {p: half[j] / RESOLUTION[p] for j, p in enumerate(names)}
    p = max(names, key=ratio.get)
    if ratio[p] > 1.0:
        return {p: f"its 95 % interval +-{_fmt(half[names.index(p)])} {UNITS[p]} is wider than "
                   f"+-{RESOLUTION[p]:g} (RESOLUTION): the poses barely move with it"}, vif
    return {}, vif


@dataclass
class Identification:
    """What :func:`identify` found in a log.

    ``values`` holds every parameter of :data:`PARAMETERS` (the nominal value where
    ``not_identifiable`` names it) and ``se`` their standard errors (NaN there); ``delay`` the
    chosen delay [steps], ``profile`` its ``Δχ²`` per searched delay and ``delay_set`` the 95 %
    set; ``rms`` (3,) the residual RMS [m, m, rad], ``sigma`` (3,) the noise level the
    residuals were weighted by, ``s2`` the weighted residual variance; ``starts`` the segments'
    first rows, ``initial_poses`` (segments, 3) their fitted initial poses, ``fitted`` (n, 3)
    the simulated poses; ``covariance`` (6, 6) that of :data:`PARAMETERS` (NaN where not
    fitted); ``lag_at_bound``: the lag's optimum is at its bound 0 (``se`` then from a secant).
    """

    source: str
    n: int
    dt: float
    segment: float
    max_delay: int
    values: dict[str, float]
    se: dict[str, float]
    covariance: np.ndarray
    not_identifiable: dict[str, str]
    delay: int
    delay_set: tuple[int, ...]
    profile: dict[int, float]
    rms: np.ndarray
    sigma: np.ndarray
    s2: float
    vif: dict[str, float]
    starts: np.ndarray
    initial_poses: np.ndarray
    fitted: np.ndarray = field(repr=False)
    lag_at_bound: bool = False

    def interval(self, name: str) -> tuple[float, float]:
        """The 95 % interval of parameter ``name`` (the lag's clipped at its bound 0)."""
        v, h = self.values[name], Z95 * self.se[name]
        return (max(v - h, 0.0) if name == "actuator_tau" else v - h), v + h


def identify(log: Log, max_delay: int = MAX_DELAY,
             segment: float = SEGMENT_SECONDS) -> Identification:  # fmt: skip
    """Fit the kinematic ``[plant]`` of §3.3 to ``log`` (the module's method).

    Parameters
    ----------
    log : Log
        From :func:`read_log`.
    max_delay : int
        Delays ``0 .. max_delay`` [steps] are searched.
    segment : float [s]
        Length of a multiple-shooting segment (``>= log.n dt``: pure output error from one
        initial pose).

    Raises
    ------
    LogError
        When no parameter can be identified from the log.
    """
    ruled = structural(log)
    reasons = {p: ruled[p] for p in PARAMETERS if p in ruled}
    _check_any(log, reasons)
    free = np.array([p not in reasons for p in PARAMETERS])
    sigma, starts = noise_level(log.z), _segments(log, segment)
    delays = [0] if "delay_steps" in ruled else list(range(max_delay + 1))
    while True:  # search the delay; drop what the log cannot resolve; search again
        chi2, fits = {}, {}
        for d in delays:
            problem = _Problem(log, d, free, starts, sigma)
            fits[d] = (problem, _solve(problem))
            chi2[d] = 2.0 * fits[d][1].cost
        best = min(chi2, key=chi2.get)
        problem, res = fits[best]
        at_bound = bool(free[_TAU]) and problem.unpack(res.x)[0][_TAU] < TAU_ZERO * log.dt
        if at_bound:  # the lag at its bound 0: refit without it (the search keeps it free)
            problem = _Problem(log, best, free & (np.arange(len(free)) != _TAU), starts, sigma)
            res = _solve(problem)
            chi2[best] = 2.0 * res.cost
        J = problem.jacobian(res.x)
        drop, vif = _unresolved(J, problem.free, chi2[best] / (J.shape[0] - J.shape[1]))
        if not drop:
            break
        reasons.update(drop)
        _check_any(log, reasons)
        free = np.array([p not in reasons for p in PARAMETERS])
    free = problem.free
    values, q0 = problem.unpack(res.x)
    names = [n for n, f in zip(PARAMETERS, free, strict=True) if f]
    if at_bound:  # the lag's sensitivity at 0: a secant over [0, dt/4] (the fit's substeps)
        J = np.column_stack((J, _lag_column(problem, values, q0)))
        names.append("actuator_tau")
    s2 = chi2[best] / (3 * log.n - J.shape[1])
    columns = [*range(int(free.sum())), *([J.shape[1] - 1] if at_bound else [])]
    where = [PARAMETERS.index(name) for name in names]
    covariance = np.full((len(PARAMETERS), len(PARAMETERS)), np.nan)
    covariance[np.ix_(where, where)] = (s2 * np.linalg.pinv(J.T @ J))[np.ix_(columns, columns)]
    se = dict(zip(PARAMETERS, np.sqrt(np.diag(covariance)).tolist(), strict=True))
    profile = {d: (c - chi2[best]) / s2 for d, c in chi2.items()}
    delay_set = tuple(d for d in delays if profile[d] <= CHI2_95)
    if "delay_steps" in ruled:
        reasons["delay_steps"] = ruled["delay_steps"]
    elif len(delays) > 1 and len(delay_set) == len(delays):
        reasons["delay_steps"] = (f"every delay searched (0..{max_delay}) fits alike "
                                  f"(Δχ² <= {CHI2_95:.2f})")  # fmt: skip
    fitted = problem.simulate(res.x)
    r = (problem.residual(res.x) * np.tile(sigma, log.n)).reshape(-1, 3)
    return Identification(
        source=log.source, n=log.n, dt=log.dt, segment=segment, max_delay=max_delay,
        values={k: float(v) for k, v in zip(PARAMETERS, values, strict=True)}, se=se,
        not_identifiable=reasons, delay=best, delay_set=delay_set, profile=profile,
        rms=np.sqrt(np.mean(r**2, axis=0)), sigma=sigma, s2=float(s2), vif=vif, starts=starts,
        initial_poses=q0, fitted=fitted, lag_at_bound=at_bound, covariance=covariance,
    )  # fmt: skip


def _check_any(log: Log, reasons: dict[str, str]) -> None:
    """:class:`LogError` when every parameter is ruled out."""
    if all(p in reasons for p in PARAMETERS):
        why = "; ".join(dict.fromkeys(reasons[p] for p in PARAMETERS))
        raise LogError(log.source, "v, w", None, "no parameter of the plant can be identified "
                                                  f"from this log: {why}")  # fmt: skip


def _lag_column(problem: _Problem, values: np.ndarray, q0: np.ndarray) -> np.ndarray:
    """The weighted residual's sensitivity to the lag at 0, a secant over ``[0, dt/4]`` (3 n,)."""
    h, lagged = 0.25 * problem.log.dt, values.copy()
    lagged[_TAU] = h
    sim = [replay(problem.log, v, problem.delay, problem.starts, q0, problem.max_substeps)
           for v in (values, lagged)]  # fmt: skip
    return ((sim[0] - sim[1]) / h / problem.sigma).ravel()


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _notes(ident: Identification) -> dict[str, str]:
    """One comment per parameter (its interval, or why it is left out), and under ``""`` the
    caveat when the delay is not exact (the intervals hold given the chosen one)."""
    out, why = {"": ""}, ident.not_identifiable
    delays = "{" + ", ".join(map(str, ident.delay_set)) + "}"
    for name in PARAMETERS:
        lo, hi = ident.interval(name)
        out[name] = (f"not identifiable from this log: {why[name]}" if name in why else
                     f"at its bound 0 (no lag found); 95 % upper limit {_fmt(hi)} s"
                     if name == "actuator_tau" and ident.lag_at_bound else
                     f"95 % interval [{_fmt(lo)}, {_fmt(hi)}] {UNITS[name]}")  # fmt: skip
    if "delay_steps" in why:
        out["delay_steps"] = f"not identifiable from this log: {why['delay_steps']}; the fit's"
        return out
    exact = len(ident.delay_set) == 1
    edge = "; at the edge of the search: raise --max-delay" if ident.delay == ident.max_delay \
        else ""
    out["delay_steps"] = (f"searched 0..{ident.max_delay}; 95 % set {delays} "
                          f"({'exact' if exact else 'not exact'}){edge}")  # fmt: skip
    if not exact:
        out[""] = (f"the intervals hold given delay_steps = {ident.delay}; the delay is not "
                   f"exact (95 % set {delays})")  # fmt: skip
    return out


def _residual_line(ident: Identification) -> str:
    rms = ", ".join(f"{c} {_fmt(v)}" for c, v in zip(("x", "y", "theta"), ident.rms, strict=True))
    return (f"residual RMS {rms} (m, m, rad); weighted residual variance s^2 = {ident.s2:.4g} "
            "(1: the model explains the log down to its noise)")  # fmt: skip


def to_toml(ident: Identification) -> str:
    """The fitted ``[plant]`` table (DESIGN §3.3) as TOML text, for a scenario to include (append
    it to a scenario without a ``[plant]``).  Parameters the log cannot identify are left out
    (their defaults apply), each with a comment saying why; the others carry their interval."""
    notes = _notes(ident)
    lines = [f"# [plant] fitted by `wmr identify` to {one_line(ident.source)}: {ident.n} rows of "
             f"dt = {ident.dt:g} s, output error over {len(ident.starts)} segment(s)",
             f"# {_residual_line(ident)}", *([f"# {notes['']}"] if notes[""] else []),
             "[plant]", 'model = "kinematic"']  # fmt: skip
    for name in (*PARAMETERS[:-1], "delay_steps", PARAMETERS[-1]):
        if name in ident.not_identifiable and name != "delay_steps":  # the fit's delay: written
            lines.append(f"# {name}: {notes[name]}")
            continue
        value = ident.delay if name == "delay_steps" else ident.values[name]
        lines.append(f"{f'{name} = {value!r}':<31} # {notes[name]}")
    return "\n".join(lines) + "\n"


def report(ident: Identification) -> str:
    """A human-readable summary: estimates, standard errors, intervals, the delay's profile,
    what could not be identified and the fit's residual."""
    notes = _notes(ident)
    lines = [f"{one_line(ident.source)}: {ident.n} rows, dt = {ident.dt:g} s, "
             f"{len(ident.starts)} shooting segment(s) of {ident.segment:g} s",
             f"{'parameter':<14}{'estimate':>12}{'std error':>12}  note"]  # fmt: skip
    for name in (*PARAMETERS, "delay_steps"):
        if name in ident.not_identifiable:
            value = se = "-"
        elif name == "delay_steps":
            value, se = str(ident.delay), ""
        else:
            value, se = _fmt(ident.values[name]), _fmt(ident.se[name])
        lines.append(f"{name:<14}{value:>12}{se:>12}  {notes[name]}")
    prof = ", ".join(f"{d}: {v:.1f}" for d, v in ident.profile.items())
    noise = ", ".join(_fmt(v) for v in ident.sigma)
    lines += [f"delay profile (Δχ² per delay): {prof}", _residual_line(ident),
              f"noise level from second differences: {noise} (m, m, rad)",
              *([notes[""]] if notes[""] else [])]  # fmt: skip
    return "\n".join(lines)
