"""What every study shares: its files, number formats, Markdown pieces and its command line.

A study (DESIGN §3.6) is a module of ``analysis/`` with

- ``STEM`` and ``TITLE``;
- ``run(out, *, quick=False, workers=None) -> record``: computes, then writes
  ``results/STEM.json`` (:func:`write_record`), ``tables/STEM.md`` (:func:`write_table`) and
  ``figures/STEM_*.png`` (:func:`save_figure`) under ``out``, and returns the record (the JSON);
- ``check(record)``: asserts its headline claims (raises ``AssertionError`` naming the claim);
- ``render(record) -> str``: its section of the report, every sentence generated from the record;
- at its end ``if __name__ == "__main__": sys.exit(common.main(sys.modules[__name__]))``, so
  ``python -m analysis.STEM [--out DIR] [--quick] [--workers N]`` runs it alone, as
  ``wmr analyze STEM`` does.

One registry (``analysis/__init__.py``) lists the studies; the CLI and the report read it.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

from wmr import io

__all__ = [
    "fmt",
    "md_table",
    "section",
    "figure_links",
    "write_record",
    "load_record",
    "write_table",
    "save_figure",
    "run_and_check",
    "main",
]


def fmt(x, digits: int = 4) -> str:
    """A number as the report prints it: ``—`` for None, fixed point between 1e-3 and 1e4 (and
    for 0), scientific otherwise; booleans as yes/no, integers and strings as they are."""
    if x is None:
        return "—"
    if isinstance(x, str):
        return x
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return str(x)
    if x == 0 or (1e-3 <= abs(x) < 1e4):
        return f"{x:.{digits}f}"
    if not math.isfinite(x):
        return str(x)
    return f"{x:.3e}"


def md_table(header: Sequence[str], rows: Iterable[Sequence]) -> list[str]:
    """A Markdown table (lines); cells are used as they are (format them first)."""
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def figure_links(names: Iterable[str]) -> list[str]:
    """Markdown image links to ``figures/<name>`` (with a blank line after, if any)."""
    links = [f"![{n}](figures/{n})" for n in names]
    return links + [""] if links else []


def section(title: str, notes: str | Sequence[str] | None = None, table: str = "",
            figures: Iterable[str] = ()) -> str:  # fmt: skip
    """A report section: ``## title``, the notes (a paragraph or a bullet list), the table
    (Markdown) and the figure links."""
    lines = [f"## {title}", ""]
    if isinstance(notes, str):
        lines += [notes, ""]
    elif notes:
        lines += [f"- {n}" for n in notes] + [""]
    if table:
        lines += table.rstrip().splitlines() + [""]
    lines += figure_links(figures)
    return "\n".join(lines)


def write_record(out: str | Path, stem: str, record: dict) -> Path:
    """Write ``out/results/<stem>.json`` atomically."""
    return io.write_json(Path(out) / "results" / f"{stem}.json", record)


def load_record(out: str | Path, stem: str) -> dict | None:
    """The stored record ``out/results/<stem>.json``, or None if there is none."""
    path = Path(out) / "results" / f"{stem}.json"
    return json.loads(path.read_text()) if path.exists() else None


def write_table(out: str | Path, stem: str, text: str) -> Path:
    """Write ``out/tables/<stem>.md`` atomically."""
    return io.atomic_write_text(Path(out) / "tables" / f"{stem}.md", text)


def save_figure(out: str | Path, name: str, fig) -> str:
    """Save ``fig`` as ``out/figures/<name>`` (reproducible PNG bytes), close it, return
    ``name``.  Name figures ``<STEM>_<what>.png``."""
    import matplotlib.pyplot as plt

    io.save_figure(fig, Path(out) / "figures" / name)
    plt.close(fig)
    return name


def run_and_check(study, out: str | Path, *, quick: bool = False, workers: int | None = None,
                  **options) -> dict:  # fmt: skip
    """``study.run(out, ...)`` then ``study.check(record)``; returns the record."""
    record = study.run(out, quick=quick, workers=workers, **options)
    study.check(record)
    return record


def _parser(study) -> argparse.ArgumentParser:
    doc = (study.__doc__ or study.STEM).strip().splitlines()[0]
    parser = argparse.ArgumentParser(prog=f"python -m analysis.{study.STEM}", description=doc)
    parser.add_argument("--out", default="paper", help="output folder (default: paper)")
    parser.add_argument("--quick", action="store_true", help="a short version (for tests)")
    parser.add_argument("--workers", type=int, default=None,
                        help="worker processes (default: the usable cores)")  # fmt: skip
    if _takes_full(study):
        parser.add_argument("--full", action="store_true",
                            help="recompute the whole study (otherwise a stored full record is "
                                 "re-rendered)")  # fmt: skip
    return parser


def _takes_full(study) -> bool:
    """Whether ``study.run`` has a ``full`` option (a study too long for ``wmr reproduce``,
    which then re-renders its stored record)."""
    import inspect

    return "full" in inspect.signature(study.run).parameters


def main(study, argv: list[str] | None = None) -> int:
    """``python -m analysis.<STEM>``: run the study into ``--out``, check it, say where it went.

    Exit 0 when its checks hold, 1 when one fails (the results are written first).
    """
    import matplotlib

    matplotlib.use("Agg")  # a command writes figures to files; no display is needed
    args = _parser(study).parse_args(argv)
    t0 = time.perf_counter()
    options = {"full": args.full} if _takes_full(study) else {}
    record = study.run(args.out, quick=args.quick, workers=args.workers, **options)
    try:
        study.check(record)
    except AssertionError as err:
        print(f"{study.STEM}: check failed: {err}", file=sys.stderr)
        return 1
    print(f"{study.STEM}: wrote {args.out}/results/{study.STEM}.json and its tables and figures "
          f"in {time.perf_counter() - t0:.1f} s")  # fmt: skip
    return 0
