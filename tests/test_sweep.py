"""Sweep specs, designs and the Parquet store (DESIGN §3.5), on the serial engine.

The Dask engines (a LocalCluster, a scheduler with worker processes, faults) are in
tests/test_engine.py."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from cases import SHORT_LEMNISCATE
from numpy.testing import assert_allclose

from wmr import cli
from wmr.closedloop.sim import simulate
from wmr.engine import batching, sweep, sweeps
from wmr.engine.jobs import job_row

SPEC = """\
name = "t"
scenarios = ["short.toml"]
controllers = ["pid", "adaptive-pid", "backstepping"]
seeds = 2

[design]
kind = "sobol"
samples = 4
seed = 3

[factors]
"plant.v_gain" = { low = 0.6, high = 1.4 }
"controllers.*.mu" = { low = 0.09, high = 90.0, log = true }
"plant.delay_steps" = [0, 1, 2]
"""
SCENARIO = SHORT_LEMNISCATE.format(duration=2.0)


def _spec(tmp_path, text=SPEC, name="spec.toml") -> Path:
    (tmp_path / "short.toml").write_text(SCENARIO)
    path = tmp_path / name
    path.write_text(text)
    return path


def _rows(out):
    return sweep.read_rows(out).to_pandas().sort_values("job_id").reset_index(drop=True)


@pytest.mark.parametrize("workers", [1, 2, 4])
def test_batches_keep_the_order_and_shrink_toward_the_end(tmp_path, workers):
    """Batches hold the jobs in order, once each; none is over ``seconds`` of estimated work
    unless it is one job; each holds at most 1/(2 workers) of the work left when it starts
    (guided scheduling), so the last ones are short."""
    text = SPEC.replace("seeds = 2", "seeds = 40")
    spec = sweep.load_spec(_spec(tmp_path, text))
    costs = {("pid", False): 1e-3, ("pid", True): 1e-3, ("adaptive-pid", False): 2e-3,
             ("adaptive-pid", True): 2e-3, ("backstepping", False): 5e-4,
             ("backstepping", True): 5e-4}  # fmt: skip
    todo = list(range(3, spec.n_jobs, 2))

    def cost(j):  # the load of job j, computed here from the spec's layout
        point, s, c, _ = spec.job(j)
        sc = spec.runs[point][s]
        return sc.n_steps * costs[(spec.controllers[c], sc.plant.ideal)]

    loads = batching.job_loads(sweep.jobs(spec, todo), costs)
    assert loads == [cost(j) for j in todo]
    groups = [[todo[i] for i in g] for g in batching.batches(loads, 2.0, workers)]
    assert [j for g in groups for j in g] == todo
    left = sum(map(cost, todo))
    for g, after in zip(groups, groups[1:] + [None], strict=True):
        work, limit = sum(map(cost, g)), min(2.0, left / (2 * workers))
        assert len(g) == 1 or work <= limit + 1e-12
        if after:  # a batch is closed only when its next job would pass the limit
            assert work + cost(after[0]) > limit - 1e-12
        left -= work
    assert abs(left) < 1e-9
    assert sum(map(cost, groups[-1])) <= sum(map(cost, todo)) / (2 * workers) / 4
    assert batching.batches(loads, 0.0, workers) == [range(i, i + 1) for i in range(len(todo))]


def test_jobs_are_the_nested_product_and_each_row_is_its_run(tmp_path):
    spec = sweep.load_spec(_spec(tmp_path))
    assert spec.n_jobs == 4 * 1 * 3 * 2 and len(spec.points) == 4
    assert spec.job(0) == (0, 0, 0, 0) and spec.job(7) == (1, 0, 0, 1)
    sweep.run_sweep(spec, tmp_path / "out", workers=1, progress=False)
    df = _rows(tmp_path / "out")
    assert list(df.job_id) == list(range(spec.n_jobs))
    for j in (0, 5, 13, 23):  # a row is exactly the simulation of its job
        point, s, c, r = spec.job(j)
        sc = spec.runs[point][s]
        res = simulate(sc, spec.controllers[c], spec.seeds[r], keep_trajectory=False)
        row = df.iloc[j]
        assert row.rmse_position == res.rmse["position"] and row.effort == res.effort
        assert (row.controller, row.seed, row.point) == (spec.controllers[c], r, point)
        assert row["plant.v_gain"] == spec.points[point][0] == sc.plant.v_gain
        assert row["plant.delay_steps"] == sc.plant.delay_steps
    # controllers.*.mu reached every selected controller that has mu (backstepping has not)
    sc = spec.runs[2][0]
    assert sc.settings("adaptive-pid").mu == (spec.points[2][1],) * 6
    assert sc.settings("pid").mu == (spec.points[2][1],) * 6
    assert "backstepping" not in sc.controllers


def test_designs():
    """Grid: the product of the levels; Sobol: a scrambled base-2 sequence; LHS: one point per
    stratum of every factor; log ranges are uniform in the logarithm."""
    f = [sweep.Factor("a", levels=(1, 2, 3)), sweep.Factor("b", levels=("x", "y"))]
    assert sweep.design_points(f, {"kind": "grid", "seed": 0}) == [
        (1, "x"), (1, "y"), (2, "x"), (2, "y"), (3, "x"), (3, "y")]  # fmt: skip
    g = [sweep.Factor("a", low=0.0, high=1.0), sweep.Factor("b", low=1e-2, high=1e2, log=True)]
    lhs = np.array(sweep.design_points(g, {"kind": "lhs", "samples": 16, "seed": 1}))
    assert sorted(np.floor(lhs[:, 0] * 16).astype(int)) == list(range(16))
    assert sorted(np.floor((np.log10(lhs[:, 1]) + 2) / 4 * 16).astype(int)) == list(range(16))
    sob = sweep.design_points(g, {"kind": "sobol", "samples": 8, "seed": 2})
    assert sob == sweep.design_points(g, {"kind": "sobol", "samples": 8, "seed": 2})
    assert sob != sweep.design_points(g, {"kind": "sobol", "samples": 8, "seed": 3})
    cat = sweep.Factor("c", levels=(0, 1, 2))
    assert [cat.value(u) for u in (0.0, 0.33, 0.34, 0.67, 0.9999)] == [0, 0, 1, 2, 2]


def test_resume_skips_finished_jobs_and_gives_the_uninterrupted_rows(tmp_path):
    spec = sweep.load_spec(_spec(tmp_path))
    full = tmp_path / "full"
    sweep.run_sweep(spec, full, workers=1, progress=False)
    part = tmp_path / "part"
    sweep.check_out(part, spec)
    store = sweeps.open_store(part, spec)  # a previous, interrupted sweep's shard
    store.write([job_row(j) for j in sweep.jobs(spec, range(0, 24, 3))])
    store.write_manifest({**store.manifest, "run_seconds_total": 1.5})
    manifest = sweep.run_sweep(spec, part, workers=1, progress=False)
    assert manifest["runs_this_time"] == spec.n_jobs - 8 and manifest["complete"]
    assert _rows(part).equals(_rows(full))  # no job twice, none lost, the same values
    # the running time of every finished invocation adds up
    assert manifest["run_seconds_total"] == pytest.approx(1.5 + manifest["run_seconds"], abs=2e-3)
    again = sweep.run_sweep(spec, part, workers=1, progress=False)
    assert again["runs_this_time"] == 0 and len(_rows(part)) == spec.n_jobs
    assert again["run_seconds_total"] == pytest.approx(
        manifest["run_seconds_total"] + again["run_seconds"], abs=2e-3)


def test_the_store(tmp_path):
    """spec.toml copied, manifest, immutable shards, summaries; a shard reads back exactly."""
    spec = sweep.load_spec(_spec(tmp_path))
    out = tmp_path / "out"
    m = sweep.run_sweep(spec, out, workers=1, progress=False, batch_seconds=1e-9,
                        flush_seconds=1e-9)  # a batch per job, a shard per batch
    assert (out / "spec.toml").read_text() == (tmp_path / "spec.toml").read_text()
    stored = json.loads((out / "manifest.json").read_text())
    assert stored == json.loads(json.dumps(m)) and stored["spec_digest"] == spec.digest
    shards = sorted((out / "rows").glob("part-*.parquet"))
    assert len(shards) == spec.n_jobs
    assert not list((out / "rows").glob(".*"))  # no temporary file left
    table = pq.read_table(shards[0])
    assert table.schema == sweep.schema(spec)
    assert table.column_names[:5] == ["job_id", "point", "scenario", "controller", "seed"]
    assert "## " not in (out / "summary.md").read_text().split("\n")[0]
    assert "Main effect of `plant.v_gain`" in (out / "summary.md").read_text()
    assert (out / "summary.png").read_bytes()[:4] == b"\x89PNG"
    import pandas as pd  # the README's ways of reading a store

    rows = sweep.read_rows(out).to_pandas()
    raw = pd.read_parquet(out / "rows")  # (no row superseded here: the same rows)
    assert raw.sort_values("job_id").reset_index(drop=True).equals(_rows(out))
    assert len(rows) == spec.n_jobs and set(rows.job_id) == set(range(spec.n_jobs))
    means = rows[rows.status == "ok"].groupby(["controller", "plant.v_gain"]).rmse_position.mean()
    assert len(means) == len(spec.controllers) * len(spec.points)


def test_a_run_that_raises_is_an_error_row_and_the_sweep_goes_on(tmp_path, monkeypatch):
    import wmr.closedloop.sim

    real = wmr.closedloop.sim.simulate

    def flaky(sc, controller, seed, **kw):
        if controller == "adaptive-pid" and seed == 1:
            raise FloatingPointError("injected")
        return real(sc, controller, seed, **kw)

    monkeypatch.setattr(wmr.closedloop.sim, "simulate", flaky)
    spec = sweep.load_spec(_spec(tmp_path))
    sweep.run_sweep(spec, tmp_path / "out", workers=1, progress=False)
    df = _rows(tmp_path / "out")
    bad = df[df.status == "error"]
    assert len(bad) == 4 and set(bad.controller) == {"adaptive-pid"} and set(bad.seed) == {1}
    assert all(e == "FloatingPointError: injected" for e in bad.error)
    assert bad.rmse_position.isna().all() and (df.status == "ok").sum() == spec.n_jobs - 4


@pytest.mark.parametrize(("edit", "needle"), [
    (("samples = 4", "samples = 6"), "design.samples = 6: must be a power of 2"),
    (('kind = "sobol"\nsamples = 4\n', 'kind = "grid"\n'), "factors.plant.v_gain"),
    (("low = 0.6, high = 1.4", "low = 1.4, high = 0.6"), "factors.plant.v_gain.low = 1.4"),
    (("seeds = 2", "seeds = 0"), "seeds = 0"),
    (('"pid", ', '"pid", "mpc", '), "controllers = 'mpc': unknown controller"),
    (('["short.toml"]', '["nowhere.toml"]'), "scenarios = 'nowhere.toml'"),
    (('"plant.v_gain"', '"plant.v_gian"'), "factors.plant.v_gian"),
    (("low = 0.09, high = 90.0, log = true", "low = -1.0, high = 90.0, log = true"),
     "must be > 0 for a log-uniform range"),
    (('"plant.delay_steps" = [0, 1, 2]', '"plant.delay_steps" = [0, 1, -2]'),
     "factors.plant.delay_steps = -2"),
    (('"plant.delay_steps" = [0, 1, 2]', '"controllers.*.hidden" = [4, 8]'),
     "no selected controller has the setting 'hidden'"),
    (('"plant.delay_steps" = [0, 1, 2]', '"seed" = [0, 1]'), "factors.seed"),
    (("name = \"t\"", "name = \"t\"\ncolour = 1"), "colour = 1: unknown key"),
], ids=["sobol-not-power-of-2", "range-in-grid", "low-above-high", "zero-seeds",
        "unknown-controller", "missing-scenario", "unknown-path", "log-nonpositive",
        "value-makes-scenario-invalid", "field-nobody-has", "reserved-column", "unknown-key"])
def test_a_bad_spec_is_exit_2_one_line_nothing_written(edit, needle, tmp_path, capsys):
    text = SPEC.replace(*edit)
    assert text != SPEC
    path = _spec(tmp_path, text)
    out = tmp_path / "out"
    assert cli.main(["sweep", str(path), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and str(path) in err, err
    assert needle in err, err
    assert not out.exists()


def test_a_different_spec_in_a_non_empty_out_is_refused(tmp_path, capsys):
    path = _spec(tmp_path)
    out = tmp_path / "out"
    assert cli.main(["sweep", str(path), "--out", str(out), "--workers", "1"]) == 0
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    other = _spec(tmp_path, SPEC.replace("seeds = 2", "seeds = 3"), "other.toml")
    capsys.readouterr()
    assert cli.main(["sweep", str(other), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "not empty" in err and err.count("\n") == 1
    assert before == {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}


def test_progress_lines_not_bars_when_not_a_terminal(tmp_path, capsys):
    path = _spec(tmp_path)
    assert cli.main(["sweep", str(path), "--out", str(tmp_path / "o"), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    assert "\r" not in err and "sweep t: 24/24 runs (100 %)" in err


def test_effort_is_the_rms_of_the_command():
    from wmr import scenario as scn

    r = simulate(scn.load(scn.builtin("sinusoid")), "adaptive-pid", 0)
    assert_allclose(r.effort, math.sqrt(np.mean(np.sum(r.u**2, axis=1))), rtol=1e-12)


def test_measures_add_their_columns(tmp_path):
    """measures = ["jacobian", "recovery"]: the Jacobian's quality (NaN for a controller with
    none) and the recovery after the first event, equal to their computation on the run."""
    from wmr.closedloop import measures
    from wmr.estimation import identification as idf

    text = SPEC.replace('seeds = 2', 'seeds = 1\nmeasures = ["jacobian", "recovery"]')
    scenario = SCENARIO + "[[disturbance]]\nstart = 1.0\nstop = 1.5\nvelocity = [0.1, 0.3]\n"
    (tmp_path / "short.toml").write_text(scenario)
    (tmp_path / "spec.toml").write_text(text)
    spec = sweep.load_spec(tmp_path / "spec.toml")
    sweep.run_sweep(spec, tmp_path / "out", workers=1, progress=False)
    df = _rows(tmp_path / "out")
    assert {"jac_rel_error", "jac_sign_w", "recovery_rmse", "recovery_peak"} <= set(df.columns)
    assert df[df.controller == "backstepping"].jac_rel_error.isna().all()
    apid = df[df.controller == "adaptive-pid"]
    # With an input delay the command does not reach the robot within the step: the true
    # Jacobian is zero at every step and the measure is undefined (NaN), not a huge ratio.
    assert apid[apid["plant.delay_steps"] > 0].jac_rel_error.isna().all()
    j = int(apid[apid["plant.delay_steps"] == 0].job_id.iloc[0])
    point, s, c, r = spec.job(j)
    sc = spec.runs[point][s]
    assert sc.plant.delay_steps == 0
    run = simulate(sc, "adaptive-pid", spec.seeds[r])
    q = idf.jacobian_quality(run, idf.plant_jacobian(sc, run), every=measures.JACOBIAN_EVERY)
    x = q.rel_error[len(q.rel_error) // 2 :]  # the true Jacobian is never zero here
    assert np.all(np.isfinite(x)) and df.iloc[j].jac_rel_error == np.mean(x)
    w = (run.t >= 1.0) & (run.t < 1.0 + measures.RECOVERY_WINDOW)
    rec = np.sqrt(np.mean(np.sum((run.ref[w, :2] - run.q[w, :2]) ** 2, axis=1)))
    assert df.iloc[j].recovery_rmse == rec


def _raising(monkeypatch, err, controller="adaptive-pid", seed=1):
    """Runs of ``controller`` with ``seed`` raise ``err`` (serial engine: this process)."""
    import wmr.closedloop.sim

    real = wmr.closedloop.sim.simulate

    def flaky(sc, c, s, **kw):
        if c == controller and s == seed:
            raise err
        return real(sc, c, s, **kw)

    monkeypatch.setattr(wmr.closedloop.sim, "simulate", flaky)


def test_retry_errors_reruns_the_error_rows_once_their_cause_is_gone(tmp_path, monkeypatch,
                                                                    capsys):  # fmt: skip
    path = _spec(tmp_path)
    full, out = tmp_path / "full", tmp_path / "out"
    argv = ["sweep", str(path), "--out", str(out), "--workers", "1"]
    assert cli.main(["sweep", str(path), "--out", str(full), "--workers", "1"]) == 0
    with monkeypatch.context() as m:
        _raising(m, ValueError("a bad setting"))
        assert cli.main(argv) == 0
    assert set(_rows(out)[lambda d: d.status == "error"].job_id) == set(sweep.error_jobs(out))
    assert len(sweep.error_jobs(out)) == 4
    assert cli.main(argv) == 0 and len(sweep.error_jobs(out)) == 4  # resume: errors are rows
    capsys.readouterr()
    assert cli.main([*argv, "--retry-errors"]) == 0
    assert "done: 24/24 runs in the store (4 this time" in capsys.readouterr().out
    assert _rows(out).equals(_rows(full)) and not sweep.error_jobs(out)


def test_a_transient_error_that_persists_is_exit_1_one_line_and_resumes(tmp_path, monkeypatch,
                                                                        capsys):  # fmt: skip
    """An OSError on every attempt of one job: the batch is tried 1 + RETRIES times, then the
    command stops with one line (exit 1) after storing what finished (no error row); the same
    command resumes to the rows of an uninterrupted sweep."""
    from wmr.engine.faults import RETRIES

    path = _spec(tmp_path)
    out, full = tmp_path / "out", tmp_path / "full"
    argv = ["sweep", str(path), "--out", str(out), "--workers", "1", "--batch-seconds", "1e-9"]
    calls = []
    with monkeypatch.context() as m:
        import wmr.closedloop.sim

        real = wmr.closedloop.sim.simulate

        def failing(sc, c, s, **kw):
            if c == "adaptive-pid" and s == 1:
                calls.append(1)
                raise OSError(28, "No space left on device")
            return real(sc, c, s, **kw)

        m.setattr(wmr.closedloop.sim, "simulate", failing)
        capsys.readouterr()
        assert cli.main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("error: a batch of 1 run (wmr-sweep-") and "failed 3 times" in err, err
    assert "OSError: [Errno 28] No space left on device" in err and "resume" in err
    assert len(calls) == 1 + RETRIES
    kept = sweep.finished_jobs(out)
    assert kept == {0, 1, 2} and not sweep.error_jobs(out)  # job 3 is adaptive-pid, seed 1
    assert cli.main(argv) == 0
    sweep.run_sweep(sweep.load_spec(path), full, workers=1, progress=False)
    assert _rows(out).equals(_rows(full))
