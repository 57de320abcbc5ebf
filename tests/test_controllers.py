"""Tests of the paper's controllers: PID (eq. 7), SGD adaptation (eqs. 8-17), IAPID-NN-DEKF, DA-NN.

Oracles: the hand-derived collapsed SGD update of reproduction-notes §4.3, finite differences,
properties that must hold along every default run (covariances SPD, no repairs, no divergence).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from wmr import controllers
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.controllers import pid
from wmr.controllers.pid import S_K, S_PHI, S_Q, S_STARTED, S_U
from wmr.model.kinematics import EULER, EXACT, input_matrix, rotation, step_jacobians

EXACT_TOL = 1e-14  # same arithmetic up to reassociation of a handful of terms


@pytest.fixture(scope="module")
def paper():
    return {name: scn.load(scn.builtin(name)) for name in scn.PAPER_SCENARIOS}


def _euler_scenario(sc):
    return dataclasses.replace(sc, integrator="euler")


@pytest.mark.parametrize("gradient", pid.GRADIENTS)
def test_sgd_step_equals_collapsed_form_with_analytic_jacobian(gradient):
    """With J = dt G(theta) and the corrected rotation at the same theta,
    T_e J = dt [[1,0],[0,0],[0,1]] and J[2, :] = (0, dt), so (notes §4.3, errata E5)
    dK_v = mu dt a1 e1 phi_v and dK_w = mu dt (a3 e3 - h) phi_w with h = (a1 - a2) e1 e2 for the
    exact gradient, h = 0 for the approximate one: only then do e2 and alpha2 drop out."""
    rng = np.random.default_rng(0)
    settings = pid.Settings(mu=(0.9, 0.5, 0.3, 0.7, 0.2, 0.1), alpha=(1.3, 7.0, 0.6),
                            gains=(5.0, 5.0, 0.5, 10.0, 2.0, 0.5), gradient=gradient)  # fmt: skip
    sc = _euler_scenario(scn.load(scn.builtin("lemniscate")))
    p, s, _, _ = pid.pack(settings, sc, rng)
    dt = 0.01
    for _ in range(20):
        theta = rng.uniform(-np.pi, np.pi)
        e = rng.normal(size=3)
        phi = rng.normal(size=6)
        s[S_K : S_K + 6] = settings.gains
        s[S_PHI : S_PHI + 6] = phi
        J = dt * input_matrix(theta)
        # the corrected heading term depends on e only: any pose and reference will do
        pid.adapt_gains(p, s, J, e, np.array([0.0, 0.0, theta]), np.zeros(5), dt)
        mu, a = np.array(settings.mu), settings.alpha
        h = (a[0] - a[1]) * e[0] * e[1] if gradient == "exact" else 0.0
        expected = np.array(settings.gains) + np.concatenate(
            (mu[:3] * dt * a[0] * e[0] * phi[:3], mu[3:] * dt * (a[2] * e[2] - h) * phi[3:])
        )
        expected = np.clip(expected, settings.gain_min, settings.gain_max)
        np.testing.assert_allclose(s[S_K : S_K + 6], expected, rtol=EXACT_TOL, atol=EXACT_TOL)


def test_sgd_with_printed_rotation_picks_up_the_spurious_sin2theta_term():
    """Printed T_e gives T_e G second row [sin 2theta, 0]: e2 then feeds the v-gains (errata E3).
    (The heading term ``h`` moves the w-gains only, ``J[2, :] = (0, dt)``: the paper's h = 0.)"""
    settings = pid.Settings(printed_rotation=True, alpha=(0.0, 1.0, 0.0))
    sc = scn.load(scn.builtin("lemniscate"))
    p, s, _, _ = pid.pack(settings, sc, np.random.default_rng(0))
    theta, dt = 0.3, 0.01
    s[S_PHI : S_PHI + 6] = 1.0
    e = np.array([0.0, 0.2, 0.0])
    pid.sgd_gain_step(p, s, dt * input_matrix(theta), e, theta, 0.0)
    dKv = s[S_K] - settings.gains[0]
    assert dKv == pytest.approx(0.9 * dt * math.sin(2 * theta) * 0.2, rel=1e-12)
    T = rotation(theta, True)
    assert (T @ input_matrix(theta))[1, 0] == pytest.approx(math.sin(2 * theta), rel=1e-14)


def test_adaptive_pid_law_uses_the_previous_step_jacobian_and_regressor(paper):
    """Causal indices (E5b): one law call equals the SGD step with J at (q_{k-1}, u_{k-1}) and
    the regressor of step k-1, followed by eq. 7 with the new gains."""
    sc = _euler_scenario(paper["sinusoid"])
    settings = pid.Settings()
    p, s, W, P = pid.pack(settings, sc, np.random.default_rng(0))
    ref = np.array([0.3, 0.1, 0.2, 0.5, 0.1])
    u = np.zeros(2)
    q0 = np.array([0.0, 0.0, 0.1])
    pid.law(p, s, W, P, q0, ref, 0.01, u)
    assert s[S_STARTED] == 1.0 and np.array_equal(s[S_K : S_K + 6], settings.gains)
    phi0, u0 = s[S_PHI : S_PHI + 6].copy(), u.copy()
    q1 = np.array([0.004, 0.0005, 0.1 + 0.01 * u0[1]])
    expected = s.copy()
    e1 = rotation(q1[2]) @ (ref[:3] - q1)
    pid.sgd_gain_step(p, expected, 0.01 * input_matrix(q0[2]), e1, q1[2],
                      pid.heading_term(p, e1, q1, ref))  # fmt: skip
    pid.law(p, s, W, P, q1, ref, 0.01, u)
    np.testing.assert_allclose(s[S_K : S_K + 6], expected[S_K : S_K + 6], rtol=1e-13)
    assert not np.allclose(s[S_PHI : S_PHI + 6], phi0)  # regressor moved on to step k
    np.testing.assert_array_equal(s[S_U : S_U + 2], u)
    np.testing.assert_array_equal(s[S_Q : S_Q + 3], q1)


def test_pid_output_is_eq7_with_discrete_integral_and_derivative(paper):
    """Three steps of the fixed PID against eq. 7 written out by hand."""
    sc = paper["sinusoid"]
    settings = pid.FixedSettings(gains=(2.0, 3.0, 0.5, 4.0, 1.5, 0.25))
    p, s, W, P = pid.pack(settings, sc, np.random.default_rng(0))
    dt = 0.01
    ref = np.array([1.0, 0.5, 0.4, 0.5, 0.2])
    qs = [np.array([0.9, 0.45, 0.3]), np.array([0.91, 0.46, 0.33]), np.array([0.93, 0.47, 0.35])]
    I1 = Is = 0.0
    prev = None
    u = np.zeros(2)
    for q in qs:
        e = rotation(q[2]) @ (ref[:3] - q)
        sig = e[2] + e[1]
        I1 += dt * e[0]
        Is += dt * sig
        d1, ds = (0.0, 0.0) if prev is None else ((e[0] - prev[0]) / dt, (sig - prev[1]) / dt)
        prev = (e[0], sig)
        K = settings.gains
        expected = (K[0] * e[0] + K[1] * I1 + K[2] * d1, K[3] * sig + K[4] * Is + K[5] * ds)
        pid.law(p, s, W, P, q, ref, dt, u)
        np.testing.assert_allclose(u, expected, rtol=1e-12)
    np.testing.assert_array_equal(s[S_K : S_K + 6], settings.gains)  # fixed: never adapted


def test_feed_forward_adds_reference_velocities():
    sc = scn.load(scn.builtin("sinusoid"))
    ref = np.array([1.0, 0.5, 0.4, 0.5, 0.2])
    q = np.array([0.9, 0.45, 0.3])
    u_lit, u_ff = np.zeros(2), np.zeros(2)
    for settings, u in ((pid.FixedSettings(), u_lit), (pid.FixedSettings(feed_forward=True), u_ff)):
        p, s, W, P = pid.pack(settings, sc, np.random.default_rng(0))
        pid.law(p, s, W, P, q, ref, 0.01, u)
    e3 = ref[2] - q[2]
    np.testing.assert_allclose(u_ff - u_lit, (ref[3] * math.cos(e3), ref[4]), rtol=1e-12)


@pytest.mark.parametrize("name", ["iapid-nn-dekf", "adaptive-nn"])
@pytest.mark.parametrize("scenario_name", scn.PAPER_SCENARIOS)
def test_weight_covariance_stays_spd_along_default_runs(paper, name, scenario_name):
    """Along every default run: no covariance repair was ever needed, and the final weight
    covariance is symmetric positive definite."""
    r = simulate(paper[scenario_name], name, seed=0)
    assert not r.diverged
    repairs = r.state[:, r.state_names.index("cov_repairs")]
    assert np.all(repairs == 0)
    P = r.final.P
    np.testing.assert_array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() > 0


def test_iapid_identifier_learns_the_plant_jacobian_direction(paper):
    """The identified Jacobian J = dt dNN/d(v, w) points roughly the way of the true ZOH Jacobian
    (cosine similarity of the 3x2 matrices, averaged over the last half of the run).  Its size is
    biased by the closed-loop noise (analysis/jacobians/ measures it); direction is what SGD needs
    for descent, so that is what is asserted."""
    r = simulate(paper["lemniscate"], "iapid-nn-dekf", seed=0)
    J = r.state[:, 6:12].reshape(-1, 3, 2)
    assert np.all(np.isfinite(J))
    half = len(J) // 2
    true = np.stack([step_jacobians(r.q_hat[k - 1], r.u[k - 1], r.dt, EXACT)[1]
                     for k in range(half, len(J))])  # fmt: skip
    learned = J[half:]
    cos = np.sum(learned * true, axis=(1, 2)) / (
        np.linalg.norm(learned, axis=(1, 2)) * np.linalg.norm(true, axis=(1, 2))
    )
    assert np.mean(cos) > 0.5  # measured ~0.8; a random or sign-flipped J gives ~0 or < 0


def test_dann_starts_as_backstepping(paper):
    """The compensator's output layer starts at zero: the first input equals backstepping's."""
    sc = paper["lemniscate"]
    a = simulate(dataclasses.replace(sc, duration=sc.dt), "adaptive-nn", seed=3)
    b = simulate(dataclasses.replace(sc, duration=sc.dt), "backstepping", seed=3)
    np.testing.assert_array_equal(a.u[0], b.u[0])


def test_printed_nn_jacobian_variant_uses_eqs_22_24(paper):
    """With printed_jacobian the logged J is dt times the printed eqs. 22-24 evaluated at the
    identifier's input and weights (replayed here step by step with the same law)."""
    from wmr.controllers import iapid_nn_dekf as ia
    from wmr.estimation import nn

    sc = paper["sinusoid"]
    st = dataclasses.replace(sc.settings("iapid-nn-dekf"), printed_jacobian=True)
    p, s, W, P = ia.pack(st, sc, np.random.default_rng(0))
    rng = np.random.default_rng(1)
    u = np.zeros(2)
    q = np.zeros(3)
    ref = np.array([0.0, 0.0, 0.0, 0.5, 0.1])
    for _ in range(5):
        q_prev, u_prev = q.copy(), u.copy()
        q = q + 0.005 * rng.normal(size=3)
        started = s[pid.S_STARTED] != 0.0
        ia.law(p, s, W, P, q, ref, 0.01, u)
        if started:
            x = ia.identifier_input(u_prev, q_prev[2])
            expected = 0.01 * nn.input_jacobian_printed(W, x, st.hidden, 3)[:, :2]
            np.testing.assert_allclose(s[6:12].reshape(3, 2), expected, rtol=1e-12, atol=1e-18)


@pytest.mark.parametrize("name", controllers.NAMES)
def test_every_controller_tracks_a_noise_free_circle(name):
    """Zero noise, start on the reference: every controller keeps the position error small."""
    sc = scn.loads(
        'name = "c"\nduration = 20.0\ndt = 0.01\ninitial_pose = [1.0, 0.0, 1.5707963267948966]\n'
        '[reference]\nkind = "circle"\nradius = 1.0\nperiod = 20.0\n'
    )
    r = simulate(sc, name, seed=0)
    assert not r.diverged
    # the literal eq. 7 PID has no feed-forward and needs its integrators to build up the
    # nominal speed: a transient of a few cm; the others track to well under a centimetre
    bound = 0.1 if name in ("pid", "adaptive-pid", "iapid-nn-dekf") else 0.01
    assert r.rmse["position"] < bound


def test_euler_scenario_runs_with_the_euler_jacobian(paper):
    """The SGD Jacobian logged by adaptive-pid is the ZOH Jacobian of the scenario's integrator,
    at the previous pose estimate and input (Euler differs from the exact arc in dx/dw)."""
    sc = dataclasses.replace(_euler_scenario(paper["sinusoid"]), duration=1.0)
    r = simulate(sc, "adaptive-pid", seed=0)
    J_logged = r.state[:, 6:12].reshape(-1, 3, 2)
    for k in (5, 50, 99):
        _, G_euler = step_jacobians(r.q_hat[k - 1], r.u[k - 1], r.dt, EULER)
        _, G_exact = step_jacobians(r.q_hat[k - 1], r.u[k - 1], r.dt, EXACT)
        np.testing.assert_allclose(J_logged[k], G_euler, rtol=1e-12, atol=1e-15)
        assert not np.allclose(J_logged[k], G_exact, rtol=1e-9, atol=0)



def test_a_failed_weight_update_is_counted_not_silent(paper):
    """A measurement covariance that makes S indefinite: the update fails (NaN NIS), changes
    nothing, and is counted (P itself stays healthy, so only the failed update can count)."""
    from wmr.controllers import iapid_nn_dekf

    sc = paper["sinusoid"]
    p, s, W, P = iapid_nn_dekf.pack(iapid_nn_dekf.Settings(), sc, np.random.default_rng(0))
    u = np.zeros(2)
    ref = np.array([0.0, 0.0, 0.0, 0.5, 0.0])
    iapid_nn_dekf.law(p, s, W, P, np.zeros(3), ref, 0.01, u)  # first step: no update yet
    p.R[:, :] = -1e9 * np.eye(3)  # injected fault: an indefinite innovation covariance
    W_before = W.copy()
    iapid_nn_dekf.law(p, s, W, P, np.array([0.005, 0.0, 0.0]), ref, 0.01, u)
    assert s[pid.S_REPAIRS] == 1
    np.testing.assert_array_equal(W, W_before)  # the failed update changed nothing
    assert np.all(np.diag(P) > 0)


@pytest.mark.parametrize("name", ["adaptive-pid", "iapid-nn-dekf", "adaptive-nn"])
def test_adaptive_controllers_remember_the_saturated_input(name, paper):
    """With tight limits the input each controller stores for its next adaptation step (Jacobian,
    identifier, regressor) is the applied, saturated one, and saturation does actually occur."""
    sc = dataclasses.replace(paper["lemniscate"], limits=scn.Limits(0.3, 0.4), duration=5.0)
    r = simulate(sc, name, seed=0)
    assert np.any(np.abs(r.u[:, 0]) == 0.3) or np.any(np.abs(r.u[:, 1]) == 0.4)
    np.testing.assert_array_equal(r.final.previous_input, r.u[-1])


def test_saturated_channel_has_a_zero_regressor(paper):
    sc = dataclasses.replace(paper["sinusoid"], limits=scn.Limits(0.01, 100.0))
    p, s, W, P = pid.pack(pid.Settings(), sc, np.random.default_rng(0))
    u = np.zeros(2)
    pid.law(p, s, W, P, np.array([-1.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0, 0.5, 0.0]), 0.01, u)
    assert u[0] == 0.01
    np.testing.assert_array_equal(s[pid.S_PHI : pid.S_PHI + 3], 0.0)  # v saturated: no gradient
    assert np.any(s[pid.S_PHI + 3 : pid.S_PHI + 6] != 0.0) or u[1] == 0.0


@pytest.mark.parametrize("heading", [0.3, np.pi - 0.01], ids=["plain", "across-the-seam"])
def test_identify_is_one_textbook_ekf_step_then_the_chain_rule_jacobian(paper, heading):
    """``iapid_nn_dekf.identify`` in isolation against an independent numpy oracle: the network
    written out, ``H`` in closed form, the dense Joseph update of ``weight_update_reference``,
    then ``J = dt dNN/d(v, w)`` by central differences at the updated weights.  The second case
    puts the previous and current headings on both sides of +-pi: the target must use the short
    way round (a wrong wrap gives a target of ~-2 pi / dt and fails)."""
    from wmr.controllers import iapid_nn_dekf as ia
    from wmr.estimation import ekf

    sc = paper["lemniscate"]
    st = sc.settings("iapid-nn-dekf")
    p, s, W, P = ia.pack(st, sc, np.random.default_rng(7))
    rng = np.random.default_rng(8)
    W += 0.3 * rng.normal(size=W.size)  # away from the near-zero start: every term matters
    n_h, dt = st.hidden, 0.01
    s[S_STARTED] = 1.0
    s[S_U : S_U + 2] = (0.6, -0.4)
    s[S_Q : S_Q + 3] = (0.2, -0.1, heading)
    q_hat = np.array([0.206, -0.097, heading + 0.004])
    q_hat[2] = math.atan2(math.sin(q_hat[2]), math.cos(q_hat[2]))

    i1, i2 = n_h * ia.N_IN, n_h * ia.N_IN + n_h
    i3 = i2 + 3 * n_h

    def net(w, x):
        V, bv, Wo, bw = w[:i1].reshape(n_h, ia.N_IN), w[i1:i2], w[i2:i3].reshape(3, n_h), w[i3:]
        h = np.tanh(V @ x + bv)
        return Wo @ h + bw, h, V, Wo

    x = np.array([0.6, -0.4, math.cos(heading), math.sin(heading)])
    z, h, V, Wo = net(W, x)
    D = Wo * (1.0 - h * h)
    H = np.hstack(((D[:, :, None] * x).reshape(3, -1), D, np.kron(np.eye(3), h), np.eye(3)))
    target = np.array([0.006, 0.003, 0.004]) / dt
    W_ref, P_ref = ekf.weight_update_reference(W, P, H, target - z, p.q_diag, p.R)

    J = ia.identify(p, s, W, P, q_hat, dt)

    np.testing.assert_allclose(s[pid.S_NN_ERR], np.linalg.norm(target - z), rtol=1e-9)
    np.testing.assert_allclose(W, W_ref, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(P, P_ref, rtol=0, atol=1e-10 * np.abs(P_ref).max())
    fd = np.empty((3, 2))
    for j in range(2):
        e = np.zeros(4)
        e[j] = 1e-6
        fd[:, j] = (net(W_ref, x + e)[0] - net(W_ref, x - e)[0]) / 2e-6
    np.testing.assert_allclose(J, dt * fd, rtol=1e-6, atol=1e-10)
