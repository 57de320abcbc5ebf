"""The generated report: byte-identical to what ``wmr report`` writes from the committed results,
every linked image exists, each stored study's section in registry order; an interrupted
``wmr reproduce`` leaves the previous results intact."""

from __future__ import annotations

import json
import re
import shutil
import types
from pathlib import Path

import numpy as np
import pytest

import analysis
from analysis import report
from wmr import cli

PAPER = Path(__file__).resolve().parents[1] / "paper"
needs_paper = pytest.mark.skipif(not (PAPER / "results" / "reproduction.json").exists(),
                                 reason="paper/ not generated yet (make reproduce)")  # fmt: skip


@needs_paper
def test_committed_report_is_what_wmr_report_writes():
    assert report.build(PAPER) == (PAPER / "report.md").read_text()


@needs_paper
def test_wmr_report_rewrites_a_copy_byte_identically(tmp_path):
    copy = tmp_path / "paper"
    shutil.copytree(PAPER, copy)
    (copy / "report.md").unlink()
    assert cli.main(["report", "--out", str(copy)]) == 0
    assert (copy / "report.md").read_bytes() == (PAPER / "report.md").read_bytes()


@needs_paper
def test_every_image_the_report_links_exists_and_there_are_at_least_six():
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", (PAPER / "report.md").read_text())
    assert len(set(links)) >= 6
    assert [x for x in links if not (PAPER / x).is_file()] == []


def _study(stem, title, render=None):
    return types.SimpleNamespace(STEM=stem, TITLE=title, render=render)


def test_each_stored_study_renders_its_section_in_registry_order(tmp_path, monkeypatch):
    """Each study whose record is stored renders its section from that record, in registry
    order; a study without a record is left out (and not even imported)."""
    studies = {"beta": _study("beta", "Beta", lambda record: f"## Beta\n\n{record['y']}\n"),
               "alpha": _study("alpha", "Alpha", lambda record: f"## Alpha\n\n{record['x']}\n")}
    monkeypatch.setattr(analysis, "STUDIES", (*studies, "missing"))
    monkeypatch.setattr(analysis, "get", studies.__getitem__)  # KeyError if "missing" is asked
    (tmp_path / "results").mkdir()
    for stem, record in (("alpha", {"x": 42}), ("beta", {"y": 7})):
        (tmp_path / "results" / f"{stem}.json").write_text(json.dumps(record))
    text = report.build(tmp_path)
    heads = re.findall(r"^## (.+)$", text, flags=re.M)
    assert heads[:2] == ["Beta", "Alpha"] and heads[2].startswith("Assumptions")
    assert "## Beta\n\n7\n\n## Alpha\n\n42\n" in text


def test_report_without_study_records_says_so(tmp_path):
    (tmp_path / "results").mkdir()
    text = report.build(tmp_path)
    assert text.startswith("# wmr: reproduction and stability/boundedness report\n")
    assert "## Errata" not in text and "## What the suite found" not in text
    assert "Not generated yet (`wmr reproduce`).\n" in text


