"""Nonlinear model-predictive tracking control on the nominal unicycle, with CasADi.

A Python-level controller (DESIGN §3.8, ``PyController``): ``make(settings, scenario, rng)``
returns an :class:`NMPC` whose ``step(q_hat, ref, dt)`` is called once per control step.

The optimal control problem at ``t_k`` (single shooting over the ``N`` inputs of the horizon,
the prediction step ``h = m dt``, ``m`` a whole number)::

    min_U  sum_{j=0}^{N-1} [ r_v (v_j - v_r,j)^2 + r_w (w_j - w_r,j)^2 ]
         + sum_{j=1}^{N} c_j [ q_p |p_j - p_r,j|^2 + q_th 2 (1 - cos(th_j - th_r,j)) ]      (M1)
    s.t.  q_0 = q_hat_k,   q_{j+1} = step(q_j, u_j, h),   |v_j| <= v_max,  |w_j| <= w_max   (M2)

with ``c_j = 1`` and ``c_N = terminal_weight``; the reference rows are those of the scenario's
reference at ``t_k + j h`` (``wmr.model.references.ReferenceSampler``, the sampler the loop reads),
``step`` the nominal model's zero-order-hold step with the scenario's integrator
(``wmr.model.symbolic.step_function``; the exact arc by default).  The heading term is the wrapped
error: ``2 (1 - cos d) = sin(d)^2 + (1 - cos d)^2`` is smooth, 2 pi-periodic and ``d^2 + O(d^4)``,
so a robot a turn away from the reference's unwrapped heading is not penalised for the turn.
The cost is a sum of squared residuals ``r(U)^T r(U)``: the solvers use its Gauss-Newton Hessian
``2 J^T J`` (positive semi-definite, no convexification needed).

Bounds: those of the scenario's ``[limits]`` (none without it: no arm gets bounds the others
lack).  Warm start: the previous solution shifted by one control period ``dt`` in time
(:func:`shift`).  Solvers (``Settings.solver``):

- ``"sqp"``: ``sqpmethod`` with ``qrqp`` and the Gauss-Newton Hessian, iterated to
  ``tolerance``;
- ``"rti"``: the real-time iteration, ``rti_iterations`` (default one) Gauss-Newton steps from
  the warm start: ``J, r`` from CasADi (its function buffer, :class:`JacobianBuffer`), the
  box-constrained QP ``min d^T J^T J d + 2 r^T J d`` by :func:`box_qp` (numpy);
- ``"ipopt"``: interior point, warm-started.

The default is ``"rti"``, by measurement (this 2-core machine, shared, load 4-6; the whole
``step`` including the preview, N = 20, h = 0.1 s, poses of a BSC run on the lemniscate):

=====================  =========================  ===========================
solver                 no limits: median / p95    limits 0.45 m/s, 0.5 rad/s
=====================  =========================  ===========================
``rti``                0.13 / 0.20 ms             0.24 / 1.0 ms
``rti``, 2 iterations  0.22 / 0.32 ms             0.45 / 1.3 ms
``sqp``                4.7 / 13 ms                3.5 / 5.3 ms
``ipopt``              3.3 / 10 ms                7.2 / 10 ms
=====================  =========================  ===========================

Within ``rti`` the pieces were measured too: CasADi's ``qrqp`` on the dense 40 x 40 QP costs
0.35 ms from Python and converting a 120 x 40 CasADi matrix to numpy 0.4 ms, against 20 us for
the Jacobian through the function buffer and 15-60 us for :func:`box_qp`; hence the numpy QP.
Converged solvers agree with ipopt to 1e-10 (``tests/test_nmpc.py``); along a closed-loop run on
the lemniscate (seed 0, measurement noise) the RTI's first command differs from the converged one
by a median 1.6e-3 m/s and 2.3e-3 rad/s (95th percentile 1.4e-2 both; 2 iterations: 2e-5 and
1e-5), with the same RMSE after the transient (2.2 mm) as the converged ``sqp``.  With a large
error and saturated inputs, ``sqp``'s Gauss-Newton Hessian converges only linearly and can hit
``max_iterations`` (a stated failure); ipopt's exact Hessian does not.

The problem is built once per process for each structure (horizon, integrator, solver and its
options) and cached (:func:`problem`); weights, prediction step, reference and pose are its
parameters, so every run reuses it.  A solver failure (not converged, or a non-finite answer)
falls back to the shifted previous solution; after ``max_failures`` consecutive failures the run
stops with :class:`ControllerStopped`, naming the cause.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass

import numpy as np

from wmr._settings import SettingError, check
from wmr.controllers.stopped import ControllerStopped
from wmr.model.references import ReferenceSampler

__all__ = ["Settings", "SOLVERS", "ControllerStopped", "Problem", "problem", "shift", "NMPC",
           "make", "STATE_NAMES", "box_qp", "JacobianBuffer", "SolveRecord", "TimeHistogram"]

#: Values of ``Settings.solver``.
SOLVERS = ("rti", "sqp", "ipopt")
#: Signals logged along a run: the solve time of the step and the solver's failure flag.
STATE_NAMES: tuple[str, ...] = ("solve_time", "solver_failed")
#: Reference rows fetched from the sampler at a time (the preview buffer grows by this much).
_CHUNK = 4096


@dataclass(frozen=True)
class Settings:
    """Nonlinear MPC settings.

    Attributes
    ----------
    horizon : int [-]
        ``N``, the number of prediction steps, >= 1.  Default 20 (2 s with the default ``h``).
    prediction_step : float [s]
        ``h``, > 0 and a whole multiple of the scenario's ``dt`` (checked against the file's
        ``dt`` when a scenario file sets it, and when the controller is made).  ``N h`` is the
        horizon in time.  Default 0.1 s.
    weights : tuple of float [1/m^2, 1/rad^2, s^2/m^2, s^2/rad^2]
        ``(q_p, q_th, r_v, r_w)`` of (M1), each > 0.  Default ``(10, 1, 0.1, 0.1)``: of the
        four sets tried on the paper's scenarios (3 seeds; ``r = 0.3`` or 1, ``q_th = 3``) the
        lowest position RMSE after the transient on the perturbed sinusoid (15 mm against
        23-40 mm) and within 0.3 mm of the best on the other two.
    terminal_weight : float [-]
        ``c_N`` of (M1), the factor on the last stage's pose terms, > 0.  Default 10.
    solver : str [-]
        ``"rti"``, ``"sqp"`` or ``"ipopt"`` (module docstring: ``"rti"`` by measurement).
    tolerance : float [-]
        Convergence tolerance of ``"sqp"`` (primal and dual) and ``"ipopt"``, > 0.
    max_iterations : int [-]
        Iteration limit of ``"sqp"`` and ``"ipopt"``, >= 1.
    rti_iterations : int [-]
        Gauss-Newton steps per control step of ``"rti"`` (1: the real-time iteration), >= 1.
    max_failures : int [-]
        Consecutive solver failures after which the run stops, >= 1.
    """

    horizon: int = 20
    prediction_step: float = 0.1
    weights: tuple[float, ...] = (10.0, 1.0, 0.1, 0.1)
    terminal_weight: float = 10.0
    solver: str = "rti"
    tolerance: float = 1e-10
    max_iterations: int = 50
    rti_iterations: int = 1
    max_failures: int = 10

    def __post_init__(self):
        check(self.horizon >= 1, "horizon", self.horizon, "must be an integer >= 1")
        check(math.isfinite(self.prediction_step) and self.prediction_step > 0,
              "prediction_step", self.prediction_step, "must be > 0")  # fmt: skip
        for w in self.weights:
            check(math.isfinite(w) and w > 0, "weights", self.weights, "entries must be > 0")
        check(math.isfinite(self.terminal_weight) and self.terminal_weight > 0,
              "terminal_weight", self.terminal_weight, "must be > 0")  # fmt: skip
        check(self.solver in SOLVERS, "solver", self.solver,
              f"must be one of {', '.join(SOLVERS)}")  # fmt: skip
        check(math.isfinite(self.tolerance) and self.tolerance > 0, "tolerance", self.tolerance,
              "must be > 0")  # fmt: skip
        check(self.max_iterations >= 1, "max_iterations", self.max_iterations, "must be >= 1")
        check(self.rti_iterations >= 1, "rti_iterations", self.rti_iterations, "must be >= 1")
        check(self.max_failures >= 1, "max_failures", self.max_failures, "must be >= 1")

    def check_dt(self, dt: float) -> None:
        """The scenario loader's check of settings against the control period ``dt`` [s]
        (``wmr.scenario``): :meth:`steps_per_prediction`."""
        self.steps_per_prediction(dt)

    def steps_per_prediction(self, dt: float) -> int:
        """``m = h / dt``; :class:`SettingError` unless it is a whole number (to 1e-9)."""
        m = self.prediction_step / dt
        check(m >= 1 - 1e-9 and abs(m - round(m)) <= 1e-9 * max(1.0, m), "prediction_step",
              self.prediction_step, f"must be a whole multiple of dt = {dt:g}")  # fmt: skip
        return int(round(m))


# ---------------------------------------------------------------------------------------------
# The problem, built once per structure


@dataclass(frozen=True)
class Problem:
    """The OCP (M1)-(M2) for one structure (built by :func:`problem`).

    ``x = vec(U)`` (2N,) holds ``(v_0, w_0, v_1, ...)``; the parameter vector ``p`` holds the
    pose ``q_0`` (3), the reference rows ``j = 0 .. N`` (5 each, ``(x_r, y_r, th_r, v_r, w_r)``),
    the weights ``(q_p, q_th, r_v, r_w)``, ``terminal_weight`` and ``h`` (:meth:`parameters`).
    ``cost(x, p)`` is ``f = r^T r``, ``jacobian(x, p)`` gives ``(J, r)`` (``J = dr/dx`` dense);
    ``solver`` is the nlpsol of ``"sqp"`` / ``"ipopt"`` (None for ``"rti"``, whose
    ``iterations`` Gauss-Newton steps are :func:`box_qp` solves of ``2 J^T J d = -2 J^T r``).
    """

    horizon: int
    solver_name: str
    iterations: int
    cost: object  # casadi.Function
    jacobian: object  # casadi.Function
    solver: object | None  # casadi.Function (nlpsol)

    @staticmethod
    def parameters(q0, rows, weights, terminal_weight, h) -> np.ndarray:
        """The parameter vector ``p`` (``rows`` of shape (N + 1, 5))."""
        return np.concatenate((np.asarray(q0, dtype=float), np.asarray(rows, float).ravel(),
                               weights, (terminal_weight, h)))  # fmt: skip

    def evaluator(self) -> JacobianBuffer:
        """A :class:`JacobianBuffer` of :attr:`jacobian` (one per controller object)."""
        return JacobianBuffer(self.jacobian)

    def gauss_newton(self, x, p, lbx, ubx, jacobian=None):
        """One Gauss-Newton step from ``x`` within the bounds: ``(x + d, ok)``."""
        J, r = (jacobian or self.evaluator())(x, p)
        H, g = 2.0 * (J.T @ J), 2.0 * (J.T @ r)
        d, ok = box_qp(H, g, lbx - x, ubx - x)
        return x + d, ok

    def solve(self, x0, p, lbx, ubx, lam_x0, jacobian=None):
        """One solve from ``x0``: ``(x, lam_x, ok, status)``; ``ok`` is False when the solver
        reports failure or returns a non-finite point.  ``jacobian``: the caller's
        :class:`JacobianBuffer` for ``"rti"`` (made here when not given)."""
        if self.solver_name == "rti":
            x, ok = np.asarray(x0, dtype=float), True
            jacobian = jacobian or self.evaluator()
            for _ in range(self.iterations):
                x, ok_qp = self.gauss_newton(x, p, lbx, ubx, jacobian)
                ok = ok and ok_qp
            ok = ok and bool(np.all(np.isfinite(x)))
            return x, lam_x0, ok, "Gauss-Newton step" if ok else "Gauss-Newton QP failed"
        sol = self.solver(x0=x0, p=p, lbx=lbx, ubx=ubx, lam_x0=lam_x0)
        stats = self.solver.stats()
        x = np.asarray(sol["x"]).ravel()
        ok = bool(stats.get("success", False)) and bool(np.all(np.isfinite(x)))
        return x, np.asarray(sol["lam_x"]).ravel(), ok, str(stats.get("return_status", ""))


class JacobianBuffer:
    """``(J, r)`` of a :attr:`Problem.jacobian` evaluated into preallocated arrays (CasADi's
    function buffer: no conversion of its outputs, ~20 us instead of ~0.4 ms per call).  Not
    shared between threads: each controller object has its own."""

    def __init__(self, f):
        self._buf, self._eval = f.buffer()
        self._x, self._p = np.zeros(f.nnz_in(0)), np.zeros(f.nnz_in(1))
        self._J, self._r = np.zeros(f.nnz_out(0)), np.zeros(f.nnz_out(1))
        for i, a in enumerate((self._x, self._p)):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate((self._J, self._r)):
            self._buf.set_res(i, memoryview(a))
        self._rows, self._cols = f.size_out(0)

    def __call__(self, x, p) -> tuple[np.ndarray, np.ndarray]:
        """``J`` (n_r, n_x) and ``r`` (n_r,) at ``(x, p)``: views, valid until the next call."""
        self._x[:] = x
        self._p[:] = p
        self._eval()
        return self._J.reshape(self._cols, self._rows).T, self._r


def box_qp(H: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray,
           max_iter: int | None = None) -> tuple[np.ndarray, bool]:
    """``argmin_d  d^T H d / 2 + g^T d``  s.t.  ``lo <= d <= hi``, for ``H`` positive definite
    and ``lo <= 0 <= hi`` (so ``d = 0`` is feasible): a primal active-set method.

    From ``d = 0``, with the bounds it touches (``lo = 0`` or ``hi = 0``: a warm start at its
    bounds) as the working set, each iteration solves the equality-constrained problem on the
    free entries (the working set held at its bounds); if that point is infeasible it moves to
    the first bound on the way and adds it, otherwise it drops the bound with the most negative
    multiplier, and stops when every multiplier has the right sign (the KKT point, exact up to
    rounding).  Without finite bounds this is one linear solve.

    Returns
    -------
    d : ndarray
    ok : bool
        False if ``max_iter`` (default ``3 n + 10``) iterations did not reach the KKT point.
    """
    n = g.size
    if not (np.isfinite(lo).any() or np.isfinite(hi).any()):
        return np.linalg.solve(H, -g), True
    d = np.zeros(n)
    fixed = (lo >= 0.0) | (hi <= 0.0)
    tol = 1e-12 * (1.0 + float(np.abs(g).max()))
    for _ in range(max_iter or 3 * n + 10):
        free = ~fixed
        target = d.copy()
        if free.any():
            rhs = -(g[free] + H[np.ix_(free, fixed)] @ d[fixed])
            target[free] = np.linalg.solve(H[np.ix_(free, free)], rhs)
        step = target - d
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(step > 0, (hi - d) / step, np.where(step < 0, (lo - d) / step,
                                                                 np.inf))  # fmt: skip
        ratio[fixed] = np.inf
        i = int(np.argmin(ratio))
        if ratio[i] < 1.0:  # blocked: move to the bound and hold it
            d = d + ratio[i] * step
            d[i] = hi[i] if step[i] > 0 else lo[i]
            fixed[i] = True
            continue
        d = target
        grad = H @ d + g  # multipliers of the held bounds (sign by side)
        wrong = np.where(fixed, np.where(d >= hi, grad, -grad), -np.inf)
        j = int(np.argmax(wrong))
        if wrong[j] <= tol:
            return d, True
        fixed[j] = False
    return d, False


def _residual(horizon: int, integrator: str):
    """``(x, p, r)`` symbols of (M1)-(M2) in least-squares form."""
    import casadi as ca

    from wmr.model.symbolic import step_function

    n = horizon
    x = ca.SX.sym("U", 2 * n)
    q0 = ca.SX.sym("q0", 3)
    rows = ca.SX.sym("R", 5 * (n + 1))
    w = ca.SX.sym("w", 4)
    c_n = ca.SX.sym("c_N")
    h = ca.SX.sym("h")
    step = step_function(integrator)
    sq = [ca.sqrt(w[i]) for i in range(4)]
    res = []
    q = q0
    for j in range(n):
        u = x[2 * j : 2 * j + 2]
        ref, nxt = rows[5 * j : 5 * j + 5], rows[5 * (j + 1) : 5 * (j + 2)]
        res += [sq[2] * (u[0] - ref[3]), sq[3] * (u[1] - ref[4])]
        q = step(q, u, h)
        c = ca.sqrt(c_n) if j == n - 1 else 1.0
        d = q[2] - nxt[2]
        res += [c * sq[0] * (q[0] - nxt[0]), c * sq[0] * (q[1] - nxt[1]),
                c * sq[1] * ca.sin(d), c * sq[1] * (1.0 - ca.cos(d))]  # fmt: skip
    return x, ca.vertcat(q0, rows, w, c_n, h), ca.vertcat(*res)


_QP_OPTIONS = {"print_iter": False, "print_header": False, "print_info": False,
               "error_on_fail": False}  # fmt: skip


@functools.cache
def problem(horizon: int, integrator: str = "exact", solver: str = "rti",
            tolerance: float = 1e-10, max_iterations: int = 1) -> Problem:
    """The :class:`Problem` of this structure, built on first use and cached for the process
    (``max_iterations``: the iteration limit of ``"sqp"`` and ``"ipopt"``, the number of
    Gauss-Newton steps of ``"rti"``).  CasADi and ``wmr.model.symbolic`` are imported here, on first
    use, not with the module: importing any ``wmr`` module loads neither
    (``tests/test_symbolic.py``), and only a run of ``nmpc`` does (``wmr.model.symbolic``'s
    docstring)."""
    import casadi as ca

    x, p, r = _residual(horizon, integrator)
    J = ca.jacobian(r, x)
    f = ca.dot(r, r)
    cost = ca.Function("nmpc_cost", [x, p], [f], ["x", "p"], ["f"])
    jac = ca.Function("nmpc_jacobian", [x, p], [ca.densify(J), r], ["x", "p"], ["J", "r"],
                      {"cse": True})  # fmt: skip
    nlp = {"x": x, "p": p, "f": f}
    if solver == "rti":
        fn = None
    elif solver == "sqp":
        H = 2.0 * ca.mtimes(J.T, J)  # Gauss-Newton Hessian of f = r^T r
        lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", 0)
        hess = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [lam_f * H],
                           ["x", "p", "lam_f", "lam_g"], ["hess_gamma_x_x"])  # fmt: skip
        fn = ca.nlpsol("nmpc_sqp", "sqpmethod", nlp, {
            "qpsol": "qrqp", "qpsol_options": _QP_OPTIONS, "hess_lag": hess,
            "max_iter": max_iterations, "tol_pr": tolerance, "tol_du": tolerance,
            "print_header": False, "print_iteration": False, "print_time": False,
            "print_status": False, "error_on_fail": False})  # fmt: skip
    elif solver == "ipopt":
        fn = ca.nlpsol("nmpc_ipopt", "ipopt", nlp, {
            "ipopt.print_level": 0, "ipopt.sb": "yes", "print_time": False,
            "ipopt.tol": tolerance, "ipopt.max_iter": max_iterations,
            "ipopt.warm_start_init_point": "yes", "error_on_fail": False})  # fmt: skip
    else:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVERS}")
    return Problem(horizon, solver, max_iterations, cost, jac, fn)


def shift(U: np.ndarray, fraction: float) -> np.ndarray:
    """The warm start: the input sequence ``U`` (N, 2) of prediction step ``h`` shifted by
    ``fraction = dt / h`` of a step in time, each new interval the time average of the old
    solution over it (``(1 - a) U_j + a U_{j+1}``, the last input held): for ``h = dt`` the
    classical shift by one, ``[U_1 .. U_{N-1}, U_{N-1}]``."""
    U = np.asarray(U, dtype=float)
    nxt = np.vstack((U[1:], U[-1:]))
    return (1.0 - fraction) * U + fraction * nxt


# ---------------------------------------------------------------------------------------------
# The controller object


class NMPC:
    """One run's NMPC (``make``): the cached problem, the reference preview, the warm start and
    the solve-time record.

    Parameters
    ----------
    settings : Settings
    scenario : wmr.scenario.Scenario
        Its ``dt``, ``integrator`` (the prediction model), ``[limits]`` and reference.
    """

    def __init__(self, settings: Settings, scenario):
        self.settings = settings
        self.dt = float(scenario.dt)
        try:
            self.m = settings.steps_per_prediction(self.dt)
        except SettingError as err:
            raise SettingError(f"controllers.nmpc.{err.key}", err.value, err.reason) from None
        self.h = self.m * self.dt
        iterations = settings.rti_iterations if settings.solver == "rti" else \
            settings.max_iterations
        self.problem = problem(settings.horizon, scenario.integrator, settings.solver,
                               settings.tolerance, iterations)  # fmt: skip
        n = settings.horizon
        lim = scenario.limits
        self.ubx = np.tile((lim.v_max, lim.w_max), n).astype(float)
        self.lbx = -self.ubx
        self.weights = np.array(settings.weights, dtype=float)
        self._jacobian = self.problem.evaluator() if settings.solver == "rti" else None
        ref = scenario.reference
        self._sampler = ReferenceSampler(ref.kind, ref.params, self.dt)
        self._rows = np.zeros((0, 5))
        self._base = 0  # sampler row index of self._rows[0]
        self._k = 0
        self._U: np.ndarray | None = None  # the warm start for this step, (N, 2)
        self._lam = np.zeros(2 * n)
        self._times = TimeHistogram()
        self._failed = 0  # consecutive failures
        self._n_failed = 0
        self._last = (0.0, 0.0)  # no step yet

    def preview(self, k: int) -> np.ndarray:
        """Reference rows at ``t_k + j h``, ``j = 0 .. N``, shape (N + 1, 5), from the
        scenario's sampler (rows fetched in order, kept from ``t_k`` on)."""
        last = k + self.settings.horizon * self.m
        end = self._base + len(self._rows)  # the sampler's next row
        if last >= end:
            new = self._sampler.rows(end, max(last + 1, end + _CHUNK))
            self._rows = np.vstack((self._rows, new))
        drop = k - self._base
        if drop > 0:
            self._rows, self._base = self._rows[drop:], k
        return self._rows[k - self._base : last - self._base + 1 : self.m]

    def step(self, q_hat, ref, dt) -> tuple[float, float]:
        """The command ``(v, w)`` at step ``k`` (calls in order from ``k = 0``).

        Raises
        ------
        ControllerStopped
            After ``max_failures`` consecutive solver failures.
        """
        t0 = time.perf_counter()
        k = self._k
        rows = self.preview(k).copy()
        rows[0] = ref[:5]
        guess = self._U
        if guess is None:  # the reference's own inputs, within the bounds
            guess = np.clip(rows[:-1, 3:5], self.lbx[:2], self.ubx[:2])
        p = Problem.parameters(q_hat, rows, self.weights, self.settings.terminal_weight, self.h)
        x, lam, ok, status = self.problem.solve(guess.ravel(), p, self.lbx, self.ubx, self._lam,
                                                self._jacobian)
        if ok:
            U, self._failed = x.reshape(-1, 2), 0
            self._lam = shift(lam.reshape(-1, 2), self.dt / self.h).ravel()
        else:
            U = guess
            self._failed += 1
            self._n_failed += 1
            if self._failed >= self.settings.max_failures:
                raise ControllerStopped(
                    f"nmpc: the {self.settings.solver} solver failed {self._failed} times in a "
                    f"row (last: {status or 'failed'}) at t = {k * self.dt:g} s")
        u = np.clip(U[0], self.lbx[:2], self.ubx[:2])
        self._U = shift(U, self.dt / self.h)
        self._k = k + 1
        elapsed = time.perf_counter() - t0
        self._times.add(elapsed)
        self._last = (elapsed, 0.0 if ok else 1.0)
        return float(u[0]), float(u[1])

    def signals(self) -> tuple[float, ...]:
        """The current values of :data:`STATE_NAMES`: the last step's time [s] and whether its
        solve failed (1.0) or not (0.0); ``(0, 0)`` before the first step."""
        return self._last

    def final(self) -> SolveRecord:
        """The run record's controller entry (``RunResult.final``): the solve-time distribution
        of the whole ``step`` (:class:`TimeHistogram`: O(1) memory however long the run) and the
        failures (:class:`SolveRecord`)."""
        h = self._times
        return SolveRecord(solver=self.settings.solver, steps=h.n,
                           solve_time_median=h.quantile(0.5), solve_time_p95=h.quantile(0.95),
                           solve_time_max=h.max, failures=self._n_failed)  # fmt: skip


