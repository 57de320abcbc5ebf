"""Scenario files (TOML, DESIGN §3.1) loaded into validated frozen dataclasses.

>>> sc = load(builtin("lemniscate"))          # doctest: +SKIP
>>> sc.n_steps, sc.reference.kind             # doctest: +SKIP
(4000, 'lemniscate')

Every error is a :class:`ScenarioError` whose one-line message names the file, the dotted key
and the offending value.  Unknown keys are errors.
"""

from __future__ import annotations

import dataclasses
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
from wmr.kinematics import INTEGRATORS
from wmr.references import KINDS

__all__ = [
    "ScenarioError",
    "ReferenceSpec",
    "Noise",
    "Disturbance",
    "Limits",
    "Estimator",
    "Plant",
    "PlantDynamic",
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


#: Keys a ``[[plant.change]]`` may set (``model``, ``delay_steps``, ``nominal_*`` and
#: ``bandwidth`` describe the robot's build and its inner loop: they cannot change mid-run).
PLANT_CHANGEABLE = ("v_gain", "w_gain", "v_from_w", "w_from_v", "slip", "actuator_tau", "mass",
                    "inertia", "friction")  # fmt: skip
_DYNAMIC_KEYS = ("mass", "inertia", "friction")


@dataclass(frozen=True)
class PlantDynamic:
    """The torque-driven robot of ``model = "dynamic"`` (``[plant.dynamic]``, DESIGN §3.3).

    ``mass v' = nominal_mass bw_v (a_v - v) - f_v v``, ``inertia w' = nominal_inertia bw_w (a_w -
    w) - f_w w``: an inner proportional velocity loop tuned with the nominal mass and inertia.

    Attributes
    ----------
    mass : float [kg]
        The true mass (> 0).
    inertia : float [kg m^2]
        The true moment of inertia about the vertical axis (> 0).
    friction : tuple of float [N s/m, N m s]
        Viscous friction ``(f_v, f_w)`` (>= 0).
    nominal_mass : float [kg]
        The mass the inner velocity loop is tuned for (> 0).
    nominal_inertia : float [kg m^2]
        The inertia the inner velocity loop is tuned for (> 0).
    bandwidth : tuple of float [1/s]
        Bandwidths ``(bw_v, bw_w)`` of the inner velocity loop (> 0).
    """

    mass: float = 10.0
    inertia: float = 0.5
    friction: tuple[float, ...] = (0.0, 0.0)
    nominal_mass: float = 10.0
    nominal_inertia: float = 0.5
    bandwidth: tuple[float, ...] = (20.0, 20.0)

    def __post_init__(self):
        for name in ("mass", "inertia", "nominal_mass", "nominal_inertia"):
            positive(name, getattr(self, name))
        for x in self.friction:
            nonnegative("friction", x)
        for x in self.bandwidth:
            positive("bandwidth", x)


@dataclass(frozen=True)
class PlantChange:
    """A ``[[plant.change]]``: from the first step with ``t_k >= at`` [s] the keys of ``values``
    take their new values (on top of the parameters in force before)."""

    at: float
    values: Mapping[str, Any]

    def __post_init__(self):
        object.__setattr__(self, "values", FrozenMap(self.values))


@dataclass(frozen=True)
class Plant:
    """The true robot (``[plant]``, DESIGN §3.3; the physics is in ``wmr.plant``).  Controllers
    and the pose EKF keep the nominal model; only the plant reads this.

    Attributes
    ----------
    model : str [-]
        ``"kinematic"`` (default: the commanded velocities act directly, possibly lagged) or
        ``"dynamic"`` (torque-driven with an inner velocity loop; needs ``[plant.dynamic]``).
    v_gain : float [-]
        Applied ``v = v_gain v_cmd + v_from_w w_cmd`` (a wheel-radius error scales both gains).
    w_gain : float [-]
        Applied ``w = w_gain w_cmd + w_from_v v_cmd`` (a radius or axle-length error).
    v_from_w : float [m/rad]
        Cross-coupling; unequal wheels of radii ``r (1 +- eps)`` and half-axle ``b`` give
        ``v_from_w = eps b``.
    w_from_v : float [rad/m]
        Cross-coupling; unequal wheels give ``w_from_v = eps / b``.
    actuator_tau : float [s]
        First-order lag of the actual ``(v, w)`` behind the mapped command (>= 0; kinematic
        model only; 0: none).  With a lag the robot starts at rest.
    delay_steps : int [-]
        Whole-sample input delay ``d >= 0``: the command computed at step ``k`` is applied at
        step ``k + d`` (zero before the first one arrives).
    slip : float [s]
        Lateral slip: side velocity ``v_s = slip v w`` in the robot frame, left positive (>= 0).
    """

    model: str = "kinematic"
    v_gain: float = 1.0
    w_gain: float = 1.0
    v_from_w: float = 0.0
    w_from_v: float = 0.0
    actuator_tau: float = 0.0
    delay_steps: int = 0
    slip: float = 0.0
    dynamic: PlantDynamic | None = field(default=None, metadata={"toml": False})
    changes: tuple[PlantChange, ...] = field(default=(), metadata={"toml": False})

    def __post_init__(self):
        check(self.model in ("kinematic", "dynamic"), "model", self.model,
              'must be "kinematic" or "dynamic"')  # fmt: skip
        nonnegative("actuator_tau", self.actuator_tau)
        nonnegative("slip", self.slip)
        check(self.delay_steps >= 0, "delay_steps", self.delay_steps, "must be an integer >= 0")
        check(self.model == "kinematic" or self.actuator_tau == 0.0, "actuator_tau",
              self.actuator_tau, 'is for model = "kinematic" only (the dynamic model has its '
              "own inner loop)")  # fmt: skip

    @property
    def ideal(self) -> bool:
        """The paper's plant: kinematic, unit gains, no coupling, lag, delay, slip or change."""
        return (self.model == "kinematic" and self.v_gain == 1.0 and self.w_gain == 1.0
                and self.v_from_w == 0.0 and self.w_from_v == 0.0 and self.actuator_tau == 0.0
                and self.delay_steps == 0 and self.slip == 0.0 and not self.changes)  # fmt: skip

    def row(self, previous: list | None = None, values: Mapping | None = None) -> list[float]:
        """A row of ``wmr.plant.PARAMS`` (substeps left 0): these parameters, or ``previous``
        with a change's ``values`` applied."""
        from wmr.plant import PARAMS

        if previous is None:
            d = self.dynamic or PlantDynamic()
            current = {"v_gain": self.v_gain, "w_gain": self.w_gain, "v_from_w": self.v_from_w,
                       "w_from_v": self.w_from_v, "actuator_tau": self.actuator_tau,
                       "slip": self.slip, "mass": d.mass, "inertia": d.inertia,
                       "friction_v": d.friction[0], "friction_w": d.friction[1],
                       "nominal_mass": d.nominal_mass, "nominal_inertia": d.nominal_inertia,
                       "bandwidth_v": d.bandwidth[0], "bandwidth_w": d.bandwidth[1],
                       "substeps": 0.0}  # fmt: skip
        else:
            current = dict(zip(PARAMS, previous, strict=True))
        for key, value in (values or {}).items():
            if key == "friction":
                current["friction_v"], current["friction_w"] = value
            else:
                current[key] = value
        return [float(current[k]) for k in PARAMS]

    def to_json(self) -> dict:
        """The parameters in force at ``t = 0`` and the change schedule (``summary.json``)."""
        out = {k: getattr(self, k) for k in ("model", "v_gain", "w_gain", "v_from_w", "w_from_v",
                                             "actuator_tau", "delay_steps", "slip")}  # fmt: skip
        out["dynamic"] = None if self.dynamic is None else {
            f.name: (list(v) if isinstance(v := getattr(self.dynamic, f.name), tuple) else v)
            for f in dataclasses.fields(self.dynamic)}  # fmt: skip
        out["changes"] = [{"at": c.at, **{k: (list(v) if isinstance(v, tuple) else v)
                                          for k, v in c.values.items()}}
                          for c in self.changes]  # fmt: skip
        return out

    def describe(self) -> str:
        """One line for table headers and figure titles ("ideal" for the paper's plant)."""
        if self.ideal:
            return "ideal plant"
        parts = [self.model]
        for k, default in (("v_gain", 1.0), ("w_gain", 1.0), ("v_from_w", 0.0),
                           ("w_from_v", 0.0), ("actuator_tau", 0.0), ("slip", 0.0)):
            if getattr(self, k) != default:
                parts.append(f"{k} {getattr(self, k):g}")
        if self.delay_steps:
            parts.append(f"delay {self.delay_steps} steps")
        if self.dynamic is not None:
            d = self.dynamic
            parts.append(f"mass {d.mass:g} (nominal {d.nominal_mass:g})")
        for c in self.changes:
            parts.append(f"at {c.at:g} s: " + ", ".join(
                f"{k} {list(v) if isinstance(v, tuple) else v}" for k, v in c.values.items()))
        return "plant: " + "; ".join(parts)


def _plant(data: Any, duration: float) -> Plant:
    """``[plant]`` with ``[plant.dynamic]`` and ``[[plant.change]]``, validated (DESIGN §3.3)."""
    check(isinstance(data, Mapping), "plant", data, "must be a table")
    base = {k: v for k, v in data.items() if k not in ("dynamic", "change")}
    plant = from_table(Plant, base, "plant")
    dyn_table = data.get("dynamic")
    if plant.model == "dynamic":
        check(dyn_table is not None, "plant.dynamic", None,
              'is required with model = "dynamic"')  # fmt: skip
        dynamic = from_table(PlantDynamic, dyn_table, "plant.dynamic")
    else:
        check(dyn_table is None, "plant.dynamic", dyn_table,
              'is only allowed with model = "dynamic"')  # fmt: skip
        dynamic, dyn_table = None, {}
    tables = data.get("change", [])
    check(isinstance(tables, list), "plant.change", tables,
          "must be an array of tables ([[plant.change]])")  # fmt: skip
    changes = []
    for i, table in enumerate(tables):
        where = f"plant.change[{i}]"
        check(isinstance(table, Mapping), where, table, "must be a table")
        at = number(f"{where}.at", _require(table, "at", f"{where}."))
        check(0.0 <= at < duration, f"{where}.at", at, f"must be in [0, duration = {duration})")
        values = {}
        for key, value in table.items():
            if key == "at":
                continue
            check(key in PLANT_CHANGEABLE, f"{where}.{key}", value,
                  f"cannot change mid-run (changeable: {', '.join(PLANT_CHANGEABLE)})")
            if key in _DYNAMIC_KEYS:
                check(dynamic is not None, f"{where}.{key}", value,
                      'is a key of the dynamic model (model = "dynamic")')  # fmt: skip
                checked = from_table(PlantDynamic, {**dyn_table, key: value}, where)
            else:
                checked = from_table(Plant, {**base, key: value}, where)
            values[key] = getattr(checked, key)
        check(values != {}, where, dict(table), "changes nothing (give at least one key)")
        changes.append(PlantChange(at, values))
    changes.sort(key=lambda c: c.at)  # stable: changes at the same time apply in file order
    return dataclasses.replace(plant, dynamic=dynamic, changes=tuple(changes))


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
    plant = _plant(data.get("plant", {}), duration)

    ctrl_tables = data.get("controllers", {})
    check(isinstance(ctrl_tables, Mapping), "controllers", ctrl_tables, "must be a table")
    ctrl_settings = {}
    for cname, table in ctrl_tables.items():
        check(cname in controllers.REGISTRY, f"controllers.{cname}", None,
              f"unknown controller (known: {', '.join(controllers.NAMES)})")  # fmt: skip
        ctrl_settings[cname] = from_table(
            controllers.get(cname).Settings, table, f"controllers.{cname}"
        )
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
