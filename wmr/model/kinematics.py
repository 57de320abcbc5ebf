"""Unicycle kinematics (eq. 1), its zero-order-hold steps and their Jacobians, the error frame.

The continuous model is eq. (1) of the paper::

    x' = v cos(theta),  y' = v sin(theta),  theta' = w.

With the input ``u = (v, w)`` held constant over ``[t_k, t_k + dt]`` (zero-order hold) the
motion is an arc, which :func:`step` integrates exactly (``EXACT``, the default) or with the
explicit Euler (``EULER``) or classical Runge-Kutta (``RK4``) schemes.  Each step sits beside its
Jacobians with respect to the pose and the input (:func:`step_jacobians`).

The closed loop calls the allocation-free forms (:func:`tracking_error_parts` returns scalars,
:func:`step_into` and :func:`step_jacobians_into` write into the caller's buffers); the functions
that return arrays wrap them, so both give the same numbers.

The tracking error of eq. (6) is ``e = T_e(theta) (q_r - q)`` with ``e3`` wrapped to (-pi, pi].
The paper prints ``T_e`` with second row ``[sin, cos, 0]``; the rotation into the robot frame has
``[-sin, cos, 0]`` (errata E3).  The printed matrix is kept behind ``printed=True``.
"""

from __future__ import annotations

import math

import numpy as np

from wmr._jit import njit

__all__ = [
    "EXACT",
    "EULER",
    "RK4",
    "INTEGRATORS",
    "integrator_code",
    "wrap_angle",
    "unicycle_rhs",
    "input_matrix",
    "step",
    "step_into",
    "step_jacobians",
    "step_jacobians_into",
    "rotation",
    "tracking_error",
    "tracking_error_parts",
    "sinc",
    "sinc_and_derivative",
]

EXACT, EULER, RK4 = 0, 1, 2
#: User-facing integrator names and their codes inside jitted code.
INTEGRATORS = {"exact": EXACT, "euler": EULER, "rk4": RK4}


def integrator_code(name: str | int) -> int:
    """Return the integer code of an integrator given by name (``"exact"``, ...) or code."""
    if isinstance(name, int | np.integer) and int(name) in INTEGRATORS.values():
        return int(name)
    try:
        return INTEGRATORS[name]  # type: ignore[index]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown integrator {name!r}; expected one of {sorted(INTEGRATORS)}"
        ) from None


@njit(inline="always")
def wrap_angle(a):
    """Wrap an angle [rad] to (-pi, pi]."""
    r = math.atan2(math.sin(a), math.cos(a))
    if r == -math.pi:  # atan2 may return -pi exactly; the interval is half-open on that side
        r = math.pi
    return r


@njit
def unicycle_rhs(q, u):
    """Right-hand side of eq. (1): ``q' = G(theta) u``, shape (3,)."""
    out = np.empty(3)
    out[0] = u[0] * math.cos(q[2])
    out[1] = u[0] * math.sin(q[2])
    out[2] = u[1]
    return out


@njit
def input_matrix(theta):
    """``G(theta) = [[cos, 0], [sin, 0], [0, 1]]``, so that ``q' = G(theta) u``; shape (3, 2)."""
    G = np.zeros((3, 2))
    G[0, 0] = math.cos(theta)
    G[1, 0] = math.sin(theta)
    G[2, 1] = 1.0
    return G


@njit(inline="always")
def sinc(a):
    """``s(a) = sin(a)/a``, by its Taylor series near 0 (error < 1e-17 there)."""
    if abs(a) < 1e-4:
        a2 = a * a
        return 1.0 - a2 / 6.0 + a2 * a2 / 120.0
    return math.sin(a) / a


@njit(inline="always")
def sinc_and_derivative(a):
    """``s(a) = sin(a)/a`` (:func:`sinc`) and ``s'(a)``, by Taylor series near 0 (error < 1e-17
    there)."""
    s = sinc(a)
    if abs(a) < 1e-4:
        return s, -a / 3.0 + a * (a * a) / 30.0
    return s, (math.cos(a) - s) / a


@njit
def _rhs_jacobians(q, u, A, B):
    """Write ``A = df/dq`` (3, 3) and ``B = df/du`` (3, 2) of eq. (1) into A and B."""
    c = math.cos(q[2])
    s = math.sin(q[2])
    A[:, :] = 0.0
    A[0, 2] = -u[0] * s
    A[1, 2] = u[0] * c
    B[:, :] = 0.0
    B[0, 0] = c
    B[1, 0] = s
    B[2, 1] = 1.0


