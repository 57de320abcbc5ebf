"""Waypoint references (DESIGN §3.4): the spline through samples of the analytic paths gives
their theta_r, v_r, w_r; files are read relative to the scenario; bad files name the row."""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose

from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.model import references

#: Spacing of the samples through which the spline is drawn [s].  A quintic spline's second
#: derivative errs by O(h^4 f^(6)); at 0.25 s on these paths that is ~4e-8, below 1e-6.
SPACING = 0.25


def _points(kind, params, t0=-1.0, t1=42.0):
    t = np.arange(t0, t1, SPACING)
    x, y, *_ = references.path_derivatives(kind, params, t)
    return [[float(a), float(b), float(c)] for a, b, c in zip(t, x, y, strict=True)]


def _scenario(reference: str, source="<string>", duration=40.0):
    return scn.loads(f'name = "wp"\nduration = {duration}\ndt = 0.01\n'
                     f"initial_pose = [0.0, 0.0, 0.0]\n[reference]\n{reference}\n", source)


@pytest.mark.parametrize(("kind", "params"), [
    ("circle", {"radius": 1.0, "period": 20.0}),
    ("lemniscate", {"size": 2.0, "period": 40.0}),
], ids=["circle", "lemniscate"])  # fmt: skip
def test_waypoints_through_an_analytic_path_reproduce_its_reference(kind, params):
    sc = _scenario(f'kind = "waypoints"\npoints = {_points(kind, params)}')
    got = references.sample("waypoints", sc.reference.params, 0.01, 4001)
    want = references.sample(kind, params, 0.01, 4001)
    assert_allclose(got, want, rtol=0, atol=1e-6)  # x_r, y_r, theta_r, v_r, w_r


def test_a_waypoint_file_is_read_relative_to_the_scenario(tmp_path):
    rows = _points("circle", {"radius": 1.0, "period": 20.0})
    (tmp_path / "paths").mkdir()
    (tmp_path / "paths" / "loop.csv").write_text(
        "t,x,y\n" + "".join(f"{t!r},{x!r},{y!r}\n" for t, x, y in rows))
    path = tmp_path / "scenario.toml"
    path.write_text('name = "wp"\nduration = 40.0\ndt = 0.01\ninitial_pose = [1.0, 0.0, 1.5707963]'
                    '\n[reference]\nkind = "waypoints"\nfile = "paths/loop.csv"\n')
    from_file = scn.load(path)
    inline = _scenario(f'kind = "waypoints"\npoints = {rows}')
    assert from_file.reference.params["points"] == inline.reference.params["points"]
    r = simulate(from_file, "backstepping", 0)
    assert not r.diverged and r.rmse["position"] < 0.01


@pytest.mark.parametrize(("content", "needle"), [
    ("t,x,y\n0,0,0\n1,1,0\n2,2,oops\n", "row 4 column y"),
    ("t,x\n0,0\n", "header must be t,x,y"),
    ("t,x,y\n0,0,0\n1,1\n", "row 3"),
    ("t,x,y\n" + "".join(f"{i},{i},0\n" for i in range(5)), "needs at least 6 rows"),
    ("t,x,y\n" + "".join(f"{i % 3},{i},0\n" for i in range(8)), "row 5"),
], ids=["bad-cell", "bad-header", "short-row", "five-rows", "t-decreasing"])  # fmt: skip
def test_a_bad_waypoint_file_names_its_row(content, needle, tmp_path):
    (tmp_path / "p.csv").write_text(content)
    path = tmp_path / "s.toml"
    path.write_text('name = "wp"\nduration = 1.0\ndt = 0.01\ninitial_pose = [0.0, 0.0, 0.0]\n'
                    '[reference]\nkind = "waypoints"\nfile = "p.csv"\n')
    with pytest.raises(scn.ScenarioError) as err:
        scn.load(path)
    message = str(err.value)
    assert needle in message and str(path) in message and "\n" not in message


def test_the_path_must_cover_the_start_of_the_run():
    late = [[t + 0.5, t, 0.0] for t in range(8)]
    with pytest.raises(scn.ScenarioError, match="first waypoint time must be <= 0"):
        _scenario(f'kind = "waypoints"\npoints = {late}', duration=5.0)
