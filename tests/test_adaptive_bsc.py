"""Adaptive backstepping (``wmr.controllers.adaptive_bsc``, issue 21 item 2).

Oracles: backstepping itself (zero adaptation is BSC bit for bit), the true plant's parameters
(planted truth the estimates must find), the Lyapunov function (A8) evaluated from the logged run
with the true parameters (its decrease up to the O(dt^2) of the sampled law, by the residual's
order in dt), a general-purpose bounded minimiser (scipy) for the metric projection, and BSC's
own seed-to-seed spread for the ideal plant.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.optimize import minimize

from wmr import cli, controllers
from wmr import scenario as scn
from wmr._settings import SettingError, from_table
from wmr.closedloop.sim import simulate
from wmr.controllers import adaptive_bsc as ab
from wmr.model.kinematics import tracking_error

#: The true map of the wheel-radius scenario (lemniscate-wheel-radius.toml), STATE order.
WHEEL_RADIUS = (0.8, 0.0, 0.8, 0.0)
#: Issue 21: the estimates within 0.03 of the true gains from t = 20 s on.
GAIN_TOL, SETTLED_BY = 0.03, 20.0
#: Seeds of the paired comparisons (each run is 4,000 steps, ~10 ms).
SEEDS = range(10)


@pytest.fixture(scope="module")
def lemniscate():
    return scn.load(scn.builtin("lemniscate"))


def _noise_free(sc: scn.Scenario) -> scn.Scenario:
    return dataclasses.replace(sc, noise=dataclasses.replace(sc.noise, pose_std=(0.0, 0.0, 0.0)))


def _estimates(r) -> np.ndarray:
    return np.column_stack([r.signal(n) for n in ab.ESTIMATE_NAMES])


def _truth(sc: scn.Scenario) -> np.ndarray:
    p = sc.plant
    return np.array([p.v_gain, p.v_from_w, p.w_gain, p.w_from_v])


# --- the law is backstepping when nothing adapts; settings -------------------------------------


@pytest.mark.parametrize("name", ["lemniscate", "lemniscate-wheel-radius", "sinusoid-perturbed"])
def test_zero_adaptation_is_backstepping_bit_for_bit(name):
    """With every adaptation gain 0 the estimate stays the nominal map and (A2) is BSC's command:
    the same commands and poses to the last bit (measurement noise included)."""
    sc = scn.load(scn.builtin(name))
    a = simulate(sc, "adaptive-bsc", 3, settings=ab.Settings(adaptation=(0.0,) * 4))
    b = simulate(sc, "backstepping", 3)
    assert np.array_equal(a.u, b.u) and np.array_equal(a.q, b.q)
    assert np.array_equal(_estimates(a)[-1], (1.0, 0.0, 1.0, 0.0))


@pytest.mark.parametrize(("table", "key"), [
    ({"adaptation": [-1.0, 0.0, 1.0, 1.0]}, "adaptation"),
    ({"identification": [1.0, -0.1]}, "identification"),
    ({"gain_bounds": [1.1, 1.5]}, "gain_bounds"),
    ({"gain_bounds": [0.5, 0.9]}, "gain_bounds"),
    ({"gain_bounds": [0.0, 1.5]}, "gain_bounds"),
    ({"coupling_bounds": [0.5, 1.0]}, "coupling_bounds"),
    ({"coupling_bounds": [-0.1, 1.0]}, "coupling_bounds"),
    ({"memory": 0.0}, "memory"),
    ({"forgetting": -1.0}, "forgetting"),
    ({"gains": [2.0, 0.0, 4.0]}, "gains"),
], ids=lambda x: x if isinstance(x, str) else None)  # fmt: skip
def test_bad_settings_are_errors_naming_the_key(table, key):
    with pytest.raises(SettingError) as err:
        from_table(ab.Settings, table, "controllers.adaptive-bsc")
    assert err.value.key == f"controllers.adaptive-bsc.{key}"
    assert "\n" not in str(err.value)


def test_bad_settings_in_a_scenario_file_exit_2_with_one_line(tmp_path, capsys):
    text = (scn.builtin("lemniscate").read_text()
            + "\n[controllers.adaptive-bsc]\ngain_bounds = [1.1, 2.0]\n")  # fmt: skip
    path = tmp_path / "bad.toml"
    path.write_text(text)
    code = cli.main(["run", str(path), "--controller", "adaptive-bsc", "--out",
                     str(tmp_path / "out")])  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "controllers.adaptive-bsc.gain_bounds" in err and "must include 1" in err
    assert not (tmp_path / "out").exists()


def test_registered_with_its_own_label_and_colour():
    row = controllers.get("adaptive-bsc")
    assert row.label == "Adaptive BSC" and "adaptive-bsc" in controllers.NAMES
    others = [c.colour for n, c in controllers.REGISTRY.items() if n != "adaptive-bsc"]
    assert row.colour not in others


# --- the estimates find the true robot ------------------------------------------------------


@pytest.mark.parametrize("seed", range(3))
def test_wheel_radius_estimates_converge_and_beat_backstepping(seed):
    """Issue 21: on the wheel-radius plant every estimate is within 0.03 of the true map from
    20 s on, and the RMSE after the transient is below BSC's (same seed, same noise)."""
    sc = scn.load(scn.builtin("lemniscate-wheel-radius"))
    assert tuple(_truth(sc)) == WHEEL_RADIUS
    r = simulate(sc, "adaptive-bsc", seed)
    late = r.t[:-1] >= SETTLED_BY
    assert np.abs(_estimates(r)[late] - WHEEL_RADIUS).max() < GAIN_TOL
    bsc = simulate(sc, "backstepping", seed, keep_trajectory=False)
    assert r.rmse_after_transient["position"] < bsc.rmse_after_transient["position"]