class TimeHistogram:
    """Step times [s] counted in log-spaced bins, for the run record's percentiles in O(1)
    memory (a run of hours keeps no per-step list; ``tests/test_reliability.py`` checks memory
    does not grow with the run length).

    Bins: :data:`PER_DECADE` per decade from :data:`LOW` s over :data:`DECADES` decades (width
    ``10^(1/200) - 1 = 1.2 %``), plus one below and one above.  :meth:`quantile` interpolates
    linearly between the geometric bin centres of the order statistics around rank
    ``q (n - 1)`` (numpy's default definition on the binned values), so it is within half a bin,
    0.6 %, of ``numpy.percentile`` of the exact times; :attr:`max` is exact.
    """

    LOW, DECADES, PER_DECADE = 1e-6, 8, 200

    def __init__(self):
        self.counts = np.zeros(self.DECADES * self.PER_DECADE + 2, dtype=np.int64)
        self.n = 0
        self.max = math.nan

    def add(self, t: float) -> None:
        """Count one time ``t`` [s]."""
        x = math.log10(t / self.LOW) * self.PER_DECADE if t > 0 else -1.0
        i = min(max(int(math.floor(x)) + 1, 0), self.counts.size - 1)
        self.counts[i] += 1
        self.n += 1
        self.max = t if not t <= self.max else self.max  # NaN-safe first value

    def _centre(self, i: int) -> float:
        j = min(max(i - 1, 0), self.counts.size - 3)  # the outer bins report the range's ends
        return self.LOW * 10.0 ** ((j + 0.5) / self.PER_DECADE)

    def quantile(self, q: float) -> float:
        """The ``q`` quantile [s] (NaN before the first time)."""
        if self.n == 0:
            return math.nan
        r = q * (self.n - 1)
        lo, frac = int(math.floor(r)), r - math.floor(r)
        cum = np.cumsum(self.counts)
        a = self._centre(int(np.searchsorted(cum, lo + 1)))
        b = self._centre(int(np.searchsorted(cum, min(lo + 2, self.n))))
        return min(a + frac * (b - a), self.max)


@dataclass(frozen=True)
class SolveRecord:
    """The end-of-run record of an :class:`NMPC` (``NMPC.final``).

    Attributes
    ----------
    solver : str
        ``Settings.solver``.
    steps : int
        Control steps taken.
    solve_time_median, solve_time_p95, solve_time_max : float [s]
        Median, 95th percentile and maximum of the wall time of ``step`` (preview, solve and
        bookkeeping) over the run; NaN before the first step.
    failures : int
        Steps whose solve failed (each fell back to the shifted previous solution).
    """

    solver: str
    steps: int
    solve_time_median: float
    solve_time_p95: float
    solve_time_max: float
    failures: int


def make(settings: Settings, scenario, rng: np.random.Generator | None = None) -> NMPC:
    """The ``PyController`` factory: an :class:`NMPC` for one run (``rng`` is not used)."""
    return NMPC(settings, scenario)
