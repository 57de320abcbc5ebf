"""Margins of adaptive backstepping frozen at its estimates (issue 21 item 3: the margins
study's ``adaptive-bsc`` rows, ``record["adaptive_bsc"]`` of ``analysis/margins/``).

With its adaptation frozen, ``adaptive-bsc`` is the static law ``u_c = G^^-1 u*(e)`` of
``wmr.controllers.adaptive_bsc`` (A2) with constant ``G^``; the true robot applies
``u = G u_c`` (A1).  Its linearisation at ``e = 0`` on an operating point's constant reference
(``wmr.linear.loops.OperatingPoint``) is ``D = G d kappa / d e`` (2, 3), ``kappa`` the controller's
own compiled law (``adaptive_bsc.law``) evaluated from a fresh state holding ``G^``, differentiated
by central differences; the loop is the backstepping loop's structure with ``D`` for the static gain
(``analysis.margins.nmpc.nmpc_loops``), broken at one applied velocity.

**Which estimates.**  Those at the end of the shipped lemniscate run (seed 0) on each plant of
:data:`PLANTS`: the ideal robot (where the estimates stay near the nominal map, so the frozen law
is BSC's up to the noise-driven estimate error), the wheel-radius robot and the unequal-wheel
robot (the ``G`` of their ``[plant]`` tables).  The end of a run, not the nominal ``(1, 0, 1,
0)``: at the nominal estimates the frozen law is BSC's exactly (a test), so the rows would only
repeat BSC's; at the end of a run they say what the adapted loop keeps on the robot it adapted
to.  The linearisation is at ``e = 0``, ``u = u_r``: the equilibrium when ``G G^^-1 = I``; a
residual estimate error moves the equilibrium and the loop by the same small order.
"""

from __future__ import annotations

import numpy as np

from analysis.margins.nmpc import nmpc_loops, pose_at_error
from wmr import scenario as scn
from wmr.linear.loops import OperatingPoint, constant_reference_scenario

__all__ = ["PLANTS", "SEED", "FD_STEP", "NOTE", "ADAPTED", "MATCH_DB", "MATCH_DEG", "check",
           "frozen_estimates", "input_map", "policy", "policy_gain", "margins",
           "table_lines", "extend"]  # fmt: skip

#: The plants: label -> the shipped scenario whose end-of-run estimates are frozen.
PLANTS = {"ideal": "lemniscate", "wheel-radius": "lemniscate-wheel-radius",
          "unequal-wheels": "lemniscate-wheel-asymmetry"}  # fmt: skip
SEED = 0
#: Central-difference step in the error [m, m, rad]: the law is smooth (cos, sin of e3), so
#: the truncation is O(h^2) ~ 1e-12 against round-off ~1e-16 / h = 1e-10.
FD_STEP = 1e-6
#: An adapted loop: ``||G G^^-1 - I||_2`` at most this (the estimates after 40 s are within
#: ~0.006 of the truth, ``analysis.estimates``).
ADAPTED = 0.01
#: An adapted loop's margins equal BSC's within these: a static input perturbation ``I + Delta``
#: moves a gain margin by at most ``20 log10(1 + |Delta|)`` ~ 0.09 dB at ``|Delta| = 0.01`` on a
#: decoupled channel; the phase margin by about ``|Delta|`` rad ~ 0.6 deg near the crossover.
MATCH_DB = 0.1
MATCH_DEG = 0.6
#: The heading of the margins table's adaptive-bsc block.
NOTE = ("Adaptive BSC (not in the paper; issue 21) frozen at its estimates at the end of the "
        "shipped lemniscate run (seed 0) on each plant.  Its law u_c = G^^-1 u*(e) is linearised "
        "at zero error by central differences, times the plant's input map G, in BSC's place; on "
        "the ideal plant it is BSC's law up to the estimates' error "
        "(tests/test_margins_adaptive.py).")


