"""Controllers from outside the package: plugins (DESIGN §3.8).

A plugin is a Python module -- a ``.py`` file or an importable name -- with a module-level
``CONTROLLERS``, a sequence of registry rows: ``wmr.controllers.Controller`` (a compiled law, the
contract of ``wmr/controllers/__init__.py``) or ``wmr.controllers.PyController`` (a Python-level
controller).  :func:`load` imports it, checks every row against the contract (:func:`check_row`)
and registers the rows, after which a plugin controller is a controller like any other
(``--controller NAME``, ``all``, ``[controllers.NAME]``, sweeps, studies that loop over the
registry).  Installed packages name such modules in the entry-point group :data:`GROUP`
(:func:`load_entry_points`).

A plugin file is imported under a name made of its stem and a digest of its content
(``wmr_plugin_<stem>_<digest>``): the same file gets the same name on every machine, so a pickled
setting of the plugin resolves on a worker, and an edited file is a new module (its rows replace the
old ones).  Workers of a Dask engine get the plugins of the driver through :class:`WorkerLoader`:
the files' contents travel with it and are written into the worker's own folder and imported there,
so a worker whose working folder and ``sys.path`` do not contain the file runs it too; the scheduler
gets them the same way (``wmr.engine.plugins_dask``).  A compiled plugin's kernel is cached under a
digest of its source (``wmr.closedloop.step.law_digest``): an edit takes effect at the next run.

Errors are :class:`PluginError` (exit 2 at the command line, one line naming the plugin): a
plugin that cannot be imported, has no ``CONTROLLERS``, a row that breaks the contract, or a
name already registered.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import importlib.metadata
import importlib.util
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from wmr import controllers
from wmr._settings import InputError

__all__ = ["GROUP", "PluginError", "Plugin", "load", "load_all", "load_entry_points", "loaded",
           "check_row", "WorkerLoader"]  # fmt: skip

#: The entry-point group of installed plugins (each entry point names a module).
GROUP = "wmr.controllers"

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.+-]*$")


class PluginError(InputError):
    """A plugin that cannot be used: ``source`` the plugin, ``key`` what is wrong in it."""


@dataclass(frozen=True)
class Plugin:
    """A loaded plugin: the reference it was given by, the module's name, the file's content
    (None for an importable module, which workers import by name) and the rows' names."""

    ref: str
    module: str
    source: bytes | None
    names: tuple[str, ...]


_LOADED: dict[str, Plugin] = {}  # by module name


def loaded() -> tuple[Plugin, ...]:
    """The plugins loaded in this process, in load order."""
    return tuple(_LOADED.values())


def _module_name(path: Path, data: bytes) -> str:
    stem = re.sub(r"\W", "_", path.stem)
    return f"wmr_plugin_{stem}_{hashlib.sha256(data).hexdigest()[:12]}"


def _import_file(ref: str, path: Path, name: str):
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        raise PluginError(ref, "file", str(path), "is not a Python module")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception as err:  # noqa: BLE001 - any failure of the plugin's own code: one line
        sys.modules.pop(name, None)
        raise PluginError(ref, "import", None, f"cannot be imported: {type(err).__name__}: "
                          f"{str(err).splitlines()[0] if str(err) else ''}") from None  # fmt: skip
    return module


def _import_name(ref: str):
    try:
        return importlib.import_module(ref)
    except Exception as err:  # noqa: BLE001
        raise PluginError(ref, "import", None, f"cannot be imported: {type(err).__name__}: "
                          f"{str(err).splitlines()[0] if str(err) else ''}") from None  # fmt: skip


def load(ref: str, base_dir: str | Path | None = None) -> Plugin:
    """Import plugin ``ref`` (a path ending in ``.py``, relative to ``base_dir`` or the working
    folder, or an importable module name), check its rows and register them.

    Loading the same content again is a no-op; an edited file replaces the rows its earlier
    version registered.  Returns the :class:`Plugin`.
    """
    ref = str(ref)
    if ref.endswith(".py") or "/" in ref or "\\" in ref:
        path = Path(ref) if base_dir is None else Path(base_dir) / ref
        try:
            data = path.read_bytes()
        except OSError as err:
            raise PluginError(ref, "file", str(path), f"cannot be read ({err.strerror})") from None
        name = _module_name(path, data)
        if name in _LOADED:
            return _LOADED[name]
        for old in [p for p in _LOADED.values() if p.ref == ref]:
            _forget(old)
        module = _import_file(ref, path, name)
        return _register(ref, module, data)
    if ref in _LOADED:
        return _LOADED[ref]
    return _register(ref, _import_name(ref), None)


def load_all(refs: Sequence[str], base_dir: str | Path | None = None) -> tuple[Plugin, ...]:
    """:func:`load` each of ``refs``."""
    return tuple(load(r, base_dir) for r in refs)