def test_wheel_asymmetry_estimates_converge():
    """The coupling of unequal wheels (v_from_w = 0.0075 m/rad, w_from_v = 0.333 rad/m): the
    gains within 0.03 and w_from_v within 10 % from 20 s on; v_from_w (its effect b w is below
    4 mm/s here) within 0.01 m/rad."""
    sc = scn.load(scn.builtin("lemniscate-wheel-asymmetry"))
    truth = _truth(sc)
    r = simulate(sc, "adaptive-bsc", 0)
    err = np.abs(_estimates(r)[r.t[:-1] >= SETTLED_BY] - truth).max(axis=0)
    assert err[0] < GAIN_TOL and err[2] < GAIN_TOL
    assert err[3] < 0.1 * truth[3] and err[1] < 0.01


def test_noise_free_estimates_reach_an_arbitrary_map():
    """Planted truth with all four entries off nominal, no noise: the estimates end within 2e-3
    of it (the regression (A5) is exact for this plant; a biased identity would show here)."""
    truth = (0.85, 0.01, 1.2, -0.25)
    plant = scn.Plant(v_gain=truth[0], v_from_w=truth[1], w_gain=truth[2], w_from_v=truth[3])
    sc = dataclasses.replace(_noise_free(scn.load(scn.builtin("lemniscate"))), plant=plant)
    r = simulate(sc, "adaptive-bsc", 0)
    assert np.abs(_estimates(r)[-1] - truth).max() < 2e-3
    final = r.final
    assert np.allclose(final.input_map, [[truth[0], truth[1]], [truth[3], truth[2]]], atol=2e-3)


def test_estimates_follow_a_plant_change():
    """Forgetting (A7): after the wheel radius changes from 0.8 to 0.7 at 20 s the estimated
    gains are within 0.03 of 0.7 from 35 s on (at the default forgetting of 0.5 1/s)."""
    sc = scn.load(scn.builtin("lemniscate-wheel-radius"))
    change = scn.PlantChange(at=20.0, values=(("v_gain", 0.7), ("w_gain", 0.7)))
    sc = dataclasses.replace(sc, plant=dataclasses.replace(sc.plant, changes=(change,)))
    r = simulate(sc, "adaptive-bsc", 0)
    est = _estimates(r)[r.t[:-1] >= 35.0]
    assert np.abs(est[:, [0, 2]] - 0.7).max() < GAIN_TOL


# --- the ideal plant: BSC within the seed-to-seed noise -----------------------------------------


def test_on_the_ideal_plant_it_equals_backstepping_within_seed_noise(lemniscate):
    """Rule: over 10 seeds (common noise), the mean paired difference of the position RMSE after
    the transient is smaller than the seed-to-seed standard deviation of BSC's own.  (Measured:
    +0.07 mm against 0.14 mm.  The full-run RMSE differs by more: the estimates move while the
    initial 0.7 m error is large, which shortens the transient.)"""
    diffs, bsc = [], []
    for seed in SEEDS:
        a = simulate(lemniscate, "adaptive-bsc", seed, keep_trajectory=False)
        b = simulate(lemniscate, "backstepping", seed, keep_trajectory=False)
        diffs.append(a.rmse_after_transient["position"] - b.rmse_after_transient["position"])
        bsc.append(b.rmse_after_transient["position"])
    assert abs(np.mean(diffs)) < np.std(bsc, ddof=1)


