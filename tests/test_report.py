"""The generated report: byte-identical to what ``wmr report`` writes from the committed results,
every linked image exists, each stored study's section in registry order; an interrupted
``wmr reproduce`` leaves the previous results intact."""

from __future__ import annotations

import json
import re
import shutil
import types
from pathlib import Path

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
    assert re.findall(r"^## (.+)$", text, flags=re.M)[-2:] == ["Beta", "Alpha"]
    assert text.endswith("## Beta\n\n7\n\n## Alpha\n\n42\n")


def test_report_without_study_records_says_so(tmp_path):
    (tmp_path / "results").mkdir()
    text = report.build(tmp_path)
    assert text.startswith("# wmr: reproduction and stability/boundedness report\n")
    assert "## Errata" not in text and text.endswith("Not generated yet (`wmr reproduce`).\n")


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
    monkeypatch.setattr(cli, "_report", lambda out: Path(out) / "report.md")
    monkeypatch.setattr(cli, "_studies", lambda: registry(True))
    assert cli.main(argv) == 130
    assert (out / "results" / "rmse.csv").read_text() == "previous\n"
    monkeypatch.setattr(cli, "_studies", lambda: registry(False))
    assert cli.main(argv) == 0
    assert (out / "results" / "rmse.csv").read_text() == "new\n"
    assert not (out / ".staging").exists()
