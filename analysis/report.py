"""The generated reproduction and stability/boundedness report: ``paper/report.md``.

The header, what the suite found (one short answer per question: ``analysis.findings``), the
section of every registered study (``analysis.STUDIES``, in that order) whose record is stored
(``study.render(record)``), then the assumptions (values the paper does not give, read from the
shipped scenario files and settings defaults) and the errata with the evidence from the stored
records of the reproduction, jacobians and boundedness studies.  Every
number is read from ``results/``; nothing is typed by hand.  ``main(out)`` rewrites
``out/report.md`` from what is stored there, deterministically.
"""

from __future__ import annotations

import math
from pathlib import Path

import analysis
from analysis import common, findings
from analysis.common import fmt
from analysis.reproduction.ablations import backstepping_damping
from wmr import controllers
from wmr import scenario as scn
from wmr.io import atomic_write_text

__all__ = ["build", "main", "lagged_channels", "LAGGED_SCENARIO"]

#: The shipped scenario whose lagged velocity loop the DA-NN row of the assumptions evaluates.
LAGGED_SCENARIO = "lemniscate-payload"


def lagged_channels(dyn, dt: float) -> dict:
    """The inner velocity loop of the lagged-velocity plant seen from a command held over one
    step.

    Per channel (``v`` with the mass, ``w`` with the inertia; ``wmr.robots.plant``):
    ``mass v' = nominal_mass bw (a - v) - f v`` is first order with time constant
    ``tau = mass / (nominal_mass bw + f)`` [s] and static gain
    ``g = nominal_mass bw / (nominal_mass bw + f)``; a command ``a`` held over ``[0, dt]`` moves
    the integral of the velocity by ``g (dt - tau (1 - exp(-dt/tau)))``, i.e. ``g rho dt`` with
    ``rho = 1 - (tau/dt)(1 - exp(-dt/tau))`` (the kinematic model: ``g = rho = 1``).

    Parameters
    ----------
    dyn : wmr.scenario.LaggedVelocity
        The plant's ``[plant.lagged-velocity]`` table (``mass``, ``inertia``, ``friction``,
        ``nominal_*``, ``bandwidth``).
    dt : float
        Sample period [s].

    Returns
    -------
    dict
        ``{"v": {"tau", "g", "rho"}, "w": {...}}``.
    """
    out = {}
    for ch, m, m_nom, bw, f in (("v", dyn.mass, dyn.nominal_mass, dyn.bandwidth[0],
                                 dyn.friction[0]),
                                ("w", dyn.inertia, dyn.nominal_inertia, dyn.bandwidth[1],
                                 dyn.friction[1])):  # fmt: skip
        tau = m / (m_nom * bw + f)
        rho = 1.0 - (tau / dt) * -math.expm1(-dt / tau)
        out[ch] = {"tau": tau, "g": m_nom * bw / (m_nom * bw + f), "rho": rho}
    return out


