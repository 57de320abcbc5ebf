"""docs/settings.md is generated from the settings dataclasses: it must be current, and complete."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from wmr import controllers
from wmr import scenario as scn
from wmr.settings_reference import attribute_docs, markdown

DOC = Path(__file__).resolve().parents[1] / "docs" / "settings.md"


def test_docs_settings_md_is_current():
    """Regenerate with ``wmr settings --out docs/settings.md`` when this fails."""
    assert DOC.read_text() == markdown()


@pytest.mark.parametrize("cls", [scn.Noise, scn.Disturbance, scn.Limits, scn.Estimator,
                                 *(c.Settings for c in controllers.REGISTRY.values())],
                         ids=lambda c: f"{c.__module__}.{c.__qualname__}")  # fmt: skip
def test_every_settings_field_has_a_unit_and_a_meaning(cls):
    docs = attribute_docs(cls)
    for f in dataclasses.fields(cls):
        unit, meaning = docs[f.name]
        assert unit and meaning, f.name
        assert f"`{f.name}`" in markdown() or f".{f.name}`" in markdown()


def test_an_undocumented_field_is_an_error():
    @dataclasses.dataclass(frozen=True)
    class Undocumented:
        """No attributes section."""

        x: float = 1.0

    from wmr.settings_reference import _table

    with pytest.raises(ValueError, match="Undocumented.x is not documented"):
        _table(Undocumented, "")