# --- the Lyapunov function (A8) along a noise-free run ---------------------------------------


def _lyapunov_residual(base: scn.Scenario, dt: float, truth) -> tuple[float, float]:
    """``max_k R_k / dt^2`` and ``max_k (V_{k+1} - V_k)`` with ``R_k = V_{k+1} - V_k - dt D_k``,
    ``D = -k1 e1^2 - (k3/k2) v_r sin^2 e3 <= 0`` (A9 without its other, also <= 0, terms)."""
    st = ab.Settings()
    plant = scn.Plant(v_gain=truth[0], v_from_w=truth[1], w_gain=truth[2], w_from_v=truth[3])
    sc = dataclasses.replace(_noise_free(base), dt=dt, duration=20.0, plant=plant)
    r = simulate(sc, "adaptive-bsc", 0)
    n = len(r.u)
    e = np.array([tracking_error(r.q[k], r.ref[k]) for k in range(n)])
    gains = np.column_stack([r.signal(name) for name in ab.GAIN_NAMES])
    V = ab.lyapunov(e, _estimates(r), gains, truth, st)
    k1, k2, k3 = st.gains
    D = -k1 * e[:, 0] ** 2 - (k3 / k2) * r.ref[:n, 3] * np.sin(e[:, 2]) ** 2
    dV = np.diff(V)
    return float((dV - dt * D[:-1]).max() / dt**2), float(dV.max())


def test_lyapunov_function_decreases_up_to_the_sampled_laws_dt_squared(lemniscate):
    """V_{k+1} - V_k <= dt D_k + C dt^2 along a noise-free run on a plant with all four entries
    off nominal: the residual over dt^2 stays put when dt halves (O(dt^2); a wrong sign or gain
    in the update leaves an O(dt) residual, whose ratio doubles: planted, it measured 56 -> 111
    -> 220), and V itself decreases at every step here."""
    truth = (0.8, 0.0075, 0.9, 0.333)
    c1, dv1 = _lyapunov_residual(lemniscate, 0.01, truth)
    c2, dv2 = _lyapunov_residual(lemniscate, 0.005, truth)
    assert 0.0 < c2 < 1.25 * c1 and c1 < 10.0  # measured 2.08 at both steps
    assert dv1 < 0.0 and dv2 < 0.0


# --- the pieces --------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(20))
def test_projection_is_the_nearest_box_point_in_the_metric(seed):
    """:func:`_project` against scipy's bounded minimiser of ``(x - y)^T P^-1 (x - y)``."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(2, 2))
    P = A @ A.T + 0.05 * np.eye(2)
    y = rng.normal(scale=2.0, size=2)
    box = ((-0.5, 0.7), (-0.3, 0.4))
    M = np.linalg.inv(P)
    got = ab._project(y[0], y[1], *box[0], *box[1], P[0, 0], P[0, 1], P[1, 1])
    ref = minimize(lambda x: (x - y) @ M @ (x - y), np.zeros(2), jac=lambda x: 2 * M @ (x - y),
                   bounds=box, method="L-BFGS-B", options={"ftol": 1e-15, "gtol": 1e-12})
    f = lambda x: (np.asarray(x) - y) @ M @ (np.asarray(x) - y)  # noqa: E731
    assert f(got) <= f(ref.x) + 1e-9
    assert np.allclose(got, ref.x, atol=1e-5)


def test_the_law_saturates_its_own_command(lemniscate):
    """With [limits] the command the law writes (and feeds its update) is within them."""
    sc = dataclasses.replace(lemniscate, limits=scn.Limits(v_max=0.2, w_max=0.3))
    p, s, theta, P = ab.pack(ab.Settings(), sc, np.random.default_rng(0))
    u = np.zeros(2)
    ref = np.array([1.0, 1.0, 0.5, 0.4, 0.3])
    ab.law(p, s, theta, P, np.zeros(3), ref, sc.dt, u)
    assert abs(u[0]) <= 0.2 and abs(u[1]) <= 0.3 and (abs(u[0]) == 0.2 or abs(u[1]) == 0.3)


def test_deterministic(lemniscate):
    a = simulate(lemniscate, "adaptive-bsc", 4)
    b = simulate(lemniscate, "adaptive-bsc", 4)
    assert np.array_equal(a.u, b.u) and np.array_equal(a.state, b.state)
