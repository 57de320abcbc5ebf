"""nmpc's local linear feedback and its margins (``analysis.margins.nmpc``, issue 21 item 3).

Oracles: the library's tracking error (eq. 6, ``wmr.model.kinematics.tracking_error``) for the pose
placed at a given error; the reference's own inputs as the policy's value at zero error (the
reference is a trajectory of the model, so it is the optimum); two finite-difference steps; and
the simulated closed loop (``wmr.closedloop.sim.simulate`` with the controller's default real-time
iteration, no noise) against the linear model built from the gain.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.margins import nmpc as mn
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.linear.loops import (
    closed_loop_matrix,
    constant_reference_scenario,
    error_plant,
    operating_point,
    slow_mode_error,
    start_state_map,
)
from wmr.model.kinematics import tracking_error

#: The two difference steps agree to this (measured 7e-8: truncation and solver noise, FD_STEP).
FD_AGREE = 1e-6
#: The simulated error against the linear prediction, relative to the largest error: the
#: nonlinearity at |e0| = 1e-3 is O(|e0|) and one Gauss-Newton step from the shifted solution is
#: exact up to O(|e|^2) near the reference.  Measured 1.1e-3 over 300 steps (the error falls to
#: 0.9 %); backstepping's linear loop in its place deviates by 0.21.
LINEAR_TOL = 0.01


@pytest.fixture(scope="module")
def op():
    return operating_point(scn.load(scn.builtin("sinusoid")), "mean")


@pytest.fixture(scope="module")
def gain(op):
    return mn.policy_gain(op)


@pytest.mark.parametrize("seed", range(4))
def test_pose_at_error_has_that_error(seed):
    rng = np.random.default_rng(seed)
    ref = np.array([*rng.normal(size=2), rng.uniform(-math.pi, math.pi), 0.3, 0.1])
    e = rng.normal(scale=0.3, size=3)
    assert np.allclose(tracking_error(mn.pose_at_error(ref, e), ref), e, atol=1e-12)


def test_the_policy_at_zero_error_is_the_reference_input(op):
    assert np.allclose(mn.policy(op)(np.zeros(3)), op.u_r, atol=1e-9)


def test_the_gain_does_not_depend_on_the_difference_step(op, gain):
    assert np.abs(gain - mn.policy_gain(op, h=10 * mn.FD_STEP)).max() < FD_AGREE
    assert gain[0, 0] > 0 and gain[1, 1] > 0 and gain[1, 2] > 0  # corrective signs (eq. 6)


def test_the_simulated_loop_follows_the_linear_model(op, gain):
    """From a small error in the slowest mode, the nonlinear loop with nmpc (its real-time
    iteration) follows ``x+ = A x`` of the plant closed by the finite-difference gain."""
    loops = mn.nmpc_loops(op, gain)
    A = closed_loop_matrix(loops["v"])
    M = start_state_map("backstepping", error_plant(op))  # a static gain: no controller state
    e0 = slow_mode_error(A, M)
    steps = 300
    r = simulate(constant_reference_scenario(op, steps * op.dt, e0), "nmpc", seed=0)
    e_sim = np.array([tracking_error(r.q[k], r.ref[k]) for k in range(steps)])
    x, e_lin = M @ e0, np.empty_like(e_sim)
    for k in range(steps):
        e_lin[k] = x[:3]
        x = A @ x
    dev = np.abs(e_sim - e_lin).max() / np.abs(e_sim).max()
    assert dev < LINEAR_TOL, dev
    assert np.linalg.norm(e_sim[-1]) < 0.2 * np.linalg.norm(e_sim[0])  # it decays


def test_margins_at_the_operating_points(op):
    res = mn.margins([op])[op.label]
    assert 0 < res["spectral_radius"] < 1
    for ch in ("v", "w"):
        assert res[ch]["closed_loop_stable"] and res[ch]["gain_margin_db"] > 6.0
        assert res[ch]["phase_margin_deg"] > 30.0
