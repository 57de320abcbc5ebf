"""The run engine on real Dask (issues 13, 19): a LocalCluster, and a scheduler plus worker
processes started as separate programs on 127.0.0.1; faults: a worker killed mid-sweep, the
driver killed with SIGKILL, a run that fails with a transient error once or always, a worker
process that dies inside a job, a run that raises (an error row) and ``--retry-errors``.  Every
time the rows equal the serial engine's."""

from __future__ import annotations

import functools
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import faults
import pytest
from cases import SHORT_LEMNISCATE

from wmr import scenario as scn
from wmr.engine import study, sweep
from wmr.engine.faults import RETRIES, RetriesExhausted
from wmr.engine.jobs import job_row

SPEC = """\
name = "engine"
scenarios = ["short.toml"]
controllers = ["iapid-nn-dekf", "pid"]
seeds = 3

[design]
kind = "grid"

[factors]
"plant.v_gain" = [0.7, 1.0, 1.3]
"estimator.process_std" = [0.003, 0.01]
"""
SCENARIO = SHORT_LEMNISCATE
PY = sys.executable
#: How long a test waits for an engine to come up or a sweep to end [s].
TIMEOUT = 240


def _spec(folder: Path, duration: float = 2.0) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "short.toml").write_text(SCENARIO.format(duration=duration))
    (folder / "spec.toml").write_text(SPEC)
    return folder / "spec.toml"


def _rows(out):
    df = sweep.read_rows(out).to_pandas()
    assert not df.job_id.duplicated().any(), "a job ran twice"
    return df.sort_values("job_id").reset_index(drop=True)


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    """The serial engine's rows of the short spec (the reference)."""
    folder = tmp_path_factory.mktemp("serial")
    spec = sweep.load_spec(_spec(folder))
    sweep.run_sweep(spec, folder / "out", workers=1, progress=False)
    return _rows(folder / "out")


def test_local_cluster_gives_the_serial_rows(serial, tmp_path):
    spec = sweep.load_spec(_spec(tmp_path))
    m = sweep.run_sweep(spec, tmp_path / "out", workers=2, progress=False, batch_seconds=0.001)
    assert m["engine"].startswith("dask LocalCluster") and m["workers"] == 2 and m["batches"] > 4
    assert _rows(tmp_path / "out").equals(serial)


def _malloc_trim():
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


def _profiling():
    import dask

    return dask.config.get("distributed.worker.profile.enabled")


def test_local_cluster_workers_keep_glibc_malloc_defaults_and_run_quiet():
    """Dask's nanny would set MALLOC_TRIM_THRESHOLD_ in its workers (numpy-heavy set-up 3-4x
    slower there); the engine's LocalCluster leaves it unset, and does not set it here either;
    its workers run without the statistical profiler (study.LOCAL_CLUSTER_CONFIG)."""
    before = _malloc_trim()
    with study.engine(2) as eng:
        assert set(eng.client.run(_malloc_trim).values()) == {None}
        assert set(eng.client.run(_profiling).values()) == {False}
    assert _malloc_trim() == before


def test_run_jobs_on_a_local_cluster_equals_serial():
    sc = scn.loads(SCENARIO.format(duration=6.0))  # past the transient: no NaN in the rows
    jobs = [study.Job(sc, c, s) for c in ("pid", "adaptive-nn") for s in range(5)]
    assert study.run_jobs(jobs, 2, progress=False) == study.run_jobs(jobs, 1, progress=False)


def _shards(out: Path) -> int:
    return len(list((out / "rows").glob("part-*.parquet")))


def _wait(ready, timeout: float = TIMEOUT):
    t0 = time.monotonic()
    while not ready():
        if time.monotonic() - t0 > timeout:
            raise TimeoutError("not ready in time")
        time.sleep(0.1)


@pytest.fixture
def cluster(tmp_path):
    """A scheduler and two worker processes started as separate programs on 127.0.0.1."""
    with study.LoopbackCluster(tmp_path / "cluster", workers=2, timeout=TIMEOUT) as c:
        yield c


def test_scheduler_and_worker_processes_give_the_serial_rows(serial, tmp_path, cluster):
    spec = sweep.load_spec(_spec(tmp_path))
    m = sweep.run_sweep(spec, tmp_path / "out", scheduler=cluster.address, progress=False,
                        batch_seconds=0.001)  # fmt: skip
    assert m["engine"] == f"dask scheduler {cluster.address}" and m["workers"] == 2
    assert _rows(tmp_path / "out").equals(serial)


