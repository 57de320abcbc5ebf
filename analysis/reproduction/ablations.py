"""Ablation variants of the reproduction study, derived from the controllers' settings fields.

A :class:`Variant` changes settings fields, the scenario, or both.  Which controllers it applies
to is derived, not listed (issue 11, item 6):

- a settings change applies to every registered controller whose settings have all the fields
  it changes (and, with ``where``, whose settings have the given values there), or to the
  controllers it names;
- a scenario change applies to every controller, or to those its ``affects`` rule selects (a
  change of pose source affects only the controllers whose pose it changes,
  :meth:`wmr.scenario.Estimator.filters`).

A field that no registered controller's settings have is an error when the variant is built,
so a misspelt field cannot silently change nothing.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

from wmr import controllers
from wmr.scenario import Scenario

__all__ = ["Variant", "pose_source", "noise_scaled", "scaled", "pose_source_changes",
           "CRITICAL_TOL", "backstepping_damping", "damping_name", "damping_phrase"]

#: |zeta - 1| below which a loop is named critically damped: half the last digit of the two
#: decimals zeta is printed with, so the name never contradicts the printed number.
CRITICAL_TOL = 0.005


def _fields(name: str) -> set[str]:
    return {f.name for f in dataclasses.fields(controllers.get(name).Settings)}


@dataclass(frozen=True)
class Variant:
    """One ablation of the reproduction study.

    Attributes
    ----------
    name : str
        Its name (the ``variant`` column of ``rmse.csv``).
    description : str
        What it changes, as the report lists it.
    settings : mapping
        Settings field -> new value, or a callable ``old value -> new value``.
    where : mapping
        Settings field -> value: only controllers whose settings have this value there.
    only : tuple of str, optional
        Only these controllers (each must have every field of ``settings``).
    scenario : callable, optional
        ``Scenario -> Scenario``: the scenario change.
    affects : callable, optional
        ``(scenario, changed scenario, controller) -> bool``: which controllers the scenario
        change concerns (default: all).

    Raises
    ------
    ValueError
        When a field of ``settings`` or ``where`` is a field of no registered controller's
        settings, or of a controller named in ``only``.
    KeyError
        When ``only`` names an unregistered controller.
    """

    name: str
    description: str
    settings: Mapping[str, Any] = field(default_factory=dict)
    where: Mapping[str, Any] = field(default_factory=dict)
    only: tuple[str, ...] | None = None
    scenario: Callable[[Scenario], Scenario] | None = None
    affects: Callable[[Scenario, Scenario, str], bool] | None = None

    def __post_init__(self):
        known = set().union(*(_fields(n) for n in controllers.NAMES))
        for key in (*self.settings, *self.where):
            if key not in known:
                raise ValueError(f"variant {self.name!r}: no registered controller's settings "
                                 f"have the field {key!r}")  # fmt: skip
        for name in self.only or ():
            missing = [k for k in (*self.settings, *self.where) if k not in _fields(name)]
            if missing:
                raise ValueError(f"variant {self.name!r}: the settings of {name!r} have no "
                                 f"field {missing[0]!r}")  # fmt: skip

    def targets(self, scenario: Scenario) -> tuple[str, ...]:
        """The controllers this variant applies to on ``scenario``, in registry order."""
        names = [n for n in controllers.NAMES if self.only is None or n in self.only]
        wanted = {*self.settings, *self.where}
        names = [n for n in names if wanted <= _fields(n)]
        names = [n for n in names
                 if all(getattr(scenario.settings(n), k) == v for k, v in self.where.items())]
        if self.scenario is not None and self.affects is not None:
            changed = self.scenario(scenario)
            names = [n for n in names if self.affects(scenario, changed, n)]
        return tuple(names)

    def apply(self, scenario: Scenario, controller: str) -> tuple[Scenario, Any]:
        """The scenario and the settings of ``controller`` under this variant."""
        settings = scenario.settings(controller)
        if self.settings:
            changes = {k: v(getattr(settings, k)) if callable(v) else v
                       for k, v in self.settings.items()}  # fmt: skip
            settings = dataclasses.replace(settings, **changes)
        if self.scenario is not None:
            scenario = self.scenario(scenario)
        return scenario, settings


def pose_source(source: str) -> Callable[[Scenario], Scenario]:
    """The scenario change ``estimator.pose_source = source``."""

    def apply(sc: Scenario) -> Scenario:
        return dataclasses.replace(sc, estimator=dataclasses.replace(sc.estimator,
                                                                     pose_source=source))

    return apply


def pose_source_changes(base: Scenario, changed: Scenario, controller: str) -> bool:
    """Whether ``controller`` acts on another pose (filtered vs raw) in ``changed``."""
    return base.estimator.filters(controller) != changed.estimator.filters(controller)


def noise_scaled(factor: float) -> Callable[[Scenario], Scenario]:
    """The scenario change: pose-measurement noise std times ``factor``."""

    def apply(sc: Scenario) -> Scenario:
        std = tuple(factor * s for s in sc.noise.pose_std)
        return dataclasses.replace(sc, noise=dataclasses.replace(sc.noise, pose_std=std))

    return apply


def scaled(factor: float) -> Callable[[tuple], tuple]:
    """A settings change: every entry of a vector field times ``factor``."""
    return lambda old: tuple(factor * x for x in old)


def backstepping_damping(gains) -> dict:
    """Damping and natural frequency of backstepping's lateral loop, linearised at ``e = 0``.

    With ``w = w_r + v_r (k2 e2 + k3 sin e3)`` and Kanayama's error dynamics
    ``e2' = -w e1 + v_r sin e3``, ``e3' = w_r - w``, at ``e = 0`` and constant ``v_r > 0``::

        e2'' + k3 v_r e2' + k2 v_r^2 e2 = 0,

    a second-order loop with ``omega_n = sqrt(k2) v_r`` and ``zeta = k3 / (2 sqrt(k2))``
    (independent of ``v_r``).  The longitudinal loop ``e1' = -k1 e1`` (at ``w_r = 0``) is first
    order.

    Parameters
    ----------
    gains : sequence of 3 floats
        ``(k1, k2, k3)`` [1/s, 1/m^2, 1/m], each > 0.

    Returns
    -------
    dict
        ``gains`` (list), ``zeta`` [-], ``omega_n_per_v_r`` = ``sqrt(k2)`` [rad/m: omega_n in
        rad/s per m/s of v_r] and ``name`` (:func:`damping_name` of ``zeta``).
    """
    k1, k2, k3 = (float(g) for g in gains)
    zeta = k3 / (2.0 * math.sqrt(k2))
    return {"gains": [k1, k2, k3], "zeta": zeta, "omega_n_per_v_r": math.sqrt(k2),
            "name": damping_name(zeta)}  # fmt: skip


def damping_name(zeta: float, tol: float = CRITICAL_TOL) -> str:
    """``"under-damped"`` (``zeta < 1``), ``"critically damped"`` (``|zeta - 1| < tol``) or
    ``"over-damped"`` (``zeta > 1``): the name a damping ratio earns, from its number."""
    if abs(zeta - 1.0) < tol:
        return "critically damped"
    return "under-damped" if zeta < 1.0 else "over-damped"


def damping_phrase(gains, reference=None) -> str:
    """How a variant's description states the damping of backstepping's lateral loop, computed
    from ``gains`` (:func:`backstepping_damping`), e.g. ``"lateral loop under-damped,
    zeta = k3/(2 sqrt k2) = 0.49, omega_n = sqrt(k2) v_r = 1.41 v_r"``; with ``reference``
    (the default gains) the default's ``omega_n`` beside it."""
    d = backstepping_damping(gains)
    text = (f"lateral loop {d['name']}, ζ = k3/(2√k2) = {d['zeta']:.2f}, ω_n = √k2 v_r = "
            f"{d['omega_n_per_v_r']:.2f} v_r")
    if reference is not None:
        text += f" (default gains {backstepping_damping(reference)['omega_n_per_v_r']:.2f} v_r)"
    return text