@njit
def step(q, u, dt, integrator=EXACT):
    """Advance the pose over one sample period with the input held constant.

    Parameters
    ----------
    q : ndarray, shape (3,)
        Pose ``(x [m], y [m], theta [rad])`` at ``t_k``.
    u : ndarray, shape (2,)
        Input ``(v [m/s], w [rad/s])`` held over ``[t_k, t_k + dt]``.
    dt : float
        Sample period [s].
    integrator : int
        ``EXACT`` (arc, default), ``EULER`` or ``RK4``.

    Returns
    -------
    ndarray, shape (3,)
        Pose at ``t_k + dt``; theta is not wrapped (it stays continuous).

    Notes
    -----
    The exact arc, with ``a = w dt / 2`` and ``sinc(a) = sin(a)/a``, is::

        x+ = x + v dt sinc(a) cos(theta + a)
        y+ = y + v dt sinc(a) sin(theta + a)
        theta+ = theta + w dt

    which equals ``x + v/w (sin(theta+) - sin(theta))`` for ``w != 0`` and the straight line for
    ``w = 0``, without the division by ``w``.  Computed by :func:`step_into`.
    """
    out = np.empty(3)
    step_into(q, u, dt, integrator, out)
    return out


@njit(inline="always")
def step_into(q, u, dt, integrator, out):
    """:func:`step` written into ``out`` (3,), which may be ``q`` itself (the pose advanced in
    place); no allocation.  The RK4 stages are held in scalars, summed in the order of the
    array expression ``q + dt/6 (k1 + 2 k2 + 2 k3 + k4)``."""
    v = u[0]
    w = u[1]
    x = q[0]
    y = q[1]
    th = q[2]
    if integrator == EXACT:
        a = 0.5 * w * dt
        s = sinc(a)
        phi = th + a
        out[0] = x + v * dt * s * math.cos(phi)
        out[1] = y + v * dt * s * math.sin(phi)
        out[2] = th + w * dt
    elif integrator == EULER:
        out[0] = x + dt * v * math.cos(th)
        out[1] = y + dt * v * math.sin(th)
        out[2] = th + dt * w
    else:  # k_i = (v cos theta_i, v sin theta_i, w) at the stage poses q + c_i dt k_{i-1}
        h = 0.5 * dt
        k1x, k1y = v * math.cos(th), v * math.sin(th)
        t2 = th + h * w
        k2x, k2y = v * math.cos(t2), v * math.sin(t2)
        t3 = th + h * w
        k3x, k3y = v * math.cos(t3), v * math.sin(t3)
        t4 = th + dt * w
        k4x, k4y = v * math.cos(t4), v * math.sin(t4)
        c = dt / 6.0
        out[0] = x + c * (k1x + 2.0 * k2x + 2.0 * k3x + k4x)
        out[1] = y + c * (k1y + 2.0 * k2y + 2.0 * k3y + k4y)
        out[2] = th + c * (w + 2.0 * w + 2.0 * w + w)


@njit
def _matmul(A, B):
    """``A @ B`` for the small matrices of this module, written out: no BLAS call, whose
    rounding would depend on the machine's BLAS kernel (determinism across machines)."""
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            a = A[i, k]
            for j in range(B.shape[1]):
                out[i, j] += a * B[k, j]
    return out


@njit
def step_jacobians(q, u, dt, integrator=EXACT):
    """Jacobians of :func:`step`: ``F = dq+/dq`` (3, 3) and ``G = dq+/du`` (3, 2).

    Derivation
    ----------
    *Exact* (``a = w dt/2``, ``s = sinc(a)``, ``phi = theta + a``)::

        dx+/dtheta = -v dt s sin(phi)          dy+/dtheta =  v dt s cos(phi)
        dx+/dv     =    dt s cos(phi)          dy+/dv     =    dt s sin(phi)
        dx+/dw = v dt^2/2 (s' cos(phi) - s sin(phi))
        dy+/dw = v dt^2/2 (s' sin(phi) + s cos(phi))
        dtheta+/dtheta = 1,  dtheta+/dw = dt.

    *Euler*: ``F = I + dt A(q)``, ``G = dt B(q)`` with ``A = df/dq``, ``B = df/du`` of eq. (1).

    *RK4*: the tangent of each stage is propagated with the chain rule; with
    ``q_i = q + c_i dt k_{i-1}`` and ``k_i = f(q_i, u)``,
    ``dk_i/dq = A(q_i) (I + c_i dt dk_{i-1}/dq)`` and
    ``dk_i/du = A(q_i) c_i dt dk_{i-1}/du + B(q_i)``; the step's Jacobians are the RK4 weighted
    sums of the stage tangents.  This is exact for the RK4 map (not an approximation of the
    flow's Jacobian).
    """
    F = np.empty((3, 3))
    G = np.empty((3, 2))
    step_jacobians_into(q, u, dt, integrator, F, G)
    return F, G


