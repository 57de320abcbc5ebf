"""Margins of nmpc through its local linear feedback (issue 21 item 3: the margins study's nmpc
rows, ``record["nmpc"]`` of ``analysis/margins/``).

The nonlinear MPC's policy ``u = kappa(e)`` (the first command of the converged solution of
(M1)-(M2), ``wmr.controllers.nmpc``, at the pose whose corrected error (eq. 6) to the reference
is ``e``) is linearised at ``e = 0`` on the constant reference of an operating point
(``wmr.linear.loops.OperatingPoint``: a line or a circle) by central finite differences:
``D = d kappa / d e`` (2, 3).  The loop is then the backstepping loop's structure with ``D`` for
the static gain: ``wmr.linear.loops.error_plant`` broken at one input
(``wmr.linear.loops.loop_transfer``), its margins by ``wmr.linear.margins.analyse_loops``.

The policy is the *converged* one (ipopt to 1e-12 from the reference's inputs): the real-time
iteration the controller runs by default is a dynamic system (its warm start is a state), whose
linearisation would add the shifted solution's 2N states; on the noise-free loop near the
reference it follows the converged policy (``tests/test_nmpc.py``: to rounding on the circle).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from wmr.linear.loops import OperatingPoint, constant_reference_scenario, error_plant, loop_transfer

__all__ = ["FD_STEP", "ORACLE_TOL", "NOTE", "pose_at_error", "policy", "policy_gain",
           "nmpc_loops", "margins", "table_lines"]  # fmt: skip

#: Central-difference step in the error [m, m, rad]: truncation O(h^2) ~ 1e-10 against the
#: solver's 1e-12 / h = 1e-7 (the two balance near 1e-4..1e-5; tests compare the two steps).
FD_STEP = 1e-5
#: ipopt's tolerance for the policy (its KKT error; the command is accurate to about this).
ORACLE_TOL = 1e-12
#: The heading of the margins table's NMPC block.
NOTE = ("NMPC (not in the paper; issue 21): its converged policy (ipopt to 1e-12, default "
        "settings) linearised at zero error by central differences (step 1e-5) on each operating "
        "point's constant reference, a static gain du/de (2 x 3) in BSC's place; the real-time "
        "iteration it runs by default is a dynamic system whose loop near the reference follows "
        "this one (tests/test_margins_nmpc.py).")


def pose_at_error(ref_row, e) -> np.ndarray:
    """The pose whose corrected error (eq. 6) to the reference pose ``ref_row[:3]`` is ``e``:
    ``theta = theta_r - e3``, ``p = p_r - R(theta) (e1, e2)`` (as
    ``wmr.linear.loops.constant_reference_scenario`` places its start)."""
    th = ref_row[2] - e[2]
    c, s = math.cos(th), math.sin(th)
    return np.array([ref_row[0] - (c * e[0] - s * e[1]), ref_row[1] - (s * e[0] + c * e[1]), th])


def policy(op: OperatingPoint, settings=None):
    """``kappa(e) -> u`` (2,), the converged nmpc policy at step 0 of ``op``'s constant reference
    (``settings``: ``nmpc.Settings``, default the defaults; its solver is replaced by ipopt)."""
    from wmr.controllers import nmpc

    st = dataclasses.replace(settings or nmpc.Settings(), solver="ipopt", tolerance=ORACLE_TOL,
                             max_iterations=3000)  # fmt: skip
    sc = constant_reference_scenario(op, st.horizon * st.prediction_step + 1.0, np.zeros(3))
    c = nmpc.make(st, sc)
    rows = c.preview(0).copy()
    guess = rows[:-1, 3:5].ravel()

    def kappa(e) -> np.ndarray:
        p = nmpc.Problem.parameters(pose_at_error(rows[0], e), rows, c.weights,
                                    st.terminal_weight, c.h)  # fmt: skip
        x, _, ok, status = c.problem.solve(guess, p, c.lbx, c.ubx, np.zeros(c.lbx.size))
        if not ok:
            raise RuntimeError(f"nmpc policy at e = {list(e)}: ipopt failed ({status})")
        return x[:2]

    return kappa


def policy_gain(op: OperatingPoint, settings=None, h: float = FD_STEP) -> np.ndarray:
    """``D = d kappa / d e`` (2, 3) at ``e = 0`` by central differences of step ``h``."""
    return error_jacobian(policy(op, settings), h)


def error_jacobian(kappa, h: float = FD_STEP) -> np.ndarray:
    """``d kappa / d e`` (2, 3) at ``e = 0`` of a policy ``kappa: e (3,) -> u (2,)`` by central
    differences of step ``h`` (the one finite-difference linearisation of a policy here)."""
    D = np.zeros((2, 3))
    for j in range(3):
        d = np.zeros(3)
        d[j] = h
        D[:, j] = (kappa(d) - kappa(-d)) / (2 * h)
    return D


def nmpc_loops(op: OperatingPoint, D: np.ndarray) -> dict:
    """``{"v": L_v, "w": L_w}`` of the plant at ``op`` closed by the static gain ``D``."""
    import control as ct

    C = ct.ss(np.zeros((0, 0)), np.zeros((0, 3)), np.zeros((2, 0)), np.asarray(D), op.dt,
              inputs=("e1", "e2", "e3"), outputs=("v", "w"), name="controller")  # fmt: skip
    P = error_plant(op)
    return {ch: loop_transfer(P, C, ch) for ch in ("v", "w")}


def margins(ops, settings=None) -> dict:
    """Per operating point: ``D``, the closed loop's spectral radius, and the margins of each
    channel (``wmr.linear.margins.LoopMargins.to_json``)."""
    from wmr.linear.margins import analyse_loops

    out = {}
    for op in ops:
        D = policy_gain(op, settings)
        res = analyse_loops(nmpc_loops(op, D), cross_check=False)
        out[op.label] = {"v_r": op.v_r, "w_r": op.w_r, "gain": D.tolist(),
                         "spectral_radius": res["spectral_radius"],
                         **{ch: res[ch].to_json() for ch in ("v", "w")}}  # fmt: skip
    return out


def margin_cell(m: dict) -> str:
    """One loop's margins as a table cell: upper gain margin [dB] / phase margin [deg] / disk
    margin alpha (a text entry, e.g. "inf", as it is)."""
    from analysis import common

    return " / ".join(common.fmt(m[k], d) if not isinstance(m[k], str) else m[k]
                      for k, d in (("gain_margin_db", 1), ("phase_margin_deg", 1),
                                   ("disk_margin", 3)))  # fmt: skip


def table_lines(record: dict) -> list[str]:
    """The margins table's NMPC block (empty when the record has no ``"nmpc"`` entry)."""
    from analysis import common

    rec = record.get("nmpc")
    if not rec:
        return []

    rows = [(label, f"{r['v_r']:.3f}", f"{r['w_r']:.3f}", margin_cell(r["v"]), margin_cell(r["w"]),
             f"{r['spectral_radius']:.5f}",
             "; ".join(", ".join(f"{x:.3f}" for x in row) for row in r["gain"]))
            for label, r in rec.items()]  # fmt: skip
    return ["", NOTE + "  GM upper dB / PM deg / alpha per loop; du/de rows v; w:", "",
            *common.md_table(("operating point", "v_r", "w_r", "NMPC v", "NMPC w", "max abs(z)",
                              "du/de"), rows)]  # fmt: skip
