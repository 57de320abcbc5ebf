"""The point study of ``analysis.jacobians``: the library's closed-form Jacobians against CasADi AD.

Every Jacobian the closed loop uses is compared with the independent CasADi oracle
(:mod:`wmr.model.symbolic`) at seeded random points, at edge points and at the states visited by a
run; the paper's printed forms (eqs. 4/6 and 22-24) are put through the same check and fail it.

Checks (``B`` is always the CasADi AD value, ``A`` the library's closed form):

- ``F = dq+/dq``, ``G = dq+/du`` of the ZOH steps (``"exact"``, ``"euler"``, ``"rk4"``):
  :func:`wmr.model.kinematics.step_jacobians`;
- the network input Jacobian ``dz/dx = W diag(1 - h^2) V`` (errata E7):
  :func:`wmr.estimation.nn.input_jacobian`, and the printed eqs. 22-24:
  :func:`wmr.estimation.nn.input_jacobian_printed`;
- the weight Jacobian ``H = dz/dtheta`` of the weight EKF (errata E8):
  :func:`wmr.estimation.nn.weight_jacobian`;
- the error frame (errata E3): ``det T_e`` symbolically (``cos 2theta`` for the printed matrix),
  and the residual of Kanayama's error dynamics against the chain-rule ``de/dt`` of
  ``e = T_e (q_r - q)`` for both matrices
  (:func:`wmr.model.symbolic.error_dynamics_residual_function`).

Computing functions return numbers (:func:`point_study`, :func:`along_run`); the figure of the
per-point errors is :func:`plot_errors`.  A private helper of the study, not part of the library.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from wmr.controllers.iapid_nn_dekf import N_OUT, identifier_input
from wmr.estimation import nn
from wmr.estimation.identification import rel_error
from wmr.model import kinematics as kin
from wmr.model import symbolic as sym

__all__ = [
    "SEED",
    "DTS",
    "NETWORK_SIZES",
    "CLOSED_FORM_TOL",
    "PRINTED_MIN_ERROR",
    "IDENTITY_TOL",
    "PRINTED_MIN_RESIDUAL",
    "DET_TOL",
    "ERROR_DEFINITION",
    "UnicyclePoints",
    "unicycle_points",
    "unicycle_errors",
    "NetworkPoints",
    "network_points",
    "network_errors",
    "error_dynamics_points",
    "error_dynamics_residuals",
    "rotation_det_check",
    "point_study",
    "along_run",
    "plot_errors",
]

SEED = 20240251  # Actuators 13(2):51
#: Sample periods of the random step points [s].
DTS = (0.001, 0.01, 0.1)
#: Network sizes ``(n_in, n_h)`` with random weights (``n_out = 3``).
NETWORK_SIZES = ((4, 5), (4, 10), (4, 20), (6, 5), (6, 10), (6, 20))

# Headline thresholds (the claims analysis.jacobians.check enforces).
# Closed form and AD are both exact in exact arithmetic, so they differ by rounding: a few ulp of
# O(1) entries relative to the matrix norm, and at worst ~1e-13 relative in G of the exact arc
# just above the library's sinc-series switch (cancellation in (cos a - sinc a)/a ~ eps/|a|,
# times v dt^2/2, over |G| ~ dt).  1e-10 leaves three decades of margin.
CLOSED_FORM_TOL = 1e-10
# The printed network Jacobian is a different function: an O(1) relative error at generic points.
PRINTED_MIN_ERROR = 0.1
# Kanayama's error dynamics with the rotation is an identity; the residual is rounding on terms of
# size up to |w e| ~ 5 x 14 = 70, i.e. ~70 eps ~ 1e-14.
IDENTITY_TOL = 1e-12
# The printed matrix's residual is O(|v| + |w e|) at generic points.
PRINTED_MIN_RESIDUAL = 1e-3
# |det T_e(printed) - cos 2theta|: two roundings of O(1) terms.
DET_TOL = 1e-14

#: The relative error used throughout (also stored in the JSON).
ERROR_DEFINITION = (
    "relative error of a matrix A against the CasADi AD value B: ||A - B||_F / max(||B||_F, "
    "2.2e-308) (Frobenius norms; 0 when both are exactly zero); the error-dynamics residual is "
    "absolute: max_i |r_i| (rad/s or m/s) of r = de/dt (chain rule, CasADi) - Kanayama(e, u, u_r)"
)


# ---------------------------------------------------------------------------------------------
# CasADi in batches
# ---------------------------------------------------------------------------------------------


def _ad_batch(fun: ca.Function, *args: np.ndarray) -> list[np.ndarray]:
    """Evaluate ``fun`` at ``N`` points in one call (``Function.map``).

    ``args[i]`` has shape (N, size of input i); returns one array (N, rows, cols) per output.
    Calling a CasADi Function from Python costs ~20 us, so points are never looped over.
    """
    N = len(args[0])
    outs = fun.map(N)(*[np.asarray(a, dtype=float).reshape(N, -1).T for a in args])
    outs = outs if isinstance(outs, tuple | list) else (outs,)
    res = []
    for i, o in enumerate(outs):
        r, c = fun.size1_out(i), fun.size2_out(i)
        res.append(o.full().reshape(r, N, c).transpose(1, 0, 2))  # hcat of (r, c) blocks
    return res


# ---------------------------------------------------------------------------------------------
# Unicycle steps
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UnicyclePoints:
    """Step points: poses ``q`` (N, 3), inputs ``u`` (N, 2), sample periods ``dt`` (N,)."""

    q: np.ndarray
    u: np.ndarray
    dt: np.ndarray

    def __len__(self) -> int:
        return len(self.dt)


def _edge_unicycle_points() -> UnicyclePoints:
    """``theta`` in {+-pi, 0, +-pi/4, pi/2}, ``v = 0``, ``w = 0``, and ``w`` on both sides of the
    library's (|a| = 1e-4) and CasADi's (|a| = 1e-3) sinc-series switches, ``a = w dt / 2``."""
    q, u, dt = [], [], []
    for h in DTS:
        ws = [0.0, 1e-9, -1e-9, 3.0]
        for a in (1e-4, 1e-3):
            ws += [2 * a / h * (1 - 1e-6), -2 * a / h * (1 + 1e-6)]
        for theta in (math.pi, -math.pi, 0.0, math.pi / 4, -math.pi / 4, math.pi / 2):
            for v in (0.0, 1.3, -0.7):
                for w in ws:
                    q.append((0.4, -1.1, theta))
                    u.append((v, w))
                    dt.append(h)
    return UnicyclePoints(np.array(q), np.array(u), np.array(dt))


def unicycle_points(rng: np.random.Generator, n: int, edges: bool = True) -> UnicyclePoints:
    """``n`` random points (x, y in [-5, 5] m, theta in [-pi, pi], v in [-2, 2] m/s,
    w in [-5, 5] rad/s, dt drawn from :data:`DTS`), plus the edge points if ``edges``."""
    q = np.column_stack(
        (rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-np.pi, np.pi, n))
    )
    u = np.column_stack((rng.uniform(-2, 2, n), rng.uniform(-5, 5, n)))
    dt = rng.choice(np.array(DTS), n)
    pts = UnicyclePoints(q, u, dt)
    if edges:
        e = _edge_unicycle_points()
        pts = UnicyclePoints(np.vstack((q, e.q)), np.vstack((u, e.u)), np.concatenate((dt, e.dt)))
    return pts


def unicycle_errors(points: UnicyclePoints) -> dict[str, dict[str, np.ndarray]]:
    """Relative errors of :func:`wmr.model.kinematics.step_jacobians` against AD, per integrator.

    Returns ``{integrator: {"F": (N,), "G": (N,)}}``.
    """
    out = {}
    for name in sym.INTEGRATORS:
        code = kin.INTEGRATORS[name]
        F_ad, G_ad = _ad_batch(sym.step_jacobian_function(name), points.q, points.u, points.dt)
        F = np.empty_like(F_ad)
        G = np.empty_like(G_ad)
        for i in range(len(points)):
            F[i], G[i] = kin.step_jacobians(points.q[i], points.u[i], float(points.dt[i]), code)
        out[name] = {"F": rel_error(F, F_ad), "G": rel_error(G, G_ad)}
    return out


# ---------------------------------------------------------------------------------------------
# Network
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class NetworkPoints:
    """Network points of one size: weights ``theta`` (N, n) and inputs ``x`` (N, n_in)."""

    n_in: int
    n_h: int
    n_out: int
    theta: np.ndarray
    x: np.ndarray

    def __len__(self) -> int:
        return len(self.x)


def _network_inputs(rng: np.random.Generator, n: int, n_in: int) -> np.ndarray:
    """Identifier-like inputs ``(v, w, cos theta, sin theta)``, then extra entries in [-1, 1]."""
    theta = rng.uniform(-np.pi, np.pi, n)
    cols = [rng.uniform(-2, 2, n), rng.uniform(-5, 5, n), np.cos(theta), np.sin(theta)]
    cols += [rng.uniform(-1, 1, n) for _ in range(n_in - 4)]
    return np.column_stack(cols)[:, :n_in]


def network_points(
    rng: np.random.Generator, n_in: int, n_h: int, n: int, n_out: int = N_OUT, edges: bool = True
) -> NetworkPoints:
    """``n`` random networks and inputs of one size, plus edge points if ``edges``.

    Weights are standard normal times a scale drawn log-uniformly in [0.1, 3] per point (from
    nearly linear to partly saturated hidden units); inputs from :func:`_network_inputs`.  Edge
    points: ``v = w = 0`` inputs, ``theta = pi`` inputs, all-zero weights, zero hidden biases.
    """
    nw = nn.n_weights(n_in, n_h, n_out)
    scale = np.exp(rng.uniform(np.log(0.1), np.log(3.0), n))
    theta = rng.standard_normal((n, nw)) * scale[:, None]
    x = _network_inputs(rng, n, n_in)
    if edges:
        k = 4
        th_e = rng.standard_normal((k, nw))
        th_e[2] = 0.0  # all weights zero: dz/dx = 0 exactly, H has only the output-bias block
        th_e[3, n_h * n_in : n_h * n_in + n_h] = 0.0  # no hidden bias
        x_e = _network_inputs(rng, k, n_in)
        x_e[0, :2] = 0.0  # v = w = 0
        x_e[1, 2:4] = (-1.0, 0.0)  # theta = pi
        theta, x = np.vstack((theta, th_e)), np.vstack((x, x_e))
    return NetworkPoints(n_in, n_h, n_out, theta, x)


def network_errors(points: NetworkPoints) -> dict[str, np.ndarray]:
    """Relative errors against AD of the corrected input Jacobian (``"input"``), the printed
    eqs. 22-24 (``"input_printed"``) and the weight Jacobian (``"weights"``), each (N,)."""
    n_in, n_h, n_out = points.n_in, points.n_h, points.n_out
    (J_ad,) = _ad_batch(
        sym.network_input_jacobian_function(n_in, n_h, n_out), points.theta, points.x
    )
    (H_ad,) = _ad_batch(
        sym.network_weight_jacobian_function(n_in, n_h, n_out), points.theta, points.x
    )
    J = np.empty_like(J_ad)
    Jp = np.empty_like(J_ad)
    H = np.empty_like(H_ad)
    for i in range(len(points)):
        th, x = np.ascontiguousarray(points.theta[i]), np.ascontiguousarray(points.x[i])
        _, h = nn.forward(th, x, n_h, n_out)
        J[i] = nn.input_jacobian(th, x, n_h, n_out, h)
        Jp[i] = nn.input_jacobian_printed(th, x, n_h, n_out)
        nn.weight_jacobian(th, x, n_h, n_out, h, H[i])
    return {
        "input": rel_error(J, J_ad),
        "input_printed": rel_error(Jp, J_ad),
        "weights": rel_error(H, H_ad),
    }


# ---------------------------------------------------------------------------------------------
# Error frame (errata E3)
# ---------------------------------------------------------------------------------------------


def error_dynamics_points(rng: np.random.Generator, n: int, edges: bool = True):
    """``(q (N, 3), u (N, 2), ref (N, 5))``: robot and reference poses in [-5, 5]^2 x [-pi, pi],
    inputs ``v, v_r`` in [-2, 2], ``w, w_r`` in [-5, 5]; edges: ``theta`` in {+-pi/4 (where the
    printed matrix is singular), +-pi}, zero error, zero inputs."""

    def pose(m):
        return np.column_stack(
            (rng.uniform(-5, 5, m), rng.uniform(-5, 5, m), rng.uniform(-np.pi, np.pi, m))
        )

    def inputs(m):
        return np.column_stack((rng.uniform(-2, 2, m), rng.uniform(-5, 5, m)))

    q, q_r, u, u_r = pose(n), pose(n), inputs(n), inputs(n)
    if edges:
        thetas = (math.pi / 4, -math.pi / 4, 3 * math.pi / 4, math.pi, -math.pi, 0.0)
        k = len(thetas)
        q_e, q_re, u_e, u_re = pose(k), pose(k), inputs(k), inputs(k)
        q_e[:, 2] = thetas
        q_re[4] = q_e[4]  # zero error
        u_e[5] = 0.0  # robot at rest
        q, q_r = np.vstack((q, q_e)), np.vstack((q_r, q_re))
        u, u_r = np.vstack((u, u_e)), np.vstack((u_r, u_re))
    return q, u, np.hstack((q_r, u_r))


def error_dynamics_residuals(q, u, ref) -> dict[str, np.ndarray]:
    """``max_i |r_i|`` per point of :func:`wmr.model.symbolic.error_dynamics_residual_function`.

    Returns ``{"corrected": (N,), "printed": (N,)}`` [m/s, rad/s].
    """
    out = {}
    for label, printed in (("corrected", False), ("printed", True)):
        (r,) = _ad_batch(sym.error_dynamics_residual_function(printed), q, u, ref)
        out[label] = np.abs(r).reshape(len(q), -1).max(axis=1)
    return out


def rotation_det_check(n_grid: int = 10001) -> dict:
    """``det T_e`` symbolically, and the printed determinant against ``cos 2theta``.

    CasADi does not expand ``cos 2theta``, so ``simplify(det - cos 2theta)`` is not reduced to 0
    symbolically (recorded in ``simplifies_to_zero``); the difference is evaluated on a grid of
    ``n_grid`` angles in [-pi, pi] instead.  It is a trigonometric polynomial of degree 2, which
    has at most 4 zeros per period unless it vanishes identically: vanishing (to rounding) at
    more than 4 distinct angles is a proof, not a sample.
    """
    d = sym.rotation_det(True)
    (theta,) = ca.symvar(d)
    diff = ca.simplify(d - ca.cos(2 * theta))
    f = ca.Function("det_minus_cos2", [theta], [diff])
    grid = np.linspace(-np.pi, np.pi, n_grid)
    dev = np.abs(f.map(n_grid)(grid[None, :]).full().ravel())
    # The corrected determinant simplifies to the constant 1 (no symbol left): rebuild it.
    det_c = ca.Function("det_corrected", [theta], [ca.det(sym.rotation_function(False)(theta))])
    det_c_dev = np.abs(det_c.map(n_grid)(grid[None, :]).full().ravel() - 1.0)
    return {
        "printed_det": sym.rotation_det_string(True),
        "corrected_det": sym.rotation_det_string(False),
        "printed_det_equals": "cos(2 theta)",
        "simplifies_to_zero": bool(diff.is_zero()),
        "grid_points": int(n_grid),
        "max_abs_det_minus_cos_2theta": float(dev.max()),
        "max_abs_corrected_det_minus_1": float(det_c_dev.max()),
        "printed_singular_at_deg": [-135.0, -45.0, 45.0, 135.0],
    }


# ---------------------------------------------------------------------------------------------
# The point study
# ---------------------------------------------------------------------------------------------


def point_study(points: int = 1000, seed: int = SEED) -> tuple[dict, dict]:
    """Closed form vs AD (and printed vs AD) at ``points`` seeded random points per check.

    Returns ``(summary, raw)``: the JSON sections, and the per-point errors for the figures.
    """
    ss = np.random.SeedSequence(seed)
    rng_u, rng_n, rng_e = (np.random.default_rng(s) for s in ss.spawn(3))
    pts = unicycle_points(rng_u, points)
    uni = unicycle_errors(pts)
    net_by_size = {}
    for n_in, n_h in NETWORK_SIZES:
        net_by_size[f"{n_in}x{n_h}"] = network_errors(network_points(rng_n, n_in, n_h, points))
    net = {
        k: np.concatenate([v[k] for v in net_by_size.values()])
        for k in ("input", "input_printed", "weights")
    }
    q, u, ref = error_dynamics_points(rng_e, points)
    res = error_dynamics_residuals(q, u, ref)
    p_in = net["input_printed"]
    summary = {
        "points": int(points),
        "error_definition": ERROR_DEFINITION,
        "network_input": {
            "corrected_max_rel_error": float(net["input"].max()),
            "printed_max_rel_error": float(p_in.max()),
            "printed_median_rel_error": float(np.median(p_in)),
            "printed_min_rel_error": float(p_in.min()),
            "printed_fraction_above_0.1": float(np.mean(p_in > PRINTED_MIN_ERROR)),
            "n": int(p_in.size),
            "sizes": [f"{a}x{b}" for a, b in NETWORK_SIZES],
            "by_size": {
                k: {
                    "corrected_max_rel_error": float(v["input"].max()),
                    "printed_median_rel_error": float(np.median(v["input_printed"])),
                }
                for k, v in net_by_size.items()
            },
        },
        "network_weights": {
            "max_rel_error": float(net["weights"].max()),
            "n": int(net["weights"].size),
        },
        "unicycle_step": {
            name: {
                "max_rel_error": float(max(e["F"].max(), e["G"].max())),
                "F_max_rel_error": float(e["F"].max()),
                "G_max_rel_error": float(e["G"].max()),
                "n": len(pts),
            }
            for name, e in uni.items()
        },
        "rotation": {
            **rotation_det_check(),
            "error_dynamics_max_residual": {
                "corrected": float(res["corrected"].max()),
                "printed": float(res["printed"].max()),
            },
            "error_dynamics_median_residual": {
                "corrected": float(np.median(res["corrected"])),
                "printed": float(np.median(res["printed"])),
            },
            "error_dynamics_points": int(len(q)),
        },
    }
    raw = {f"step {name} {m}": e[m] for name, e in uni.items() for m in ("F", "G")}
    raw |= {
        "network dz/dx": net["input"],
        "network H": net["weights"],
        "network dz/dx printed": p_in,
    }
    raw |= {"error dynamics corrected": res["corrected"], "error dynamics printed": res["printed"]}
    return summary, raw


# ---------------------------------------------------------------------------------------------
# Along runs
# ---------------------------------------------------------------------------------------------


def along_run(run, max_points: int | None = None) -> dict:
    """The same comparisons at the states and inputs visited by one ``iapid-nn-dekf`` run.

    Step Jacobians at the true poses ``q_k`` and logged inputs ``u_k`` (every integrator, the
    run's ``dt``); the network Jacobians with the run's final weights at the identifier inputs
    ``(u_k, cos theta_hat_k, sin theta_hat_k)``; the error-dynamics residual at
    ``(q_k, u_k, ref_k)``.  ``max_points`` subsamples the steps evenly.
    """
    n = len(run.u)
    idx = (
        np.arange(n)
        if max_points is None or n <= max_points
        else np.linspace(0, n - 1, max_points).round().astype(int)
    )
    q, u, q_hat, ref = run.q[idx], run.u[idx], run.q_hat[idx], run.ref[idx]
    dt = np.full(len(idx), run.dt)
    uni = unicycle_errors(UnicyclePoints(q, u, dt))
    theta = np.asarray(run.final.theta, dtype=float)
    x = np.array([identifier_input(u[i], q_hat[i, 2]) for i in range(len(idx))])
    net = network_errors(NetworkPoints(x.shape[1], run.settings.hidden, N_OUT,
                                       np.tile(theta, (len(idx), 1)), x))  # fmt: skip
    res = error_dynamics_residuals(q, u, ref)
    return {
        "steps": int(len(idx)),
        "unicycle_step": {
            k: {"max_rel_error": float(max(e["F"].max(), e["G"].max()))} for k, e in uni.items()
        },
        "network_input": {
            "corrected_max_rel_error": float(net["input"].max()),
            "printed_median_rel_error": float(np.median(net["input_printed"])),
        },
        "network_weights": {"max_rel_error": float(net["weights"].max())},
        "error_dynamics_max_residual": {
            "corrected": float(res["corrected"].max()),
            "printed": float(res["printed"].max()),
        },
        "error_dynamics_median_residual": {"printed": float(np.median(res["printed"]))},
    }


_FLOOR = 1e-18  # exact zeros are drawn here on log axes


def plot_errors(raw: dict[str, np.ndarray]):
    """Max and median error per check (log scale) and the distributions, printed forms in red.

    ``raw``: the per-point errors of :func:`point_study`; returns the figure.
    """
    import matplotlib.pyplot as plt

    names = list(raw)
    printed = ["printed" in n for n in names]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 5.2), layout="constrained")
    y = np.arange(len(names))
    mx = np.array([max(raw[n].max(), _FLOOR) for n in names])
    md = np.array([max(np.median(raw[n]), _FLOOR) for n in names])
    colors = ["tab:red" if p else "tab:blue" for p in printed]
    ax1.barh(y, mx, color=colors, alpha=0.8, label="max")
    ax1.plot(md, y, "k|", ms=14, mew=2, label="median")
    ax1.axvline(
        CLOSED_FORM_TOL,
        color="tab:green",
        ls="--",
        lw=1,
        label=f"closed-form tolerance {CLOSED_FORM_TOL:g}",
    )
    ax1.axvline(
        PRINTED_MIN_ERROR,
        color="tab:red",
        ls=":",
        lw=1,
        label=f"printed forms fail above {PRINTED_MIN_ERROR:g}",
    )
    ax1.set_xscale("log")
    ax1.set_yticks(y, names, fontsize=8)
    ax1.invert_yaxis()
    ax1.set_xlabel("relative error vs CasADi AD (error dynamics: absolute residual)")
    ax1.set_xlim(_FLOOR / 3, None)
    ax1.legend(fontsize=7, loc="upper right")
    ax1.grid(alpha=0.3, axis="x")
    bins = np.linspace(-18, 3, 64)
    for n, p in zip(names, printed, strict=True):
        if not (n.startswith("network") or n.startswith("error") or n.endswith("G")):
            continue
        v = np.log10(np.maximum(raw[n], _FLOOR))
        ax2.hist(v, bins=bins, histtype="step", lw=1.3, ls="-" if not p else "--", label=n)
    ax2.set_yscale("log")
    ax2.set_xlabel(f"log10 error (exact zeros drawn at {np.log10(_FLOOR):.0f})")
    ax2.set_ylabel("points")
    ax2.legend(fontsize=7)
    ax2.grid(alpha=0.3)
    fig.suptitle("Library closed forms vs CasADi AD (blue) and the paper's printed forms (red)")
    return fig

