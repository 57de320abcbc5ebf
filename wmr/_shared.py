"""What the runs of a scenario share, built once per process (issue 25: set-up once, not per run).

:data:`SHARED` holds values computed from immutable parts of a scenario (its reference, plant,
filter settings, a controller's settings) and only read by the runs that use them: the reference
table and the plant table of ``wmr.closedloop.runsetup``, the read-only parameters of the
controllers' packs.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Callable

__all__ = ["Shared", "SHARED"]


class Shared:
    """What the runs of a scenario share, built once: ``get(kind, parts, extra, build)``
    returns ``build()`` for the scenario's ``parts`` (immutable objects: a ``ReferenceSpec``,
    ``Plant``, ...) and the hashable ``extra`` (``dt``, a name), computed on the first call and
    kept.

    Keyed by the parts' identity (each is kept alive beside its value, so an identity is never
    reused while its entry lives): a scenario and its ``dataclasses.replace`` copies share their
    unchanged parts.  At most ``size`` entries per kind, the least recently used dropped.  The
    values are read by the runs, never written (each run copies what it mutates)."""

    def __init__(self, size: int = 32):
        self.size = size
        self._tables: dict[str, OrderedDict] = {}
        self._lock = threading.Lock()

    def get(self, kind: str, parts: tuple, extra, build: Callable):
        key = (*map(id, parts), extra)
        with self._lock:
            table = self._tables.setdefault(kind, OrderedDict())
            hit = table.get(key)
            if hit is not None:
                table.move_to_end(key)
                return hit[1]
        value = build()
        with self._lock:
            table[key] = (parts, value)
            while len(table) > self.size:
                table.popitem(last=False)
        return value

    def clear(self) -> None:
        """Forget everything (tests; a process that changes the registry's rows in place)."""
        with self._lock:
            self._tables.clear()


#: The per-process store of scenario set-up (:class:`Shared`).
SHARED = Shared()
