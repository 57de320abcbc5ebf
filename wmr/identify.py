"""``wmr identify``: the kinematic ``[plant]`` of DESIGN §3.3 fitted to a robot's log.

The log.  A CSV file with a header; the columns read (others, e.g. the true pose ``x, y, theta``
of ``wmr run``'s trajectory CSV, are ignored: a real robot's log does not have them):

- ``t`` [s], strictly increasing with a constant step ``dt`` (the plant's delay is in steps);
- ``v, w`` [m/s, rad/s]: the saturated command sent at ``t_k``;
- ``x_meas, y_meas, theta_meas`` [m, m, rad]: the measured pose ``z_k = q_k + n_k`` at ``t_k``
  (``theta_meas`` unwrapped or wrapped: residuals are wrapped);
- ``dv, dw`` (optional, 0 if absent): the disturbance in force at ``t_k``, added to the delayed
  command before the plant (``wmr.loop.disturb``).

Trailing rows whose per-step cells are all empty (the last instant of ``wmr run``'s CSV) are
dropped.  The robot is at rest at the first row and no command is in the delay line before it
(§3.3: what ``wmr run`` logs).

The model: ``wmr.plant``'s kinematic robot with the parameters ``PARAMETERS`` and the integer
``delay_steps``, driven by the logged commands (:func:`replay`).  The fit is **output error**:
the residual is the measured pose minus the pose the plant *simulates* over the log's commands
(heading wrapped), per channel divided by the noise level estimated from second differences of
the measured pose (``var(Δ²z) = 6 σ²`` for white noise), minimised by
``scipy.optimize.least_squares`` (``actuator_tau >= 0``); the delay by search over ``0 ..
max_delay``.  Equation error on differenced noisy poses would be biased, its intervals wrong: the
noise on increments ``n_{k+1} - n_k`` is MA(1) and sits in the regressors.  With white
measurement noise the simulated pose at ``t_k`` depends on commands up to ``t_{k-1}`` only,
so output error stays consistent on closed-loop logs (the commands depend on past noise).

Drift: **multiple shooting**.  The log is cut into segments of ``segment`` seconds (default
:data:`SEGMENT_SECONDS`); each restarts the simulated pose from its own initial pose, three
parameters fitted with the rest.  The lag state and the delay line run on across the cuts (they
are fixed by the commands and cannot drift).  Why: an open-loop simulation of a plant that is
not exactly this model (the MuJoCo robot, unmodelled effects) drifts away from the measured path
over a long log, and a wrong initial guess makes a long horizon strongly non-convex; a segment
long enough that a gain error accumulates into a drift well above the noise keeps nearly all the
information (per segment it grows like its length cubed) while bounding the drift.

Intervals: Gauss-Newton, ``cov = s^2 (J^T J)^-1`` with the Jacobian of the weighted residuals
at the optimum (central differences of :func:`replay`) and ``s^2`` the weighted residual
variance (1 when the model explains the log down to the estimated noise); 95 % intervals
``estimate +- 1.96 se``.  The delay's 95 % set: the delays whose profile ``Δχ² = (cost_d -
cost_best) / s^2 <= 3.84`` (chi-square, 1 degree of freedom).

Identifiability, said not guessed: a parameter is *not identifiable from this log* (kept at its
nominal value, left out of the written table, the reason in the report) when (1) the commands
rule it out (:func:`structural`: ``w`` never nonzero, ``v`` never nonzero, ``v w`` never
nonzero, a command that never changes), (2) its Jacobian column is zero at the optimum, or (3)
it cannot be told from the other parameters: variance inflation factor ``1 / (1 - R_j^2)`` above
:data:`VIF_LIMIT` (the column-normalised Jacobian is rank deficient).  Nothing identifiable:
:class:`LogError` (exit 2).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from wmr import plant
from wmr._jit import njit
from wmr._settings import InputError, one_line
from wmr.scenario import Plant

__all__ = [
    "LogError",
    "PARAMETERS",
    "NOMINAL",
    "REQUIRED",
    "OPTIONAL",
    "MIN_ROWS",
    "SEGMENT_SECONDS",
    "MAX_DELAY",
    "VIF_LIMIT",
    "RESOLUTION",
    "Log",
    "read_log",
    "structural",
    "replay",
    "Identification",
    "identify",
    "to_toml",
    "report",
]

#: The continuous parameters fitted (DESIGN §3.3), in this order, and their nominal values.
PARAMETERS = ("v_gain", "w_gain", "v_from_w", "w_from_v", "actuator_tau", "slip")
NOMINAL = {"v_gain": 1.0, "w_gain": 1.0, "v_from_w": 0.0, "w_from_v": 0.0,
           "actuator_tau": 0.0, "slip": 0.0}  # fmt: skip
UNITS = {"v_gain": "-", "w_gain": "-", "v_from_w": "m/rad", "w_from_v": "rad/m",
         "actuator_tau": "s", "slip": "s"}  # fmt: skip
#: Columns a log must have, and those that default to 0.
REQUIRED = ("t", "v", "w", "x_meas", "y_meas", "theta_meas")
OPTIONAL = ("dv", "dw")
#: Fewest rows with a measured pose (0.5 s at 10 ms: enough residuals for 9 parameters).
MIN_ROWS = 50
#: Default length of a multiple-shooting segment [s].
SEGMENT_SECONDS = 5.0
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
#: Time steps of ``dt`` may differ by this much (relative) and still count as uniform.
DT_RTOL = 1e-6
#: Starting lag [steps of dt]; lags below ``TAU_ZERO dt`` are written as 0 (no lag).
TAU_START, TAU_ZERO = 2.0, 1e-3
#: The fit integrates the lag with at most this many substeps (the plant's own rule, ``wmr.plant
#: .substeps``, for lags down to dt/4; finer for the final replay and a written scenario).
MAX_FIT_SUBSTEPS = 8
#: Central-difference steps of the Jacobian (relative to max(1, |p|)).
FD_STEP = 1e-6
_COLS = [plant.PARAMS.index(p) for p in PARAMETERS]
_TAU = PARAMETERS.index("actuator_tau")
_N_SUB = plant.PARAMS.index("substeps")


class LogError(InputError):
    """A log ``wmr identify`` cannot use: one line naming the file, line/column and value."""


@dataclass(frozen=True)
class Log:
    """A robot's log as :func:`identify` reads it (``n`` rows, ``t_k = t_0 + k dt``).

    Attributes
    ----------
    source : str
        Where it came from (for messages).
    dt : float [s]
        The constant sample period.
    u : ndarray (n, 2) [m/s, rad/s]
        The saturated command ``(v, w)`` sent at ``t_k``.
    z : ndarray (n, 3) [m, m, rad]
        The measured pose at ``t_k``.
    dist : ndarray (n, 2) [m/s, rad/s]
        The disturbance in force at ``t_k`` (zeros if the log has none).
    """

    source: str
    dt: float
    u: np.ndarray
    z: np.ndarray
    dist: np.ndarray

    @property
    def n(self) -> int:
        return len(self.u)


def _cell(text: str, source: str, line: int, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise LogError(source, f"line {line} column {name}", text, "not a number") from None
    if not math.isfinite(value):
        raise LogError(source, f"line {line} column {name}", text, "not a finite number")
    return value


def read_log(path) -> Log:
    """Read and check a log (the module's columns); :class:`LogError` on any problem."""
    source = str(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as err:
        raise LogError(source, "(file)", None, f"cannot read: {err.strerror}") from None
    except (UnicodeDecodeError, csv.Error) as err:
        raise LogError(source, "(file)", None, f"not a CSV text file: {err}") from None
    if not rows:
        raise LogError(source, "(header)", None, "empty file: no header")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise LogError(source, "(header)", None,
                       f"missing column(s) {', '.join(missing)} (needs {', '.join(REQUIRED)}; "
                       f"optional {', '.join(OPTIONAL)})")  # fmt: skip
    names = [c for c in (*REQUIRED, *OPTIONAL) if c in header]
    index = [header.index(c) for c in names]
    body = rows[1:]
    while body and all(i >= len(body[-1]) or not body[-1][i].strip() for i in index[1:]):
        body.pop()  # the last instant of `wmr run`'s CSV has no step after it
    data = np.empty((len(body), len(names)))
    for r, row in enumerate(body):
        line = r + 2
        if len(row) < len(header):
            raise LogError(source, f"line {line}", None,
                           f"has {len(row)} cells, the header {len(header)}")  # fmt: skip
        for c, (i, name) in enumerate(zip(index, names, strict=True)):
            data[r, c] = _cell(row[i].strip(), source, line, name)
    if len(data) < MIN_ROWS:
        raise LogError(source, "(rows)", len(data),
                       f"too short: at least {MIN_ROWS} rows with a command and a measured "
                       "pose are needed")  # fmt: skip
    col = {name: data[:, c] for c, name in enumerate(names)}
    t = col["t"]
    steps = np.diff(t)
    bad = np.flatnonzero(steps <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        raise LogError(source, f"line {k + 2} column t", float(t[k]),
                       f"not after the previous t = {float(t[k - 1])!r}")  # fmt: skip
    dt = float((t[-1] - t[0]) / (len(t) - 1))
    off = np.flatnonzero(np.abs(steps - dt) > DT_RTOL * dt)
    if off.size:
        k = int(off[0]) + 1
        raise LogError(source, f"line {k + 2} column t", float(t[k]),
                       f"not uniformly sampled (step {float(steps[k - 1])!r}, mean {dt!r}): the "
                       "plant's delay is in whole steps")  # fmt: skip
    zeros = np.zeros(len(t))
    return Log(source=source, dt=dt, u=np.column_stack((col["v"], col["w"])),
               z=np.column_stack((col["x_meas"], col["y_meas"], col["theta_meas"])),
               dist=np.column_stack((col.get("dv", zeros), col.get("dw", zeros))))  # fmt: skip


def structural(log: Log) -> dict[str, str]:
    """Parameters the log's commands rule out, with the reason: ``{parameter: reason}``.

    With the applied command ``c = u + dist``: ``w_gain`` and ``v_from_w`` multiply ``w``,
    ``v_gain`` and ``w_from_v`` multiply ``v``: a factor zero on every row leaves the poses
    independent of the parameter, whatever the others are.  (``slip`` multiplies the *applied*
    ``v w``, which the coupling can make nonzero when the commanded ``v w`` is zero: the
    Jacobian decides.)  A command that never changes moves the lag and the delay only through
    the start from rest, i.e. through the assumption, not the data: both are ruled out.
    """
    c = log.u + log.dist
    out = {}
    if not np.any(c[:, 1]):
        for p in ("w_gain", "v_from_w"):
            out[p] = "w (+ dw) is zero on every row"
    if not np.any(c[:, 0]):
        for p in ("v_gain", "w_from_v"):
            out[p] = "v (+ dv) is zero on every row"
    if np.all(c == c[0]):
        out["actuator_tau"] = "the command never changes (only the assumed start from rest would "\
                              "inform the lag)"
        out["delay_steps"] = "the command never changes (only the assumed start from rest would "\
                             "inform the delay)"
    return out


@njit
def _replay(u, dist, dt, table, at, ints, buffer, starts, q0, out):
    """The plant half of ``wmr.loop`` (delay -> disturbance -> ``wmr.plant.apply``) driven by
    logged commands; ``out[k]`` the pose at ``t_k``, reset to ``q0[j]`` at row ``starts[j]``."""
    vel = np.zeros(2)
    ua = np.zeros(2)
    q = np.zeros(3)
    j = 0
    for k in range(u.shape[0]):
        if j < starts.size and k == starts[j]:
            q[0] = q0[j, 0]
            q[1] = q0[j, 1]
            q[2] = q0[j, 2]
            j += 1
        out[k, 0] = q[0]
        out[k, 1] = q[1]
        out[k, 2] = q[2]
        ua[0] = u[k, 0]
        ua[1] = u[k, 1]
        plant.delayed(ua, ints, buffer)
        ua[0] += dist[k, 0]
        ua[1] += dist[k, 1]
        plant.apply(k, dt, ua, q, table, at, ints, vel)


def _table(values, dt: float, max_substeps: int | None = None) -> np.ndarray:
    """The one-row parameter table of ``wmr.plant`` with ``values`` (6,) of :data:`PARAMETERS`
    (the other columns at ``wmr.scenario.Plant``'s defaults, substeps by ``wmr.plant.substeps``,
    capped at ``max_substeps``)."""
    row = np.array(Plant().row(), dtype=float)
    row[_COLS] = values
    n = plant.substeps(row, plant.KINEMATIC, dt)
    row[_N_SUB] = n if max_substeps is None else min(n, max_substeps)
    return row[None, :]


def replay(log: Log, values, delay: int, starts, q0, max_substeps: int | None = None):
    """The poses ``wmr.plant`` gives over the log's commands: shape (n, 3) [m, m, rad].

    A replay of the logged commands through the plant half of the step (``wmr.loop``: the
    command delayed by ``delay`` steps, zeros before the first, the logged disturbance added,
    ``wmr.plant.apply`` over each step), not a copy of the closed loop: no sensing, no law.
    ``values`` (6,) are :data:`PARAMETERS`; the pose restarts from ``q0[j]`` (3,) at row
    ``starts[j]`` (``starts[0] = 0``), the actual velocities and the delay line run on; the
    robot starts at rest.
    """
    spec = Plant(delay_steps=int(delay))
    _, at, ints, _, buffer = plant.arrays(spec, log.dt)
    out = np.empty((log.n, 3))
    _replay(log.u, log.dist, log.dt, _table(np.asarray(values, dtype=float), log.dt,
                                            max_substeps),
            at, ints, buffer, np.asarray(starts, dtype=np.int64),
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
    """First rows of the shooting segments of ``segment`` seconds (a short last one merged)."""
    length = max(1, round(segment / log.dt))
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


def _start(problem: _Problem) -> np.ndarray:
    """Nominal parameters (the lag at ``TAU_START dt``), each segment from its measured pose."""
    values = np.array([NOMINAL[p] for p in PARAMETERS])
    values[_TAU] = TAU_START * problem.log.dt
    return np.concatenate((values[problem.free], problem.log.z[problem.starts].ravel()))


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
    covariance: np.ndarray | None = None

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
            fits[d] = (problem, _fit(problem, _start(problem)))
            chi2[d] = 2.0 * fits[d][1].cost
        best = min(chi2, key=chi2.get)
        problem, res = fits[best]
        at_bound = bool(free[_TAU]) and problem.unpack(res.x)[0][_TAU] < TAU_ZERO * log.dt
        if at_bound:  # the lag at its bound 0: refit without it (the search keeps it free)
            problem = _Problem(log, best, free & (np.arange(len(free)) != _TAU), starts, sigma)
            res = _fit(problem, _start(problem))
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
    cov = s2 * np.linalg.pinv(J.T @ J)
    columns = [*range(int(free.sum())), *([J.shape[1] - 1] if at_bound else [])]
    where = [PARAMETERS.index(name) for name in names]
    covariance = np.full((len(PARAMETERS), len(PARAMETERS)), np.nan)
    covariance[np.ix_(where, where)] = cov[np.ix_(columns, columns)]
    se = {name: math.sqrt(max(covariance[i, i], 0.0)) if i in where else math.nan
          for i, name in enumerate(PARAMETERS)}  # fmt: skip
    profile = {d: (c - chi2[best]) / s2 for d, c in chi2.items()}
    delay_set = tuple(d for d in delays if profile[d] <= CHI2_95)
    if "delay_steps" in ruled:
        reasons["delay_steps"] = ruled["delay_steps"]
    elif len(delays) > 1 and len(delay_set) == len(delays):
        reasons["delay_steps"] = (f"every delay searched (0..{max_delay}) fits alike "
                                  f"(Δχ² <= {CHI2_95:.2f})")  # fmt: skip
    fitted = problem.simulate(res.x)
    r = log.z - fitted
    r[:, 2] = _wrap(r[:, 2])
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
    lagged = values.copy()
    lagged[_TAU] = 0.25 * problem.log.dt
    log = problem.log
    d = (replay(log, values, problem.delay, problem.starts, q0, problem.max_substeps)
         - replay(log, lagged, problem.delay, problem.starts, q0, problem.max_substeps))
    return (d / (0.25 * log.dt) / problem.sigma).ravel()


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _notes(ident: Identification) -> dict[str, str]:
    """One comment per parameter of the written table: its interval, or why it is left out."""
    out = {}
    for name in PARAMETERS:
        if name in ident.not_identifiable:
            out[name] = f"not identifiable from this log: {ident.not_identifiable[name]}"
        elif name == "actuator_tau" and ident.lag_at_bound:
            out[name] = (f"at its bound 0 (no lag found); 95 % upper limit "
                         f"{_fmt(ident.interval(name)[1])} s")  # fmt: skip
        else:
            lo, hi = ident.interval(name)
            out[name] = f"95 % interval [{_fmt(lo)}, {_fmt(hi)}] {UNITS[name]}"
    if "delay_steps" in ident.not_identifiable:
        out["delay_steps"] = f"not identifiable from this log: {ident.not_identifiable['delay_steps']}"
    else:
        searched = f"searched 0..{ident.max_delay}"
        exact = "exact" if len(ident.delay_set) == 1 else "not exact"
        out["delay_steps"] = (f"{searched}; 95 % set {{{', '.join(map(str, ident.delay_set))}}} "
                              f"({exact})" + ("; at the edge of the search: raise --max-delay"
                                              if ident.delay == ident.max_delay else ""))  # fmt: skip
    return out


def _conditional(ident: Identification) -> list[str]:
    """A comment line when the delay is not exact: the intervals hold given the chosen one."""
    if "delay_steps" in ident.not_identifiable or len(ident.delay_set) <= 1:
        return []
    return [f"# the intervals hold given delay_steps = {ident.delay}; the delay is not exact "
            f"(95 % set {{{', '.join(map(str, ident.delay_set))}}})"]


def to_toml(ident: Identification) -> str:
    """The fitted ``[plant]`` table (DESIGN §3.3) as TOML text, for a scenario to include (append
    it to a scenario without a ``[plant]``).  Parameters the log cannot identify are left out
    (their defaults apply), each with a comment saying why; the others carry their interval."""
    notes = _notes(ident)
    rms = ", ".join(f"{c} {_fmt(v)}" for c, v in zip(("x", "y", "theta"), ident.rms, strict=True))
    lines = [f"# [plant] fitted by `wmr identify` to {one_line(ident.source)}: {ident.n} rows of "
             f"dt = {ident.dt:g} s, output error over {len(ident.starts)} segment(s)",
             f"# residual RMS {rms} (m, m, rad); weighted residual variance s^2 = "
             f"{ident.s2:.4g} (1: the model explains the log down to its noise)",
             *_conditional(ident), "[plant]", 'model = "kinematic"']  # fmt: skip
    for name in (*PARAMETERS[:-1], "delay_steps", PARAMETERS[-1]):
        if name in ident.not_identifiable:
            lines.append(f"# {name}: {notes[name]}")
            continue
        value = ident.delay if name == "delay_steps" else (
            0.0 if name == "actuator_tau" and ident.lag_at_bound else ident.values[name])
        lines.append(f"{f'{name} = {value!r}':<31} # {notes[name]}")
    return "\n".join(lines) + "\n"


def report(ident: Identification) -> str:
    """A human-readable summary: estimates, standard errors, intervals, the delay's profile,
    what could not be identified and the fit's residual."""
    notes = _notes(ident)
    lines = [f"{one_line(ident.source)}: {ident.n} rows, dt = {ident.dt:g} s, "
             f"{len(ident.starts)} shooting segment(s) of {ident.segment:g} s",
             f"{'parameter':<14}{'estimate':>12}{'std error':>12}  note"]  # fmt: skip
    for name in PARAMETERS:
        if name in ident.not_identifiable:
            lines.append(f"{name:<14}{'-':>12}{'-':>12}  {notes[name]}")
        else:
            lines.append(f"{name:<14}{_fmt(ident.values[name]):>12}{_fmt(ident.se[name]):>12}"
                         f"  {notes[name]}")  # fmt: skip
    delay = "-" if "delay_steps" in ident.not_identifiable else str(ident.delay)
    lines.append(f"{'delay_steps':<14}{delay:>12}{'':>12}  {notes['delay_steps']}")
    prof = ", ".join(f"{d}: {v:.1f}" for d, v in ident.profile.items())
    lines.append(f"delay profile (Δχ² per delay): {prof}")
    rms = ", ".join(f"{c} {_fmt(v)}" for c, v in zip(("x", "y", "theta"), ident.rms, strict=True))
    noise = ", ".join(_fmt(v) for v in ident.sigma)
    lines.append(f"residual RMS {rms} (m, m, rad); noise level from second differences {noise};"
                 f" s^2 = {ident.s2:.4g}")  # fmt: skip
    return "\n".join([*lines, *(c[2:] for c in _conditional(ident))])