def load_entry_points() -> tuple[Plugin, ...]:
    """Load the modules named by the installed entry points of :data:`GROUP`."""
    out = []
    for ep in importlib.metadata.entry_points(group=GROUP):
        out.append(load(ep.value.split(":")[0].strip()))
    return tuple(out)


def _forget(plugin: Plugin) -> None:
    for name in plugin.names:
        controllers.unregister(name)
    _LOADED.pop(plugin.module, None)


def _register(ref: str, module, source: bytes | None) -> Plugin:
    rows = getattr(module, "CONTROLLERS", None)
    if rows is None:
        raise PluginError(ref, "CONTROLLERS", None, "the plugin has no module-level CONTROLLERS")
    if isinstance(rows, str | bytes) or not isinstance(rows, Sequence):
        raise PluginError(ref, "CONTROLLERS", type(rows).__name__,
                          "must be a sequence of registry rows")  # fmt: skip
    names = []
    for i, row in enumerate(rows):
        check_row(row, f"{ref}: CONTROLLERS[{i}]")
        if row.name in controllers.REGISTRY or row.name in names:
            raise PluginError(ref, f"CONTROLLERS[{i}].name", row.name,
                              "is already a registered controller")  # fmt: skip
        names.append(row.name)
    for row in rows:
        controllers.register(row)
    plugin = Plugin(ref=ref, module=module.__name__, source=source, names=tuple(names))
    _LOADED[plugin.module] = plugin
    return plugin


def _fail(where: str, key: str, value, reason: str):
    raise PluginError(where, key, value, reason)


def check_row(row, where: str = "<row>") -> None:
    """The contract of a registry row (``wmr.controllers``), for built-in and plugin rows alike:
    :class:`PluginError` naming the broken item.

    1. a ``Controller`` or ``PyController``; a ``name`` of letters, digits and ``_.+-``;
    2. ``Settings`` a frozen dataclass whose defaults construct it (``Settings()``);
    3. ``state_names`` a tuple of distinct strings; ``label`` a non-empty string;
       ``uses_estimator`` a bool;
    4. a ``Controller``: ``pack`` and ``final_state`` callable, ``law`` a numba-jitted function
       (the kernel inlines it); a ``PyController``: ``make`` callable.
    """
    if not isinstance(row, controllers.Controller | controllers.PyController):
        _fail(where, "type", type(row).__name__,
              "must be wmr.controllers.Controller or wmr.controllers.PyController")  # fmt: skip
    if not (isinstance(row.name, str) and _NAME.match(row.name)):
        _fail(where, "name", row.name, "must be letters, digits and _.+- (no spaces)")
    S = row.Settings
    if not (isinstance(S, type) and dataclasses.is_dataclass(S)
            and S.__dataclass_params__.frozen):  # fmt: skip
        _fail(where, "Settings", S, "must be a frozen dataclass")
    try:
        S()
    except Exception as err:  # noqa: BLE001
        _fail(where, "Settings", S.__name__, f"its defaults do not construct it ({err})")
    names = row.state_names
    if not (isinstance(names, tuple) and all(isinstance(n, str) for n in names)
            and len(set(names)) == len(names)):  # fmt: skip
        _fail(where, "state_names", names, "must be a tuple of distinct strings")
    if not (isinstance(row.label, str) and row.label):
        _fail(where, "label", row.label, "must be a non-empty string")
    if not isinstance(row.uses_estimator, bool):
        _fail(where, "uses_estimator", row.uses_estimator, "must be a bool")
    if isinstance(row, controllers.PyController):
        if not callable(row.make):
            _fail(where, "make", row.make, "must be callable: make(settings, scenario, rng)")
        return
    for key in ("pack", "final_state"):
        if not callable(getattr(row, key)):
            _fail(where, key, getattr(row, key), "must be callable")
    if not hasattr(row.law, "py_func"):
        _fail(where, "law", row.law, "must be a numba-jitted function (wmr.njit); a Python "
              "law is a PyController")  # fmt: skip


class WorkerLoader:
    """A Dask worker plugin that loads the driver's plugins on every worker, present and future
    (``Client.register_plugin``): file contents are written into the worker's local folder and
    imported under the driver's module names, importable modules are imported by name."""

    name = "wmr-plugins"

    def __init__(self, plugins: Sequence[Plugin]):
        self.plugins = tuple(plugins)

    def setup(self, worker=None):
        folder = Path(getattr(worker, "local_directory", None) or ".") / "wmr-plugins"
        for p in self.plugins:
            if p.module in _LOADED:
                continue
            if p.source is None:
                _register(p.ref, _import_name(p.ref), None)
                continue
            folder.mkdir(parents=True, exist_ok=True)
            path = folder / f"{p.module}.py"
            path.write_bytes(p.source)
            _register(p.ref, _import_file(p.ref, path, p.module), p.source)

    def teardown(self, worker=None):
        pass
