"""Network: forward pass, input Jacobian (errata E7), weight Jacobian (E8) against oracles."""

from __future__ import annotations

import numpy as np
import pytest

from wmr.estimation import nn

SIZES = [(2, 10, 3), (4, 10, 3), (6, 8, 2), (4, 1, 3), (3, 20, 3)]
IDS = [f"in{a}-h{b}-out{c}" for a, b, c in SIZES]
FD_H = 1e-6
FD_TOL = 1e-8  # central differences: O(h^2) ~ 1e-12 truncation plus ~eps/h ~ 1e-10 round-off


def _random_net(rng, n_in, n_h, n_out):
    theta = rng.normal(size=nn.n_weights(n_in, n_h, n_out))
    return theta, rng.normal(size=n_in)


def _fd(f, x):
    cols = []
    for i in range(x.size):
        d = np.zeros_like(x)
        d[i] = FD_H
        cols.append((f(x + d) - f(x - d)) / (2 * FD_H))
    return np.array(cols).T


@pytest.mark.parametrize("n_in,n_h,n_out", SIZES, ids=IDS)
def test_forward_matches_numpy_matrices(n_in, n_h, n_out):
    rng = np.random.default_rng(1)
    theta, x = _random_net(rng, n_in, n_h, n_out)
    i1, i2, i3 = n_h * n_in, n_h * n_in + n_h, n_h * n_in + n_h + n_out * n_h
    V, bv = theta[:i1].reshape(n_h, n_in), theta[i1:i2]
    W, bw = theta[i2:i3].reshape(n_out, n_h), theta[i3:]
    z, h = nn.forward(theta, x, n_h, n_out)
    np.testing.assert_allclose(h, np.tanh(V @ x + bv), rtol=1e-14)
    np.testing.assert_allclose(z, W @ np.tanh(V @ x + bv) + bw, rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("n_in,n_h,n_out", SIZES, ids=IDS)
@pytest.mark.parametrize("seed", range(5))
def test_input_jacobian_matches_finite_differences(n_in, n_h, n_out, seed):
    rng = np.random.default_rng(seed)
    theta, x = _random_net(rng, n_in, n_h, n_out)
    _, h = nn.forward(theta, x, n_h, n_out)
    J = nn.input_jacobian(theta, x, n_h, n_out, h)
    J_fd = _fd(lambda xx: nn.forward(theta, xx, n_h, n_out)[0], x)
    np.testing.assert_allclose(J, J_fd, atol=FD_TOL)


@pytest.mark.parametrize("n_in,n_h,n_out", SIZES, ids=IDS)
@pytest.mark.parametrize("seed", range(3))
def test_weight_jacobian_matches_finite_differences(n_in, n_h, n_out, seed):
    rng = np.random.default_rng(100 + seed)
    theta, x = _random_net(rng, n_in, n_h, n_out)
    _, h = nn.forward(theta, x, n_h, n_out)
    H = np.full((n_out, theta.size), np.nan)
    nn.weight_jacobian(theta, x, n_h, n_out, h, H)
    H_fd = _fd(lambda th: nn.forward(th, x, n_h, n_out)[0], theta)
    np.testing.assert_allclose(H, H_fd, atol=FD_TOL)


def test_printed_eqs_22_24_differ_from_the_true_jacobian():
    """The printed form is wrong by O(1) (not a rounding issue) at random points."""
    rng = np.random.default_rng(7)
    rel = []
    for _ in range(50):
        theta, x = _random_net(rng, 4, 10, 3)
        _, h = nn.forward(theta, x, 10, 3)
        J = nn.input_jacobian(theta, x, 10, 3, h)
        Jp = nn.input_jacobian_printed(theta, x, 10, 3)
        rel.append(np.linalg.norm(Jp - J) / np.linalg.norm(J))
    assert np.median(rel) > 0.5


def test_init_weights_layout_and_determinism():
    a = nn.init_weights(np.random.default_rng(3), 4, 10, 3)
    b = nn.init_weights(np.random.default_rng(3), 4, 10, 3)
    np.testing.assert_array_equal(a, b)
    assert a.size == nn.n_weights(4, 10, 3) == 83
    V, bv, W, bw = nn.unpack(a, 4, 10, 3)
    assert np.all(bv == 0) and np.all(bw == 0)
    assert np.abs(W).max() < np.abs(V).max()  # small output layer: the net starts near zero
