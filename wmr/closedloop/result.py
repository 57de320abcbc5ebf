"""The typed record of a run (:class:`RunResult`) and its one-line summary (:class:`Row`).

Analyses read a run through names, never through offsets: ``result.signal("Kpv")``,
``result.gains()``, ``result.jacobian()``, ``result.final`` (the controller's final state as its
dataclass, e.g. ``result.final.theta`` for a network's weights) and ``result.settings`` (what it
ran with).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from wmr.controllers.pid import GAIN_NAMES, J_NAMES

__all__ = ["RunResult", "Row", "STEP_LOG"]

#: Signals every run with a trajectory has besides its controller's: the applied input, the
#: pose estimate the controller acted on, the measured pose and the disturbance in force.
_COMMON = {"v": ("u", 0), "w": ("u", 1),
           "x_hat": ("q_hat", 0), "y_hat": ("q_hat", 1), "theta_hat": ("q_hat", 2),
           "x_meas": ("z", 0), "y_meas": ("z", 1), "theta_meas": ("z", 2),
           "dv": ("disturbance", 0), "dw": ("disturbance", 1)}  # fmt: skip
#: Per-step columns of the trajectory CSV after the command: the measured pose and the
#: disturbance in force at t_k (what a robot's log holds; ``wmr identify``).
STEP_LOG = ("x_meas", "y_meas", "theta_meas", "dv", "dw")


def _num(x):
    return None if x is None or not math.isfinite(x) else float(x)


@dataclass
class RunResult:
    """One closed-loop run.

    Arrays are row-per-instant: ``t``, ``q``, ``ref`` have ``n + 1`` rows (``q_0 .. q_n``), the
    per-step signals ``q_hat``, ``u``, ``state`` have ``n`` rows, where ``n`` is the number of
    steps simulated (``n_steps`` unless the run diverged).  They are ``None`` when the run was
    made with ``keep_trajectory=False``.

    Attributes
    ----------
    rmse : dict
        ``{"x", "y", "theta", "position"}`` over ``q_0 .. q_N`` (eq. 64, theta wrapped); NaN
        when the run diverged.
    rmse_robot_frame : dict
        RMSE of ``e1``, ``e2`` (robot frame) — their squares sum to the position error.
    rmse_after_transient : dict
        The RMSE of ``rmse`` over the poses with ``t >= wmr.closedloop.metrics.TRANSIENT`` only (NaN
        if none, or diverged): the initial pose error dominates the full-run figure.
    effort : float
        RMS of the saturated command, ``sqrt(mean_k (v_k^2 + w_k^2))``
        (``wmr.closedloop.metrics.reduce``; NaN if diverged).
    diverged, diverged_at, cause
        Whether the run stopped early, at which time [s], and why.
    settings
        The controller settings the run used.
    final
        The controller's state at the end of the run, as its dataclass
        (``wmr.controllers.<module>.State``).
    pose_estimate, pose_covariance
        The pose filter's final estimate (3,) and covariance (3, 3); the covariance is ``None``
        when the controller acted on the raw measurement.
    plant_velocity
        With a trajectory and a non-ideal plant: the true robot's actual ``(v, w)`` at each
        ``t_k`` before its step, shape (n, 2) (``None`` otherwise).
    z, disturbance
        With a trajectory: the measured pose ``z_k = q_k + n_k`` (n, 3) [m, m, rad], what the
        estimator received, and the disturbance ``(dv, dw)`` in force at each ``t_k`` (n, 2)
        [m/s, rad/s], added to the saturated command before the plant (a robot's log: what
        ``wmr identify`` reads).
    """

    scenario: str
    controller: str
    seed: int
    dt: float
    n_steps: int
    rmse: dict[str, float]
    rmse_robot_frame: dict[str, float]
    rmse_after_transient: dict[str, float] = field(default_factory=dict)
    effort: float = math.nan
    diverged: bool = False
    diverged_at: float | None = None
    cause: str | None = None
    state_names: tuple[str, ...] = ()
    settings: Any = None
    final: Any = None
    pose_estimate: np.ndarray | None = None
    pose_covariance: np.ndarray | None = None
    t: np.ndarray | None = None
    q: np.ndarray | None = None
    ref: np.ndarray | None = None
    q_hat: np.ndarray | None = None
    u: np.ndarray | None = None
    state: np.ndarray | None = None
    plant_velocity: np.ndarray | None = None
    z: np.ndarray | None = None
    disturbance: np.ndarray | None = None

    def summary(self) -> dict:
        """The JSON record of DESIGN §3.2 (``null`` for the RMSE of a diverged run)."""
        return {
            "controller": self.controller,
            "rmse": {k: _num(v) for k, v in self.rmse.items()},
            "diverged": self.diverged,
            "diverged_at": _num(self.diverged_at),
        }

    @property
    def signal_names(self) -> tuple[str, ...]:
        """Names :meth:`signal` accepts: the controller's logged state, then the common ones."""
        return (*self.state_names, *_COMMON)

    def signal(self, name: str) -> np.ndarray:
        """The per-step signal ``name`` (``n`` rows): a logged controller state entry (e.g.
        ``"Kpv"``, ``"J_xv"``, ``"nn_error"``), the applied input ``"v"``/``"w"`` or the pose
        estimate ``"x_hat"``, ``"y_hat"``, ``"theta_hat"``."""
        if self.state is None:
            raise ValueError(f"run of {self.controller} on {self.scenario} kept no trajectory "
                             "(keep_trajectory=False): no signals")  # fmt: skip
        if name in self.state_names:
            return self.state[:, self.state_names.index(name)]
        if name in _COMMON:
            array, column = _COMMON[name]
            return getattr(self, array)[:, column]
        raise KeyError(f"{self.controller} has no signal {name!r}; known: "
                       f"{', '.join(self.signal_names)}")  # fmt: skip

    @property
    def csv_header(self) -> tuple[str, ...]:
        """Columns of :meth:`to_csv`."""
        return ("t", "x", "y", "theta", "x_r", "y_r", "theta_r", "v_r", "w_r",
                "x_hat", "y_hat", "theta_hat", "v", "w", *STEP_LOG, *self.state_names)  # fmt: skip

    def to_csv(self, path, rows_per_block: int = 2_000) -> None:
        """Write the trajectory as CSV (:attr:`csv_header`; one row per instant ``t_0 .. t_n``,
        the per-step columns empty on the last row), atomically and in blocks, so memory does
        not grow with the run; floats in shortest round-trip form."""
        from wmr.io import atomic_writer

        if self.state is None:
            raise ValueError("no trajectory to write (keep_trajectory=False)")
        n = len(self.u)
        with atomic_writer(path) as fh:
            fh.write(",".join(self.csv_header) + "\n")
            for k0 in range(0, len(self.t), rows_per_block):
                k1 = min(k0 + rows_per_block, len(self.t))
                m = max(min(k1, n), k0)  # rows k0 .. m-1 have a step after them
                instant = np.column_stack((self.t[k0:k1], self.q[k0:k1], self.ref[k0:k1]))
                step = np.column_stack((self.q_hat[k0:m], self.u[k0:m], self.z[k0:m],
                                        self.disturbance[k0:m], self.state[k0:m]))  # fmt: skip
                lines = [",".join(map(repr, row)) for row in instant.tolist()]
                for i, row in enumerate(step.tolist()):
                    lines[i] += "," + ",".join(map(repr, row))
                for i in range(m - k0, k1 - k0):  # the last instant has no step after it
                    lines[i] += "," * (5 + len(STEP_LOG) + len(self.state_names))
                fh.write("\n".join(lines) + "\n")

    def _block(self, names: tuple[str, ...], what: str) -> np.ndarray:
        missing = [n for n in names if n not in self.state_names]
        if missing:
            raise KeyError(f"{self.controller} logs no {what} (no signal {missing[0]!r})")
        return np.column_stack([self.signal(n) for n in names])

    def gains(self) -> np.ndarray:
        """The PID gains ``(Kpv, Kiv, Kdv, Kpw, Kiw, Kdw)`` along the run, shape (n, 6)."""
        return self._block(GAIN_NAMES, "PID gains")

    def jacobian(self) -> np.ndarray:
        """The plant Jacobian ``J_{k-1}`` the SGD step used at each step, shape (n, 3, 2)
        (zero at ``k = 0``, before the first step)."""
        return self._block(J_NAMES, "plant Jacobian").reshape(-1, 3, 2)


