"""One-hidden-layer network (tanh hidden units, linear outputs): forward pass and Jacobians.

The network of eqs. (18)-(19) with the bias counted once (errata E7)::

    a_j = sum_k V[j, k] x_k + b_v[j],   h_j = tanh(a_j),   z_i = sum_j W[i, j] h_j + b_w[i].

Weights live in one flat vector ``theta`` of length ``n = n_h n_in + n_h + n_out n_h + n_out``,
laid out ``[V (row-major), b_v, W (row-major), b_w]`` (docs/conventions.md); the weight EKF
treats ``theta`` as its state.

Two Jacobians are needed and they are different matrices (errata E8):

- the input Jacobian ``dz/dx = W diag(1 - h^2) V`` (n_out, n_in), which the indirect adaptive PID
  uses as the identified plant Jacobian (eqs. 20-24, corrected by the chain rule);
- the weight Jacobian ``H = dz/dtheta`` (n_out, n), the EKF's measurement matrix.
"""

from __future__ import annotations

import math

import numpy as np

from wmr._jit import njit

__all__ = [
    "n_weights",
    "init_weights",
    "unpack",
    "forward",
    "forward_into",
    "input_jacobian",
    "input_jacobian_into",
    "input_jacobian_printed",
    "weight_jacobian",
]


@njit
def n_weights(n_in, n_h, n_out):
    """Number of weights ``n_h n_in + n_h + n_out n_h + n_out``."""
    return n_h * n_in + n_h + n_out * n_h + n_out


def init_weights(rng: np.random.Generator, n_in: int, n_h: int, n_out: int,
                 output_scale: float = 0.1) -> np.ndarray:  # fmt: skip
    """Initial weights: Glorot-normal ``V`` (std ``sqrt(2/(n_in+n_h))``), zero biases, and output
    weights ``W`` of std ``output_scale/sqrt(n_h)``, so the network starts near its (zero) bias."""
    V = rng.standard_normal((n_h, n_in)) * math.sqrt(2.0 / (n_in + n_h))
    W = rng.standard_normal((n_out, n_h)) * output_scale / math.sqrt(n_h)
    return np.concatenate((V.ravel(), np.zeros(n_h), W.ravel(), np.zeros(n_out)))


@njit
def unpack(theta, n_in, n_h, n_out):
    """Views ``(V (n_h, n_in), b_v (n_h,), W (n_out, n_h), b_w (n_out,))`` into ``theta``."""
    i1 = n_h * n_in
    i2 = i1 + n_h
    i3 = i2 + n_out * n_h
    return (theta[:i1].reshape((n_h, n_in)), theta[i1:i2],
            theta[i2:i3].reshape((n_out, n_h)), theta[i3 : i3 + n_out])  # fmt: skip


@njit
def forward(theta, x, n_h, n_out):
    """Outputs ``z`` (n_out,) and hidden activations ``h`` (n_h,) for input ``x`` (n_in,)."""
    z = np.empty(n_out)
    h = np.empty(n_h)
    forward_into(theta, x, n_h, n_out, z, h)
    return z, h


@njit
def forward_into(theta, x, n_h, n_out, z, h):
    """:func:`forward` written into ``z`` (n_out,) and ``h`` (n_h,): no allocation."""
    n_in = x.size
    V, b_v, W, b_w = unpack(theta, n_in, n_h, n_out)
    for j in range(n_h):
        a = b_v[j]
        for k in range(n_in):
            a += V[j, k] * x[k]
        h[j] = math.tanh(a)
    for i in range(n_out):
        z[i] = b_w[i]
        for j in range(n_h):
            z[i] += W[i, j] * h[j]


@njit
def input_jacobian(theta, x, n_h, n_out, h):
    """``dz/dx = W diag(1 - h^2) V``, shape (n_out, n_in); ``h`` from :func:`forward` at ``x``.

    Chain rule (errata E7): ``dz_i/dh_j = W[i, j]``, ``dh_j/dx_k = (1 - h_j^2) V[j, k]``, summed
    over the hidden units ``j``.
    """
    J = np.empty((n_out, x.size))
    input_jacobian_into(theta, x, n_h, n_out, h, J)
    return J


@njit
def input_jacobian_into(theta, x, n_h, n_out, h, J):
    """:func:`input_jacobian` written into ``J`` (n_out, n_in): no allocation."""
    n_in = x.size
    V, _, W, _ = unpack(theta, n_in, n_h, n_out)
    J[:, :] = 0.0
    for j in range(n_h):
        d = 1.0 - h[j] * h[j]
        for i in range(n_out):
            wd = W[i, j] * d
            for k in range(n_in):
                J[i, k] += wd * V[j, k]


@njit
def input_jacobian_printed(theta, x, n_h, n_out):
    """The paper's printed eqs. (22)-(24), for the analyses to show that they are wrong.

    Reading chosen (the printed eq. 24 leaves ``j`` free; eq. 21 is a matrix product, so ``j`` is
    summed)::

        dz_i/dx_k = sum_j  W[i, j] (sum_j' W[i, j'] h_j')  V[j, k] tanh(sum_k' V[j, k'] x_k')

    i.e. eq. (22)'s extra factor ``sum_j' W[i, j'] h_j'``, eq. (23)'s ``sigma`` in place of
    ``sigma'`` and its argument without the hidden bias.
    """
    n_in = x.size
    V, _, W, _ = unpack(theta, n_in, n_h, n_out)
    _, h = forward(theta, x, n_h, n_out)
    J = np.zeros((n_out, n_in))
    for i in range(n_out):
        wh = 0.0
        for j in range(n_h):
            wh += W[i, j] * h[j]
        for j in range(n_h):
            a = 0.0
            for k in range(n_in):
                a += V[j, k] * x[k]
            s = math.tanh(a)
            for k in range(n_in):
                J[i, k] += W[i, j] * wh * V[j, k] * s
    return J


@njit
def weight_jacobian(theta, x, n_h, n_out, h, H):
    """Write ``H = dz/dtheta`` (n_out, n) into ``H`` (in place; the EKF's measurement matrix).

    Derivation (errata E8), with ``d_j = 1 - h_j^2``::

        dz_i/dV[j, k] = W[i, j] d_j x_k      dz_i/db_v[j] = W[i, j] d_j
        dz_i/dW[i', j] = delta_ii' h_j       dz_i/db_w[i'] = delta_ii'
    """
    n_in = x.size
    _, _, W, _ = unpack(theta, n_in, n_h, n_out)
    i1 = n_h * n_in
    i2 = i1 + n_h
    i3 = i2 + n_out * n_h
    H[:, :] = 0.0
    for i in range(n_out):
        for j in range(n_h):
            wd = W[i, j] * (1.0 - h[j] * h[j])
            for k in range(n_in):
                H[i, j * n_in + k] = wd * x[k]
            H[i, i1 + j] = wd
            H[i, i2 + i * n_h + j] = h[j]
        H[i, i3 + i] = 1.0
