"""References: (theta_r, v_r, w_r) against finite differences of the sampled path, continuity of
theta_r, closed forms for the circle and sinusoid, and chunk-size independence of the sampler.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from wmr.model import references
from wmr.model.references import ReferenceSampler

#: One parameter set per kind (the paper's lemniscate and sinusoid; a circle of 3.5 turns in 35 s).
PARAMS = {
    "lemniscate": {"size": 2.0, "period": 40.0},
    "sinusoid": {"speed": 0.5, "amplitude": 1.0, "omega": 0.5},
    "circle": {"radius": 1.5, "period": 10.0},
}
KIND_PARAMS = [pytest.param(kind, params, id=kind) for kind, params in PARAMS.items()]

#: Sampling for the finite-difference oracle.
FD_DT = 1e-3
FD_DURATION = 40.0
#: Central differences err by dt^2/6 * |third derivative|: <= 1e-6/6 * 0.4 ~ 7e-8 for these paths
#: (circle: R W^3 = 0.37), plus rounding eps |x| / dt <= 2.2e-16 * 25 / 1e-3 ~ 6e-12.  The heading
#: from differenced velocities and w_r from the differenced heading inherit the same order.
FD_ATOL = 1e-6


@pytest.mark.parametrize(("kind", "params"), KIND_PARAMS)
def test_heading_speed_turn_rate_match_finite_differences(kind, params):
    n = round(FD_DURATION / FD_DT) + 1
    ref = references.sample(kind, params, FD_DT, n)
    assert ref.shape == (n, 5)
    x, y, theta, v, w = ref.T
    xd = (x[2:] - x[:-2]) / (2 * FD_DT)
    yd = (y[2:] - y[:-2]) / (2 * FD_DT)
    heading_error = np.angle(np.exp(1j * (theta[1:-1] - np.arctan2(yd, xd))))  # wrapped difference
    assert_allclose(heading_error, 0.0, atol=FD_ATOL)
    assert_allclose(v[1:-1], np.hypot(xd, yd), rtol=0, atol=FD_ATOL)
    # theta_r is unwrapped, so its plain central difference is the turn rate
    assert_allclose(w[1:-1], (theta[2:] - theta[:-2]) / (2 * FD_DT), rtol=0, atol=FD_ATOL)


@pytest.mark.parametrize(("kind", "params"), KIND_PARAMS)
def test_heading_is_continuous(kind, params):
    ref = references.sample(kind, params, 0.01, 4001)
    # the largest heading change per step is |w_r| max * dt, far below a 2 pi jump
    assert np.max(np.abs(np.diff(ref[:, 2]))) < 0.05


def test_circle_heading_over_several_turns():
    """Circle: theta_r = pi/2 + 2 pi t / period exactly (continuous over 3.5 turns)."""
    p = PARAMS["circle"]
    dt = 0.01
    ref = references.sample("circle", p, dt, 3501)
    t = np.arange(3501) * dt
    W = 2 * math.pi / p["period"]
    # |theta| <= 25 rad: atan2 and the added whole turns round at ~1e-14
    assert_allclose(ref[:, 2], math.pi / 2 + W * t, rtol=0, atol=1e-12)
    assert ref[-1, 2] - ref[0, 2] == pytest.approx(3.5 * 2 * math.pi, abs=1e-12)
    assert_allclose(ref[:, 3], p["radius"] * W, rtol=1e-14)  # constant speed
    assert_allclose(ref[:, 4], W, rtol=1e-14)  # constant turn rate
    assert_allclose(np.hypot(ref[:, 0], ref[:, 1]), p["radius"], rtol=1e-14)


def test_lemniscate_heading_returns_after_one_period():
    """A figure-eight has no net turning: theta_r(period) = theta_r(0) = pi/4."""
    p = PARAMS["lemniscate"]
    dt = 0.01
    n = round(p["period"] / dt) + 1
    ref = references.sample("lemniscate", p, dt, n)
    assert ref[0, 2] == pytest.approx(math.pi / 4, abs=1e-15)
    assert ref[-1, 2] == pytest.approx(math.pi / 4, abs=1e-12)
    # it does turn in between: one lobe each way, heading spans more than a half turn
    assert np.ptp(ref[:, 2]) > math.pi
    a, W = p["size"], 2 * math.pi / p["period"]
    assert ref[0, 3] == pytest.approx(a * W * math.sqrt(2), rel=1e-15)
    assert ref[0, 4] == 0.0  # no acceleration at the centre crossing


def test_sinusoid_closed_form():
    p = PARAMS["sinusoid"]
    t = np.arange(4001) * 0.01
    ref = references.sample("sinusoid", p, 0.01, 4001)
    yd = p["amplitude"] * p["omega"] * np.cos(p["omega"] * t)
    ydd = -p["amplitude"] * p["omega"] ** 2 * np.sin(p["omega"] * t)
    assert_allclose(ref[:, 0], p["speed"] * t, rtol=1e-15)
    assert_allclose(ref[:, 2], np.arctan(yd / p["speed"]), rtol=0, atol=1e-15)
    assert_allclose(ref[:, 3], np.hypot(p["speed"], yd), rtol=1e-15)
    assert_allclose(ref[:, 4], p["speed"] * ydd / (p["speed"] ** 2 + yd**2), rtol=1e-13, atol=1e-16)


def _random_chunks(rng, n: int) -> list[tuple[int, int]]:
    """Consecutive chunks covering 0..n, some of them empty."""
    cuts = np.sort(rng.integers(0, n + 1, size=12))
    bounds = [0, *cuts.tolist(), n]
    return list(zip(bounds[:-1], bounds[1:], strict=True))


@pytest.mark.parametrize(("kind", "params"), KIND_PARAMS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_chunked_sampling_is_bit_identical(kind, params, seed):
    dt, n = 0.01, 5000  # the circle turns 5 times: many branch cuts fall inside chunks
    one_shot = references.sample(kind, params, dt, n)
    sampler = ReferenceSampler(kind, params, dt)
    chunks = _random_chunks(np.random.default_rng(seed), n)
    chunked = np.vstack([sampler.rows(k0, k1) for k0, k1 in chunks])
    assert_array_equal(chunked, one_shot)


def test_single_row_chunks_are_bit_identical():
    p = PARAMS["circle"]
    sampler = ReferenceSampler("circle", p, 0.05)
    rows = np.vstack([sampler.rows(k, k + 1) for k in range(600)])  # 3 turns, one row at a time
    assert_array_equal(rows, references.sample("circle", p, 0.05, 600))


def test_empty_sample():
    assert references.sample("circle", PARAMS["circle"], 0.01, 0).shape == (0, 5)


def test_sampler_rejects_chunks_out_of_order():
    sampler = ReferenceSampler("circle", PARAMS["circle"], 0.01)
    sampler.rows(0, 10)
    with pytest.raises(ValueError, match="consecutive"):
        sampler.rows(11, 20)
    with pytest.raises(ValueError, match="consecutive"):
        sampler.rows(0, 10)
    with pytest.raises(ValueError):
        sampler.rows(10, 5)  # a chunk may not end before it starts
    assert_array_equal(
        sampler.rows(10, 20), references.sample("circle", PARAMS["circle"], 0.01, 20)[10:]
    )


def test_unknown_kind():
    with pytest.raises(ValueError, match="unknown reference kind"):
        ReferenceSampler("spiral", {}, 0.01)
    with pytest.raises(ValueError, match="unknown reference kind"):
        references.path_derivatives("spiral", {}, np.zeros(3))


@pytest.mark.parametrize("kind", ["lemniscate", "circle"])
def test_absurd_period_gives_non_finite_values_not_an_exception(kind):
    """A period so short that (2 pi / period)^2 overflows: IEEE values, no OverflowError, no warning
    (the simulator reports the run as diverged; the loader cannot know every overflow)."""
    params = dict(PARAMS[kind], period=1e-200)
    ref = references.sample(kind, params, 0.01, 5)
    assert ref.shape == (5, 5)
    assert not np.all(np.isfinite(ref))
