"""The studies that produce ``paper/`` and their registry (DESIGN §3.6).

Each study is a module of this package with ``STEM``, ``TITLE``, ``run``, ``check`` and ``render``
(``analysis.common`` says what each does).  :data:`STUDIES` is the one list of them, in report
order: ``wmr analyze`` offers these names, ``wmr reproduce`` runs them in this order, the report
renders their sections in this order.
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = ["STUDIES", "get"]

#: The registered studies, in the order ``wmr reproduce`` runs them and the report shows them.
STUDIES: tuple[str, ...] = (
    "reproduction",
    "jacobians",
    "margins",
    "boundedness",
    "robots",
    "regimes",
    "estimates",
    "calibration",
    "performance",
    "reliability",
)


def get(name: str) -> ModuleType:
    """The study module ``name`` (imported on first use); ``KeyError`` for an unknown one."""
    if name not in STUDIES:
        raise KeyError(f"unknown study {name!r}; known: {', '.join(STUDIES)}")
    return importlib.import_module(f"{__name__}.{name}")
