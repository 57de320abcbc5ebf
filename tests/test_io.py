"""Atomic output: a failed write leaves the previous file intact and no temporary file behind."""

from __future__ import annotations

import csv
import json
import math
import os
import stat

import matplotlib.pyplot as plt
import pytest

from wmr import io


@pytest.fixture
def old_file(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text('{"old": true}\n')
    return path


def _assert_untouched(path):
    assert path.read_text() == '{"old": true}\n'
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary file left


def test_failed_rename_keeps_the_old_file(old_file, monkeypatch):
    def failing_replace(src, dst):
        raise OSError("disk on fire")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk on fire"):
        io.write_json(old_file, {"new": True})
    _assert_untouched(old_file)


def test_interrupt_during_write_keeps_the_old_file(old_file, monkeypatch):
    def interrupted_fsync(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupted_fsync)
    with pytest.raises(KeyboardInterrupt):
        io.atomic_write_text(old_file, "half")
    _assert_untouched(old_file)


def test_failing_row_generator_keeps_the_old_file(tmp_path):
    path = tmp_path / "trajectory.csv"
    path.write_text('{"old": true}\n')

    def rows():
        yield [0.0, 1.0]
        raise RuntimeError("simulation crashed")

    with pytest.raises(RuntimeError, match="simulation crashed"):
        io.write_csv(path, ["t", "x"], rows())
    _assert_untouched(path)


def test_unserialisable_json_keeps_the_old_file(old_file):
    with pytest.raises(ValueError):  # NaN is not JSON; the summary must use null
        io.write_json(old_file, {"rmse": math.nan})
    _assert_untouched(old_file)


def test_write_json_and_csv_round_trip(tmp_path):
    obj = {"scenario": "s", "seed": 3, "runs": [{"rmse": {"x": 0.1}, "diverged_at": None}]}
    io.write_json(tmp_path / "a.json", obj)
    assert json.loads((tmp_path / "a.json").read_text()) == obj
    values = [0.1, 1 / 3, 2.0**-40, 1e300, math.pi]
    io.write_csv(tmp_path / "a.csv", ["v", "label"], [[v, "row"] for v in values])
    with open(tmp_path / "a.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["v", "label"]
    assert [float(r[0]) for r in rows[1:]] == values  # repr precision: exact round trip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "a.json"]


def test_creates_missing_parent_folders(tmp_path):
    io.atomic_write_text(tmp_path / "a" / "b" / "c.txt", "x")
    assert (tmp_path / "a" / "b" / "c.txt").read_text() == "x"


def test_written_files_get_the_usual_permissions(tmp_path):
    """Atomic writes must not leave the 0600 mode of the temporary file on the result."""
    plain = tmp_path / "plain.txt"
    plain.write_text("x")  # what open() gives under the current umask
    written = io.atomic_write_text(tmp_path / "atomic.txt", "x")
    assert stat.S_IMODE(written.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode)


def test_save_figure_is_a_reproducible_png(tmp_path):
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    a = io.save_figure(fig, tmp_path / "a.png")
    b = io.save_figure(fig, tmp_path / "b.png")
    plt.close(fig)
    data = a.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    assert data == b.read_bytes()  # no timestamp or software metadata
