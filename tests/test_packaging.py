"""What ``pip install .`` installs: the package ``wmr`` (with its scenarios), not the repository's
studies -- a top-level ``analysis`` in site-packages would clash with any other project's."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

from wmr import cli

ROOT = Path(__file__).resolve().parents[1]


def _source_tree(dest: Path) -> Path:
    """The checkout's files (tracked, or new and not ignored) copied into ``dest``: a build
    from a clean tree, as on a fresh clone (no stale ``build/`` of an earlier layout)."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.splitlines()
    for name in files:
        if (ROOT / name).is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(ROOT / name, dest / name)
    return dest


def test_the_wheel_holds_wmr_and_no_top_level_analysis(tmp_path):
    src = _source_tree(tmp_path / "src")
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w",
                           str(tmp_path / "dist"), str(src)], capture_output=True, text=True)
    (tmp_path / "dist").mkdir(exist_ok=True)
    assert done.returncode == 0, done.stderr
    (wheel,) = (tmp_path / "dist").glob("wmr-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert "analysis" not in tops, sorted(tops)
    assert "wmr/closedloop/step.py" in names and "wmr/scenarios/mujoco/lemniscate.toml" in names
    assert "wmr/scenarios/lemniscate.toml" in names


def test_the_studies_are_found_in_the_checkout_and_outside_one_it_is_exit_2(tmp_path,
                                                                             monkeypatch,
                                                                             capsys):  # fmt: skip
    assert cli._checkout() == ROOT
    monkeypatch.setattr(cli, "_checkout", lambda: None)
    assert cli.main(["analyze", "margins", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "run this command from a checkout" in err
    assert not (tmp_path / "x").exists()