def test_a_worker_killed_mid_sweep_loses_no_row(tmp_path, cluster):
    """The driver (``wmr sweep --scheduler``) as a program; one worker is killed once rows are
    flowing: its batch is run again elsewhere; every row is there once, equal to the serial."""
    spec_path = _spec(tmp_path / "long", duration=20.0)  # runs of 2,000 steps: seconds of work
    out = tmp_path / "out"
    driver = subprocess.Popen(
        [PY, "-m", "wmr.cli", "sweep", str(spec_path), "--out", str(out), "--scheduler",
         cluster.address, "--batch-seconds", "0.3", "--flush-seconds", "0.2"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip
    _wait(lambda: _shards(out) >= 1 or driver.poll() is not None)
    assert driver.poll() is None, driver.communicate()
    cluster.workers[0].kill()
    stdout, stderr = driver.communicate(timeout=TIMEOUT)
    assert driver.returncode == 0, stderr.decode()
    spec = sweep.load_spec(spec_path)
    reference = tmp_path / "reference"
    sweep.run_sweep(spec, reference, workers=1, progress=False)
    assert _rows(out).equals(_rows(reference))


def test_sigkill_of_the_driver_then_rerun_resumes_to_the_same_rows(serial, tmp_path):
    """``wmr sweep`` on a LocalCluster, killed with SIGKILL (with its workers) once a shard is
    written; the same command again completes the store: the rows of an uninterrupted sweep,
    none twice."""
    spec_path = _spec(tmp_path)
    out = tmp_path / "out"
    argv = [PY, "-m", "wmr.cli", "sweep", str(spec_path), "--out", str(out), "--workers", "2",
            "--batch-seconds", "0.02", "--flush-seconds", "0.01"]  # fmt: skip
    first = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True)  # fmt: skip
    _wait(lambda: _shards(out) >= 1 or first.poll() is not None)
    os.killpg(first.pid, signal.SIGKILL)
    first.wait(timeout=30)
    killed_with = len(sweep.finished_jobs(out))
    done = subprocess.run(argv, capture_output=True, text=True, timeout=TIMEOUT)
    assert done.returncode == 0, done.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["complete"] and manifest["runs_this_time"] == manifest["jobs"] - killed_with
    assert _rows(out).equals(serial)


# ---------------------------------------------------------------------------------------------
# Transient failures and error rows on a LocalCluster of worker processes (``tests/faults.py``:
# the run itself raises, in the worker, for the chosen jobs)


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    """One LocalCluster of 2 worker processes for the fault tests, and its spec folder."""
    folder = tmp_path_factory.mktemp("faults")
    _spec(folder)
    with study.engine(2) as eng:
        yield eng, folder


def _sweep(local, out, fn, **kw):
    """``run_sweep`` of the short spec on the module's cluster (left running), a job per
    batch."""
    eng, folder = local
    return sweep.run_sweep(sweep.load_spec(folder / "spec.toml"), out, eng=eng, progress=False,
                           batch_seconds=0.001, fn=fn, **kw)  # fmt: skip


def test_a_transient_error_is_retried_and_never_a_row(serial, local, tmp_path):
    """An OSError raised by a run on its first attempt (jobs 3 and 20): its batch runs again
    and the rows are the serial engine's, none an error."""
    fn = functools.partial(faults.oserror_once, str(tmp_path), frozenset({3, 20}))
    m = _sweep(local, tmp_path / "out", fn)
    rows = _rows(tmp_path / "out")
    assert (rows.status == "ok").all() and m["errors"] == 0 and m["retried_batches"] == 2
    assert rows.equals(serial)


def test_a_worker_killed_inside_a_job_is_retried_not_an_error(serial, local,
                                                              tmp_path):  # fmt: skip
    """The worker process dies (os._exit) on the first attempt of job 7: Dask reschedules the
    batch on a live worker; the row is the serial one, not an error."""
    fn = functools.partial(faults.exit_once, str(tmp_path), frozenset({7}))
    m = _sweep(local, tmp_path / "out", fn)
    assert (tmp_path / "attempted-7").exists()  # it did die once
    assert m["errors"] == 0 and _rows(tmp_path / "out").equals(serial)


def test_a_raising_run_is_an_error_row_and_retry_errors_replaces_it(serial, local,
                                                                    tmp_path):  # fmt: skip
    """A ValueError raised by the runs of jobs 2 and 31 is an error row each (the sweep goes
    on, nothing retried); once its cause is gone, ``retry_errors`` runs those two only and their
    new rows supersede the error rows: the store reads as the serial sweep."""
    cause = tmp_path / "cause"
    cause.write_text("broken")
    fn = functools.partial(faults.value_error_while, str(cause), frozenset({2, 31}))
    out = tmp_path / "out"
    m = _sweep(local, out, fn)
    rows = _rows(out)
    bad = rows[rows.status == "error"]
    assert list(bad.job_id) == [2, 31] and m["errors"] == 2 and m["retried_batches"] == 0
    assert bad.error.str.startswith("ValueError: injected").all() and bad.rmse_x.isna().all()
    ok = rows.status == "ok"
    assert rows[ok].equals(serial[ok])
    again = _sweep(local, out, fn)  # the cause is still there: nothing is rerun
    assert again["runs_this_time"] == 0 and again["errors"] == 2
    cause.unlink()
    shards = len(list((out / "rows").glob("part-*.parquet")))
    fixed = _sweep(local, out, fn, retry_errors=True)
    assert fixed["runs_this_time"] == 2 and fixed["retried_errors"] == 2 and fixed["errors"] == 0
    assert len(list((out / "rows").glob("part-*.parquet"))) > shards  # old shards untouched
    assert _rows(out).equals(serial)


def test_when_the_retries_run_out_the_sweep_stops_and_resumes(serial, local,
                                                              tmp_path):  # fmt: skip
    """Job 30 fails with an OSError on every attempt: after 1 + RETRIES attempts the sweep
    stops (RetriesExhausted, naming the error); the rows that finished are stored, none of them
    an error and none for job 30; the same sweep then resumes to the serial rows."""
    fn = functools.partial(faults.oserror_always, frozenset({30}))
    out = tmp_path / "out"
    with pytest.raises(RetriesExhausted, match=f"failed {1 + RETRIES} times .*OSError.*no space"):
        _sweep(local, out, fn)
    kept = sweep.finished_jobs(out)
    assert 30 not in kept and not sweep.error_jobs(out)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["done"] == len(kept) and not manifest["complete"]
    m = _sweep(local, out, job_row)
    assert m["runs_this_time"] == 36 - len(kept) and m["complete"]
    assert _rows(out).equals(serial)
