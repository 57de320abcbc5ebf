"""Tests of wmr/linear/floquet.py: Floquet multipliers of the loops about a periodic reference
orbit.

Oracles: the closed form of a constant reference (a circle: ``Phi = A^N``, ``mu = eig(A)^N`` with
``A`` built independently by python-control in ``wmr.linear.loops``); the per-step Jacobians against
python-control's loop at the local ``(v_r, w_r)``; the similarity of monodromies started at
different phases; an extended-precision product for the round-off bounds; and the nonlinear
simulator (``wmr.closedloop.sim.simulate``), whose small perturbation must shrink by the slowest
multiplier over one period.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from wmr import scenario as scn
from wmr.linear import floquet as fq
from wmr.linear import loops as lp
from wmr.model import symbolic as sym

DT = 0.01
# Per-step Jacobians: CasADi's closed loop vs python-control's interconnection of CasADi's plant
# with the hand-written PID; both exact, they differ by round-off only.
JAC_TOL = 1e-12
# Phi vs A^N: N sequential products vs repeated squaring, each ~eps relative per product of
# these well-scaled contracting matrices: ~N eps ~ 1e-13 of the largest entry at N ~ 2000.
POWER_TOL = 1e-10
# mu vs eig(A)^N: eig(A)'s relative round-off (~1e-14 here) is multiplied by N by the power.
EIG_POWER_TOL = 1e-8


@pytest.fixture(scope="module")
def scenarios():
    return {name: scn.load(scn.builtin(name)) for name in ("lemniscate", "sinusoid")}


def test_monodromy_puts_later_steps_on_the_left():
    rng = np.random.default_rng(0)
    A, B, C = rng.normal(size=(3, 4, 4))
    assert np.array_equal(fq.monodromy(np.stack([A, B, C])), C @ (B @ A))
    assert np.allclose(fq.monodromy(np.stack([A, B]), np.longdouble).astype(float), B @ A,
                       rtol=1e-15, atol=1e-15)  # fmt: skip


def test_periods_and_orbits(scenarios):
    assert fq.reference_period("lemniscate", {"size": 2.0, "period": 40.0}) == 40.0
    assert fq.reference_period("sinusoid", {"omega": 0.5}) == pytest.approx(4 * math.pi)
    with pytest.raises(ValueError, match="not periodic"):
        fq.reference_period("waypoints", {})
    lem, sin = fq.orbit(scenarios["lemniscate"]), fq.orbit(scenarios["sinusoid"])
    assert lem.n_steps == 4000 and lem.mismatch == 0.0
    assert sin.n_steps == 1257 and sin.mismatch == pytest.approx(12.57 - 4 * math.pi, abs=1e-12)
    ref = sin.samples()
    assert ref.shape == (1258, 5)
    shifted = dataclasses.replace(sin, start=100).samples()
    assert np.array_equal(shifted[:-100], ref[100:])  # the same grid, read from step 100
    with pytest.raises(ValueError, match="ideal plant"):
        fq.orbit(scn.load(scn.builtin("lemniscate-slip")))


@pytest.mark.parametrize("controller", fq.CONTROLLERS)
def test_step_jacobians_are_the_python_control_loops_at_the_local_reference(scenarios, controller):
    """Each A_k is the frozen-time closed loop at (v_r(t_k), w_r(t_k)) (wmr.linear.loops), and the
    mapped CasADi call equals its one-by-one evaluation; the PID's without feed-forward at the
    integrals' equilibrium is the same matrix."""
    ref = fq.orbit(scenarios["lemniscate"]).samples()
    ks = [0, 517, 1000, 2999]
    A = fq.step_jacobians(controller, ref[ks, 3:5], DT)
    loops_of = lp.pid_loops if controller == "pid" else lp.backstepping_loops
    for A_k, k in zip(A, ks, strict=True):
        op = lp.OperatingPoint(ref[k, 3], ref[k, 4], DT)
        np.testing.assert_allclose(A_k, lp.closed_loop_matrix(loops_of(op)["v"]), rtol=0,
                                   atol=JAC_TOL)  # fmt: skip
        if controller == "pid":
            no_ff = sym.pid_closed_loop_jacobian_function("exact")
            x_star = lp.pid_equilibrium(op, lp.PID_GAINS)
            np.testing.assert_allclose(np.asarray(no_ff(x_star, op.u_r, lp.PID_GAINS, DT)), A_k,
                                       rtol=0, atol=1e-15)  # fmt: skip
    one = fq.step_jacobians(controller, ref[517, 3:5], DT)
    assert np.array_equal(one[0], A[1])
    with pytest.raises(ValueError, match="controller"):
        fq.step_jacobians("adaptive-pid", ref[ks, 3:5], DT)