def _dann_row() -> tuple[str, str, str]:
    """The assumptions row of DA-NN: its design, and what it can adapt to on the shipped lagged
    velocity loop (before and after its change), computed by :func:`lagged_channels`."""
    import dataclasses

    dann = controllers.get("adaptive-nn").Settings()
    sc = scn.load(scn.builtin(LAGGED_SCENARIO))
    dyn = sc.plant.model_table
    phases = [("at start", dyn)]
    for ch in sc.plant.changes:
        keys = {k: v for k, v in ch.values.items() if k in ("mass", "inertia", "friction")}
        phases.append((f"from {ch.at:g} s", dataclasses.replace(phases[-1][1], **keys)))
    parts = []
    for label, d in phases:
        c = lagged_channels(d, sc.dt)
        parts.append(f"{label}: τ = {c['v']['tau']:.3f}/{c['w']['tau']:.3f} s, g = "
                     f"{c['v']['g']:.3f}/{c['w']['g']:.3f}, g ρ = "
                     f"{c['v']['g'] * c['v']['rho']:.3f}/{c['w']['g'] * c['w']['rho']:.3f}")
    value = (f"backstepping {dann.gains} + NN compensator ({dann.hidden} hidden) trained by an "
             "EKF with the paper's P0, Q, R: u = u_bsc + NN(e1, e2, sin e3, cos e3 − 1, v_r, "
             "w_r), innovation q_r,k − q̂_k through the nominal unicycle's one-step Jacobian G")
    why = ("design not given; notes §4.2.  It compensates the error the base law leaves, as a "
           "static function of (e, v_r, w_r).  On the lagged velocity loop (`wmr.robots.plant`, "
           f"`{LAGGED_SCENARIO}`, v/w channels) a command held one step moves the pose by "
           "g ρ G, ρ = 1 − (τ/dt)(1 − e^(−dt/τ)) (" + "; ".join(parts) + "): its EKF's direction "
           "has the right sign and an effect overstated by 1/(g ρ); a static gain loss g is a "
           "function of v_r, w_r (it can learn the correction (1/g − 1) v_r); the lag τ is not "
           "(cancelling it needs the reference's acceleration or the measured velocity, "
           "neither an input): see `wmr.controllers.adaptive_nn`")  # fmt: skip
    return ("DA-NN", value, why)


def _assumptions() -> list[str]:
    """Values the paper does not give, read from the shipped scenarios and settings defaults."""
    sc = {n: scn.load(scn.builtin(n)) for n in scn.PAPER_SCENARIOS}
    lem, sin, per = sc["lemniscate"], sc["sinusoid"], sc["sinusoid-perturbed"]
    pid_s = controllers.get("adaptive-pid").Settings()
    iapid = controllers.get("iapid-nn-dekf").Settings()
    bsc = controllers.get("backstepping").Settings()
    damp = backstepping_damping(bsc.gains)
    d = per.disturbances[0]
    rows = [
        ("sample period dt", f"{lem.dt} s", "Kanayama (1990) and related work use 10 ms"),
        ("run length", f"{lem.duration} s",
         "must cover the 15-20 s perturbation; one lemniscate loop"),
        ("plant integration", lem.integrator,
         "zero-order hold, exact arc (no discretisation error)"),
        ("lemniscate", f"Gerono, size {lem.reference.params['size']} m, period "
         f"{lem.reference.params['period']} s", "formula not given; passes through the origin"),
        ("sinusoid", f"x = {sin.reference.params['speed']} t, y = "
         f"{sin.reference.params['amplitude']} sin({sin.reference.params['omega']} t)",
         "formula not given"),
        ("perturbation", f"(v, w) += {d.velocity} for {d.start} <= t < {d.stop} s",
         "window from the paper; its nature is not given (additive input disturbance)"),
        ("pose measurement noise", f"std {lem.noise.pose_std}", "not given"),
        ("pose EKF", f"process std {lem.estimator.process_std}; used by: "
         + ", ".join(n for n in controllers.NAMES if lem.estimator.filters(n)),
         "errata E9, reading A"),
        ("initial PID gains", str(pid_s.gains), "not given; a fixed PID that tracks to cm level"),
        ("gain clamps", f"[{pid_s.gain_min}, {pid_s.gain_max}]",
         "E5d: noise drives Kd up; the linearised loop is unstable past Kd ~ 0.95 (margins)"),
        ("SGD rates mu, alpha", f"{pid_s.mu[0]} (paper), alpha = {pid_s.alpha}", "alpha not given"),
        ("PID feed-forward", str(pid_s.feed_forward), "eq. 7 is literal (no feed-forward)"),
        ("identifier", f"tanh, {iapid.hidden} hidden, inputs (v, w, cos θ, sin θ), targets "
         "(q̂_k − q̂_(k−1))/dt", "E6: a static (v, w) -> pose map cannot identify the robot"),
        ("weight DEKF", f"P0 = {iapid.p0} I, Q = {iapid.q} I, R = {iapid.r} I3", "paper eq. 63"),
        ("backstepping gains", str(bsc.gains), "not given; of the order of published gains "
         f"(notes §4.1); lateral loop {damp['name']}, ζ = k3/(2√k2) = {damp['zeta']:.2f}"),
        _dann_row(),
    ]  # fmt: skip
    return common.md_table(["item", "value used", "why"], rows)


