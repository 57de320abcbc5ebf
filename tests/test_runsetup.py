"""The run's set-up (``wmr.closedloop.runsetup``): what the runs of a scenario share is built once
and gives the numbers a fresh build gives, and the shared parts are never written by a run.

Oracles: numpy's own ``SeedSequence.spawn`` for the streams; a run with an emptied store (every
shared part rebuilt) for the shared set-up; the tables' bytes before and after runs.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from wmr import controllers
from wmr import scenario as scn
from wmr.closedloop import runsetup
from wmr.closedloop import step as loop
from wmr.closedloop.sim import simulate


@pytest.mark.parametrize("seed", [0, 7, 2**40, [3, 1, 4]])
def test_seed_sequences_are_the_spawned_children(seed):
    for a, b in zip(runsetup.seed_sequences(seed), np.random.SeedSequence(seed).spawn(2),
                    strict=True):  # fmt: skip
        assert_array_equal(np.random.default_rng(a).standard_normal(50),
                           np.random.default_rng(b).standard_normal(50))  # fmt: skip


#: Logged state channels that are wall-clock measurements (not deterministic by nature).
TIMED = ("solve_time",)


@pytest.mark.parametrize("controller", list(controllers.REGISTRY))
def test_shared_set_up_gives_the_numbers_of_a_fresh_one(controller):
    """A run on set-up shared with earlier runs (other seeds, other controllers, a longer run of
    the same reference) equals the run on set-up built afresh, bit for bit; and the shared
    tables (reference, filter matrices, plant table) are not written by the runs."""
    sc = dataclasses.replace(scn.load(scn.builtin("sinusoid-perturbed")), duration=3.0)
    runsetup.SHARED.clear()
    fresh = simulate(sc, controller, 5)
    long = dataclasses.replace(sc, duration=6.0)  # the table grows; the short run reads a prefix
    for name in controllers.NAMES:
        simulate(long, name, 1, keep_trajectory=False)
    run = loop.prepare(sc, controller, 5)
    shared = [run.reference, run.Qp, run.Rp, run.plant_table, run.disturbance]
    before = [a.copy() for a in shared]
    again = simulate(sc, controller, 5)
    for name in ("q", "q_hat", "u", "ref"):
        assert_array_equal(getattr(again, name), getattr(fresh, name), err_msg=name)
    # the logged state, but for a wall-clock measurement (nmpc's solve_time: a time, not a number
    # of the run)
    keep = [i for i, n in enumerate(fresh.state_names) if n not in TIMED]
    assert_array_equal(again.state[:, keep], fresh.state[:, keep], err_msg="state")
    assert again.rmse == fresh.rmse
    for a, b in zip(shared, before, strict=True):
        assert_array_equal(a, b)


def test_a_scenario_copy_shares_its_unchanged_parts():
    """``dataclasses.replace`` keeps the parts it does not change: the copy reads the same
    reference table (shared, not rebuilt); a changed reference gets its own."""
    sc = scn.load(scn.builtin("lemniscate"))
    copy = dataclasses.replace(sc, seed=3)
    assert runsetup.reference_table(copy) is runsetup.reference_table(sc)
    other = dataclasses.replace(sc, reference=scn.ReferenceSpec("circle", {"radius": 1.0,
                                                                           "period": 20.0}))
    assert not np.array_equal(runsetup.reference_table(other), runsetup.reference_table(sc))


class _Wrapped:
    """A Python-level controller: backstepping's law; with ``nested`` it also simulates a short
    run of its own at every step (as a controller with a model rollout inside would)."""

    nested = False

    def __init__(self, settings, scenario, rng):
        from wmr.controllers import backstepping

        self.law = backstepping.law
        self.p, self.s, self.theta, self.P = backstepping.pack(settings, scenario, rng)
        self.short = dataclasses.replace(scenario, duration=10 * scenario.dt)
        self.u = np.zeros(2)

    def step(self, q_hat, ref, dt):
        if self.nested:
            simulate(self.short, "backstepping", 9, keep_trajectory=False)
        self.law(self.p, self.s, self.theta, self.P, q_hat, ref, dt, self.u)
        return self.u[0], self.u[1]


class _Nested(_Wrapped):
    nested = True


def test_a_run_inside_a_python_controller_leaves_the_outer_run_alone(monkeypatch):
    """The thread's noise buffer serves the compiled kernel only: a run started from inside a
    Python-level controller's step (the Python driver) must not overwrite the outer run's noise."""
    from wmr.controllers import PyController, backstepping

    sc = dataclasses.replace(scn.load(scn.builtin("lemniscate")), duration=0.5)
    for name, cls in (("bsc-py", _Wrapped), ("bsc-py-nested", _Nested)):
        monkeypatch.setitem(controllers.REGISTRY, name,
                            PyController(name, cls, backstepping.Settings))  # fmt: skip
    plain = simulate(sc, "bsc-py", 4)
    nested = simulate(sc, "bsc-py-nested", 4)
    assert_array_equal(nested.q, plain.q)
    assert_array_equal(plain.q, simulate(sc, "backstepping", 4).q)


@pytest.mark.parametrize("seed", [0, 11])
def test_compiled_noise_draws_are_numpys(seed):
    """``draw_noise`` (numba's ``Generator.standard_normal``) gives numpy's draws times the
    deviations, bit for bit, over enough draws to pass through the ziggurat's tail many times
    (P(|z| > 3.65) ~ 3e-4 per draw), and leaves the generator in numpy's state."""
    std = np.array([0.01, 0.02, 0.005])
    a = np.random.default_rng(seed)
    b = np.random.default_rng(seed)
    out = np.empty((100_000, 3))
    for _ in range(3):  # the stream continues across calls, as across a run's chunks
        runsetup.draw_noise(a, std, out)
        assert_array_equal(out, b.standard_normal(out.shape) * std)
    assert a.bit_generator.state == b.bit_generator.state


def test_a_long_run_draws_its_noise_as_a_short_one():
    """A run whose chunks are drawn by the compiled ``draw_noise`` (``>= JIT_NOISE_ROWS`` steps)
    sees the noise numpy would draw: its first steps equal a run short enough for numpy's draw
    (same seed, same measured poses)."""
    sc = scn.load(scn.builtin("lemniscate"))
    n_short = runsetup.JIT_NOISE_ROWS // 2
    assert sc.n_steps >= runsetup.JIT_NOISE_ROWS
    long = simulate(sc, "backstepping", seed=3)
    short = simulate(dataclasses.replace(sc, duration=n_short * sc.dt), "backstepping", seed=3)
    assert_array_equal(long.z[:n_short], short.z)
    assert_array_equal(long.q[: n_short + 1], short.q)


#: Seeds of one and two 32-bit words, the edges of each, and numpy integers.
FAST_SEEDS = [0, 1, 5, 2**31, 2**32 - 1, 2**32, 2**40 + 7, 2**63, 2**64 - 1, np.int64(12)]


def test_compiled_spawned_states_are_numpys():
    """``seeding.spawned_states`` gives ``SeedSequence(seed, spawn_key=(i,)).generate_state(4,
    uint64)`` for i = 0, 1, over the edge seeds and 300 random ones of up to 64 bits."""
    from wmr.closedloop import seeding

    rng = np.random.default_rng(2)
    seeds = [int(s) for s in FAST_SEEDS] + [int(x) for x in rng.integers(0, 2**63, 200)]
    seeds += [int(x) for x in rng.integers(0, 2**32, 100)]
    words = np.empty((2, 8), dtype=np.int64)
    for seed in seeds:
        seeding.spawned_states(seed & 0xFFFFFFFF, seed >> 32, words)
        got = words.astype("<u4").view("<u8").astype(np.uint64)
        for i in range(2):
            want = np.random.SeedSequence(seed, spawn_key=(i,)).generate_state(4, np.uint64)
            assert_array_equal(got[i], want, err_msg=f"seed {seed}, key {i}")


@pytest.mark.parametrize("seed", [*FAST_SEEDS, 2**64, 2**70 + 1, [3, 1, 4],
                                  np.random.SeedSequence(9)])  # fmt: skip
def test_a_runs_generators_are_numpys_children(seed):
    """``seeding.generators`` (the compiled path for seeds in [0, 2**64), numpy's otherwise)
    gives the generators ``default_rng`` makes of the seed's two spawned children: same state,
    same draws; without ``draws`` the noise stream alone."""
    from wmr.closedloop import seeding

    children = (seed.spawn(2) if isinstance(seed, np.random.SeedSequence)
                else np.random.SeedSequence(seed).spawn(2))  # fmt: skip
    if isinstance(seed, np.random.SeedSequence):  # spawning advances the parent: a fresh one
        seed = np.random.SeedSequence(9)
    noise, init = seeding.generators(seed)
    for got, child in zip((noise, init), children, strict=True):
        want = np.random.default_rng(child)
        assert got.bit_generator.state == want.bit_generator.state
        assert_array_equal(got.standard_normal(20), want.standard_normal(20))
    if not isinstance(seed, np.random.SeedSequence):
        alone, none = seeding.generators(seed, draws=False)
        assert none is None
        assert alone.bit_generator.state == np.random.default_rng(children[0]).bit_generator.state