def test_report_without_results_is_a_usage_error(tmp_path, capsys):
    assert cli.main(["report", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("error: ")


def test_interrupted_reproduce_keeps_previous_results_and_a_rerun_completes(tmp_path, monkeypatch):
    out = tmp_path / "paper"
    (out / "results").mkdir(parents=True)
    (out / "results" / "rmse.csv").write_text("previous\n")

    def registry(fail):
        def run(stage, **kwargs):
            (Path(stage) / "results").mkdir(parents=True, exist_ok=True)
            (Path(stage) / "results" / "rmse.csv").write_text("new\n")
            if fail:
                raise KeyboardInterrupt  # the user presses Ctrl-C in the middle of the study
            return {}

        study = types.SimpleNamespace(STEM="reproduction", TITLE="t", run=run,
                                      check=lambda record: None)  # fmt: skip
        return types.SimpleNamespace(STUDIES=("reproduction",), get=lambda name: study)

    argv = ["reproduce", "--out", str(out), "--skip-analyses", "--skip-bench", "--seeds", "1"]
    monkeypatch.setattr(cli, "_report", lambda out, html=False: Path(out) / "report.md")
    monkeypatch.setattr(cli, "_studies", lambda: registry(True))
    assert cli.main(argv) == 130
    assert (out / "results" / "rmse.csv").read_text() == "previous\n"
    monkeypatch.setattr(cli, "_studies", lambda: registry(False))
    assert cli.main(argv) == 0
    assert (out / "results" / "rmse.csv").read_text() == "new\n"
    assert not (out / ".staging").exists()


# --- The assumptions: what DA-NN can adapt to on the lagged velocity loop ----------------------

# The FD step of wmr.estimation.identification.plant_jacobian gives ~1e-10 relative; over one step
# the
#: heading turns by w dt <= ~5e-3 rad, which moves the (x, y) norm of the v column by ~1e-5.
FD_RTOL, TURN_RTOL = 1e-7, 1e-4


@pytest.mark.parametrize("k", [500, 3000], ids=["before the payload", "after the payload"])
def test_lagged_channels_give_the_true_robots_one_step_jacobian(k):
    """Oracle: the true robot's step (wmr.robots.plant) differentiated in the command by central
    differences (wmr.estimation.identification.plant_jacobian), along a run of the shipped
    lagged-velocity plant: the heading row of the w column is g_w rho_w dt, the (x, y) part of the v
    column has norm g_v rho_v dt, where the kinematic G has dt."""
    import dataclasses

    from wmr import scenario as scn
    from wmr.closedloop.sim import simulate
    from wmr.estimation.identification import plant_jacobian

    sc = scn.load(scn.builtin(report.LAGGED_SCENARIO))
    run = simulate(sc, "backstepping", 0)
    J = plant_jacobian(sc, run)(k, run.q[k], run.u[k], sc.dt)
    dyn = sc.plant.model_table
    if k * sc.dt >= sc.plant.changes[0].at:
        dyn = dataclasses.replace(dyn, **{key: v for key, v in sc.plant.changes[0].values.items()})
    c = report.lagged_channels(dyn, sc.dt)
    assert J[2, 1] == pytest.approx(c["w"]["g"] * c["w"]["rho"] * sc.dt, rel=FD_RTOL)
    assert np.hypot(*J[:2, 0]) == pytest.approx(c["v"]["g"] * c["v"]["rho"] * sc.dt,
                                                rel=TURN_RTOL)  # fmt: skip
    assert 0.0 < c["v"]["rho"] < 1.0 and c["v"]["g"] < 1.0  # a lag and a friction loss


def test_the_kinematic_limit_of_the_lagged_channels():
    """A very fast inner loop without friction is the kinematic model: g = 1, rho -> 1."""
    from wmr.scenario import LaggedVelocity

    c = report.lagged_channels(LaggedVelocity(bandwidth=(1e7, 1e7)), 0.01)
    assert c["v"]["g"] == 1.0 and c["v"]["rho"] == pytest.approx(1.0, abs=1e-5)


def test_assumptions_and_errata_are_computed_not_typed(tmp_path):
    text = "\n".join(report._assumptions())
    assert "lateral loop under-damped, ζ = k3/(2√k2) = 0.63" in text
    assert "g ρ = 0.094/0.094" in text and "from 20 s" in text
    assert "barely" not in text


@needs_paper
def test_e4_and_e7_state_the_records_numbers(tmp_path):
    """E4 counts the scenarios where the PID family is best with and without feed-forward, E7
    gives the largest P/I gain excursion: both read from the reproduction record."""
    (tmp_path / "results").mkdir()
    for stem in ("reproduction", "jacobians", "boundedness"):
        shutil.copy(PAPER / "results" / f"{stem}.json", tmp_path / "results")
    path = tmp_path / "results" / "reproduction.json"
    rep = json.loads(path.read_text())
    family = ["iapid-nn-dekf", "adaptive-pid", "pid"]
    rep["feed_forward_best"] = {
        "lemniscate": {"without": {"best": "backstepping"}, "with": {"best": "pid",
                                                                     "on_variant": family}},
        "sinusoid": {"without": {"best": "pid"}, "with": {"best": "adaptive-nn",
                                                          "on_variant": family}},
    }  # fmt: skip
    for d in rep["gain_excursion"].values():
        for r in d.values():
            r["max_rel"] = dict.fromkeys(r["max_rel"], 0.0)
    rep["gain_excursion"]["sinusoid"]["adaptive-pid"]["max_rel"]["Kiw"] = 0.123
    path.write_text(json.dumps(rep))
    text = "\n".join(report._errata(tmp_path))
    assert "with it the PID family has the lowest mean position RMSE in 1 of 2 scenarios (1 of 2 " \
           "without)" in text
    assert "by at most 12.3 % over a run: see the verdict" in text and "barely" not in text