@njit(inline="always")
def step_jacobians_into(q, u, dt, integrator, F, G):
    """:func:`step_jacobians` written into ``F`` (3, 3) and ``G`` (3, 2); either may be None (not
    computed: the branch is pruned at compile time).  No allocation for the exact and Euler
    steps (the RK4 tangents are propagated in temporary matrices)."""
    if integrator != EXACT and integrator != EULER:
        _rk4_jacobians(q, u, dt, F, G)
        return
    v = u[0]
    w = u[1]
    if F is not None:
        F[:, :] = 0.0
        F[0, 0] = F[1, 1] = F[2, 2] = 1.0
    if G is not None:
        G[:, :] = 0.0
    if integrator == EXACT:
        a = 0.5 * w * dt
        s, ds = sinc_and_derivative(a)
        phi = q[2] + a
        c = math.cos(phi)
        sn = math.sin(phi)
        if F is not None:
            F[0, 2] = -v * dt * s * sn
            F[1, 2] = v * dt * s * c
        if G is not None:
            G[0, 0] = dt * s * c
            G[1, 0] = dt * s * sn
            G[0, 1] = 0.5 * v * dt * dt * (ds * c - s * sn)
            G[1, 1] = 0.5 * v * dt * dt * (ds * sn + s * c)
            G[2, 1] = dt
    else:
        c = math.cos(q[2])
        sn = math.sin(q[2])
        if F is not None:
            F[0, 2] = -dt * v * sn
            F[1, 2] = dt * v * c
        if G is not None:
            G[0, 0] = dt * c
            G[1, 0] = dt * sn
            G[2, 1] = dt


@njit
def _rk4_jacobians(q, u, dt, F, G):
    """The RK4 step's Jacobians (see :func:`step_jacobians`) into ``F`` and ``G`` (or None)."""
    A = np.empty((3, 3))
    B = np.empty((3, 2))
    Fq = np.zeros((3, 3))  # running sum of weighted stage tangents wrt q
    Fu = np.zeros((3, 2))  # ... and wrt u
    dk_dq = np.zeros((3, 3))
    dk_du = np.zeros((3, 2))
    k = np.zeros(3)
    coeffs = (0.0, 0.5, 0.5, 1.0)
    weights = (1.0, 2.0, 2.0, 1.0)
    eye = np.eye(3)
    for i in range(4):
        ci = coeffs[i] * dt
        qi = q + ci * k
        _rhs_jacobians(qi, u, A, B)
        dqi_dq = eye + ci * dk_dq
        dqi_du = ci * dk_du
        dk_dq = _matmul(A, dqi_dq)
        dk_du = _matmul(A, dqi_du) + B
        k = unicycle_rhs(qi, u)
        Fq += weights[i] * dk_dq
        Fu += weights[i] * dk_du
    if F is not None:
        F[:, :] = eye + dt / 6.0 * Fq
    if G is not None:
        G[:, :] = dt / 6.0 * Fu


@njit
def rotation(theta, printed=False):
    """The world-to-robot-frame matrix ``T_e(theta)`` of eqs. (4)/(6), shape (3, 3).

    ``printed=False`` (default) gives the rotation ``[[c, s, 0], [-s, c, 0], [0, 0, 1]]``
    (errata E3).  ``printed=True`` gives the paper's printed ``[[c, s, 0], [s, c, 0], [0, 0, 1]]``,
    whose determinant is ``cos(2 theta)`` (singular at theta = +-45 deg).
    """
    c = math.cos(theta)
    s = math.sin(theta)
    T = np.eye(3)
    T[0, 0] = c
    T[0, 1] = s
    T[1, 0] = s if printed else -s
    T[1, 1] = c
    return T


@njit
def tracking_error(q, q_r, printed=False):
    """Tracking error of eq. (6): ``e = T_e(theta) (q_r - q)``, shape (3,).

    ``q_r`` may be a full reference sample (length >= 3); only its pose is used.  ``e3`` is the
    wrapped heading error ``theta_r - theta`` (errata E2), in (-pi, pi].  Computed by
    :func:`tracking_error_parts`.
    """
    e = np.empty(3)
    e[0], e[1], e[2] = tracking_error_parts(q, q_r, printed)
    return e


@njit(inline="always")
def tracking_error_parts(q, q_r, printed=False):
    """:func:`tracking_error` as the scalars ``(e1, e2, e3)``: no allocation (the laws' form)."""
    c = math.cos(q[2])
    s = math.sin(q[2])
    dx = q_r[0] - q[0]
    dy = q_r[1] - q[1]
    return c * dx + s * dy, (s if printed else -s) * dx + c * dy, wrap_angle(q_r[2] - q[2])
