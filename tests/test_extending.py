"""docs/extending.md: its worked examples are executed as written, and each new row passes its
registry's contract (the same checks as tests/test_registry.py)."""

from __future__ import annotations

import importlib
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import test_registry as contract

import analysis
from analysis import report
from wmr import cli, controllers
from wmr import scenario as scn
from wmr.closedloop.sim import simulate
from wmr.model import references

DOC = Path(__file__).resolve().parents[1] / "docs" / "extending.md"


def _example(name: str) -> str:
    """The code block after the ``<!-- example: name -->`` marker of docs/extending.md."""
    m = re.search(rf"<!-- example: {name} -->\n```python\n(.*?)```", DOC.read_text(), re.S)
    assert m, f"no example {name!r} in {DOC}"
    return m.group(1)


@pytest.fixture
def package(tmp_path, monkeypatch):
    """A temporary folder on sys.path for the examples' modules."""
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    for name in ("wmr_example_simple", "example_study"):
        sys.modules.pop(name, None)


def test_the_controller_example_is_a_working_registry_row(package, monkeypatch):
    (package / "wmr_example_simple.py").write_text(_example("controller-module"))
    simple = importlib.import_module("wmr_example_simple")
    row = eval(_example("controller-row"), {"Controller": controllers.Controller,
                                            "simple": simple})  # fmt: skip
    monkeypatch.setitem(controllers.REGISTRY, row.name, row)
    sc = scn.load(scn.builtin("lemniscate"))
    contract.test_controller_settings_are_frozen_validated_dataclasses(row)
    contract.test_controller_pack_law_and_final_state(row, sc)
    contract.test_controller_runs_and_its_record_names_its_signals(row, sc)
    text = scn.builtin("lemniscate").read_text() + "\n[controllers.simple]\ngains = [1.5, 3.0]\n"
    r = simulate(scn.loads(text), "simple", 0)
    assert not r.diverged and r.settings.gains == (1.5, 3.0)  # (no lateral term: a poor tracker)


def test_the_reference_example_is_a_working_registry_row(monkeypatch):
    ns = {"math": math, "np": np, "ReferenceKind": references.ReferenceKind}
    exec(_example("reference-path"), ns)
    row = eval(_example("reference-row"), ns)
    monkeypatch.setitem(references.KINDS, row.name, row)
    contract.test_reference_kind_derivatives_match_finite_differences(row)
    contract.test_reference_kind_example_loads_and_positivity_is_enforced(row)
    sc = scn.loads('name = "e"\nduration = 30.0\ndt = 0.01\ninitial_pose = [2.0, 0.0, 1.5707963]\n'
                   '[reference]\nkind = "ellipse"\na = 2.0\nb = 1.0\nperiod = 30.0\n')
    ref = references.sample("ellipse", sc.reference.params, sc.dt, 3001)
    assert np.all(np.diff(ref[:, 2]) > 0)  # counter-clockwise: theta_r increases, unwrapped
    assert simulate(sc, "backstepping", 0).rmse["position"] < 0.01


def test_the_study_example_runs_checks_and_renders(package, monkeypatch, tmp_path, capsys):
    (package / "example_study.py").write_text(_example("study-module"))
    study = importlib.import_module("example_study")
    monkeypatch.setattr(analysis, "STUDIES", ("example",))
    monkeypatch.setattr(analysis, "get", {"example": study}.__getitem__)
    out = tmp_path / "paper"
    assert cli.main(["analyze", "example", "--out", str(out)]) == 0
    record = json.loads((out / "results" / "example.json").read_text())
    study.check(record)
    text = report.build(out)
    assert study.render(record).rstrip() in text
    assert "## Example: every controller on a circle" in text
    assert (out / "tables" / "example.md").read_text() == study.table(record)
