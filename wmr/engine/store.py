"""The one shard store: a folder of immutable Parquet shards of rows, its manifest and digests.

A store is a folder:

- ``manifest.json``: the store's ``kind``, the digests of every input its runs read (named by
  the caller: a sweep's spec and scenario files and wmr's code, the calibration's sources and
  shipped scenarios) and whatever counts and timings the caller adds;
- ``rows/part-<ns>-<pid>.parquet``: immutable shards, each written to a temporary file, synced
  and renamed (a reader never sees half a shard; an interrupted writer loses only its
  buffer).  A shard's name sorts after every earlier one, and when the store is read a newer
  shard's row supersedes an older one of the same ``job_id`` (``wmr sweep --retry-errors``
  reruns error rows that way; shards are never rewritten).

:meth:`ShardStore.open` resumes a store whose digests are those of the runs about to be made;
a store of other digests (or a folder that is no such store) is stale: it is **set aside**
(renamed ``<folder>.stale-<time>``, one line on stderr) and rebuilt, never reused and never a
failure.  (``wmr sweep`` refuses a different spec in a non-empty folder before opening it:
exit 2, DESIGN §3.5.)
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

__all__ = ["ShardStore", "set_aside", "digest_files", "read_manifest", "stale_reason",
           "studies_folder", "MANIFEST", "ROWS", "STALE"]  # fmt: skip

MANIFEST = "manifest.json"
ROWS = "rows"
#: Suffix of a stale store set aside: ``<folder>.stale-<UTC time>``.
STALE = ".stale-"


def studies_folder() -> Path:
    """Where the studies keep their stores: ``$WMR_STORES``, default ``~/.cache/wmr/stores``
    (one folder per study, e.g. ``regimes/``, ``calibration/``; a stale one is set aside)."""
    return Path(os.environ.get("WMR_STORES", Path.home() / ".cache" / "wmr" / "stores"))


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def digest_files(paths: Iterable[str | Path], extra: str = "") -> str:
    """A hash (16 hex digits) of the files ``paths`` (their names and bytes, in the given
    order) and ``extra``."""
    h = hashlib.sha256()
    for p in paths:
        p = Path(p)
        h.update(p.name.encode() + b"\0" + p.read_bytes() + b"\0")
    h.update(extra.encode())
    return h.hexdigest()[:16]


def read_manifest(folder: str | Path) -> dict | None:
    """The manifest of the store at ``folder`` (None if there is none or it is unreadable)."""
    try:
        data = json.loads((Path(folder) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def stale_reason(folder: str | Path, kind: str, digests: Mapping[str, str]) -> str | None:
    """Why the folder cannot be resumed as a ``kind`` store of ``digests`` (None: it can, or it
    is absent or empty)."""
    folder = Path(folder)
    if not folder.exists() or (folder.is_dir() and not any(folder.iterdir())):
        return None
    manifest = read_manifest(folder) if folder.is_dir() else None
    if manifest is None or manifest.get("kind", kind) != kind:
        return f"holds no {kind}"
    for name, value in digests.items():
        if manifest.get(name) != value:
            return f"holds runs of other inputs ({name} {manifest.get(name)} != {value})"
    return None


def set_aside(folder: str | Path, reason: str, say: Callable[[str], None] = _say) -> Path:
    """Rename ``folder`` to ``<folder>.stale-<UTC time>`` (a free name) and say so in one line;
    returns the new path."""
    folder = Path(folder)
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    target = folder.with_name(f"{folder.name}{STALE}{stamp}")
    n = 1
    while target.exists():
        n += 1
        target = folder.with_name(f"{folder.name}{STALE}{stamp}-{n}")
    os.replace(folder, target)
    say(f"wmr: {folder} {reason}: set aside as {target.name}; rebuilding")
    return target


class ShardStore:
    """The store at ``folder`` (see the module).

    Parameters
    ----------
    folder : path
        The store's folder.
    schema : pyarrow.Schema, optional
        The rows' schema (needed to write; reading takes the shards' own).
    id_column : str
        The column naming a row's job (a newer row of the same value supersedes an older).
    """

    def __init__(self, folder: str | Path, schema=None, id_column: str = "job_id"):
        self.folder, self.schema, self.id_column = Path(folder), schema, id_column
        self._last = max((self._stamp(p) for p in self.shards()), default=0)

    @classmethod
    def open(cls, folder: str | Path, schema, digests: Mapping[str, str], *, kind: str,
             say: Callable[[str], None] = _say, **manifest: Any) -> ShardStore:  # fmt: skip
        """The ``kind`` store at ``folder`` for runs whose inputs have ``digests``, resumed if
        it holds one of these digests, else (a stale store, or a folder that is none) set aside
        and created afresh, its manifest holding ``kind``, ``digests`` and ``manifest``."""
        folder = Path(folder)
        reason = stale_reason(folder, kind, digests)
        if reason:
            set_aside(folder, reason, say)
        store = cls(folder, schema)
        (folder / ROWS).mkdir(parents=True, exist_ok=True)
        if read_manifest(folder) is None:
            store.write_manifest({**manifest, "kind": kind, **digests})
        return store

    # -- the manifest ----------------------------------------------------------------------------
    @property
    def manifest(self) -> dict:
        """The stored manifest (empty if none)."""
        return read_manifest(self.folder) or {}

    def write_manifest(self, manifest: Mapping[str, Any]) -> None:
        """Replace the manifest (atomically)."""
        from wmr.io import write_json

        write_json(self.folder / MANIFEST, dict(manifest))

    # -- shards ----------------------------------------------------------------------------------
    def shards(self) -> list[Path]:
        """The shards, oldest first."""
        return sorted((self.folder / ROWS).glob("part-*.parquet"))

    @staticmethod
    def _stamp(path: Path) -> int:
        try:
            return int(path.name.split("-")[1])
        except (IndexError, ValueError):
            return 0

    def table(self, rows: Sequence[Mapping[str, Any]]):
        """``rows`` (dicts by column name) as a table of the store's schema; a value of a text
        column that is not text (a factor's level) is written as ``str(value)``."""
        import pyarrow as pa

        cols = {}
        for f in self.schema:
            values = [r.get(f.name) for r in rows]
            if f.type == pa.string():
                values = [v if v is None or isinstance(v, str) else str(v) for v in values]
            cols[f.name] = values
        return pa.table(cols, schema=self.schema)

    def write(self, rows: Sequence[Mapping[str, Any]]) -> Path | None:
        """Write ``rows`` as a new immutable shard, atomically (a temporary file, synced, then a
        rename: a reader never sees a half-written shard); its name sorts after every earlier
        shard's.  Nothing for no rows."""
        import pyarrow.parquet as pq

        if not rows:
            return None
        folder = self.folder / ROWS
        folder.mkdir(parents=True, exist_ok=True)
        self._last = max(time.time_ns(), self._last + 1)
        name = f"part-{self._last:020d}-{os.getpid()}.parquet"
        tmp = folder / f".{name}.tmp"
        pq.write_table(self.table(rows), tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, folder / name)
        return folder / name

    def read(self, columns: Sequence[str] | None = None):
        """Every current row as a ``pyarrow.Table`` (None if the store has none): the shards in
        order, a row dropped when a newer shard has one of the same ``job_id``."""
        import pyarrow as pa
        import pyarrow.parquet as pq

        shards = self.shards()
        if not shards:
            return None
        want = None if columns is None else list(dict.fromkeys([*columns, self.id_column]))
        table = pa.concat_tables([pq.read_table(p, columns=want) for p in shards])
        ids = table.column(self.id_column).to_pylist()
        last = {v: i for i, v in enumerate(ids)}
        if len(last) < len(ids):
            table = table.take(sorted(last.values()))
        return table if columns is None else table.select(list(columns))

    def ids(self, status: str | None = None) -> set:
        """The ``job_id`` of every current row (only those of ``status``, if given)."""
        table = self.read([self.id_column] + (["status"] if status else []))
        if table is None:
            return set()
        ids = table.column(self.id_column).to_pylist()
        if status is None:
            return set(ids)
        return {i for i, s in zip(ids, table.column("status").to_pylist(), strict=True)
                if s == status}  # fmt: skip
