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
    _jit._prune_old_caches(str(current), keep=3)
    left = sorted(p.name for p in tmp_path.iterdir())
    assert left == ["numba-00", "numba-04", "numba-05", "numba-06", "other"]


def test_cache_dir_is_named_by_the_source_hash():
    name = os.path.basename(_jit.CACHE_DIR)
    if not os.environ.get("NUMBA_CACHE_DIR"):
        assert name.startswith("numba-") and len(name) == len("numba-") + 16
        assert os.path.dirname(_jit.CACHE_DIR).endswith(os.path.join("wmr", "__pycache__"))
