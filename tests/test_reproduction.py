"""The reproduction study: ablations derived from settings fields, jobs, run/check/render.

Oracles: the controllers each ablation applied to when they were listed by hand (before issue 11),
the settings dataclasses' fields, and the committed record and report of ``paper/``.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from analysis import reproduction as rep
from analysis._ablations import Variant, noise_scaled
from wmr import controllers
from wmr import scenario as scn

PAPER = Path(__file__).resolve().parents[1] / "paper"
COMMITTED = PAPER / "results" / "reproduction.json"
needs_paper = pytest.mark.skipif(not COMMITTED.exists(), reason="paper/ not generated yet")

ALL = set(controllers.NAMES)
#: The controllers each ablation applied to when the lists were written by hand.
HAND_LISTS = {
    "rotation-printed": ALL,
    "nn-jacobian-printed": {"iapid-nn-dekf"},
    "feed-forward": {"pid", "adaptive-pid", "iapid-nn-dekf"},
    "pose-filtered": {"backstepping", "pid", "adaptive-pid", "adaptive-nn"},
    "pose-raw": {"iapid-nn-dekf"},
    "bsc-gains-low": {"backstepping"},
    "bsc-gains-kanayama": {"backstepping"},
    "noise-free": ALL,
    "noise-x3": ALL,
    "mu-x0.1": {"adaptive-pid", "iapid-nn-dekf"},
    "mu-x10": {"adaptive-pid", "iapid-nn-dekf"},
}


@pytest.fixture(scope="module")
def lemniscate():
    return scn.load(scn.builtin("lemniscate"))


def _has(name: str, field: str) -> bool:
    return field in {f.name for f in dataclasses.fields(controllers.get(name).Settings)}


def test_derived_targets_are_the_former_hand_lists(lemniscate):
    assert list(rep.VARIANTS) == list(HAND_LISTS)
    for name, variant in rep.VARIANTS.items():
        assert set(variant.targets(lemniscate)) == HAND_LISTS[name], name


@pytest.mark.parametrize("field", ["printed_rotation", "feed_forward", "printed_jacobian"])
def test_a_settings_variant_applies_to_every_controller_whose_settings_have_the_field(
        lemniscate, field):  # fmt: skip
    variant = Variant("v", "d", settings={field: True})
    expected = tuple(n for n in controllers.NAMES if _has(n, field))
    assert variant.targets(lemniscate) == expected and expected
    for name in expected:
        sc, settings = variant.apply(lemniscate, name)
        assert sc is lemniscate
        assert getattr(settings, field) is True
        assert settings == dataclasses.replace(lemniscate.settings(name), **{field: True})


@pytest.mark.parametrize(("kwargs", "field"), [
    ({"settings": {"prnted_rotation": True}}, "prnted_rotation"),
    ({"settings": {"mu": (1.0,) * 6}, "where": {"adaptt": True}}, "adaptt"),
], ids=["settings", "where"])  # fmt: skip
def test_a_variant_naming_a_field_no_controller_has_is_an_error(kwargs, field):
    with pytest.raises(ValueError, match=f"no registered controller's settings have the field "
                                         f"'{field}'"):  # fmt: skip
        Variant("typo", "a misspelt field", **kwargs)


def test_a_named_controller_must_have_the_field():
    with pytest.raises(ValueError, match="'backstepping' have no field 'mu'"):
        Variant("v", "d", settings={"mu": (1.0,) * 6}, only=("backstepping",))
    with pytest.raises(KeyError, match="mpc"):
        Variant("v", "d", settings={"gains": (1.0,)}, only=("mpc",))


def test_a_scenario_variant_applies_to_every_controller(lemniscate):
    variant = Variant("v", "d", scenario=noise_scaled(2.0))
    assert variant.targets(lemniscate) == controllers.NAMES
    sc, settings = variant.apply(lemniscate, "pid")
    assert sc.noise.pose_std == tuple(2 * s for s in lemniscate.noise.pose_std)
    assert settings == lemniscate.settings("pid")


def test_jobs_carry_each_variant_change(lemniscate):
    jobs = rep.build_jobs({"lemniscate": lemniscate}, seeds=2)
    by = {}
    for job in jobs:
        by.setdefault((job.variant, job.controller), []).append(job)
    assert all(len(js) == 2 for js in by.values())
    assert set(by) == {("default", n) for n in controllers.NAMES} | {
        (v, n) for v, names in HAND_LISTS.items() for n in names}  # fmt: skip
    mu = lemniscate.settings("adaptive-pid").mu
    assert by[("mu-x10", "adaptive-pid")][0].settings.mu == tuple(10.0 * m for m in mu)
    assert by[("pose-raw", "iapid-nn-dekf")][0].scenario.estimator.pose_source == "raw"
    assert by[("bsc-gains-low", "backstepping")][0].settings.gains == (0.5, 2.0, 1.4)
    assert by[("default", "pid")][0].settings is None


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduction")
    return out, rep.run(out, quick=True, workers=1, progress=False)


def test_quick_run_writes_its_files_and_passes_its_check(quick):
    out, record = quick
    assert record["seeds"] == rep.QUICK_SEEDS
    rep.check(record)
    stored = json.loads((out / "results" / "reproduction.json").read_text())
    assert stored == record
    rep.check(stored)
    rows = (out / "results" / "rmse.csv").read_text().splitlines()
    runs = sum(len(d) for e in record["scenarios"].values() for d in e["runs"].values())
    assert len(rows) == 1 + runs * rep.QUICK_SEEDS
    for num in (1, 2, 3):
        assert (out / "tables" / f"table{num}.md").is_file()
        assert (out / "tables" / f"table{num}.tex").is_file()
    assert record["figures"] and all(f.startswith("reproduction_") for f in record["figures"])
    assert all((out / "figures" / f).is_file() for f in record["figures"])


def test_render_gives_the_three_sections_and_links_existing_figures(quick):
    out, record = quick
    text = rep.render(record)
    titles = re.findall(r"^## (.+)$", text, flags=re.M)
    assert titles == [rep.TITLE, "Does the paper's ranking appear?", "Ablations and sensitivities"]
    for sc in record["scenarios"]:
        assert rep.table_markdown(record, sc).rstrip() in text
    links = re.findall(r"!\[[^\]]*\]\(figures/([^)]+)\)", text)
    assert len(links) == 4 and all((out / "figures" / x).is_file() for x in links)


def test_check_catches_a_missing_or_unaccounted_run(quick):
    _, record = quick
    broken = json.loads(json.dumps(record))
    del broken["scenarios"]["sinusoid"]["runs"]["pid"]["feed-forward"]
    with pytest.raises(AssertionError):
        rep.check(broken)
    broken = json.loads(json.dumps(record))
    broken["scenarios"]["lemniscate"]["runs"]["pid"]["default"]["n_diverged"] = 1
    with pytest.raises(AssertionError):
        rep.check(broken)


@needs_paper
def test_committed_record_passes_the_check_and_renders_as_the_committed_report():
    record = json.loads(COMMITTED.read_text())
    rep.check(record)
    assert rep.render(record) in (PAPER / "report.md").read_text()
    for sc, num in rep.TABLE_NUMBER.items():
        assert rep.table_markdown(record, sc) == (PAPER / "tables" / f"table{num}.md").read_text()
        assert rep.table_latex(record, sc) == (PAPER / "tables" / f"table{num}.tex").read_text()
