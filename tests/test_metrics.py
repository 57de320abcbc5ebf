"""Metrics: the RMSE of eq. (64) on a case computed by hand, and theta wrapping."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.testing import assert_array_equal

from wmr.closedloop import metrics


def test_rmse_hand_computed():
    # errors ref - q:  x: 3, 0, 0   y: 4, 0, 2   theta: 0, 0.1, 0.2 (the last one across +-pi)
    q = [[0.0, 0.0, 0.0], [1.0, 1.0, 0.1], [2.0, 0.0, math.pi - 0.1]]
    ref = [
        [3.0, 4.0, 0.0, 9.0, 9.0],
        [1.0, 1.0, 0.2, 9.0, 9.0],
        [2.0, 2.0, -math.pi + 0.1, 9.0, 9.0],
    ]
    r = metrics.rmse(q, ref)
    assert list(r) == list(metrics.RMSE_KEYS)
    assert r["x"] == pytest.approx(math.sqrt(9 / 3), rel=1e-15)
    assert r["y"] == pytest.approx(math.sqrt(20 / 3), rel=1e-15)
    assert r["theta"] == pytest.approx(math.sqrt(0.05 / 3), rel=1e-14)  # 0.1^2 + 0.2^2 = 0.05
    assert r["position"] == pytest.approx(math.sqrt(29 / 3), rel=1e-15)  # 9 + 16 + 4


def test_rmse_theta_takes_the_short_way_round():
    q = np.array([[0.0, 0.0, math.pi - 0.05]])
    ref = np.array([[0.0, 0.0, -math.pi + 0.05]])  # raw difference -2 pi + 0.1
    assert metrics.rmse(q, ref)["theta"] == pytest.approx(0.1, abs=1e-14)
    ref = np.array([[0.0, 0.0, math.pi - 0.05 + 6 * math.pi]])  # three whole turns: no error
    assert metrics.rmse(q, ref)["theta"] == pytest.approx(0.0, abs=1e-14)
    ref = np.array([[0.0, 0.0, math.pi - 0.05 + math.pi]])  # opposite heading: error pi, not 0
    assert metrics.rmse(q, ref)["theta"] == pytest.approx(math.pi, abs=1e-14)


def test_rmse_of_a_perfect_track_is_zero():
    ref = np.column_stack((np.linspace(0, 1, 5), np.zeros(5), np.linspace(-4, 4, 5)))
    assert metrics.rmse(ref, ref) == dict.fromkeys(metrics.RMSE_KEYS, 0.0)


@pytest.mark.parametrize(
    ("q_shape", "ref_shape"),
    [((3, 2), (3, 3)), ((3, 3), (4, 3)), ((3, 3), (3, 2)), ((3,), (3,))],
    ids=["q-2-columns", "row-mismatch", "ref-2-columns", "1-d"],
)
def test_rmse_rejects_bad_shapes(q_shape, ref_shape):
    with pytest.raises(ValueError, match="rmse needs"):
        metrics.rmse(np.zeros(q_shape), np.zeros(ref_shape))


def test_wrap_interval():
    a = np.array([-math.pi, math.pi, 0.0, 3 * math.pi, -3 * math.pi, 7.0, -7.0])
    w = metrics.wrap(a)
    assert w[0] == math.pi and w[1] == math.pi and w[2] == 0.0
    assert np.all((w > -math.pi) & (w <= math.pi))
    assert_array_equal(np.round((a - w) / (2 * math.pi)), (a - w) / (2 * math.pi))