def input_map(v_gain: float, v_from_w: float, w_gain: float, w_from_v: float) -> np.ndarray:
    """``G = [[v_gain, v_from_w], [w_from_v, w_gain]]`` of (A1), shape (2, 2)."""
    return np.array([[v_gain, v_from_w], [w_from_v, w_gain]], dtype=float)


def frozen_estimates(scenario: str, seed: int = SEED) -> dict:
    """The estimates ``(v_gain, v_from_w, w_gain, w_from_v)`` after the last update of
    ``adaptive-bsc``'s run on the shipped ``scenario`` (``adaptive_bsc.State``), and the
    plant's true ones."""
    from wmr.closedloop.sim import simulate

    sc = scn.load(scn.builtin(scenario))
    st = simulate(sc, "adaptive-bsc", seed, keep_trajectory=False).final
    names = ("v_gain", "v_from_w", "w_gain", "w_from_v")
    return {"scenario": scenario, "seed": seed,
            "estimates": {n: float(getattr(st, n)) for n in names},
            "truth": {n: float(getattr(sc.plant, n)) for n in names}}  # fmt: skip


def policy(op: OperatingPoint, estimates, settings=None):
    """``kappa(e) -> u_c`` (2,): ``adaptive_bsc.law`` with the estimates ``(v_gain, v_from_w,
    w_gain, w_from_v)`` frozen, on the reference pose at the origin moving at ``op.u_r``."""
    from wmr.controllers import adaptive_bsc as abc

    st = settings or abc.Settings()
    sc = constant_reference_scenario(op, 1.0, np.zeros(3))
    p, s0, theta, P = abc.pack(st, sc, np.random.default_rng(0))
    s0[abc.S_EST : abc.S_EST + 4] = estimates
    ref = np.array([0.0, 0.0, 0.0, op.v_r, op.w_r])

    def kappa(e) -> np.ndarray:
        u = np.zeros(2)
        abc.law(p, s0.copy(), theta, P, pose_at_error(ref, e), ref, op.dt, u)
        return u

    return kappa


def policy_gain(op: OperatingPoint, estimates, h: float = FD_STEP) -> np.ndarray:
    """``d kappa / d e`` (2, 3) at ``e = 0`` by central differences of step ``h``."""
    from analysis.margins.nmpc import error_jacobian

    return error_jacobian(policy(op, estimates), h)


def margins(ops) -> dict:
    """Per plant of :data:`PLANTS`: the frozen estimates, and per operating point the gain
    ``D = G d kappa/d e``, the closed loop's spectral radius and each channel's margins
    (``wmr.linear.margins.LoopMargins.to_json``)."""
    from wmr.linear.margins import analyse_loops

    out = {}
    for plant, scenario in PLANTS.items():
        fz = frozen_estimates(scenario)
        est = [fz["estimates"][n] for n in ("v_gain", "v_from_w", "w_gain", "w_from_v")]
        G = input_map(**fz["truth"])
        entry = {**fz, "points": {}}
        for op in ops:
            D = G @ policy_gain(op, est)
            res = analyse_loops(nmpc_loops(op, D), cross_check=False)
            entry["points"][op.label] = {"v_r": op.v_r, "w_r": op.w_r, "gain": D.tolist(),
                                         "spectral_radius": res["spectral_radius"],
                                         **{ch: res[ch].to_json() for ch in ("v", "w")}}
        out[plant] = entry
    return out


def check(record: dict) -> None:
    """Each plant's frozen estimates adapted the loop (``||G G^^-1 - I|| <= ADAPTED``) and then
    its margins equal BSC's within :data:`MATCH_DB` and :data:`MATCH_DEG` at every operating
    point (BSC's on the ideal plant, ``record["operating_points"]``); a record older than issue
    21 (no ``"adaptive_bsc"``) passes."""
    names = ("v_gain", "v_from_w", "w_gain", "w_from_v")
    for plant, e in record.get("adaptive_bsc", {}).items():
        G = input_map(**e["truth"])
        G_hat = input_map(*(e["estimates"][n] for n in names))
        delta = float(np.linalg.norm(G @ np.linalg.inv(G_hat) - np.eye(2), 2))
        assert delta <= ADAPTED, f"{plant}: ||G G^^-1 - I|| = {delta:.4f} > {ADAPTED}"
        for label, r in e["points"].items():
            bsc = record["operating_points"][label]["backstepping"]
            for ch in ("v", "w"):
                for key, tol in (("gain_margin_db", MATCH_DB), ("phase_margin_deg", MATCH_DEG)):
                    a, b = r[ch][key], bsc[ch][key]
                    assert a == b or abs(a - b) <= tol, (plant, label, ch, key, a, b)


