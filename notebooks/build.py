"""Build and execute the notebooks from their cell sources here (so diffs stay reviewable).

Usage: ``.venv/bin/python notebooks/build.py [NAME ...]`` (needs the ``dev`` extra: nbclient).
Each notebook is written to ``notebooks/NAME.ipynb`` with its outputs; nbval re-runs it in
``make test`` and compares the printed outputs.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import nbformat
from nbclient import NotebookClient

HERE = Path(__file__).resolve().parent
# the kernels import the studies (analysis/) from the checkout, as under `make test`
os.environ["PYTHONPATH"] = os.pathsep.join(
    p for p in (str(HERE.parent), os.environ.get("PYTHONPATH")) if p)
SETUP = """\
# NBVAL_IGNORE_OUTPUT
import numpy as np
import matplotlib.pyplot as plt
%matplotlib inline
np.set_printoptions(precision=4, suppress=True)
rng = np.random.default_rng(0)  # every random draw of this notebook comes from here or a seed"""


def _cells(source: str):
    """Split a notebook source on lines '# %%' (code) and '# %% [md]' (markdown)."""
    cells, kind, buf = [], None, []
    for line in source.splitlines():
        if line.startswith("# %%"):
            if kind is not None:
                cells.append((kind, "\n".join(buf).strip("\n")))
            kind, buf = ("md" if "[md]" in line else "code"), []
        else:
            buf.append(line[2:] if kind == "md" and line.startswith("# ") else
                       ("" if kind == "md" and line == "#" else line))  # fmt: skip
    if kind is not None:
        cells.append((kind, "\n".join(buf).strip("\n")))
    return cells


def build(name: str) -> Path:
    src = (HERE / "src" / f"{name}.py").read_text()
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3",
                                 "language": "python"}
    nb.cells.append(nbformat.v4.new_code_cell(SETUP))
    for kind, text in _cells(src):
        new = nbformat.v4.new_markdown_cell if kind == "md" else nbformat.v4.new_code_cell
        cell = new(text)
        nb.cells.append(cell)
    for i, cell in enumerate(nb.cells):
        cell["id"] = f"{name[:2]}-{i:02d}"
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(HERE)}}).execute()  # as nbval: in notebooks/
    out = HERE / f"{name}.ipynb"
    nbformat.write(nb, out)
    return out


if __name__ == "__main__":
    names = sys.argv[1:] or sorted(p.stem for p in (HERE / "src").glob("*.py"))
    for n in names:
        print("built", build(n))
