"""The one shard store (``wmr.engine.store``): atomic shards, supersession by ``job_id``, shard
order, digests, stale stores set aside; and the digests of the sweeps' and the calibration's
stores covering every file their runs read."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow as pa
import pytest
from cases import SHORT_LEMNISCATE

from wmr import cli
from wmr import scenario as scn
from wmr.engine import store as st
from wmr.engine import sweep, sweeps

SCHEMA = pa.schema([("job_id", pa.int64()), ("level", pa.string()), ("x", pa.float64()),
                    ("status", pa.string())])  # fmt: skip


def _row(job_id, x, status="ok", level="a"):
    return {"job_id": job_id, "level": level, "x": x, "status": status}


def test_a_newer_shard_supersedes_an_older_row_of_the_same_job(tmp_path):
    s = st.ShardStore(tmp_path, SCHEMA)
    s.write([_row(0, 1.0), _row(1, float("nan"), "error"), _row(2, 3.0)])
    s.write([_row(1, 2.0)])
    t = s.read().to_pydict()
    # the survivors in shard order; job 1's row is the newer shard's
    assert t["job_id"] == [0, 2, 1] and t["x"] == [1.0, 3.0, 2.0] and t["status"] == ["ok"] * 3
    assert s.ids() == {0, 1, 2} and s.ids("error") == set()
    assert s.read(["x"]).column_names == ["x"]  # the id column is read, not returned
    s.write([_row(2, float("nan"), "error")])  # a newer error row supersedes an ok one too
    assert s.ids("error") == {2}


def test_shards_are_atomic_and_sort_after_earlier_ones_if_the_clock_steps_back(tmp_path,
                                                                             monkeypatch):
    s = st.ShardStore(tmp_path, SCHEMA)
    first = s.write([_row(0, 1.0)])
    monkeypatch.setattr(st.time, "time_ns", lambda: 1_000)  # a clock set back
    second = st.ShardStore(tmp_path, SCHEMA).write([_row(0, 2.0)])  # a later invocation
    assert first.name < second.name and s.shards() == [first, second]
    assert s.read().column("x").to_pylist() == [2.0]
    assert not list((tmp_path / "rows").glob(".*"))  # no temporary file left
    assert s.write([]) is None and len(s.shards()) == 2


def test_a_text_column_stores_a_non_text_value_as_its_str(tmp_path):
    s = st.ShardStore(tmp_path, SCHEMA)
    s.write([_row(0, 1.0, level=(5.0, 1.0)), _row(1, 1.0, level=None)])
    assert s.read().column("level").to_pylist() == ["(5.0, 1.0)", None]


def test_open_resumes_its_digests_and_sets_a_stale_store_aside(tmp_path):
    said = []
    folder = tmp_path / "study"
    s = st.ShardStore.open(folder, SCHEMA, {"digest": "1"}, kind="k", say=said.append, n=3)
    assert s.manifest == {"n": 3, "kind": "k", "digest": "1"}
    s.write([_row(0, 1.0)])
    again = st.ShardStore.open(folder, SCHEMA, {"digest": "1"}, kind="k", say=said.append)
    assert again.ids() == {0} and said == []
    fresh = st.ShardStore.open(folder, SCHEMA, {"digest": "2"}, kind="k", say=said.append)
    assert fresh.ids() == set() and fresh.manifest["digest"] == "2"
    (aside,) = tmp_path.glob("study.stale-*")
    assert len(said) == 1 and "\n" not in said[0] and aside.name in said[0]
    assert "digest 1 != 2" in said[0] and st.ShardStore(aside).ids() == {0}  # kept, not lost
    other = tmp_path / "other"  # a folder holding something that is no store of this kind
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    st.ShardStore.open(other, SCHEMA, {"digest": "2"}, kind="k", say=said.append)
    assert "holds no k" in said[-1]
    assert (next(tmp_path.glob("other.stale-*")) / "notes.txt").read_text() == "mine"


# ---------------------------------------------------------------------------------------------
# The sweep's store: its digests cover the spec's files and wmr's code

SPEC = """\
name = "d"
scenarios = ["short.toml"]
controllers = ["pid"]
seeds = 2
[design]
kind = "grid"
[factors]
"plant.v_gain" = [0.8, 1.0]
"""


def _spec(folder: Path, spec: str = SPEC, scenario: str | None = None) -> Path:
    (folder / "short.toml").write_text(scenario or SHORT_LEMNISCATE.format(duration=1.0))
    (folder / "spec.toml").write_text(spec)
    return folder / "spec.toml"


def test_the_spec_digest_covers_its_scenario_files_and_the_files_they_name(tmp_path):
    base = sweep.load_spec(_spec(tmp_path)).digest
    assert sweep.load_spec(_spec(tmp_path)).digest == base  # the same files: the same digest
    edited = SHORT_LEMNISCATE.format(duration=1.0).replace("size = 2.0", "size = 2.5")
    assert sweep.load_spec(_spec(tmp_path, scenario=edited)).digest != base
    # a built-in waypoint scenario copied beside the spec, with its table of points
    waypoints = scn.builtin("waypoints-lane-change")
    (tmp_path / waypoints.name).write_text(waypoints.read_text())
    table = waypoints.parent / "lane-change.csv"
    (tmp_path / table.name).write_text(table.read_text())
    spec = SPEC.replace('"short.toml"', f'"{waypoints.name}"')
    (tmp_path / "w.toml").write_text(spec)
    before = sweep.load_spec(tmp_path / "w.toml").digest
    lines = table.read_text().splitlines()
    t, x, y = lines[-1].split(",")
    (tmp_path / table.name).write_text("\n".join([*lines[:-1], f"{t},{float(x) + 0.5},{y}"]))
    assert sweep.load_spec(tmp_path / "w.toml").digest != before


def test_a_sweep_store_of_other_code_is_set_aside_and_rebuilt(tmp_path, monkeypatch, capsys):
    path = _spec(tmp_path)
    out = tmp_path / "out"
    real = sweeps.code_digest
    monkeypatch.setattr(sweeps, "code_digest", lambda: "an-older-wmr")
    assert cli.main(["sweep", str(path), "--out", str(out), "--workers", "1"]) == 0
    monkeypatch.setattr(sweeps, "code_digest", real)
    capsys.readouterr()
    assert cli.main(["sweep", str(path), "--out", str(out), "--workers", "1"]) == 0
    err = capsys.readouterr().err
    (aside,) = tmp_path.glob("out.stale-*")
    note = [line for line in err.splitlines() if "set aside" in line]
    assert len(note) == 1 and aside.name in note[0] and "code_digest an-older-wmr" in note[0]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["code_digest"] == real() and manifest["runs_this_time"] == 4
    assert manifest["complete"] and json.loads((aside / "manifest.json").read_text())["complete"]


def test_a_study_store_of_another_spec_is_set_aside_not_refused(tmp_path, capsys):
    """The studies' mode (``stale="set-aside"``, the regimes' stores): a changed design gives a
    new store, with a message, where ``wmr sweep`` would refuse (exit 2)."""
    out = tmp_path / "out"
    sweeps.run_sweep(sweep.load_spec(_spec(tmp_path)), out, workers=1, progress=False,
                     stale="set-aside")  # fmt: skip
    other = sweep.load_spec(_spec(tmp_path, SPEC.replace("seeds = 2", "seeds = 3")))
    with pytest.raises(sweep.SweepError, match="not empty"):
        sweeps.run_sweep(other, out, workers=1, progress=False)
    capsys.readouterr()
    m = sweeps.run_sweep(other, out, workers=1, progress=False, stale="set-aside")
    assert m["complete"] and m["jobs"] == 6 and m["spec_digest"] == other.digest
    assert "spec_digest" in capsys.readouterr().err and len(list(tmp_path.glob("out.stale-*"))) == 1