def _largest_gap(record: dict) -> tuple[float, float]:
    """The largest |adaptive-bsc - BSC| of the finite gain and phase margins, [dB], [deg]."""
    gaps = {"gain_margin_db": 0.0, "phase_margin_deg": 0.0}
    for e in record["adaptive_bsc"].values():
        for label, r in e["points"].items():
            bsc = record["operating_points"][label]["backstepping"]
            for ch in ("v", "w"):
                for key in gaps:
                    a, b = r[ch][key], bsc[ch][key]
                    if not (isinstance(a, str) or isinstance(b, str)):
                        gaps[key] = max(gaps[key], abs(a - b))
    return gaps["gain_margin_db"], gaps["phase_margin_deg"]


def table_lines(record: dict) -> list[str]:
    """The margins table's adaptive-bsc block (empty when the record has no ``"adaptive_bsc"``
    entry), beside BSC's margins at the same operating point."""
    from analysis import common
    from analysis.margins.nmpc import margin_cell

    rec = record.get("adaptive_bsc")
    if not rec:
        return []

    rows = []
    for plant, e in rec.items():
        est = ", ".join(f"{e['estimates'][n]:.4f}" for n in ("v_gain", "v_from_w", "w_gain",
                                                             "w_from_v"))  # fmt: skip
        for label, r in e["points"].items():
            bsc = record["operating_points"][label]["backstepping"]
            rows.append((plant, est, label, margin_cell(r["v"]), margin_cell(r["w"]),
                         margin_cell(bsc["v"]), margin_cell(bsc["w"]),
                         f"{r['spectral_radius']:.5f}"))  # fmt: skip
    gm, pm = _largest_gap(record)
    summary = (f"Once adapted it keeps BSC's margins: on every plant and operating point within "
               f"{gm:.3f} dB of gain and {pm:.3f}° of phase margin.")
    return ["", NOTE + "  " + summary + "  Estimates (v_gain, v_from_w, w_gain, w_from_v); GM "
            "upper dB / PM deg / alpha per loop, BSC's on the ideal plant beside them:", "",
            *common.md_table(("plant", "frozen estimates", "operating point", "Adaptive BSC v",
                              "Adaptive BSC w", "BSC v", "BSC w", "max abs(z)"), rows)]


def extend(out) -> dict:
    """Add ``"adaptive_bsc"`` to the committed margins record in ``out`` (every other key kept
    as stored: a full rerun on another CPU moves their last bits, as for ``nmpc``), rewrite its
    table; return the record."""
    from analysis import common
    from analysis import margins as study
    from wmr.linear.loops import operating_point

    record = common.load_record(out, study.STEM)
    sc = {n: scn.load(scn.builtin(n)) for n in ("sinusoid", "lemniscate")}
    ops = [operating_point(sc[n], where) for n in ("sinusoid", "lemniscate")
           for where in ("mean", "max-curvature")]  # fmt: skip
    assert [o.label for o in ops] == list(record["operating_points"]), "operating points moved"
    record["adaptive_bsc"] = margins(ops)
    study.check(record)
    common.write_record(out, study.STEM, record)
    common.write_table(out, study.STEM, study.table(record))
    return record


if __name__ == "__main__":  # python -m analysis.margins.adaptive [OUT]: extend OUT's record
    import sys

    extend(sys.argv[1] if len(sys.argv) > 1 else "paper")
