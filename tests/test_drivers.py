"""The step is written once and driven twice: the compiled kernel and the Python driver.

The oracle for the Python driver is the compiled kernel (and the other way round): both run
``wmr.closedloop.step._advance_template`` on the same noise and reference, so every record must be
equal bit for bit (``assert_array_equal``, no tolerance) -- for every compiled registry row, with
probes, with the built-in plant wrapped as a Python-level plant (``wmr.robots.pyplant.TablePlant``),
and with a Python-level controller that wraps a compiled law. Any difference means the two drivers
do not run the same step.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from test_performance import short_lemniscate, short_perturbed  # the benchmark's short runs

from wmr import controllers
from wmr.closedloop import step as loop
from wmr.closedloop.sim import simulate
from wmr.controllers import PyController, backstepping
from wmr.robots import pyplant
from wmr.scenario import Estimator, Plant, PlantChange

COMPILED = [n for n, c in controllers.REGISTRY.items() if c.compiled]


def _filtered_perturbed():
    return dataclasses.replace(short_perturbed(), estimator=Estimator(pose_source="filtered"))


def _true_robot():
    """Every plant effect of the parameter table at once, with a mid-run change."""
    sc = short_lemniscate()
    spec = Plant(v_gain=0.9, w_gain=1.1, v_from_w=0.01, w_from_v=0.02, actuator_tau=0.05,
                 delay_steps=2, changes=(PlantChange(at=0.5, values={"v_gain": 0.7}),))
    return dataclasses.replace(sc, plant=spec)


def _rk4_filtered():
    """The RK4 step with the pose filter: its Jacobians allocate inside the loop, so a buffer of
    the kernel freed while still in use (a borrowed view outliving its owner, wmr._borrow) would
    be overwritten mid-run (it was: the compiled pose estimate drifted 1e-4 from the Python
    driver's at step 1)."""
    return dataclasses.replace(_filtered_perturbed(), integrator="rk4")


SCENARIOS = {"lemniscate": short_lemniscate, "perturbed-filtered": _filtered_perturbed,
             "true-robot": _true_robot, "rk4-filtered": _rk4_filtered}


def assert_same_run(a, b):
    """Two records of the same run, equal to the last bit (trajectories, signals, metrics)."""
    assert (a.diverged, a.diverged_at, a.cause) == (b.diverged, b.diverged_at, b.cause)
    assert a.rmse == b.rmse and a.rmse_after_transient == b.rmse_after_transient
    assert a.effort == b.effort
    for name in ("q", "ref", "q_hat", "u", "state", "pose_estimate"):
        assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    if a.plant_velocity is not None and b.plant_velocity is not None:
        assert_array_equal(a.plant_velocity, b.plant_velocity)


class _AllHooks:
    """A probe with every hook (it only counts: the hooks must not change the run)."""

    def __init__(self):
        self.n = [0, 0, 0]

    def after_estimate(self, k, q, q_hat, Pq, nis):
        self.n[0] += 1

    def before_law(self, k, p, s, theta, P, q_hat):
        self.n[1] += 1

    def after_law(self, k, p, s, theta, P, q_hat, u):
        self.n[2] += 1


@pytest.mark.parametrize("scenario", list(SCENARIOS))
@pytest.mark.parametrize("controller", COMPILED)
def test_both_drivers_and_the_probed_run_give_the_same_record(controller, scenario):
    sc = SCENARIOS[scenario]()
    compiled = simulate(sc, controller, 2, driver="compiled")
    assert_same_run(compiled, simulate(sc, controller, 2, driver="python"))
    # a probe with every hook, and a Python-level plant that wraps the built-in step, in one
    # run (each alone is the Python driver above with one part changed): the same numbers
    probe = _AllHooks()
    assert_same_run(compiled, simulate(sc, controller, 2, probe=probe, robot=pyplant.TablePlant))
    assert probe.n == [sc.n_steps] * 3


def test_the_table_plant_is_driven_through_the_python_driver():
    """``robot=`` really replaces the plant (a plant that never moves gives another run)."""

    class Frozen(pyplant.TablePlant):
        def advance(self, k, a):
            pass

    sc = _true_robot()
    run = loop.prepare(sc, "backstepping", 0, robot=pyplant.TablePlant)
    assert run.plant_kind == loop.PLANT_PYTHON and isinstance(run.pyplant, pyplant.PyPlant)
    frozen = simulate(sc, "backstepping", 0, robot=Frozen)
    assert np.all(frozen.q == frozen.q[0])  # the robot stayed where it was put
    assert not np.array_equal(frozen.q, simulate(sc, "backstepping", 0).q)


class _Wrapped:
    """A Python-level controller that calls backstepping's compiled law (same packed inputs)."""

    def __init__(self, settings, scenario, rng):
        self.p, self.s, self.theta, self.P = backstepping.pack(settings, scenario, rng)
        self.u = np.zeros(2)

    def step(self, q_hat, ref, dt):
        backstepping.law(self.p, self.s, self.theta, self.P, q_hat, ref, dt, self.u)
        return self.u[0], self.u[1]


@pytest.fixture
def wrapped(monkeypatch):
    row = PyController("bsc-python", _Wrapped, backstepping.Settings, label="BSC (Python)")
    monkeypatch.setitem(controllers.REGISTRY, row.name, row)
    return row.name


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_a_python_controller_wrapping_a_compiled_law_equals_the_kernel(wrapped, scenario):
    sc = SCENARIOS[scenario]()
    a = simulate(sc, "backstepping", 4)
    b = simulate(sc, wrapped, 4)
    assert b.state.shape == (sc.n_steps, 0)
    for name in ("q", "ref", "q_hat", "u"):
        assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.rmse == b.rmse


def test_a_python_controller_cannot_run_in_the_compiled_driver(wrapped):
    with pytest.raises(ValueError, match="driver='python'"):
        simulate(short_lemniscate(), wrapped, 0, driver="compiled")
    with pytest.raises(ValueError, match="driver must be"):
        simulate(short_lemniscate(), "backstepping", 0, driver="numba")


class _Stopping:
    """Stops the run at its 7th step, with a stated cause; logs its step count."""

    def __init__(self, settings, scenario, rng):
        self.k = 0

    def step(self, q_hat, ref, dt):
        if self.k == 7:
            raise controllers.ControllerStopped("solver failed 3 times in a row")
        self.k += 1
        return 0.1, 0.0

    def signals(self):
        return (float(self.k),)


def test_controller_stopped_is_a_stated_cause_not_a_crash(monkeypatch):
    row = PyController("stopper", _Stopping, backstepping.Settings, state_names=("k",))
    monkeypatch.setitem(controllers.REGISTRY, row.name, row)
    sc = short_lemniscate()
    r = simulate(sc, "stopper", 0)
    assert r.diverged and r.cause == "controller stopped: solver failed 3 times in a row"
    assert r.diverged_at == pytest.approx(7 * sc.dt)
    assert_array_equal(r.signal("k"), np.arange(1, 8, dtype=float))  # logged after each step
    assert r.final.k == 7.0  # the last signals, as a dataclass (no final() on the object)
    # the same controller without the stop runs to the end
    assert not simulate(sc, "backstepping", 0).diverged


def test_a_python_controller_sees_copies_of_the_loop_state(monkeypatch):
    """Writing into ``q_hat`` or ``ref`` cannot corrupt the loop: the driver hands in copies."""

    class Vandal(_Wrapped):
        def step(self, q_hat, ref, dt):
            out = super().step(q_hat, ref, dt)
            q_hat[:] = 1e9
            ref[:] = -1e9
            return out

    row = PyController("vandal", Vandal, backstepping.Settings)
    monkeypatch.setitem(controllers.REGISTRY, row.name, row)
    sc = short_lemniscate()
    assert_array_equal(simulate(sc, "vandal", 1).q, simulate(sc, "backstepping", 1).q)


def test_kernels_of_laws_outside_wmr_carry_their_source_digest(tmp_path):
    """A law defined in a file outside the package gets a kernel named by its source's digest
    (numba's disk cache is keyed by the name): another source, another kernel."""
    assert loop.law_digest(backstepping.law) == ""
    f = tmp_path / "law_a.py"
    f.write_text("import wmr\n@wmr.njit\ndef law(p, s, theta, P, q_hat, ref, dt, u):\n"
                 "    u[0] = 0.1\n    u[1] = 0.0\n")
    ns: dict = {}
    exec(compile(f.read_text(), str(f), "exec"), ns)
    d1 = loop.law_digest(ns["law"])
    f.write_text(f.read_text().replace("0.1", "0.2"))
    d2 = loop.law_digest(ns["law"])  # the digest reads the file as it is now
    assert len(d1) == 12 and d1 != d2
    assert loop._kernel_name("x", ns["law"], loop.PLANT_IDEAL, False).endswith(d2)
