"""Stability margins of the linearised sampled-data loops (``wmr.linear.loops``), loop at a time.

Margins, per SISO loop ``L`` (discrete, negative feedback, evaluated on the unit circle
``z = exp(j w dt)``, ``0 < w <= pi/dt``):

- classical gain margins: ``1/|L|`` where the Nyquist plot crosses the negative real axis; the
  upper one (gain increase) and the lower one (gain reduction; a loop holding several
  integrations, like the PID's ``w`` loop, is conditionally stable), 0 when there is none;
- classical phase margin: ``180 deg + arg L`` at ``|L| = 1``;
- the balanced (skew ``sigma = 0``) disk margin ``alpha = 1 / max_w |(S - T)/2| =
  1 / max_w |S - 1/2|`` with ``S = 1/(1 + L)``, ``T = L/(1 + L) = 1 - S`` (Seiler, Packard &
  Gahinet, "An introduction to disk margins", IEEE Control Systems Magazine 40(5):78-95, 2020),
  from ``control.disk_margins``: the loop stays stable for every complex gain
  ``(1 + alpha d/2)/(1 - alpha d/2)``, ``|d| < 1``; its disk gain margin is
  ``(1 + alpha/2)/(1 - alpha/2)`` and its disk phase margin ``2 atan(alpha/2)``
  (:func:`disk_gain_phase_margins`).

Loop-at-a-time margins ignore simultaneous perturbations of both channels (multiloop disk margins
would include them).

The classical margins are found on the exact state-space frequency response (dense grid, then
root refinement: :func:`loop_margins`), not with ``control.stability_margins``: in python-control
0.10.2 its polynomial method returns spurious crossovers for these loops (poles clustered at
``z = 1`` with ``dt = 0.01``), and both of its methods skip a phase crossover at the Nyquist
frequency (``z = -1``, where every real loop is real; ``margins._z_filter`` keeps ``arg z < pi``),
which is where the upper gain margin of these loops lies.  ``stability_margins`` on the same
frequency data is kept as a cross-check of the phase margin.

Independent check: :func:`eigen_margins` recomputes each margin from closed-loop eigenvalues only
(the smallest real gain, phase rotation ``exp(-j phi)`` and disk perturbation that put an
eigenvalue on the unit circle); :func:`compare_margins` measures the agreement.

Along a run (:func:`margins_along_run`) the analysis is frozen-time: the loop relinearised at the
local ``(v_r, w_r)`` with the gains in use at ``t_k``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import control as ct
import numpy as np
from scipy import optimize

from wmr.linear.loops import (
    CHANNELS,
    OperatingPoint,
    closed_loop_matrix,
    first_crossing,
    frequency_response,
    pid_loops,
    spectral_radius,
)

__all__ = [
    "W_MIN",
    "N_GRID",
    "G_RANGE",
    "LoopMargins",
    "loop_margins",
    "disk_gain_phase_margins",
    "eigen_margins",
    "analyse_loops",
    "compare_margins",
    "margins_along_run",
    "json_number",
]

#: Lowest frequency of the frequency-response grid [rad/s]: time scales up to ~1000 s, far beyond
#: the 40 s runs; lower, (zI - A) at z ~ 1 becomes too ill-conditioned for the double integrators.
W_MIN = 1e-3
#: Points of the (log-spaced) frequency grid of :func:`loop_margins`.
N_GRID = 3000
#: Gains swept by the eigenvalue cross-check of the gain margins (:func:`eigen_margins`).
G_RANGE = (1e-4, 1e4)


@dataclass
class LoopMargins:
    """Margins of one SISO loop (loop-at-a-time).  Gains are ratios (not dB) here.

    Attributes
    ----------
    stable : bool
        The nominal closed loop is stable (``max |z| < 1``); otherwise every margin is zero.
    gain_margin, gain_margin_lower : float
        The real gains ``g`` with ``gain_margin_lower < g < gain_margin`` keep the loop stable
        (``gain_margin >= 1`` or inf; ``gain_margin_lower <= 1``, 0 if none).
    phase_margin_deg : float
        [deg]; inf if ``|L|`` never crosses 1.
    disk_margin : float
        The balanced disk margin ``alpha``; ``disk_gain_margin_db`` [dB] and
        ``disk_phase_margin_deg`` [deg] are its gain and phase margins.
    phase_crossover_rad_s, gain_crossover_rad_s, disk_frequency_rad_s : float
        [rad/s] where the upper gain margin, the phase margin and the disk margin occur.
    python_control : dict
        ``control.stability_margins`` on the same frequency data (for comparison), if computed.
    """

    stable: bool
    gain_margin: float
    gain_margin_lower: float
    phase_margin_deg: float
    disk_margin: float
    disk_gain_margin_db: float
    disk_phase_margin_deg: float
    phase_crossover_rad_s: float = math.nan
    gain_crossover_rad_s: float = math.nan
    disk_frequency_rad_s: float = math.nan
    python_control: dict = dataclasses.field(default_factory=dict)

    @property
    def gain_margin_db(self) -> float:
        """The upper gain margin [dB]."""
        return 20.0 * math.log10(self.gain_margin) if self.gain_margin > 0 else -math.inf

    @property
    def gain_margin_lower_db(self) -> float:
        """The lower gain margin [dB] (``-inf`` if none)."""
        return (
            20.0 * math.log10(self.gain_margin_lower) if self.gain_margin_lower > 0 else -math.inf
        )

    def to_json(self) -> dict:
        """The margins in dB and deg for JSON (:func:`json_number`: infinities as strings)."""
        out = {
            "gain_margin_db": json_number(self.gain_margin_db),
            "phase_margin_deg": json_number(self.phase_margin_deg),
            "disk_margin": json_number(self.disk_margin),
            "gain_margin_lower_db": json_number(self.gain_margin_lower_db),
            "disk_gain_margin_db": json_number(self.disk_gain_margin_db),
            "disk_phase_margin_deg": json_number(self.disk_phase_margin_deg),
            "phase_crossover_rad_s": json_number(self.phase_crossover_rad_s),
            "gain_crossover_rad_s": json_number(self.gain_crossover_rad_s),
            "disk_frequency_rad_s": json_number(self.disk_frequency_rad_s),
            "closed_loop_stable": self.stable,
        }
        if self.python_control:
            out["python_control"] = {k: json_number(v) for k, v in self.python_control.items()}
        return out


def loop_margins(L: ct.StateSpace, *, python_control: bool = True, n_grid: int = N_GRID,
                 w_min: float = W_MIN) -> LoopMargins:  # fmt: skip
    """Classical and disk margins of the SISO discrete loop ``L`` (negative feedback).

    The frequency response on ``w_min .. pi/dt`` [rad/s] (``n_grid`` log-spaced points, the
    Nyquist frequency included) locates sign changes of ``Im L`` with ``Re L < 0`` (phase
    crossovers) and of ``|L| - 1`` (gain crossovers), each refined by Brent's method on the
    state-space response; the maximum of ``|S - 1/2|`` is refined by bounded scalar minimisation.
    With ``python_control``, the disk margin is the one of ``control.disk_margins`` on the grid
    plus the refined frequency, and ``control.stability_margins`` on the same frequency data is
    recorded for comparison; otherwise the same formulas are evaluated here (used along runs, for
    speed).  An unstable nominal loop gets zero margins.
    """
    nyq = math.pi / L.dt
    w = np.geomspace(w_min, nyq, n_grid)
    H = frequency_response(L, w)
    if not spectral_radius(closed_loop_matrix(L)) < 1.0:  # (NaN: unstable too)
        return LoopMargins(False, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0)

    def resp(x):
        return frequency_response(L, x)[0]

    gm, gm_lo, w_gm = _gain_margins(resp, w, H, nyq)
    pm, w_pm = _phase_margin(resp, w, H)
    # Disk margin: alpha = 1 / max |S - 1/2| (skew 0).
    dev = np.abs(1.0 / (1.0 + H) - 0.5)
    i = int(np.argmax(dev))
    lo_w, hi_w = w[max(i - 1, 0)], w[min(i + 1, w.size - 1)]
    res = optimize.minimize_scalar(lambda x: -abs(1.0 / (1.0 + resp(x)) - 0.5),
                                   bounds=(lo_w, hi_w), method="bounded",
                                   options={"xatol": 1e-10 * hi_w})  # fmt: skip
    w_dm = float(res.x) if -res.fun > dev[i] else float(w[i])
    pc = {}
    if python_control:
        dm, dgm, dpm = ct.disk_margins(L, np.sort(np.append(w, w_dm)))
        dm, dgm, dpm = float(dm), float(dgm), float(dpm)
        mag_pc, ph_pc = np.abs(H), np.degrees(np.unwrap(np.angle(H)))
        sm = ct.stability_margins((mag_pc, ph_pc, w))
        pc = {"stability_margins_gm_db": 20 * math.log10(sm[0]) if sm[0] > 0 else -math.inf,
              "stability_margins_pm_deg": float(sm[1]),
              "stability_margins_wgc_rad_s": float(sm[4])}  # fmt: skip
    else:
        dm = 1.0 / abs(1.0 / (1.0 + resp(w_dm)) - 0.5)
        dgm, dpm = disk_gain_phase_margins(dm)
    return LoopMargins(True, gm, gm_lo, pm, dm, dgm, dpm, w_gm, w_pm, w_dm, pc)


def disk_gain_phase_margins(alpha: float) -> tuple[float, float]:
    """Disk gain margin [dB] and phase margin [deg] of the balanced disk of size ``alpha``.

    The disk ``{(1 + alpha d/2)/(1 - alpha d/2), |d| <= 1}`` meets the real axis at
    ``g = (1 + alpha/2)/(1 - alpha/2)`` and ``1/g``, and the unit circle at ``+-2 atan(alpha/2)``.
    """
    a = alpha / 2.0
    dgm = math.inf if a >= 1.0 else 20.0 * math.log10((1.0 + a) / (1.0 - a))
    return dgm, math.degrees(2.0 * math.atan(a))


def eigen_margins(L: ct.StateSpace, n_psi: int = 73) -> dict:
    """The margins of ``L`` from closed-loop eigenvalues only (independent of the frequency axis).

    - gain margins: the smallest ``g > 1`` and largest ``g < 1`` (scanned on ``G_RANGE``) with
      ``max |eig(A - g B C)| = 1``;
    - phase margin: the smallest ``phi`` with ``max |eig(A - exp(-j phi) B C)| = 1`` (the spectrum
      of ``exp(+j phi)`` is the conjugate one);
    - disk margin: the smallest ``alpha`` for which some ``f = (1 + alpha d/2)/(1 - alpha d/2)``,
      ``d = exp(j psi)``, gives ``max |eig(A - f B (1 + f D)^-1 C)| = 1``; ``psi`` on ``[0, pi]``
      (``n_psi`` points, conjugate symmetry), then refined around the smallest.

    Returns ``{"gain_margin", "gain_margin_lower", "phase_margin_deg", "disk_margin"}``; a gain
    margin beyond ``G_RANGE`` is ``inf`` (upper) or ``0`` (lower).
    """

    def rho(f):
        return spectral_radius(closed_loop_matrix(L, f))

    g_hi = first_crossing(lambda lg: rho(10.0**lg), np.linspace(0.0, math.log10(G_RANGE[1]), 81))
    g_lo = first_crossing(lambda lg: rho(10.0**lg), np.linspace(0.0, math.log10(G_RANGE[0]), 81))
    phi = first_crossing(lambda p: rho(np.exp(-1j * p)), np.linspace(0.0, math.pi, 181))

    def alpha_crit(psi):
        d = np.exp(1j * psi)
        a = first_crossing(lambda al: rho((1 + al * d / 2) / (1 - al * d / 2)),
                           np.linspace(0.0, 1.999, 41), tol=1e-11)  # fmt: skip
        return 2.0 if a is None else a

    psis = np.linspace(0.0, math.pi, n_psi)
    crit = np.array([alpha_crit(p) for p in psis])
    i = int(np.argmin(crit))
    bounds = (psis[max(i - 1, 0)], psis[min(i + 1, n_psi - 1)])
    res = optimize.minimize_scalar(alpha_crit, bounds=bounds,
                                   method="bounded", options={"xatol": 1e-9})  # fmt: skip
    return {
        "gain_margin": math.inf if g_hi is None else 10.0**g_hi,
        "gain_margin_lower": 0.0 if g_lo is None else 10.0**g_lo,
        "phase_margin_deg": math.inf if phi is None else math.degrees(phi),
        "disk_margin": float(min(res.fun, crit[i])),
    }


def analyse_loops(loops: dict, *, python_control: bool = True, cross_check: bool = True) -> dict:
    """Margins of both channels of ``loops`` (``{"v": L_v, "w": L_w}``,
    ``wmr.linear.loops.pid_loops``).

    Returns ``{"eigenvalues", "spectral_radius", "v", "w", "same_closed_loop"}``: the nominal
    closed loop's eigenvalues and ``max |z|``, a :class:`LoopMargins` per channel, and the largest
    entry of the difference between the two loops' closed-loop matrices (0 up to round-off); with
    ``cross_check`` also ``"v_eigen"``, ``"w_eigen"`` (:func:`eigen_margins`).
    """
    A_cl = closed_loop_matrix(loops["v"])
    eig = np.linalg.eigvals(A_cl)
    out = {"eigenvalues": eig, "spectral_radius": float(np.max(np.abs(eig)))}
    for ch in CHANNELS:
        out[ch] = loop_margins(loops[ch], python_control=python_control)
        if cross_check:
            out[f"{ch}_eigen"] = eigen_margins(loops[ch])
    out["same_closed_loop"] = float(np.abs(closed_loop_matrix(loops["w"]) - A_cl).max())
    return out


def compare_margins(m: LoopMargins, e: dict) -> dict:
    """Differences between the frequency-domain margins ``m`` and the eigenvalue ones ``e``
    (:func:`eigen_margins`) of one loop, and whether the disk margins lie within the classical.

    Returns relative differences of the gain margins (the lower one compared on ``G_RANGE``,
    which is all the eigenvalue scan sees) and of the disk margin, the absolute difference of the
    phase margins [deg] (0 when both are inf), and ``disk_gm_below_classical``,
    ``disk_pm_below_classical``.
    """

    def rel(a, b):
        if math.isinf(a) and math.isinf(b):
            return 0.0
        if a == 0 and b == 0:
            return 0.0
        return abs(a - b) / max(abs(a), abs(b))

    lo = m.gain_margin_lower if m.gain_margin_lower >= G_RANGE[0] else 0.0
    return {
        "gain_margin_rel_diff": rel(m.gain_margin, e["gain_margin"]),
        "gain_margin_lower_rel_diff": rel(lo, e["gain_margin_lower"]),
        "phase_margin_abs_diff_deg": (0.0 if math.isinf(m.phase_margin_deg)
                                      and math.isinf(e["phase_margin_deg"])
                                      else abs(m.phase_margin_deg - e["phase_margin_deg"])),
        "disk_margin_rel_diff": rel(m.disk_margin, e["disk_margin"]),
        "disk_gm_below_classical": bool(m.disk_gain_margin_db <= m.gain_margin_db + 1e-9 and
                                        (m.gain_margin_lower == 0 or
                                         m.disk_gain_margin_db <= -m.gain_margin_lower_db + 1e-9)),
        "disk_pm_below_classical": bool(m.disk_phase_margin_deg <= abs(m.phase_margin_deg) + 1e-9),
    }  # fmt: skip


def margins_along_run(run, every: int = 50, integrator: str = "exact") -> dict:
    """Frozen-time margins along a run of the PID family, every ``every`` steps.

    At step ``k``: the gains ``run.gains()[k]`` (those used at ``t_k``) and the local
    ``(v_r, w_r)`` of ``run.ref[k]``; the loop relinearised there (frozen-time analysis: a slowly
    varying loop is not guaranteed stable by stable frozen loops, but it is the standard
    engineering view).  ``integrator`` is the robot's step of the run's scenario.

    Parameters
    ----------
    run : wmr.closedloop.result.RunResult
        A run of ``pid``, ``adaptive-pid`` or ``iapid-nn-dekf`` with its trajectory.

    Returns
    -------
    dict
        ``t`` (m,) [s], ``gains`` (m, 6), ``v_r``, ``w_r``, ``rho`` (closed-loop ``max|z|``) and per
        channel ``{ch}_gm_db``, ``{ch}_gm_lower_db``, ``{ch}_pm_deg``, ``{ch}_dm`` (m,), with
        ``m = ceil(n / every)``.
    """
    gains = run.gains()
    ks = np.arange(0, gains.shape[0], every)
    rec = {"t": run.t[ks], "gains": gains[ks], "v_r": run.ref[ks, 3],
           "w_r": run.ref[ks, 4], "rho": np.empty(ks.size)}  # fmt: skip
    for ch in CHANNELS:
        for key in ("gm_db", "gm_lower_db", "pm_deg", "dm"):
            rec[f"{ch}_{key}"] = np.empty(ks.size)
    for j, k in enumerate(ks):
        op = OperatingPoint(float(run.ref[k, 3]), float(run.ref[k, 4]), run.dt, integrator)
        loops = pid_loops(op, gains[k])
        rec["rho"][j] = spectral_radius(closed_loop_matrix(loops["v"]))
        for ch in CHANNELS:
            m = loop_margins(loops[ch], python_control=False)
            rec[f"{ch}_gm_db"][j] = m.gain_margin_db
            rec[f"{ch}_gm_lower_db"][j] = m.gain_margin_lower_db
            rec[f"{ch}_pm_deg"][j] = m.phase_margin_deg
            rec[f"{ch}_dm"][j] = m.disk_margin
    return rec


def json_number(x):
    """A float for JSON; infinities as the strings ``"inf"`` / ``"-inf"``, NaN as None (null)."""
    x = float(x)
    if math.isnan(x):
        return None
    if math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return x


# ---------------------------------------------------------------------------------------------
# Private helpers
# ---------------------------------------------------------------------------------------------


def _gain_margins(resp, w: np.ndarray, H: np.ndarray, nyq: float) -> tuple[float, float, float]:
    """Upper and lower gain margins and the frequency of the upper one, from the phase
    crossovers: sign changes of ``Im L`` where ``Re L < 0``, and ``z = -1``, where ``L`` is real."""
    gms, w_pc = [], []
    im = H.imag
    for i in np.flatnonzero(np.sign(im[:-1]) * np.sign(im[1:]) < 0):
        wc = optimize.brentq(lambda x: resp(x).imag, w[i], w[i + 1], xtol=1e-14, rtol=1e-14)
        h = resp(wc)
        if h.real < 0:
            gms.append(-1.0 / h.real)
            w_pc.append(wc)
    h_nyq = resp(nyq)
    if h_nyq.real < 0 and abs(h_nyq.imag) <= 1e-9 * abs(h_nyq):
        gms.append(-1.0 / h_nyq.real)
        w_pc.append(nyq)
    gms, w_pc = np.array(gms), np.array(w_pc)
    up, lo = gms > 1.0, gms < 1.0
    gm = float(np.min(gms[up])) if up.any() else math.inf
    gm_lo = float(np.max(gms[lo])) if lo.any() else 0.0
    w_gm = float(w_pc[up][np.argmin(gms[up])]) if up.any() else math.nan
    return gm, gm_lo, w_gm


def _phase_margin(resp, w: np.ndarray, H: np.ndarray) -> tuple[float, float]:
    """The phase margin [deg] of smallest magnitude over the gain crossovers (``|L| = 1``) and
    its frequency; ``(inf, nan)`` if there is none."""
    pms, w_gc = [], []
    mag = np.abs(H) - 1.0
    for i in np.flatnonzero(np.sign(mag[:-1]) * np.sign(mag[1:]) < 0):
        wc = optimize.brentq(lambda x: abs(resp(x)) - 1.0, w[i], w[i + 1], xtol=1e-14, rtol=1e-14)
        pms.append(((math.degrees(np.angle(resp(wc))) + 180.0) + 180.0) % 360.0 - 180.0)
        w_gc.append(wc)
    if not pms:
        return math.inf, math.nan
    j = int(np.argmin(np.abs(pms)))
    return float(pms[j]), float(w_gc[j])