def _errata(out: Path) -> list[str]:
    """The errata of the paper with the evidence this suite produced for each (from results/)."""
    rep = common.load_record(out, "reproduction")
    jac = common.load_record(out, "jacobians")
    bnd = common.load_record(out, "boundedness")
    if not (rep and jac and bnd):
        return []

    def pos(sc, name, variant="default"):
        rec = rep["scenarios"][sc]["runs"][name].get(variant)
        return None if rec is None else rec["position"]["mean"]

    rot = jac["rotation"]
    net = jac["network_input"]
    lem = "lemniscate"
    ratio = {n: pos(lem, n, "rotation-printed") / pos(lem, n) for n in
             ("pid", "adaptive-pid", "iapid-nn-dekf", "backstepping", "adaptive-nn")}  # fmt: skip
    ff = pos("sinusoid", "pid") / pos("sinusoid", "pid", "feed-forward")
    ff_best = rep.get("feed_forward_best", {})
    ff_family = {n for d in ff_best.values() for n in d["with"]["on_variant"]}
    ff_count = {k: sum(d[k]["best"] in ff_family for d in ff_best.values())
                for k in ("without", "with")}  # fmt: skip
    ff_text = (f"; with it the PID family has the lowest mean position RMSE in {ff_count['with']} "
               f"of {len(ff_best)} scenarios ({ff_count['without']} of {len(ff_best)} without)"
               if ff_best else "")  # fmt: skip
    exc = rep.get("gain_excursion", {})
    kpi = max((r["max_rel"][g] for d in exc.values() for r in d.values()
               for g in ("Kpv", "Kiv", "Kpw", "Kiw")), default=None)  # fmt: skip
    e7_text = (f" (at the defaults SGD moves the proportional and integral gains by at most "
               f"{100 * kpi:.1f} % over a run: see the verdict)" if kpi is not None else "")
    nnj = pos(lem, "iapid-nn-dekf", "nn-jacobian-printed") / pos(lem, "iapid-nn-dekf")
    alphas = [bnd[sc]["alpha"] for sc in bnd]
    nees = [bnd[sc]["nees_mean"] for sc in bnd]
    bands = [bnd[sc]["nees_bounds"] for sc in bnd]
    dt = scn.load(scn.builtin("lemniscate")).dt
    rows = [
        ("E1, E2", "eq. 2 uses v, eq. 3 has w_r − w",
         "references from v_r, w_r; e3 = wrap(θ_r − θ)",
         "by construction (tests: references vs finite differences)"),
        ("E3", "rotation of eqs. 4/6 has row [sin θ, cos θ, 0]",
         "row [−sin θ, cos θ, 0]; printed form behind printed_rotation",
         f"det(printed) = {rot['printed_det']} = cos 2θ (max deviation "
         f"{fmt(rot['max_abs_det_minus_cos_2theta'])}); Kanayama's error dynamics: residual "
         f"{fmt(rot['error_dynamics_max_residual']['corrected'])} (rotation) vs median "
         f"{fmt(rot['error_dynamics_median_residual']['printed'], 2)} (printed); lemniscate "
         "position RMSE × "
         + ", ".join(f"{fmt(v, 2)} ({controllers.label(k)})" for k, v in ratio.items())
         + " with the printed matrix"),
        ("E4", "eq. 7 has no feed-forward", "literal by default; feed_forward option",
         f"feed-forward lowers the fixed PID's sinusoid position RMSE {fmt(ff, 1)}×{ff_text}"),
        ("E5", "gradient indices and clamps unspecified",
         "K ← clip(K + μ∘(∂u_(k−1)/∂K)ᵀ J_(k−1)ᵀ T_eᵀ Γ e_k)",
         "tests: the collapsed form of notes §4.3 with the analytic Jacobian"),
        ("E6", "NN maps (v, w) to the absolute pose",
         "series-parallel identifier on (v, w, cos θ, sin θ), targets (q̂_k − q̂_(k−1))/dt",
         "learned Jacobian: see the Jacobians section"),
        ("E7", "eqs. 22–24 (extra factor, σ for σ′, no sum over j)", "W diag(σ′(a)) V_u",
         f"printed form vs AD: median relative error {fmt(net['printed_median_rel_error'], 2)} "
         f"(corrected: max {fmt(net['corrected_max_rel_error'])}); in closed loop it changes "
         f"IAPID's lemniscate RMSE by × {fmt(nnj, 3)}{e7_text}"),
        ("E8", "eq. 30 evaluates h(θ, 0); H_k undefined", "h(θ, x_k); H_k = ∂z/∂θ (3 × n)",
         "weight Jacobian vs AD and the EKF vs a linear Kalman filter (tests)"),
        ("E9", "no localisation model", "pose EKF on the unicycle, H = I3 (reading A)",
         "pose NEES mean " + ", ".join(fmt(x, 2) for x in nees) + " against the χ² band "
         + ", ".join(f"[{fmt(b[0], 2)}, {fmt(b[1], 2)}]" for b in bands) + " ("
         + ("below it: over-cautious" if all(x < b[0] for x, b in zip(nees, bands, strict=True))
            else "not all below it") + ")"),
        ("E10", "stability proof indices, Assumption 1 bounds", "Reif et al. two-step form",
         "Lemma 2's α = " + ", ".join(fmt(a) for a in alphas) + ": the guaranteed contraction "
         f"needs ~{fmt(min(dt / a for a in alphas), 0)} s (dt/α) to shrink an error by e"),
    ]  # fmt: skip
    table = common.md_table(["erratum", "printed", "used here", "evidence"], rows)
    return ["## Errata of the paper and the evidence", "", *table, ""]