@pytest.mark.parametrize("controller", fq.CONTROLLERS)
@pytest.mark.parametrize(("v_r", "w_r"), [(0.5, 0.5), (0.3, -0.2)], ids=["left", "right"])
def test_circle_closed_form(controller, v_r, w_r):
    """A constant (v_r, w_r): Phi = A^N and mu = eig(A)^N, the average rate is max|eig(A)|
    and every frozen-time radius along the orbit is that one."""
    op = lp.OperatingPoint(v_r, w_r, DT)
    c = fq.circle_check(op, (controller,))[controller]
    assert c["monodromy_rel_diff"] < POWER_TOL, c
    assert c["multipliers_rel_diff"] < EIG_POWER_TOL and c["multipliers_compared"] >= 2, c
    A = lp.closed_loop_matrix((lp.pid_loops if controller == "pid" else lp.backstepping_loops)(
        dataclasses.replace(op, w_r=abs(w_r)))["v"])  # fmt: skip
    R = abs(v_r / w_r)
    fl = fq.floquet(controller, fq.Orbit("circle", {"radius": R, "period": 2 * math.pi / abs(w_r)},
                                         DT))  # fmt: skip
    assert fl.average_rate == pytest.approx(lp.spectral_radius(A), rel=1e-12)
    np.testing.assert_allclose(fl.frozen_rho, lp.spectral_radius(A), rtol=1e-12)
    assert fl.stable


def test_multipliers_do_not_depend_on_the_starting_phase(scenarios):
    """The monodromy started at step s is similar to the one started at 0 (the same Jacobians,
    cyclically permuted, for a whole-step period): the same multipliers up to round-off."""
    orb = fq.orbit(scenarios["lemniscate"])
    for c in fq.CONTROLLERS:
        a = fq.floquet(c, orb)
        b = fq.floquet(c, dataclasses.replace(orb, start=orb.n_steps // 3))
        k = int(np.sum(a.resolved))
        assert k >= 2
        np.testing.assert_allclose(b.moduli[:k], a.moduli[:k], rtol=1e-9)


def test_round_off_bounds_cover_an_extended_precision_product(scenarios):
    """The resolved multipliers of the double-precision monodromy lie within their bounds of
    those of the extended-precision product; the PID's smallest ones are marked unresolved."""
    orb = fq.orbit(scenarios["lemniscate"])
    J = fq.step_jacobians("pid", orb.samples()[:-1, 3:5], DT)
    fl = fq.floquet_of(J)
    ext = np.linalg.eigvals(fq.monodromy(J, np.longdouble).astype(float))
    for mu, bound in zip(fl.multipliers[fl.resolved], fl.error_bound[fl.resolved], strict=True):
        assert np.min(np.abs(ext - mu)) <= bound, (mu, bound)
    assert fl.resolved[:2].all() and not fl.resolved[2:].any()
    # the left eigenvectors are normalised against the right ones
    assert abs(fl.left[0] @ fl.right[:, 0] - 1) < 1e-12


def test_a_destabilised_loop_has_a_multiplier_outside_the_unit_circle(scenarios):
    """The fixed PID with Kdv beyond its frozen-time limit (~0.98 at dt = 0.01) everywhere on the
    orbit: the loop about the orbit is unstable, its slowest multiplier outside the circle."""
    orb = fq.orbit(scenarios["sinusoid"])
    gains = list(lp.PID_GAINS)
    gains[2] = 1.2
    fl = fq.floquet("pid", orb, gains)
    assert np.all(fl.frozen_rho > 1.0)
    assert not fl.stable and fl.moduli[0] > 1.0 and fl.average_rate > 1.0
    assert fq.summary(fl, DT)["time_constant_s"] is None


SIMULATED = [("lemniscate", "pid"), ("sinusoid", "pid"), ("sinusoid", "backstepping")]


@pytest.mark.parametrize(("name", "controller"), SIMULATED)
def test_the_simulated_perturbation_shrinks_by_the_slowest_multiplier(scenarios, name, controller):
    """The nonlinear loop started 1e-4 off the reference along the slowest Floquet mode: over
    one period the perturbation's coordinate on that mode is multiplied by mu_1, and the whole
    perturbation is Phi times the initial one (tolerance: fq.SIM_TOL, its reason there)."""
    d = fq.simulator_check(scenarios[name], controller)
    assert not d["diverged"]
    assert d["perturbation_after_period"] > fq.SIM_FLOOR
    assert d["modal_ratio_rel_error"] < fq.SIM_TOL, d
    assert d["prediction_rel_error"] < fq.SIM_TOL, d
    assert np.linalg.norm(d["e0"]) == pytest.approx(fq.SIM_SIZE)


def test_analyse_records_and_skips_what_the_simulator_cannot_resolve(scenarios):
    """Backstepping's multiplier on the lemniscate (~1e-11) would shrink a 1e-4 perturbation to
    the poses' round-off: the simulator check is skipped with its reason."""
    rec = fq.analyse(scenarios["lemniscate"], ("backstepping",))
    r = rec["backstepping"]
    assert "skipped" in r["simulated"] and r["moduli"][0] * fq.SIM_SIZE < fq.SIM_FLOOR
    assert r["stable"] and r["frozen_rho_min"] <= r["frozen_rho_max"] < 1.0
    assert r["average_rate"] == pytest.approx(r["moduli"][0] ** (1 / rec["steps"]))
    assert r["time_constant_s"] == pytest.approx(-DT / math.log(r["average_rate"]))
    assert r["phase_shift_rel_diff"] < 1e-9
    assert r["frozen_period_prediction"] == pytest.approx(
        r["frozen_rho_geometric_mean"] ** rec["steps"])  # fmt: skip
