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
