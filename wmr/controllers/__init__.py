"""The tracking controllers and their registry.

A controller is a pure jitted law plus explicit state (STYLE §7)::

    law(p, s, theta, P, q_hat, ref, dt, u) -> None

``p`` are its frozen parameters (a namedtuple or float vector), ``s`` its small mutable state
(integrals, gains, previous signals...), ``theta`` and ``P`` its flat network weight vector and
that vector's covariance (empty for controllers without a network); it writes the input
``(v, w)`` into ``u``.  The loop (``wmr.closedloop.step``) owns and advances them.

The contract of a controller module, one row of :data:`REGISTRY` each (a test runs over every
row, ``tests/test_registry.py``):

1. ``Settings``: a frozen dataclass of validated settings with defaults (``wmr._settings``);
   the scenario table ``[controllers.<name>]`` is converted into it.  Settings that must fit the
   control period define ``check_dt(dt)`` (raising ``SettingError``); the scenario loader calls
   it with the file's ``dt`` (``nmpc``'s prediction step).
2. ``pack(settings, scenario, rng) -> (p, s, theta, P)``: the law's inputs from the settings
   (``rng`` initialises network weights; nothing else may draw from it).
3. ``law``: the jitted law above.  It must saturate its own output when it remembers the input
   it applied (the loop saturates again; that clip is then a no-op).
4. ``state_names``: the first ``len(state_names)`` entries of ``s`` are logged along a run under
   these names (``RunResult.signal``).
5. ``final_state(p, s, theta, P)``: the controller state as a dataclass (``RunResult.final``),
   called once, when the run is over: it may keep the run's arrays rather than copy them.
6. ``uses_estimator``: whether it acts on the pose filter's estimate under
   ``pose_source = "paper"`` (``wmr.scenario.Estimator.filters``).
7. ``label`` and ``colour``: how tables and figures name and draw it.
8. ``oracle``: a diagnostic arm that reads the true pose (the loop writes it into ``p.truth``
   before the law); not a controller a real robot could run, so not in :data:`NAMES` ("all").

A :class:`PyController` row is a Python-level controller (DESIGN §3.8): for prototypes and for
laws numba cannot compile (an optimiser in the loop).  Its runs go through the loop's Python
driver; the row derives ``pack``, ``law`` and ``final_state`` from its ``make`` (see the class).

Rows also come from outside the package: plugins (``wmr.plugins``) add them to :data:`REGISTRY`
through :func:`register`, after the same contract check (``wmr.plugins.check_row``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, make_dataclass

import numpy as np

from wmr.controllers import adaptive_bsc, adaptive_nn, backstepping, iapid_nn_dekf, nmpc, pid
from wmr.controllers.stopped import ControllerStopped

__all__ = ["Controller", "PyController", "ControllerStopped", "REGISTRY", "NAMES", "BUILTIN_NAMES",
           "ORACLE_NAMES", "PAPER_NAMES", "get", "label", "colour", "register", "unregister"]


@dataclass(frozen=True)
class Controller:
    """A registered controller (one row of the registry; see the module's contract)."""

    name: str
    Settings: type
    pack: Callable
    law: Callable
    final_state: Callable
    state_names: tuple[str, ...]
    uses_estimator: bool
    label: str
    colour: str
    oracle: bool = False

    #: Whether the law is a jitted function the compiled kernel can inline.
    compiled = True


@dataclass(frozen=True)
class PyController:
    """A Python-level controller (DESIGN §3.8), one registry row.

    Parameters
    ----------
    name : str
        Its name (``--controller NAME``, ``[controllers.NAME]``).
    make : callable
        ``make(settings, scenario, rng)`` returns the controller object of one run: its
        ``step(q_hat, ref, dt)`` returns the command ``(v, w)`` [m/s, rad/s] for the pose estimate
        ``q_hat = (x, y, theta)`` and the reference row ``ref = (x_r, y_r, theta_r, v_r, w_r)``
        at ``t_k``; it is called once per control step, in order (``k = 0, 1, ...``), and may
        raise :class:`ControllerStopped`.  With ``state_names``, ``signals()`` returns the
        current value of each named signal (logged along the run).  An optional ``final()``
        returns the record of the run's end (``RunResult.final``; default: the last signals).
        ``rng`` is the run's initialisation stream (a ``numpy.random.Generator``).
    Settings : type
        A frozen dataclass with defaults; the scenario table ``[controllers.NAME]`` is converted
        into it (unknown keys are errors).
    label, colour : str
        How tables and figures name and draw it.
    uses_estimator : bool
        Whether it acts on the pose filter's estimate under ``pose_source = "paper"``.
    state_names : tuple of str
        The signals ``signals()`` returns.
    """

    name: str
    make: Callable
    Settings: type
    label: str = ""
    colour: str | None = None
    uses_estimator: bool = False
    state_names: tuple[str, ...] = ()
    oracle: bool = field(default=False, init=False)

    compiled = False

    def __post_init__(self):
        object.__setattr__(self, "state_names", tuple(self.state_names))
        if not self.label:
            object.__setattr__(self, "label", self.name)

    def pack(self, settings, scenario, rng):
        """``(p, s, theta, P)`` of the loop: ``p`` the object ``make`` returns, ``s`` the logged
        signals (initially those of the fresh object), no weights."""
        obj = self.make(settings, scenario, rng)
        s = np.zeros(len(self.state_names))
        if self.state_names:
            s[:] = obj.signals()
        return obj, s, _EMPTY, _EMPTY2

    @staticmethod
    def law(p, s, theta, P, q_hat, ref, dt, u):
        """The loop's law: ``u = p.step(q_hat, ref, dt)`` (copies handed in), signals into ``s``;
        a :class:`ControllerStopped` makes the command non-finite (the loop stops the run) and
        is kept on the object for the run's record."""
        try:
            v, w = p.step(q_hat.copy(), ref.copy(), dt)
        except ControllerStopped as stop:
            p.__dict__["_wmr_stopped"] = str(stop)
            u[0] = u[1] = np.nan
            return
        u[0] = v
        u[1] = w
        if s.size:
            s[:] = p.signals()

    def final_state(self, p, s, theta, P):
        """``p.final()`` if the object has one, else the last signals as a dataclass."""
        if hasattr(p, "final"):
            return p.final()
        cls = make_dataclass(f"{self.name}-state".replace("-", "_"),
                             [(n, float) for n in self.state_names], frozen=True)  # fmt: skip
        return cls(*(float(x) for x in s))

    @staticmethod
    def stopped(p) -> str | None:
        """The message of the :class:`ControllerStopped` that stopped the run, if any."""
        return getattr(p, "__dict__", {}).get("_wmr_stopped")


_EMPTY = np.zeros(0)
_EMPTY.flags.writeable = False
_EMPTY2 = np.zeros((0, 0))
_EMPTY2.flags.writeable = False


REGISTRY: dict[str, Controller] = {
    c.name: c
    for c in (
        Controller("iapid-nn-dekf", iapid_nn_dekf.Settings, iapid_nn_dekf.pack,
                   iapid_nn_dekf.law, iapid_nn_dekf.final_state, iapid_nn_dekf.STATE_NAMES,
                   uses_estimator=True, label="IAPID-NN-DEKF", colour="tab:blue"),
        Controller("backstepping", backstepping.Settings, backstepping.pack, backstepping.law,
                   backstepping.final_state, backstepping.STATE_NAMES,
                   uses_estimator=False, label="BSC", colour="tab:orange"),
        Controller("adaptive-nn", adaptive_nn.Settings, adaptive_nn.pack, adaptive_nn.law,
                   adaptive_nn.final_state, adaptive_nn.STATE_NAMES,
                   uses_estimator=False, label="DA-NN", colour="tab:red"),
        Controller("adaptive-pid", pid.Settings, pid.pack, pid.law, pid.final_state,
                   pid.STATE_NAMES, uses_estimator=False, label="APID", colour="tab:pink"),
        Controller("pid", pid.FixedSettings, pid.pack, pid.law, pid.final_state,
                   pid.GAIN_NAMES, uses_estimator=False, label="PID (fixed)",
                   colour="tab:gray"),
        Controller("adaptive-bsc", adaptive_bsc.Settings, adaptive_bsc.pack, adaptive_bsc.law,
                   adaptive_bsc.final_state, adaptive_bsc.STATE_NAMES, uses_estimator=False,
                   label="Adaptive BSC", colour="tab:green"),
        PyController("nmpc", nmpc.make, nmpc.Settings, label="NMPC", colour="tab:purple",
                     uses_estimator=False, state_names=nmpc.STATE_NAMES),
        Controller("iapid-oracle", iapid_nn_dekf.Settings, iapid_nn_dekf.pack_oracle,
                   iapid_nn_dekf.law, iapid_nn_dekf.final_state, iapid_nn_dekf.STATE_NAMES,
                   uses_estimator=True, label="IAPID (oracle identifier)", colour="tab:cyan",
                   oracle=True),
    )
}  # fmt: skip
#: The built-in controllers a robot could run, in table order (``all`` without plugins).
BUILTIN_NAMES: tuple[str, ...] = tuple(n for n, c in REGISTRY.items() if not c.oracle)
#: Controller names in table order: the controllers a robot could run (``all``), the built-in
#: ones and then those of the plugins loaded in this process (``register``).
NAMES: tuple[str, ...] = BUILTIN_NAMES
#: Diagnostic arms that read the true pose (``oracle``), by name only.
ORACLE_NAMES: tuple[str, ...] = tuple(n for n, c in REGISTRY.items() if c.oracle)
#: The four controllers of the paper's tables.
PAPER_NAMES: tuple[str, ...] = ("iapid-nn-dekf", "backstepping", "adaptive-nn", "adaptive-pid")


def register(row: Controller | PyController) -> None:
    """Add a (plugin's) row to the registry and to :data:`NAMES`; ``ValueError`` if its name is
    already taken.  Check the row first (``wmr.plugins.check_row``)."""
    global NAMES
    if row.name in REGISTRY:
        raise ValueError(f"controller name {row.name!r} is already registered")
    REGISTRY[row.name] = row
    if not row.oracle:
        NAMES = (*NAMES, row.name)


def unregister(name: str) -> None:
    """Remove a plugin's row (the built-in rows cannot be removed)."""
    global NAMES
    if name in BUILTIN_NAMES or name in ORACLE_NAMES:
        raise ValueError(f"{name!r} is a built-in controller")
    REGISTRY.pop(name, None)
    NAMES = tuple(n for n in NAMES if n != name)


def get(name: str) -> Controller | PyController:
    """The registered controller ``name``; ``KeyError`` with the known names otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown controller {name!r}; known: {', '.join(NAMES)}") from None


def label(name: str) -> str:
    """The table label of controller ``name`` (the name itself for an unregistered one)."""
    return REGISTRY[name].label if name in REGISTRY else name


def colour(name: str) -> str | None:
    """The figure colour of controller ``name`` (None for an unregistered one)."""
    return REGISTRY[name].colour if name in REGISTRY else None
