"""requirements.lock: well formed, consistent with pyproject.toml's ranges, and (inside the
repository's .venv, the one `make` builds from it) installed exactly.
"""

from __future__ import annotations

import importlib.metadata
import re
import sys
import tomllib
from pathlib import Path

import pytest
from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "requirements.lock"
#: Never locked: the project itself (installed editable on top) and the installer's own tools.
UNLOCKED = {"wmr", "pip", "setuptools", "wheel"}


def normalize(name: str) -> str:
    """PEP 503 normalized project name."""
    return re.sub(r"[-_.]+", "-", name).lower()


def read_lock() -> dict[str, str]:
    """{normalized name: version} of every pin of requirements.lock."""
    pins: dict[str, str] = {}
    for number, raw in enumerate(LOCK.read_text().splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        m = re.fullmatch(r"([A-Za-z0-9][A-Za-z0-9._-]*)==([A-Za-z0-9.+!_-]+)", line)
        assert m, f"requirements.lock:{number}: not a `name==version` pin: {raw!r}"
        name = normalize(m.group(1))
        assert name not in pins, f"requirements.lock:{number}: {name} pinned twice"
        pins[name] = m.group(2)
    return pins


def declared_requirements() -> list[Requirement]:
    """pyproject.toml's runtime dependencies and the test extra (what `make lock` resolves)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    specs = project["dependencies"] + project["optional-dependencies"]["test"]
    return [Requirement(spec) for spec in specs]


def test_lock_is_well_formed() -> None:
    pins = read_lock()
    assert pins, "requirements.lock pins nothing"
    assert not UNLOCKED & pins.keys(), f"{sorted(UNLOCKED & pins.keys())} must not be locked"
    text = LOCK.read_text()
    assert "make lock" in text.split("\n", 1)[0], "the header says how to regenerate the lock"


def test_lock_satisfies_pyproject() -> None:
    """Every declared dependency is locked at a version inside its range: a change of
    pyproject.toml's dependencies without `make lock` fails here."""
    pins = read_lock()
    for req in declared_requirements():
        name = normalize(req.name)
        assert name in pins, f"{req} is declared in pyproject.toml but not locked: run `make lock`"
        assert req.specifier.contains(pins[name], prereleases=True), (
            f"{name}=={pins[name]} in requirements.lock is outside pyproject.toml's {req}: "
            "run `make lock`"
        )


def installed() -> dict[str, set[str]]:
    """{normalized name: versions} of the distributions importable in this interpreter."""
    found: dict[str, set[str]] = {}
    for dist in importlib.metadata.distributions():
        name = dist.metadata["Name"]
        if name:
            found.setdefault(normalize(name), set()).add(dist.version)
    return found


@pytest.mark.skipif(
    Path(sys.prefix).resolve() != (ROOT / ".venv").resolve(),
    reason="not running inside the repository's .venv (the one `make` builds from "
    "requirements.lock): the installed versions of another environment are not checked",
)
def test_environment_matches_lock() -> None:
    have = installed()
    wrong = {
        name: (version, sorted(have.get(name, set())) or "missing")
        for name, version in read_lock().items()
        if have.get(name) != {version}
    }
    assert not wrong, (
        f"installed distributions differ from requirements.lock ({{name: (locked, installed)}}): "
        f"{wrong}; `make clean-venv` then `make test` rebuilds .venv from the lock"
    )
