"""Scenario files (TOML, DESIGN §3.1) loaded into validated frozen dataclasses.

>>> sc = load(builtin("lemniscate"))          # doctest: +SKIP
>>> sc.n_steps, sc.reference.kind             # doctest: +SKIP
(4000, 'lemniscate')

Every error is a :class:`ScenarioError` whose one-line message names the file, the dotted key
and the offending value.  Unknown keys are errors.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from wmr import controllers
from wmr._settings import (
    FrozenMap,
    InputError,
    SettingError,
    check,
    from_table,
    nonnegative,
    number,
    positive,
)
from wmr.model.kinematics import INTEGRATORS
from wmr.model.references import KINDS
from wmr.robots import plantspec
from wmr.robots.plantspec import PLANT_CHANGEABLE, LaggedVelocity, Plant, PlantChange

__all__ = [
    "ScenarioError",
    "ReferenceSpec",
    "Noise",
    "Disturbance",
    "Limits",
    "Estimator",
    "Plant",
    "LaggedVelocity",
    "PlantChange",
    "PLANT_CHANGEABLE",
    "Scenario",
    "load",
    "loads",
    "from_dict",
    "builtin",
    "shipped",
    "PAPER_SCENARIOS",
    "MAX_STEPS",
]

#: The paper's three scenarios, shipped in ``wmr/scenarios/``.
PAPER_SCENARIOS: tuple[str, ...] = ("lemniscate", "sinusoid", "sinusoid-perturbed")
#: Largest number of steps a scenario may ask for (1e8 steps is ~12 days at dt = 0.01 s).
MAX_STEPS = 100_000_000
#: Tolerance on duration/dt being a whole number of steps (relative).
_STEP_TOL = 1e-9


class ScenarioError(InputError):
    """An unreadable or invalid scenario: ``source`` file, dotted ``key``, ``value``, ``reason``."""


@dataclass(frozen=True)
class ReferenceSpec:
    """A reference kind (``lemniscate``, ``sinusoid``, ``circle``) and its parameters."""

    kind: str
    params: Mapping[str, float]

    def __post_init__(self):
        check(isinstance(self.kind, str) and self.kind in KINDS, "kind", self.kind,
              f"unknown kind (known: {', '.join(KINDS)})")  # fmt: skip
        object.__setattr__(self, "params", FrozenMap(self.params))


@dataclass(frozen=True)
class Noise:
    """Additive Gaussian pose-measurement noise.

    Attributes
    ----------
    pose_std : tuple of float [m, m, rad]
        Std of the noise added to the measured ``(x, y, theta)`` at every step.
    """

    pose_std: tuple[float, ...] = (0.0, 0.0, 0.0)

    def __post_init__(self):
        for s in self.pose_std:
            nonnegative("pose_std", s)


@dataclass(frozen=True)
class Disturbance:
    """A window of additive input disturbance (``[[disturbance]]``, zero or more).

    Attributes
    ----------
    start : float [s]
        The window opens at ``t_k = start`` (>= 0, inside the run).
    stop : float [s]
        It closes before ``t_k = stop`` (> start): active for ``start <= t_k < stop``.
    velocity : tuple of float [m/s, rad/s]
        ``(dv, dw)`` added to the saturated command ``(v, w)`` before the plant.
    """

    start: float
    stop: float
    velocity: tuple[float, ...] = (0.0, 0.0)

    def __post_init__(self):
        nonnegative("start", self.start)
        check(self.stop > self.start, "stop", self.stop, f"must be > start = {self.start}")


@dataclass(frozen=True)
class Limits:
    """Actuator saturation, applied to the controllers' command before the disturbance.

    Attributes
    ----------
    v_max : float [m/s]
        ``|v| <= v_max`` (> 0; default inf: no limit).
    w_max : float [rad/s]
        ``|w| <= w_max`` (> 0; default inf: no limit).
    """

    v_max: float = math.inf
    w_max: float = math.inf

    def __post_init__(self):
        for name in ("v_max", "w_max"):
            value = getattr(self, name)
            check(value > 0 and not math.isnan(value), name, value, "must be > 0")


@dataclass(frozen=True)
class Estimator:
    """The pose EKF (errata E9, reading A) and which controllers use it.

    Attributes
    ----------
    pose_source : str [-]
        ``"paper"``: only ``iapid-nn-dekf`` uses the filtered pose (the paper's scheme), the others
        the raw measurement; ``"filtered"``: every controller uses the EKF estimate; ``"raw"``:
        every controller uses the raw measurement.
    process_std : tuple of float [m, m, rad]
        Std of the EKF's process noise per step (x, y, theta).  Not in the paper.
    min_measurement_std : float [m or rad]
        Floor on the EKF's measurement std (it uses the scenario's ``noise.pose_std``), so a
        noise-free scenario still has an invertible innovation covariance.
    """

    pose_source: str = "paper"
    process_std: tuple[float, ...] = (0.01, 0.01, 0.01)
    min_measurement_std: float = 1e-4

    def __post_init__(self):
        check(
            self.pose_source in ("paper", "filtered", "raw"),
            "pose_source",
            self.pose_source,
            'must be "paper", "filtered" or "raw"',
        )
        for s in self.process_std:
            nonnegative("process_std", s)
        positive("min_measurement_std", self.min_measurement_std)

    def filters(self, controller: str) -> bool:
        """Whether ``controller`` acts on the filtered pose (the one place this rule lives)."""
        if self.pose_source == "paper":
            return controllers.get(controller).uses_estimator
        return self.pose_source == "filtered"

    def matrices(self, noise: Noise) -> tuple[np.ndarray, np.ndarray]:
        """The pose filter's process and measurement covariances ``(Qp, Rp)``, diagonal (3, 3).

        ``Rp`` uses the scenario's measurement noise, floored at ``min_measurement_std``.
        """
        with np.errstate(over="ignore"):  # an absurd std: an infinite covariance, not a warning
            Qp = np.diag(np.square(self.process_std))
            Rp = np.diag(np.square(np.maximum(noise.pose_std, self.min_measurement_std)))
        return Qp, Rp


@dataclass(frozen=True)
class Scenario:
    """A validated scenario.  Build it with :func:`load`; vary it with ``dataclasses.replace``.

    Attributes
    ----------
    name : str [-]
        Required; usable as a folder name (``wmr run`` writes to ``wmr-runs/<name>``).
    duration : float [s]
        Required, > 0, a whole number of steps of ``dt`` (N = duration / dt steps).
    dt : float [s]
        Required, > 0: the sample period of measurement and control.
    initial_pose : tuple of float [m, m, rad]
        Required: the robot's ``(x, y, theta)`` at ``t = 0``.
    integrator : str [-]
        The plant's integration over a sample with the input held: ``"exact"`` (the arc, default),
        ``"euler"`` or ``"rk4"``.
    seed : int [-]
        Default seed of a run (>= 0); ``--seed`` overrides it.
    divergence_bound : float [m]
        A run stops, diverged, when the position error exceeds it (> 0; default 10).
    """

    name: str
    duration: float
    dt: float
    initial_pose: tuple[float, ...]
    reference: ReferenceSpec
    integrator: str = "exact"
    seed: int = 0
    noise: Noise = Noise()
    disturbances: tuple[Disturbance, ...] = ()
    limits: Limits = Limits()
    estimator: Estimator = Estimator()
    plant: Plant = Plant()
    divergence_bound: float = 10.0
    controllers: Mapping[str, Any] = field(default_factory=dict)
    source: str = "<scenario>"

    def __post_init__(self):
        object.__setattr__(self, "controllers", FrozenMap(self.controllers))

    @property
    def n_steps(self) -> int:
        """Number of steps ``N = round(duration / dt)``."""
        return round(self.duration / self.dt)

    def settings(self, controller: str):
        """The settings of ``controller``: from the file, or its defaults."""
        ctrl = controllers.get(controller)
        return self.controllers.get(controller) or ctrl.Settings()


def _require(table: Mapping, key: str, where: str):
    if key not in table:
        raise SettingError(f"{where}{key}", None, "required key is missing")
    return table[key]


_TOP_KEYS = {
    "name", "duration", "dt", "initial_pose", "integrator", "seed", "divergence_bound",
    "reference", "noise", "disturbance", "limits", "estimator", "controllers", "plant",
}  # fmt: skip


def _reference_params(spec, ref: Mapping[str, Any], source: str) -> dict:
    """The parameters of reference kind ``spec`` from the ``[reference]`` table."""
    if spec.parse is not None:
        return spec.parse(ref, source)
    for key in ref:
        if key != "kind":
            check(key in spec.params, f"reference.{key}", ref[key],
                  f"unknown key for kind {spec.name!r} "
                  f"(known: kind, {', '.join(spec.params)})")  # fmt: skip
    params = {key: number(f"reference.{key}", _require(ref, key, "reference."))
              for key in spec.params}  # fmt: skip
    for key in spec.positive:
        positive(f"reference.{key}", params[key])
    return params


def _build(data: Mapping[str, Any], source: str) -> Scenario:
    for key in data:
        check(key in _TOP_KEYS, key, data[key],
              f"unknown key (known: {', '.join(sorted(_TOP_KEYS))})")
    name = _require(data, "name", "")
    check(isinstance(name, str) and name.strip() != "", "name", name, "must be a non-empty string")
    # the name becomes a folder (``wmr run``'s default --out is wmr-runs/<name>)
    safe = name.isprintable() and "/" not in name and "\\" not in name and name.strip(".") != ""
    check(safe, "name", name, "must be usable as a folder name (printable, no / or \\, not ..)")
    duration = number("duration", _require(data, "duration", ""))
    positive("duration", duration)
    dt = number("dt", _require(data, "dt", ""))
    positive("dt", dt)
    check(dt <= duration, "dt", dt, f"must be <= duration = {duration}")
    steps = duration / dt
    check(steps <= MAX_STEPS, "duration", duration,
          f"needs {steps:.3g} steps, more than {MAX_STEPS}")
    check(
        abs(steps - round(steps)) <= _STEP_TOL * max(1.0, steps),
        "duration",
        duration,
        f"is not a whole number of steps of dt = {dt} ({steps:.6g})",
    )
    pose = _require(data, "initial_pose", "")
    check(isinstance(pose, list), "initial_pose", pose, "must be an array [x, y, theta]")
    check(len(pose) == 3, "initial_pose", pose, f"must have 3 elements, has {len(pose)}")
    pose_t = tuple(number(f"initial_pose[{i}]", p) for i, p in enumerate(pose))
    integrator = data.get("integrator", "exact")
    check(
        isinstance(integrator, str) and integrator in INTEGRATORS,
        "integrator",
        integrator,
        f"unknown integrator (known: {', '.join(INTEGRATORS)})",
    )
    seed = data.get("seed", 0)
    check(isinstance(seed, int) and not isinstance(seed, bool) and seed >= 0, "seed", seed,
          "must be an integer >= 0")  # fmt: skip
    bound = number("divergence_bound", data.get("divergence_bound", 10.0))
    positive("divergence_bound", bound)

    ref = _require(data, "reference", "")
    check(isinstance(ref, Mapping), "reference", ref, "must be a table")
    kind = _require(ref, "kind", "reference.")
    check(isinstance(kind, str) and kind in KINDS, "reference.kind", kind,
          f"unknown kind (known: {', '.join(KINDS)})")  # fmt: skip
    params = _reference_params(KINDS[kind], ref, source)
    if KINDS[kind].validate is not None:
        KINDS[kind].validate(params, duration, dt)

    noise = from_table(Noise, data.get("noise", {}), "noise")
    dist_tables = data.get("disturbance", [])
    check(isinstance(dist_tables, list), "disturbance", dist_tables,
          "must be an array of tables ([[disturbance]])")  # fmt: skip
    disturbances = []
    for i, table in enumerate(dist_tables):
        d = from_table(Disturbance, table, f"disturbance[{i}]")
        check(d.start < duration, f"disturbance[{i}].start", d.start,
              f"is outside the run (duration = {duration})")  # fmt: skip
        disturbances.append(d)
    limits = from_table(Limits, data.get("limits", {}), "limits")
    estimator = from_table(Estimator, data.get("estimator", {}), "estimator")
    plant = plantspec.parse(data.get("plant", {}), plantspec.Context(duration, dt, source))

    ctrl_tables = data.get("controllers", {})
    check(isinstance(ctrl_tables, Mapping), "controllers", ctrl_tables, "must be a table")
    ctrl_settings = {}
    for cname, table in ctrl_tables.items():
        check(cname in controllers.REGISTRY, f"controllers.{cname}", None,
              f"unknown controller (known: {', '.join(controllers.NAMES)})")  # fmt: skip
        ctrl_settings[cname] = st = from_table(
            controllers.get(cname).Settings, table, f"controllers.{cname}"
        )
        if hasattr(st, "check_dt"):  # settings that must fit the control period (nmpc's h)
            try:
                st.check_dt(dt)
            except SettingError as err:
                key = f"controllers.{cname}.{err.key}"
                raise SettingError(key, err.value, err.reason) from None
    return Scenario(
        name=name, duration=duration, dt=dt, initial_pose=pose_t,
        reference=ReferenceSpec(kind, params), integrator=integrator, seed=seed, noise=noise,
        disturbances=tuple(disturbances), limits=limits, estimator=estimator, plant=plant,
        divergence_bound=bound, controllers=ctrl_settings, source=source,
    )  # fmt: skip


def from_dict(data: Mapping[str, Any], source: str = "<scenario>") -> Scenario:
    """Validate a parsed TOML document; :class:`ScenarioError` on any problem."""
    try:
        return _build(data, source)
    except SettingError as err:
        raise ScenarioError(source, err.key, err.value, err.reason) from None


def loads(text: str, source: str = "<string>") -> Scenario:
    """Parse and validate TOML text."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise ScenarioError(source, "(syntax)", None, f"invalid TOML: {err}") from None
    return from_dict(data, source)


def load(path: str | Path) -> Scenario:
    """Read and validate the scenario file ``path``."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as err:
        raise ScenarioError(str(path), "(file)", None, f"cannot read: {err.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ScenarioError(str(path), "(file)", None, "not UTF-8 text") from None
    return loads(text, str(path))


def builtin(name: str) -> Path:
    """Path of a shipped scenario (``"lemniscate"``, ..., :func:`shipped` lists them)."""
    path = Path(str(resources.files("wmr") / "scenarios" / f"{name}.toml"))
    if not path.exists():
        raise FileNotFoundError(f"no built-in scenario {name!r}; known: {', '.join(shipped())}")
    return path


def shipped() -> tuple[str, ...]:
    """The names of the scenarios shipped in ``wmr/scenarios/`` (the paper's first)."""
    folder = Path(str(resources.files("wmr") / "scenarios"))
    others = sorted(p.stem for p in folder.glob("*.toml") if p.stem not in PAPER_SCENARIOS)
    return (*PAPER_SCENARIOS, *others)
