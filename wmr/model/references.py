"""Reference trajectories: lemniscate (Gerono), sinusoid, circle, waypoints (DESIGN §3.1, §3.4).

Each reference is a planar path ``(x_r(t), y_r(t))`` with analytic first and second
derivatives, from which (Kanayama 1990; errata E1)::

    theta_r = atan2(y_r', x_r')              (continuous, unwrapped)
    v_r     = sqrt(x_r'^2 + y_r'^2)
    w_r     = (x_r' y_r'' - y_r' x_r'') / (x_r'^2 + y_r'^2)

A sampled reference is an array of shape ``(len(t), 5)`` with columns
``(x_r, y_r, theta_r, v_r, w_r)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from wmr._jit import njit
from wmr.model import waypoints

__all__ = ["ReferenceKind", "KINDS", "path_derivatives", "sample", "ReferenceSampler"]


def _elementwise(path, t, *args):
    """``path(t_flat, *args) -> (6, n)`` on the times ``t`` of any shape: the six arrays."""
    t = np.asarray(t, dtype=float)
    out = path(np.ascontiguousarray(t).reshape(-1), *args)
    return tuple(out[j].reshape(t.shape) for j in range(6))


@njit
def _lemniscate_path(t, a, W):
    out = np.empty((6, t.size))
    W2 = W * W  # not W**2: float ** raises OverflowError where * gives inf
    for i in range(t.size):
        phi = W * t[i]
        s1, c1, s2, c2 = math.sin(phi), math.cos(phi), math.sin(2 * phi), math.cos(2 * phi)
        out[0, i] = a * s1
        out[1, i] = 0.5 * a * s2
        out[2, i] = a * W * c1
        out[3, i] = a * W * c2
        out[4, i] = -a * W2 * s1
        out[5, i] = -2 * a * W2 * s2
    return out


def _lemniscate(params, t):
    """Gerono: ``phi = 2 pi t / period``, ``x = a sin(phi)``, ``y = a sin(phi) cos(phi) =
    (a/2) sin(2 phi)``, with ``a = size``."""
    return _elementwise(_lemniscate_path, t, params["size"], 2.0 * math.pi / params["period"])


@njit
def _sinusoid_path(t, s, A, w):
    out = np.empty((6, t.size))
    for i in range(t.size):
        sn, cs = math.sin(w * t[i]), math.cos(w * t[i])
        out[0, i] = s * t[i]
        out[1, i] = A * sn
        out[2, i] = s + 0.0
        out[3, i] = A * w * cs
        out[4, i] = 0.0
        out[5, i] = -A * w * w * sn
    return out


def _sinusoid(params, t):
    """``x = speed t``, ``y = amplitude sin(omega t)``."""
    return _elementwise(_sinusoid_path, t, params["speed"], params["amplitude"], params["omega"])


@njit
def _circle_path(t, R, W):
    out = np.empty((6, t.size))
    W2 = W * W
    for i in range(t.size):
        phi = W * t[i]
        sn, cs = math.sin(phi), math.cos(phi)
        out[0, i] = R * cs
        out[1, i] = R * sn
        out[2, i] = -R * W * sn
        out[3, i] = R * W * cs
        out[4, i] = -R * W2 * cs
        out[5, i] = -R * W2 * sn
    return out


def _circle(params, t):
    """``phi = 2 pi t / period``, ``x = radius cos(phi)``, ``y = radius sin(phi)``."""
    return _elementwise(_circle_path, t, params["radius"], 2.0 * math.pi / params["period"])


@dataclass(frozen=True)
class ReferenceKind:
    """A reference kind: one row of :data:`KINDS` (a test runs over every row).

    Attributes
    ----------
    name : str
        The scenario's ``reference.kind``.
    params : tuple of str
        Its required numeric parameters (the keys of the ``[reference]`` table besides ``kind``).
    positive : tuple of str
        Those of ``params`` that must be > 0.
    path : callable
        ``path(params, t) -> (x, y, x', y', x'', y'')``: the path and its analytic first and
        second time derivatives at the times ``t`` (an array), each of the shape of ``t``.
    units : tuple of str
        The unit of each parameter, for the settings reference.
    example : mapping
        Valid parameters (for the contract tests and the documentation).
    parse : callable, optional
        ``parse(table, source) -> params`` for a kind whose parameters are not numbers (the
        scenario's ``[reference]`` table and file name); default: each of ``params`` is a
        finite number, those of ``positive`` > 0.
    validate : callable, optional
        ``validate(params, duration, dt)``: checks against the run (raises ``SettingError``).
    """

    name: str
    params: tuple[str, ...]
    positive: tuple[str, ...]
    path: Callable
    units: tuple[str, ...]
    example: Mapping
    parse: Callable | None = None
    validate: Callable | None = None


#: The reference kinds, by name.
KINDS: dict[str, ReferenceKind] = {
    k.name: k
    for k in (
        ReferenceKind("lemniscate", ("size", "period"), ("size", "period"), _lemniscate,
                      ("m", "s"), {"size": 2.0, "period": 40.0}),
        ReferenceKind("sinusoid", ("speed", "amplitude", "omega"), ("speed",), _sinusoid,
                      ("m/s", "m", "rad/s"), {"speed": 0.5, "amplitude": 1.0, "omega": 0.5}),
        ReferenceKind("circle", ("radius", "period"), ("radius", "period"), _circle, ("m", "s"),
                      {"radius": 1.0, "period": 20.0}),
        ReferenceKind("waypoints", ("file", "points"), (), waypoints.path, ("-", "s, m, m"),
                      {"points": tuple((t, math.cos(t / 3.0), math.sin(t / 3.0))
                                       for t in np.arange(-1.0, 12.0, 0.25).tolist())},
                      parse=waypoints.parse, validate=waypoints.validate),
    )
}  # fmt: skip


def path_derivatives(kind: str, params: Mapping[str, float], t):
    """Path and its time derivatives at times ``t`` [s].

    Returns
    -------
    tuple of ndarray
        ``(x, y, xd, yd, xdd, ydd)``, each of the shape of ``t``; the formulas are in the
        docstrings of the kinds' ``path`` functions (:data:`KINDS`).
    """
    t = np.asarray(t, dtype=float)
    if kind not in KINDS:
        raise ValueError(f"unknown reference kind {kind!r}; expected one of {sorted(KINDS)}")
    # absurd parameters (a period of 1e-200 s) overflow: return IEEE inf/nan, which the simulator
    # reports as a non-finite divergence, instead of raising or warning
    with np.errstate(over="ignore", invalid="ignore"):
        return KINDS[kind].path(params, t)


def _columns(kind, params, t):
    """Columns of a reference sample except that theta_r is wrapped (atan2)."""
    x, y, xd, yd, xdd, ydd = path_derivatives(kind, params, t)
    out = np.empty((np.size(t), 5))
    _fill_columns(*(np.ascontiguousarray(c, dtype=float).reshape(-1)
                    for c in (x, y, xd, yd, xdd, ydd)), out)  # fmt: skip
    return out


@njit
def _fill_columns(x, y, xd, yd, xdd, ydd, out):
    """``(x_r, y_r, atan2(y', x'), |v|, w_r)`` per row (``w_r = 0`` where the speed is 0)."""
    for i in range(out.shape[0]):
        speed2 = xd[i] * xd[i] + yd[i] * yd[i]
        out[i, 0] = x[i]
        out[i, 1] = y[i]
        out[i, 2] = math.atan2(yd[i], xd[i])
        out[i, 3] = math.sqrt(speed2)
        out[i, 4] = (xd[i] * ydd[i] - yd[i] * xdd[i]) / speed2 if speed2 > 0.0 else 0.0


@njit
def _unwrap(heading, prev, turns):
    """Unwrap ``heading`` (wrapped, in place) by counting whole turns in integers: each step's
    jump from ``prev`` (the previous wrapped value) is ``rint(jump / 2 pi)`` turns (none for a
    non-finite one); returns ``(turns, last wrapped value)`` for the next chunk."""
    two_pi = 2 * math.pi
    for i in range(heading.size):
        wrapped = heading[i]
        jump = np.rint((wrapped - prev) / two_pi)
        if math.isfinite(jump):
            turns -= np.int64(jump)
        heading[i] = wrapped + two_pi * turns
        prev = wrapped
    return turns, prev


class ReferenceSampler:
    """Samples a reference on the grid ``t_k = k dt`` in consecutive chunks.

    Chunking keeps memory independent of run length; ``theta_r`` is unwrapped across chunks by
    counting whole turns in integers, so the values do not depend on the chunk size.
    """

    def __init__(self, kind: str, params: Mapping[str, float], dt: float):
        if kind not in KINDS:
            raise ValueError(f"unknown reference kind {kind!r}; expected one of {sorted(KINDS)}")
        self.kind, self.params, self.dt = kind, dict(params), float(dt)
        self._next_k = 0
        self._turns = 0  # whole turns added to atan2 so far
        self._last_wrapped: float | None = None

    def rows(self, k0: int, k1: int) -> np.ndarray:
        """Rows for ``k = k0 .. k1 - 1``; chunks must be requested in order from 0."""
        if k0 != self._next_k:
            raise ValueError(f"chunks must be consecutive: expected k0={self._next_k}, got {k0}")
        if k1 < k0:
            raise ValueError(f"chunk ends before it starts: k0={k0}, k1={k1}")
        out = _columns(self.kind, self.params, np.arange(k0, k1) * self.dt)
        if k1 == k0:
            return out
        prev = out[0, 2] if self._last_wrapped is None else self._last_wrapped
        heading = np.ascontiguousarray(out[:, 2])
        turns, last = _unwrap(heading, prev, self._turns)
        out[:, 2] = heading
        self._turns = int(turns)
        self._last_wrapped = float(last)
        self._next_k = k1
        return out


def sample(kind: str, params: Mapping[str, float], dt: float, n: int) -> np.ndarray:
    """The reference at ``t_k = k dt``, ``k = 0 .. n - 1``, shape ``(n, 5)``."""
    return ReferenceSampler(kind, params, dt).rows(0, n)
