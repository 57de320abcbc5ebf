"""Backstepping (Kanayama 1990): the law's formula, exact feed-forward at zero error, settings
validation, and convergence from a grid of initial poses on every reference kind.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from wmr import scenario as scn
from wmr._settings import SettingError
from wmr.closedloop import sim
from wmr.controllers import backstepping
from wmr.model import kinematics as km
from wmr.model import references

REFERENCES = {
    "circle": {"radius": 1.5, "period": 20.0},
    "sinusoid": {"speed": 0.5, "amplitude": 1.0, "omega": 0.5},
    "lemniscate": {"size": 2.0, "period": 40.0},
}
#: Final position error required after the settling time [m].
TOL = 1e-3
#: Initial offsets (dx [m], dy [m], dtheta [rad]) from the reference's initial pose.
OFFSETS = [
    (0.5, 0.0, 0.0),
    (-0.5, 0.0, 0.0),
    (0.0, 0.5, 0.0),
    (0.0, -0.5, 0.0),
    (0.0, 0.0, 1.0),
    (0.5, 0.0, -1.0),
    (-0.5, 0.5, -1.0),
    (1.0, 1.0, 0.0),
    (0.0, 0.0, 2.5),
    (-1.0, 0.0, math.pi / 2),
]


def _offset_id(o):
    return f"dx={o[0]:g},dy={o[1]:g},dθ={o[2]:.3g}"


def _scenario(kind: str, offset=(0.0, 0.0, 0.0), duration=40.0, **changes) -> scn.Scenario:
    """Noise-free, undisturbed, unsaturated scenario on ``kind`` starting at ref(0) + offset."""
    ref0 = references.sample(kind, REFERENCES[kind], 0.01, 1)[0]
    base = scn.load(scn.builtin("sinusoid"))
    return dataclasses.replace(
        base,
        duration=duration,
        reference=scn.ReferenceSpec(kind, REFERENCES[kind]),
        initial_pose=tuple(float(r + o) for r, o in zip(ref0[:3], offset, strict=True)),
        noise=scn.Noise(),
        **changes,
    )


def _law(q_hat, ref, gains, printed=False):
    """The law of the module docstring, evaluated in numpy (rows of q_hat and ref)."""
    k1, k2, k3 = gains
    e = np.array([km.tracking_error(q, r, printed) for q, r in zip(q_hat, ref, strict=True)])
    v_r, w_r = ref[:, 3], ref[:, 4]
    return np.column_stack(
        (v_r * np.cos(e[:, 2]) + k1 * e[:, 0], w_r + v_r * (k2 * e[:, 1] + k3 * np.sin(e[:, 2])))
    )


@pytest.mark.parametrize("kind", REFERENCES)
def test_zero_error_gives_exactly_the_feed_forward(kind):
    r = sim.simulate(_scenario(kind, duration=1.0), "backstepping")
    # e = 0 exactly: v = v_r cos 0 + k1 0 and w = w_r + v_r (0 + k3 sin 0), bit for bit
    assert_array_equal(r.u[0], r.ref[0, 3:5])


@pytest.mark.parametrize("printed", [False, True], ids=["corrected", "printed"])
def test_law_matches_its_formula_along_a_noisy_run(printed):
    gains = (1.5, 8.0, 3.0)
    settings = backstepping.Settings(gains=gains, printed_rotation=printed)
    sc = dataclasses.replace(
        scn.load(scn.builtin("sinusoid-perturbed")), duration=10.0
    )  # noise, disturbance, no limits
    r = sim.simulate(sc, "backstepping", settings=settings)
    # jitted vs numpy evaluation of the same formula: a few ulps of |u| <= ~10
    assert_allclose(r.u, _law(r.q_hat, r.ref[:-1], gains, printed), rtol=0, atol=1e-13)
    if printed:  # the option is live: it does change the input
        corrected = _law(r.q_hat, r.ref[:-1], gains, False)
        assert np.max(np.abs(r.u - corrected)) > 1e-3


@pytest.mark.parametrize(
    "gains",
    [(0.0, 10.0, 4.0), (2.0, -1.0, 4.0), (2.0, 10.0, math.nan), (2.0, 10.0, math.inf)],
    ids=["k1=0", "k2<0", "k3=nan", "k3=inf"],
)
def test_settings_reject_bad_gains(gains):
    with pytest.raises(SettingError, match="gains"):
        backstepping.Settings(gains=gains)


def _settling_time(kind: str, offset) -> float:
    """Time after which the position error must stay below TOL, from the linearised loop.

    The slowest linear mode decays at rate = min(k1, k3 v_r,min / 2) (the longitudinal pole
    and the real part of the underdamped lateral pair).  The initial error is measured by the
    Lyapunov function V = (e1^2 + e2^2)/2 + (1 - cos e3)/k2 as sqrt(2 V0), and the target is
    TOL / 10: one decade of margin for the non-normal transient (the heading error is turned into
    position error before it decays).  This gives 10-23 s on these references.
    """
    k1, k2, k3 = backstepping.Settings().gains
    v_min = references.sample(kind, REFERENCES[kind], 0.01, 4001)[:, 3].min()
    rate = min(k1, k3 * v_min / 2)
    dx, dy, dth = offset
    e0 = math.sqrt(dx * dx + dy * dy + 2 * (1 - math.cos(dth)) / k2)
    return math.log(e0 / (TOL / 10)) / rate


@pytest.mark.parametrize("offset", OFFSETS, ids=_offset_id)
@pytest.mark.parametrize("kind", REFERENCES)
def test_converges_from_a_grid_of_initial_poses(kind, offset):
    t_settle = _settling_time(kind, offset)
    duration = 40.0
    assert t_settle < duration - 5.0  # the check below covers at least 5 s
    r = sim.simulate(_scenario(kind, offset, duration=duration), "backstepping")
    assert not r.diverged
    err = np.hypot(r.q[:, 0] - r.ref[:, 0], r.q[:, 1] - r.ref[:, 1])
    after = r.t >= t_settle
    assert err[after].max() < TOL
    heading = np.abs([km.wrap_angle(a) for a in r.ref[after, 2] - r.q[after, 2]])
    assert heading.max() < 2 * TOL  # the heading settles too (its ZOH residual: ~9e-4 rad)
