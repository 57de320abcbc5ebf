"""Transient failures and errors on the serial engine (``wmr.engine.faults``): what is retried,
what propagates, what becomes an error row.  The Dask engine's are in tests/test_engine.py."""

from __future__ import annotations

import functools

import faults
import pytest
from cases import SHORT_LEMNISCATE

from wmr import scenario as scn
from wmr.engine import faults as ef
from wmr.engine import study
from wmr.engine.jobs import job_row

SC = scn.loads(SHORT_LEMNISCATE.format(duration=6.0))  # past the transient: no NaN in the rows
JOBS = [study.Job(SC, "pid", s, job_id=s) for s in range(4)]


def _simulate_failing(monkeypatch, errors: dict):
    """``wmr.closedloop.sim.simulate`` raises ``errors[seed].pop(0)`` while that list lasts; the
    calls of each seed are counted."""
    import wmr.closedloop.sim

    real, calls = wmr.closedloop.sim.simulate, {}

    def flaky(sc, controller, seed, **kw):
        calls[seed] = calls.get(seed, 0) + 1
        if errors.get(seed):
            raise errors[seed].pop(0)
        return real(sc, controller, seed, **kw)

    monkeypatch.setattr(wmr.closedloop.sim, "simulate", flaky)
    return calls


def test_which_errors_are_transient():
    from distributed import KilledWorker
    from distributed.comm.core import CommClosedError

    for err in (MemoryError(), OSError(5, "io"), TimeoutError(), CommClosedError("gone"),
                KilledWorker("k", None, 3), FileNotFoundError("f")):  # fmt: skip
        assert ef.is_transient(err), err
    for err in (ValueError(), FloatingPointError(), KeyError("k"), RuntimeError()):
        assert not ef.is_transient(err), err


def test_a_transient_error_is_retried_and_the_rows_are_the_clean_ones(monkeypatch):
    clean = study.run_jobs(JOBS, 1, progress=False)
    calls = _simulate_failing(monkeypatch, {1: [MemoryError()], 2: [OSError(5, "io")] * 2})
    assert study.run_jobs(JOBS, 1, progress=False, batch_seconds=0.0) == clean
    assert calls == {0: 1, 1: 2, 2: 3, 3: 1}


def test_another_error_of_run_jobs_propagates_at_once(monkeypatch):
    calls = _simulate_failing(monkeypatch, {2: [ValueError("bad")]})
    with pytest.raises(ValueError, match="bad"):
        study.run_jobs(JOBS, 1, progress=False, batch_seconds=0.0)
    assert calls[2] == 1  # not retried


def test_a_transient_error_is_never_an_error_row_and_retries_are_bounded(monkeypatch, tmp_path):
    """job_row makes an error row of a ValueError but lets an OSError through: it is retried,
    and after 1 + RETRIES failures the call stops with RetriesExhausted naming it."""
    rows = study.run_jobs(JOBS, 1, progress=False, fn=job_row)
    cause = tmp_path / "cause"
    cause.write_text("x")
    bad = study.run_jobs(JOBS, 1, progress=False, fn=functools.partial(
        faults.value_error_while, str(cause), frozenset({3})))  # fmt: skip
    assert [r["status"] for r in bad] == ["ok", "ok", "ok", "error"] and bad[:3] == rows[:3]
    assert bad[3]["error"] == "ValueError: injected: job 3 cannot run"
    once = functools.partial(faults.oserror_once, str(tmp_path), frozenset({0, 3}))
    assert study.run_jobs(JOBS, 1, progress=False, fn=once) == rows
    always = functools.partial(faults.oserror_always, frozenset({2}))
    with pytest.raises(ef.RetriesExhausted, match=r"failed 3 times.*OSError: \[Errno 28\]"):
        study.run_jobs(JOBS, 1, progress=False, fn=always, batch_seconds=0.0)
