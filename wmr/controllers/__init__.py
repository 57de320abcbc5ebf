"""The tracking controllers and their registry.

A controller is a pure jitted law plus explicit state (STYLE §7)::

    law(p, s, theta, P, q_hat, ref, dt, u) -> None

``p`` are its frozen parameters (a namedtuple or float vector), ``s`` its small mutable state
(integrals, gains, previous signals...), ``theta`` and ``P`` its flat network weight vector and
that vector's covariance (empty for controllers without a network); it writes the input
``(v, w)`` into ``u``.  The loop (``wmr.loop``) owns and advances them.

The contract of a controller module, one row of :data:`REGISTRY` each (a test runs over every
row, ``tests/test_registry.py``):

1. ``Settings``: a frozen dataclass of validated settings with defaults (``wmr._settings``);
   the scenario table ``[controllers.<name>]`` is converted into it.
2. ``pack(settings, scenario, rng) -> (p, s, theta, P)``: the law's inputs from the settings
   (``rng`` initialises network weights; nothing else may draw from it).
3. ``law``: the jitted law above.  It must saturate its own output when it remembers the input
   it applied (the loop saturates again; that clip is then a no-op).
4. ``state_names``: the first ``len(state_names)`` entries of ``s`` are logged along a run under
   these names (``RunResult.signal``).
5. ``final_state(p, s, theta, P)``: the controller state as a dataclass (``RunResult.final``).
6. ``uses_estimator``: whether it acts on the pose filter's estimate under
   ``pose_source = "paper"`` (``wmr.scenario.Estimator.filters``).
7. ``label`` and ``colour``: how tables and figures name and draw it.
8. ``oracle``: a diagnostic arm that reads the true pose (the loop writes it into ``p.truth``
   before the law); not a controller a real robot could run, so not in :data:`NAMES` ("all").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from wmr.controllers import adaptive_bsc, adaptive_nn, backstepping, iapid_nn_dekf, pid

__all__ = ["Controller", "REGISTRY", "NAMES", "ORACLE_NAMES", "PAPER_NAMES", "get", "label",
           "colour"]


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
        Controller("iapid-oracle", iapid_nn_dekf.Settings, iapid_nn_dekf.pack_oracle,
                   iapid_nn_dekf.law, iapid_nn_dekf.final_state, iapid_nn_dekf.STATE_NAMES,
                   uses_estimator=True, label="IAPID (oracle identifier)", colour="tab:cyan",
                   oracle=True),
    )
}  # fmt: skip
#: Controller names in table order: the controllers a robot could run (``all``).
NAMES: tuple[str, ...] = tuple(n for n, c in REGISTRY.items() if not c.oracle)
#: Diagnostic arms that read the true pose (``oracle``), by name only.
ORACLE_NAMES: tuple[str, ...] = tuple(n for n, c in REGISTRY.items() if c.oracle)
#: The four controllers of the paper's tables.
PAPER_NAMES: tuple[str, ...] = ("iapid-nn-dekf", "backstepping", "adaptive-nn", "adaptive-pid")


def get(name: str) -> Controller:
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
