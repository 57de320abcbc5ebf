"""The numba cache folder: keyed by the package source, old versions pruned."""

from __future__ import annotations

import os

from wmr import _jit


def test_prune_keeps_the_current_and_the_newest_old_caches(tmp_path):
    dirs = [tmp_path / f"numba-{i:02d}" for i in range(7)]
    for i, d in enumerate(dirs):
        d.mkdir()
        (d / "index.nbi").write_text("x")
        os.utime(d, (1_000_000 + i, 1_000_000 + i))  # numba-06 is the newest
    (tmp_path / "other").mkdir()  # not a numba cache: never touched
    current = dirs[0]  # the oldest by mtime, but it is the one in use
    _jit.prune_old_caches(str(current), keep=3)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ["numba-00", "numba-04", "numba-05", "numba-06", "other"]


def test_cache_dir_changes_with_any_source_file_and_only_with_sources(tmp_path, monkeypatch):
    """numba checks only a function's own file, so the folder must change when *any* module
    changes (a callee edited in another file), and stay put otherwise."""
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "a.py").write_text("x = 1\n")
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    first = _jit._cache_dir(pkg)
    assert first == str(pkg / "__pycache__" / os.path.basename(first))
    assert os.path.basename(first).startswith("numba-")
    (pkg / "notes.txt").write_text("not source")  # non-Python files do not count
    assert _jit._cache_dir(pkg) == first
    (pkg / "sub" / "b.py").write_text("y = 3\n")  # a callee in another module changed
    second = _jit._cache_dir(pkg)
    assert second != first
    (pkg / "sub" / "b.py").write_text("y = 2\n")
    assert _jit._cache_dir(pkg) == first  # same sources, same folder (deterministic)


def test_warm_compiles_what_a_later_run_loads(tmp_path):
    """``wmr cache --warm`` for one controller, into an empty cache: a later process's run of
    a shipped scenario on that controller loads every kernel it needs from the cache and
    compiles none (numba's cache log says so)."""
    import subprocess
    import sys

    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "NUMBA_DEBUG_CACHE": "1"}
    warm = subprocess.run([sys.executable, "-m", "wmr.cli", "cache", "--warm", "--controller",
                           "backstepping", "--jobs", "2"], env=env, capture_output=True,
                          text=True, check=True)  # fmt: skip
    assert "2 kernel(s) ready" in warm.stdout, warm.stdout
    assert "data saved" in warm.stdout + warm.stderr
    run = subprocess.run([sys.executable, "-c", (
        "from dataclasses import replace; from wmr import scenario as s; "
        "from wmr.closedloop.sim import simulate; "
        "sc = s.load(s.builtin('lemniscate-slip')); "
        "simulate(replace(sc, duration=10 * sc.dt), 'backstepping', 3)")],
        env=env, capture_output=True, text=True, check=True)  # fmt: skip
    log = run.stdout + run.stderr
    assert "data loaded" in log and "data saved" not in log, log[-2000:]