def build(out: str | Path) -> str:
    """The report's Markdown from the results stored in ``out``: the header, what the suite
    found (``analysis.findings``), the section of every registered study (``analysis.STUDIES``,
    in order) whose record is stored, then the assumptions and the errata."""
    out = Path(out)
    head = ["# wmr: reproduction and stability/boundedness report", "",
            "Silaa, Bencherif, Barambones, *Indirect Adaptive Control Using Neural Network and "
            "Discrete Extended Kalman Filter for Wheeled Mobile Robot*, Actuators 2024, 13, 51 — "
            "reproduced, checked and extended.  Generated by `wmr report` from `results/`; "
            "regenerate everything with `make reproduce`.", "",
            *findings.render(findings.findings(out))]  # fmt: skip
    sections = []
    for name in analysis.STUDIES:  # a study's STEM is its registry name
        record = common.load_record(out, name)
        if record is not None:  # only then import the study (some import heavy packages)
            sections.append(analysis.get(name).render(record))
    if not sections:
        sections.append("## Studies\n\nNot generated yet (`wmr reproduce`).\n")
    tail = ["## Assumptions: what the paper does not give, and what was used", "",
            *_assumptions(), "", *_errata(out)]  # fmt: skip
    return "\n".join(["\n".join(head), *sections, "\n".join(tail)]).rstrip() + "\n"


def main(out: str | Path = "paper", *, html: bool = False) -> Path:
    """Write ``out/report.md`` from ``out/results`` (and ``out/report.html`` with ``html``:
    ``analysis.report_html``); check that every linked image exists.  Returns the Markdown
    report's path."""
    out = Path(out)
    text = build(out)
    missing = [
        link for link in (seg.split(")")[0] for seg in text.split("](")[1:])
        if link.startswith("figures/") and not (out / link).exists()
    ]  # fmt: skip
    assert not missing, f"report links missing images: {missing}"
    path = atomic_write_text(out / "report.md", text)
    if html:
        from analysis import report_html

        report_html.write(out)
    return path
