"""The python-control closed loop (``wmr.linear.nlsys``) against ``wmr.closedloop.sim.simulate``.

The oracle is the compiled kernel: the nlsys's update function calls the same jitted phases and
law in the same order on the same noise and reference, so its trajectory must equal
``simulate``'s bit for bit (``assert_array_equal``, no tolerance): any difference means the
two paths do not run the same step.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from test_performance import short_lemniscate, short_perturbed  # the benchmark's short runs

from wmr import controllers
from wmr import scenario as scn
from wmr.closedloop import step as loop
from wmr.closedloop.sim import simulate
from wmr.controllers import backstepping
from wmr.linear import nlsys
from wmr.scenario import Estimator

ct = pytest.importorskip("control")


def perturbed_saturated():
    """A disturbance window and tight limits inside the run, every controller on the pose EKF."""
    return dataclasses.replace(short_perturbed(), estimator=Estimator(pose_source="filtered"))


SCENARIOS = {"lemniscate": short_lemniscate, "perturbed-saturated-filtered": perturbed_saturated}


#: Every compiled registry row, the diagnostic (oracle) arms included: the oracle's true pose is
#: written by the loop's one step, which the nlsys calls too.
COMPILED = [n for n, c in controllers.REGISTRY.items() if c.compiled]


@pytest.mark.parametrize("scenario", list(SCENARIOS))
@pytest.mark.parametrize("controller", COMPILED)
def test_trajectory_equals_simulate(controller, scenario):
    sc = SCENARIOS[scenario]()
    cl = nlsys.closed_loop(sc, controller, 3)
    resp = cl.response()
    run = simulate(sc, controller, 3, keep_trajectory=True)
    assert not run.diverged
    assert_array_equal(resp.outputs.T, run.q)
    q, q_hat, Pq, s, theta, P = cl.layout.split(resp.states[:, -1].copy())
    assert_array_equal(q, run.q[-1])
    assert_array_equal(q_hat, run.pose_estimate)
    if run.pose_covariance is not None:
        assert_array_equal(Pq, run.pose_covariance)
    assert_array_equal(theta, getattr(run.final, "theta", np.zeros(0)))
    assert_array_equal(P, getattr(run.final, "P", np.zeros((0, 0))))
    # the logged controller entries after each step's law: the s part of x_1 .. x_N
    s_rows = cl.layout.split(np.arange(cl.layout.n_states))[3]  # where s sits in x
    logged = resp.states[s_rows[: run.state.shape[1]], 1:]
    assert_array_equal(logged.T, run.state)
    if scenario.startswith("perturbed"):  # the case exercises the limits
        assert np.any(np.abs(run.u) == [0.6, 1.5])


def test_runs_longer_than_a_chunk():
    """The inputs are the kernel's chunks joined: the same trajectory across a chunk seam."""
    sc = dataclasses.replace(scn.load(scn.builtin("lemniscate")), duration=(loop.CHUNK + 50) * 0.01)
    cl = nlsys.closed_loop(sc, "backstepping", 1)
    assert cl.U.shape == (8, sc.n_steps + 1)
    assert_array_equal(cl.response().outputs.T, simulate(sc, "backstepping", 1).q)


def test_non_finite_command_makes_the_state_nan():
    """Where the kernel stops a run (non-finite command) the nlsys's next state is NaN."""
    sc = short_lemniscate()
    wild = backstepping.Settings(gains=(1e308, 1e308, 1e308))
    run = simulate(sc, "backstepping", 0, settings=wild)
    assert run.diverged and run.cause == "non-finite value"
    k = round(run.diverged_at / sc.dt)
    states = nlsys.closed_loop(sc, "backstepping", 0, settings=wild).response().states
    assert_array_equal(states[:3, : k + 1].T, run.q)
    assert np.all(np.isnan(states[:, k + 1 :]))


def test_system_and_layout():
    sc = short_lemniscate()
    cl = nlsys.closed_loop(sc, "iapid-nn-dekf", 0)
    lay, sys = cl.layout, cl.system
    n = sc.settings("iapid-nn-dekf").hidden * 4 + 10 + 3 * 10 + 3  # wmr.estimation.nn, N_IN = 4
    assert lay.n_theta == n and lay.n_states == 15 + lay.n_s + n + n * n
    assert (sys.nstates, sys.ninputs, sys.noutputs) == (lay.n_states, 8, 3)
    assert sys.isdtime(strict=True) and sys.dt == sc.dt
    assert sys.state_labels[:3] == ["q[0]", "q[1]", "q[2]"]
    assert sys.state_labels[-1] == f"P[{n * n - 1}]"
    assert sys.input_labels == list(nlsys.INPUTS) and sys.output_labels == list(nlsys.OUTPUTS)
    parts = lay.split(cl.X0.copy())
    assert_array_equal(lay.pack(*parts), cl.X0)
    assert parts[5].shape == (n, n) and np.shares_memory(lay.split(cl.X0)[5], cl.X0)


def test_update_leaves_its_input_state_alone():
    """python-control stores the state it hands to the update: the update must copy it."""
    cl = nlsys.closed_loop(short_lemniscate(), "adaptive-pid", 0)
    x0 = cl.X0.copy()
    x1 = cl.system.dynamics(0.0, cl.X0, cl.U[:, 0])
    x2 = cl.system.dynamics(0.01, x1, cl.U[:, 1])
    assert_array_equal(cl.X0, x0)
    assert not np.array_equal(x1, x2)
