"""Controllers from outside the package (DESIGN §3.8, ``wmr.plugins``).

The plugin is the example of ``docs/extending.md`` (executed as written), saved in a folder
outside the repository.  Its compiled and its Python-level row compute the same law, so they
must give the same run; the contract's failures must be exit 2 with one line naming the plugin.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_array_equal
from test_extending import _example as example

from wmr import cli, controllers, plugins
from wmr import scenario as scn
from wmr.closedloop.sim import simulate


@pytest.fixture
def clean_registry():
    """Whatever a test loads is unloaded afterwards (the registry is the process's)."""
    before = dict(plugins._LOADED)
    yield
    for p in list(plugins._LOADED.values()):
        if p.module not in before:
            plugins._forget(p)


@pytest.fixture
def plugin_file(tmp_path_factory, clean_registry) -> Path:
    """``my_trackers.py`` in a folder outside the repository and outside ``sys.path``."""
    path = tmp_path_factory.mktemp("outside") / "my_trackers.py"
    path.write_text(example("plugin-file"))
    return path


def test_the_example_plugin_loads_and_its_two_rows_agree(plugin_file):
    p = plugins.load(str(plugin_file))
    assert p.names == ("simple-compiled", "simple-python")
    assert set(p.names) <= set(controllers.NAMES)  # "all" includes them
    assert str(plugin_file.parent) not in sys.path
    assert controllers.get("simple-compiled").compiled
    assert not controllers.get("simple-python").compiled
    sc = scn.load(scn.builtin("sinusoid"))
    a = simulate(sc, "simple-compiled", 3)
    b = simulate(sc, "simple-python", 3)
    for name in ("q", "q_hat", "u"):  # the same law, compiled or in Python: the same run
        assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert_array_equal(b.signal("steps"), np.arange(1, sc.n_steps + 1))
    assert plugins.load(str(plugin_file)) is p  # the same content again: a no-op


def test_a_scenario_sets_a_plugin_controllers_settings(plugin_file):
    plugins.load(str(plugin_file))
    text = (scn.builtin("sinusoid").read_text()
            + "\n[controllers.simple-python]\ngains = [1.5, 3.0]\n")  # fmt: skip
    sc = scn.loads(text)
    r = simulate(sc, "simple-python", 0)
    assert r.settings.gains == (1.5, 3.0)
    assert r.rmse != simulate(scn.load(scn.builtin("sinusoid")), "simple-python", 0).rmse
    with pytest.raises(scn.ScenarioError, match="gainz"):
        scn.loads(scn.builtin("sinusoid").read_text()
                  + "\n[controllers.simple-python]\ngainz = [1.5, 3.0]\n")  # fmt: skip


def test_wmr_run_with_a_plugin_and_editing_its_law_takes_effect(plugin_file, tmp_path):
    """Two fresh processes (the kernel's disk cache in between): the edited law's numbers."""
    scenario = str(scn.builtin("lemniscate"))

    def run(tag: str) -> float:
        out = tmp_path / tag
        done = subprocess.run([sys.executable, "-m", "wmr.cli", "run", scenario, "--plugin",
                               str(plugin_file), "--controller", "simple-compiled",
                               "--out", str(out)], capture_output=True, text=True,
                              cwd=tmp_path)  # fmt: skip
        assert done.returncode == 0, done.stderr
        return json.loads((out / "summary.json").read_text())["runs"][0]["rmse"]["position"]

    first = run("a")
    assert run("b") == first  # deterministic, and a cache hit changes nothing
    text = plugin_file.read_text()
    plugin_file.write_text(text.replace("u[1] = ref[4] + p[1] * e[2]",
                                        "u[1] = ref[4] + 0.5 * p[1] * e[2]"))  # fmt: skip
    assert plugin_file.read_text() != text
    assert run("c") != first


BAD = {
    "syntax error": ("def broken(:\n", "cannot be imported: SyntaxError"),
    "raises": ("raise RuntimeError('no robot here')\n", "cannot be imported: RuntimeError"),
    "no CONTROLLERS": ("X = 1\n", "has no module-level CONTROLLERS"),
    "not rows": ("CONTROLLERS = [1]\n", "must be wmr.controllers.Controller"),
    "mutable settings": (textwrap.dedent("""\
        from dataclasses import dataclass
        import wmr
        @dataclass
        class S:
            a: float = 1.0
        CONTROLLERS = [wmr.PyController("mutable", lambda s, sc, r: None, S)]
        """), "Settings = .*must be a frozen dataclass"),
    "a Python law as compiled": (textwrap.dedent("""\
        from wmr.controllers import backstepping as b
        import wmr
        def law(p, s, theta, P, q_hat, ref, dt, u):
            pass
        CONTROLLERS = [wmr.Controller("pylaw", b.Settings, b.pack, law, b.final_state, (),
                                      uses_estimator=False, label="x", colour="k")]
        """), "law = .*must be a numba-jitted function"),
    "name taken": (textwrap.dedent("""\
        from wmr.controllers import backstepping as b
        import wmr
        CONTROLLERS = [wmr.Controller("backstepping", b.Settings, b.pack, b.law,
                                      b.final_state, (), uses_estimator=False, label="x",
                                      colour="k")]
        """), "'backstepping': is already a registered controller"),
    "missing file": (None, "cannot be read"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_plugin_is_exit_2_with_one_line(case, tmp_path, capsys, clean_registry):
    text, message = BAD[case]
    path = tmp_path / "bad_plugin.py"
    if text is not None:
        path.write_text(text)
    before = dict(controllers.REGISTRY)
    code = cli.main(["run", str(scn.builtin("lemniscate")), "--plugin", str(path),
                     "--out", str(tmp_path / "out")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert str(path) in err and re.search(message, err), err
    assert "Traceback" not in err and not (tmp_path / "out").exists()
    assert controllers.REGISTRY == before  # nothing half-registered


def test_an_installed_plugin_is_found_through_its_entry_point(tmp_path, monkeypatch,
                                                              clean_registry):  # fmt: skip
    """A dist-info folder on sys.path (what pip writes, no network install) names the module."""
    (tmp_path / "ep_trackers.py").write_text(example("plugin-file").replace(
        '"simple-compiled"', '"ep-compiled"').replace('"simple-python"', '"ep-python"'))
    info = tmp_path / "ep_trackers-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: ep-trackers\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[wmr.controllers]\nep_trackers = ep_trackers\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    loaded = plugins.load_entry_points()
    assert [p.names for p in loaded if p.ref == "ep_trackers"] == [("ep-compiled", "ep-python")]
    assert not simulate(scn.load(scn.builtin("sinusoid")), "ep-python", 0).diverged


def test_reproduce_uses_the_built_in_controllers_only(monkeypatch, tmp_path, clean_registry):
    """``wmr reproduce`` does not load entry points (only ``--plugin``)."""
    called = []
    monkeypatch.setattr(plugins, "load_entry_points", lambda: called.append(1) or ())
    args = cli.build_parser().parse_args(["reproduce", "--out", str(tmp_path)])
    cli._plugins(args, entry_points=False)
    assert called == []
    cli._plugins(cli.build_parser().parse_args(["run", "x.toml"]))
    assert called == [1]


def test_the_worker_loader_imports_the_file_under_the_drivers_module_name(plugin_file, tmp_path):
    """What a Dask worker runs at start-up (``WorkerLoader.setup``), in a process that never saw
    the file: the content travels with the loader, not the path."""
    p = plugins.load(str(plugin_file))
    code = textwrap.dedent("""
        import pickle, sys
        from pathlib import Path
        from wmr import controllers, plugins
        loader = pickle.loads(Path(sys.argv[1]).read_bytes())
        class W:
            local_directory = sys.argv[2]
        loader.setup(W())
        assert "simple-python" in controllers.NAMES
        print(sorted(plugins._LOADED))
        """)
    import pickle

    blob = tmp_path / "loader.pkl"
    blob.write_bytes(pickle.dumps(plugins.WorkerLoader([p])))
    plugin_file.unlink()  # the worker cannot read the original
    done = subprocess.run([sys.executable, "-c", code, str(blob), str(tmp_path / "worker")],
                          capture_output=True, text=True, cwd=tmp_path)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert p.module in done.stdout


PLUGIN_SPEC = """\
name = "plugin-sweep"
scenarios = ["short.toml"]
controllers = ["simple-compiled", "simple-python"]
seeds = 2
plugins = ["my_trackers.py"]

[factors]
"controllers.*.gains" = [[1.0, 2.0], [2.0, 4.0], [3.0, 1.0]]
"""


def test_a_plugin_sweeps_on_every_engine_with_the_serial_rows(tmp_path_factory, clean_registry):
    """``plugins = [...]`` in a spec: serial, a 2-worker LocalCluster, and a scheduler with two
    worker processes started on 127.0.0.1 in a folder that does not hold the plugin (the file's
    content travels to the workers: ``wmr.engine.plugins_dask``) give the same rows."""
    from cases import SHORT_LEMNISCATE, rows_on_every_engine

    from wmr.engine import sweep

    folder = tmp_path_factory.mktemp("plugin-sweep")
    (folder / "my_trackers.py").write_text(example("plugin-file"))
    (folder / "short.toml").write_text(SHORT_LEMNISCATE.format(duration=2.0))
    (folder / "spec.toml").write_text(PLUGIN_SPEC)
    spec = sweep.load_spec(folder / "spec.toml")
    assert "simple-python" in controllers.REGISTRY

    rows_on_every_engine(spec, folder, tmp_path_factory.mktemp("elsewhere"))
    assert len(sweep.read_rows(folder / "serial")) == 3 * 2 * 2


def test_a_bad_plugin_in_a_spec_is_a_sweep_error(tmp_path, clean_registry):
    from wmr.engine import sweep

    (tmp_path / "spec.toml").write_text(PLUGIN_SPEC.replace("my_trackers.py", "nowhere.py"))
    with pytest.raises(sweep.SweepError, match=r"plugins = 'nowhere.py'.*cannot be read"):
        sweep.load_spec(tmp_path / "spec.toml")