@dataclass(frozen=True)
class Row:
    """The summary of one run (a row of ``paper/results/rmse.csv`` and of a sweep's store)."""

    scenario: str
    controller: str
    variant: str
    seed: int
    rmse_x: float
    rmse_y: float
    rmse_theta: float
    rmse_position: float
    diverged: bool
    diverged_at: float | None = None
    cause: str | None = None
    tail_x: float = math.nan  # RMSE over t >= wmr.closedloop.metrics.TRANSIENT (not in rmse.csv)
    tail_y: float = math.nan
    tail_theta: float = math.nan
    tail_position: float = math.nan
    effort: float = math.nan  # RMS of the command (not in rmse.csv)

    #: Columns of ``paper/results/rmse.csv``.
    CSV_HEADER = ("scenario", "controller", "variant", "seed", "rmse_x", "rmse_y", "rmse_theta",
                  "rmse_position", "diverged")  # fmt: skip

    @classmethod
    def of(cls, r: RunResult, variant: str = "default") -> Row:
        """The row of run ``r``."""
        m, t = r.rmse, r.rmse_after_transient
        return cls(r.scenario, r.controller, variant, r.seed, m["x"], m["y"], m["theta"],
                   m["position"], r.diverged, r.diverged_at, r.cause,
                   t["x"], t["y"], t["theta"], t["position"], r.effort)  # fmt: skip

    def csv_row(self) -> tuple:
        return (self.scenario, self.controller, self.variant, self.seed, self.rmse_x, self.rmse_y,
                self.rmse_theta, self.rmse_position, str(self.diverged).lower())  # fmt: skip
