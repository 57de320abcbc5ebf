"""Tests of wmr.closedloop.probes: probed runs are the kernel's, the identifier's pair is the law's,
and the probes' readings against independent computations."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose

from wmr import scenario as scn
from wmr.closedloop import step as loop
from wmr.closedloop.probes import (
    PoseProbe,
    WeightProbe,
    identical_runs,
    identifier_pair,
    target_noise,
)
from wmr.closedloop.sim import simulate
from wmr.estimation import ekf, nn
from wmr.estimation import stability as stab
from wmr.scenario import Disturbance

#: The probe's innovation and the law's are the same jitted forward pass; the norm is summed in
#: a different order.
INNOVATION_RTOL = 1e-12
#: Round-off of a handful of float operations.
EXACT_RTOL = 1e-14
#: The direct generalised eigenvalue (Cholesky of the stored P) against the cancellation-free one:
#: absolute error ~eps times a condition number on 1 - lambda.
DIRECT_ATOL = 1e-13


def _short(name, duration=2.0, **changes):
    sc = scn.load(scn.builtin(name))
    return dataclasses.replace(sc, duration=duration, **changes)


class _Trace:
    """Every hook, recording what it saw (copies)."""

    def __init__(self):
        self.estimates, self.before, self.after = [], [], []

    def after_estimate(self, k, q, q_hat, Pq, nis):
        self.estimates.append((k, q.copy(), q_hat.copy()))

    def before_law(self, k, p, s, theta, P, q_hat):
        self.before.append(k)

    def after_law(self, k, p, s, theta, P, q_hat, u):
        self.after.append((k, q_hat.copy(), u.copy()))


@pytest.mark.parametrize(
    "name, controller, changes",
    [
        ("lemniscate", "iapid-nn-dekf", {}),
        ("sinusoid", "adaptive-pid", {}),
        ("lemniscate", "backstepping", {}),
        ("sinusoid-perturbed", "iapid-nn-dekf",
         {"disturbances": (Disturbance(0.5, 1.0, (0.1, 0.3)),)}),
    ],
    ids=["iapid-lemniscate", "apid-sinusoid", "bsc-lemniscate", "iapid-disturbed"],
)  # fmt: skip
def test_probed_run_equals_kernel_bit_for_bit(name, controller, changes):
    sc = _short(name, **changes)
    trace = _Trace()
    probed = simulate(sc, controller, 3, probe=trace)
    kernel = simulate(sc, controller, 3)
    assert not probed.diverged and len(probed.u) == sc.n_steps
    assert identical_runs(probed, kernel)
    n = sc.n_steps
    assert [k for k, *_ in trace.estimates] == trace.before == [k for k, *_ in trace.after]
    assert trace.before == list(range(n))
    assert np.array_equal(np.array([q for _, q, _ in trace.estimates]), kernel.q[:n])
    assert np.array_equal(np.array([u for *_, u in trace.after]), kernel.u)
    assert np.array_equal(np.array([q for _, q, _ in trace.after]), kernel.q_hat)


def test_probed_run_equals_kernel_when_it_diverges():
    # A bound below the initial position error: the run stops at its first step, both ways.
    sc = _short("lemniscate", duration=0.5, divergence_bound=0.05)
    probed = simulate(sc, "iapid-nn-dekf", 0, probe=_Trace())
    kernel = simulate(sc, "iapid-nn-dekf", 0)
    assert probed.diverged and np.isnan(probed.rmse["position"])
    assert identical_runs(probed, kernel)


def test_identical_runs_sees_a_different_seed():
    sc = _short("lemniscate", duration=0.5)
    assert not identical_runs(simulate(sc, "iapid-nn-dekf", 0), simulate(sc, "iapid-nn-dekf", 1))


def test_identifier_pair_by_hand_across_the_heading_seam():
    # Heading from pi - 0.01 to -pi + 0.01: the wrapped difference is +0.02, not -2 pi + 0.02.
    dt = 0.01
    x, d = identifier_pair(np.array([0.5, -0.2]), np.array([1.0, 2.0, math.pi - 0.01]),
                           np.array([1.003, 1.999, -math.pi + 0.01]), dt)  # fmt: skip
    assert_allclose(x, [0.5, -0.2, math.cos(math.pi - 0.01), math.sin(math.pi - 0.01)],
                    rtol=EXACT_RTOL)  # fmt: skip
    assert_allclose(d, [0.3, -0.1, 2.0], rtol=1e-9)  # 1e-9: (1.003 - 1.0) / dt loses digits


def test_target_noise_is_the_identifier_pairs_target_minus_the_true_increment():
    """Oracle: identifier_pair (the law's own target) minus the true increment, step by step,
    across the heading seam; the first M rows of q are used (a run's q has one row more)."""
    dt, rng = 0.01, np.random.default_rng(5)
    q = np.cumsum(rng.normal(0, 0.01, (8, 3)), axis=0)
    q[:, 2] += math.pi - 0.02  # the heading crosses +-pi
    q_hat = q[:7] + rng.normal(0, 0.003, (7, 3))
    q_hat[:, 2] = np.arctan2(np.sin(q_hat[:, 2]), np.cos(q_hat[:, 2]))
    noise, signal = target_noise(q, q_hat, dt)
    assert noise.shape == signal.shape == (6, 3)
    for i in range(6):
        _, d = identifier_pair(np.zeros(2), q_hat[i], q_hat[i + 1], dt)
        _, true = identifier_pair(np.zeros(2), q[i], q[i + 1], dt)
        assert_allclose(noise[i], d - true, rtol=0, atol=1e-12)  # ~1e-3 m / 1e-2 s, rounding
        assert_allclose(signal[i], true, rtol=0, atol=1e-12)


class _Innovation:
    """The identifier's innovation before each law call, from identifier_pair alone."""

    def __init__(self, dt):
        self.dt, self.previous, self.norms = dt, None, {}

    def before_law(self, k, p, s, theta, P, q_hat):
        if self.previous is not None:
            x, d = identifier_pair(*self.previous, q_hat, self.dt)
            z, _ = nn.forward(theta, x, p.nn_n_h, 3)
            self.norms[k] = float(np.linalg.norm(d - z))

    def after_law(self, k, p, s, theta, P, q_hat, u):
        self.previous = (u.copy(), q_hat.copy())


def test_identifier_pair_gives_the_laws_innovation():
    # Oracle: the law logs the norm of its own innovation (signal "nn_error") at every step.
    sc = _short("sinusoid-perturbed", disturbances=(Disturbance(0.5, 1.0, (0.1, 0.3)),))
    probe = _Innovation(sc.dt)
    res = simulate(sc, "iapid-nn-dekf", 2, probe=probe)
    law = res.signal("nn_error")
    assert sorted(probe.norms) == list(range(1, sc.n_steps)) and law[0] == 0.0
    assert_allclose([probe.norms[k] for k in range(1, sc.n_steps)], law[1:],
                    rtol=INNOVATION_RTOL)  # fmt: skip


class _SnapshotProbe(WeightProbe):
    """The weight probe, keeping the filter's input (weights, covariance) and H at step k_keep."""

    def __init__(self, *args, k_keep: int, **kwargs):
        super().__init__(*args, **kwargs)
        self.k_keep = k_keep

    def before_law(self, k, p, s, theta, P, q_hat):
        super().before_law(k, p, s, theta, P, q_hat)
        if k == self.k_keep:
            self.kept = {"theta": theta.copy(), "P": P.copy(), "nu": self._nu.copy()}

    def after_law(self, k, p, s, theta, P, q_hat, u):
        super().after_law(k, p, s, theta, P, q_hat, u)
        if k == self.k_keep:
            self.kept.update(H=p.H.copy(), theta_after=theta.copy(), P_after=P.copy())


def test_weight_probe_readings():
    sc = _short("lemniscate", duration=0.3)
    st = sc.settings("iapid-nn-dekf")
    prep = loop.prepare(sc, "iapid-nn-dekf", 0)
    n = prep.theta.size
    probe = _SnapshotProbe(sc.n_steps, n, sc.dt, every=1, k_keep=7)
    res = simulate(sc, "iapid-nn-dekf", 0, probe=probe)
    a = probe.a
    assert np.isnan(a["norm_H"][0]) and np.isnan(a["alpha_k"][0])  # no update at k = 0
    upd = slice(1, None)
    for key in ("norm_H", "alpha_k", "direct_gap", "nis", "mu", "pred_error", "lmin_prior"):
        assert np.all(np.isfinite(a[key][upd])), key
    assert np.all(a["spd"][upd] == 1.0)
    assert_allclose(a["direct_gap"][upd], a["alpha_k"][upd], rtol=0, atol=DIRECT_ATOL)
    assert np.all(a["lmin_prior"][upd] >= st.q)  # P + Q >= Q
    assert np.array_equal(probe.theta[-1], res.final.theta)
    assert_allclose(a["trace"][-1], np.trace(res.final.P), rtol=EXACT_RTOL)
    alpha = stab.lemma2_alpha(1.0, np.nanmax(a["norm_H"]), np.nanmax(a["lmax_prior"]), st.q, st.r)
    assert np.all(a["alpha_k"][upd] >= alpha)  # (48) along the run (Lemma 2)
    # Oracles at step 7: the dense EKF step from the kept input gives the law's weights and
    # covariance (so the probe's innovation and H are the law's), and the fused filter's own
    # NIS is the probe's.
    kept = probe.kept
    theta_ref, P_ref = ekf.weight_update_reference(kept["theta"], kept["P"], kept["H"],
                                                   kept["nu"], prep.p.q_diag, prep.p.R)  # fmt: skip
    assert_allclose(theta_ref, kept["theta_after"], rtol=1e-9, atol=1e-12)
    assert_allclose(P_ref, kept["P_after"], rtol=1e-9, atol=1e-9)
    nis = ekf.weight_update(kept["theta"].copy(), kept["P"].copy(), kept["H"], kept["nu"],
                            prep.p.q_diag, prep.p.R, np.zeros((3, 3, n)))  # fmt: skip
    assert_allclose(a["nis"][7], nis, rtol=1e-9)


def test_pose_probe_on_the_raw_measurement_is_chi2_of_the_noise():
    # A controller acting on the raw measurement: q_hat = z and the pose filter is never run, so
    # P = Rp = diag(std^2) and NEES_k = sum_j (n_kj / std_j)^2 = the squared standard normals
    # the noise stream drew (seed_sequences' first stream, one chunk).
    sc = _short("sinusoid", duration=1.0)
    assert not sc.estimator.filters("adaptive-pid")
    probe = PoseProbe(sc.n_steps)
    simulate(sc, "adaptive-pid", 5, probe=probe, keep_trajectory=False)
    g = np.random.default_rng(loop.seed_sequences(5)[0]).standard_normal((sc.n_steps, 3))
    assert_allclose(probe.nees, np.sum(g**2, axis=1), rtol=1e-9)  # (q + n) - q loses digits
    assert np.all(np.isnan(probe.nis)) and probe.spd_failures == 0


def test_pose_probe_with_the_filter():
    sc = _short("lemniscate", duration=1.0)
    probe = PoseProbe(sc.n_steps)
    simulate(sc, "iapid-nn-dekf", 0, probe=probe, keep_trajectory=False)
    assert np.isnan(probe.nis[0]) and np.all(np.isfinite(probe.nis[1:]))
    assert np.all(probe.nees >= 0) and probe.spd_failures == 0
