"""The true robot's specification (``[plant]``, DESIGN §3.3): frozen dataclasses built from their
fields' metadata.

Every key of ``[plant]`` and of a model's table is one field, declared with :func:`param`, of a
class made by :func:`plant_table` (a frozen dataclass); the field's metadata says everything the
rest of the suite needs to know about it:

- ``unit`` and ``doc``: the class's numpydoc ``Attributes`` section is written from them (so the
  settings reference, ``wmr settings``, follows);
- ``rule``: the check of its value (applied at construction, then the class's ``__post_init__``
  checks what involves several fields);
- ``ideal``: its value on the paper's plant (:attr:`Plant.ideal` is every field at it);
- ``column``: the column(s) of the compiled plant's parameter table it fills
  (:data:`COLUMNS`, :meth:`Plant.row`; ``wmr.robots.plant.PARAMS`` is these plus ``substeps``);
- ``changeable``: whether a ``[[plant.change]]`` may set it mid-run (:func:`changeable`);
- ``label`` and ``describe``: how :meth:`Plant.describe` shows it.

:meth:`Plant.to_json` and :meth:`Plant.describe` walk the fields.  Adding an effect is a field
here and its equation in ``wmr.robots.plant`` (``docs/extending.md``).

The models (``[plant] model``) are rows of :data:`MODELS`: each names the dataclass of its own
table ``[plant.<model>]`` (required with that model, an error with any other) and the keys of
``[plant]`` that are errors with it, and optionally a ``finish`` step for what needs the
scenario around the table (:class:`Context`: a file relative to the scenario, a rule on ``dt``).
:data:`RENAMED` maps an earlier model name to its new one (an error that names the new name).
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import math
import textwrap
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from wmr._settings import (
    FrozenMap,
    SettingError,
    check,
    from_table,
    nonnegative,
    number,
    positive,
)

__all__ = [
    "param",
    "plant_table",
    "spec_fields",
    "Model",
    "Context",
    "MODELS",
    "RENAMED",
    "LaggedVelocity",
    "PlantChange",
    "Plant",
    "columns",
    "COLUMNS",
    "PLANT_CHANGEABLE",
    "changeable",
    "parse",
]

_SAME = object()  # ``ideal`` not given: the default is the ideal value


def param(default: Any, *, unit: str, doc: str, rule: Callable[[str, Any], None] | None = None,
          ideal: Any = _SAME, column: bool | tuple[str, ...] = False, changeable: bool = False,
          label: str = "{name} {value}", describe: bool = False, example: Any = None):
    """A field of a plant table with its metadata (see the module docstring).

    Parameters
    ----------
    default : float, int, str or tuple of float
        The default value (a key left out of the file takes it).
    unit, doc : str
        Unit (``-``: dimensionless) and one-sentence meaning, with the rule in words.
    rule : callable, optional
        ``rule(key, value)`` raises :class:`SettingError` for a bad value (a tuple field: each
        element); e.g. ``wmr._settings.nonnegative``.
    ideal : optional
        The value on the paper's (ideal) plant; default: ``default``.
    column : bool or tuple of str
        ``True``: one column of the compiled plant's parameter table named as the field; a tuple:
        one column per element of a tuple field; ``False``: not a column.
    changeable : bool
        A ``[[plant.change]]`` may set it mid-run.
    label : str
        Format of the field in :meth:`Plant.describe` (``{name}``, ``{value}``).
    describe : bool
        Shown by :meth:`Plant.describe` even at its default (a model table's key).
    example : optional
        A valid value away from the default (tests and docs; default: one derived from it).
    """
    meta = {"unit": unit, "doc": doc, "rule": rule,
            "ideal": default if ideal is _SAME else ideal, "column": column,
            "changeable": changeable, "label": label, "describe": describe, "example": example}
    return field(default=default, metadata=meta)


def _type_text(annotation: Any) -> str:
    if typing.get_origin(annotation) is tuple:
        return "tuple of float"
    return getattr(annotation, "__name__", str(annotation))


def plant_table(cls: type) -> type:
    """Make ``cls`` a plant table: a frozen dataclass whose fields' rules are checked at
    construction (before its own ``__post_init__``, if any) and whose numpydoc ``Attributes``
    section is written from its fields' metadata."""
    own = getattr(cls, "__post_init__", None)

    def __post_init__(self):
        _apply_rules(self)
        if own is not None:
            own(self)

    cls.__post_init__ = __post_init__
    return _documented(dataclass(frozen=True)(cls))


def _documented(cls: type) -> type:
    """Append the numpydoc ``Attributes`` section of ``cls`` written from its fields' metadata."""
    hints = typing.get_type_hints(cls)
    lines = [inspect.cleandoc(cls.__doc__ or ""), "", "Attributes", "----------"]
    for f in spec_fields(cls):
        lines.append(f"{f.name} : {_type_text(hints[f.name])} [{f.metadata['unit']}]")
        lines += textwrap.wrap(f.metadata["doc"], 92, initial_indent="    ",
                               subsequent_indent="    ", break_on_hyphens=False)  # fmt: skip
    cls.__doc__ = "\n".join(lines)
    return cls


@functools.cache
def spec_fields(cls: type) -> tuple[dataclasses.Field, ...]:
    """The fields of ``cls`` that are keys of its TOML table (declared with :func:`param`)."""
    return tuple(f for f in dataclasses.fields(cls) if "doc" in f.metadata)


def _apply_rules(obj) -> None:
    for f in spec_fields(type(obj)):
        rule, value = f.metadata["rule"], getattr(obj, f.name)
        if rule is not None:
            for x in value if isinstance(value, tuple) else (value,):
                rule(f.name, x)


def _count(key: str, value: Any) -> None:
    check(value >= 0, key, value, "must be an integer >= 0")


def _fmt(value: Any) -> str:
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, tuple):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return str(value)


def _json(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


@plant_table
class LaggedVelocity:
    """The inner velocity loop of ``model = "lagged-velocity"`` (``[plant.lagged-velocity]``,
    DESIGN §3.3): a first-order lag whose time constant follows the mass.

    ``mass v' = nominal_mass bw_v (a_v - v) - f_v v``, ``inertia w' = nominal_inertia bw_w (a_w -
    w) - f_w w``: a proportional velocity loop tuned with the nominal mass and inertia, with
    inertia and viscous friction (no wheels, torques or torque limits: those are the MuJoCo
    robot's, DESIGN §3.7).
    """

    mass: float = param(10.0, unit="kg", doc="The true mass (> 0).", rule=positive,
                        column=True, changeable=True, describe=True)  # fmt: skip
    inertia: float = param(0.5, unit="kg m^2", rule=positive, column=True, changeable=True,
                           doc="The true moment of inertia about the vertical axis (> 0).")
    friction: tuple[float, ...] = param(
        (0.0, 0.0), unit="N s/m, N m s", doc="Viscous friction ``(f_v, f_w)`` (>= 0).",
        rule=nonnegative, column=("friction_v", "friction_w"), changeable=True)
    nominal_mass: float = param(10.0, unit="kg", rule=positive, column=True, describe=True,
                                doc="The mass the inner velocity loop is tuned for (> 0).")
    nominal_inertia: float = param(0.5, unit="kg m^2", rule=positive, column=True,
                                   doc="The inertia the inner velocity loop is tuned for (> 0).")
    bandwidth: tuple[float, ...] = param(
        (20.0, 20.0), unit="1/s", doc="Bandwidths ``(bw_v, bw_w)`` of the inner velocity loop "
        "(> 0).", rule=positive, column=("bandwidth_v", "bandwidth_w"))


@dataclass(frozen=True)
class Model:
    """A value of ``[plant] model``.

    Attributes
    ----------
    name : str [-]
        The value of ``model`` (and the name of its table, ``[plant.<name>]``).
    table : type or None [-]
        The class of ``[plant.<name>]`` (made by :func:`plant_table`), required with this model
        and an error with any other; None: the model has no table.
    excluded : tuple of str [-]
        Keys of ``[plant]`` that are errors with this model (given in the file, or away from
        their default in code), with the reason ``why``.
    why : str [-]
        Why the ``excluded`` keys do not apply.
    doc : str [-]
        What the model is, in a few words.
    finish : callable or None [-]
        ``finish(table, context) -> table``: called by :func:`parse` with the validated table and
        the scenario's :class:`Context`, for what needs more than the table itself (a file
        relative to the scenario read in, a rule on ``dt``); returns the table to keep, raises
        :class:`SettingError` naming the key (``plant.<name>.<key>``).  None: nothing to do.
    parse_table : callable or None [-]
        For a model whose table is not a :func:`plant_table` class (a Python-level robot such as
        the MuJoCo one, ``wmr.robots.pyplant``): ``parse_table(table, context) -> spec`` validates
        ``[plant.<name>]`` itself (``table`` is then None).
    change_keys : tuple of str [-]
        Keys of such a model that a ``[[plant.change]]`` may set (the robot applies them).
    change_rule : callable or None [-]
        ``change_rule(spec, key, value, where, context) -> value``: one such key validated.
    """

    name: str
    table: type | None
    excluded: tuple[str, ...] = ()
    why: str = ""
    doc: str = ""
    finish: Callable[[Any, Context], Any] | None = None
    parse_table: Callable[[Any, Context], Any] | None = None
    change_keys: tuple[str, ...] = ()
    change_rule: Callable[[Any, str, Any, str, Context], Any] | None = None

    @property
    def has_table(self) -> bool:
        """Whether the model has its own table ``[plant.<name>]`` (required with it)."""
        return self.table is not None or self.parse_table is not None


@dataclass(frozen=True)
class Context:
    """The scenario around a ``[plant]`` table (:func:`parse`, :attr:`Model.finish`).

    Attributes
    ----------
    duration : float [s]
        The run's length (a change must come before it).
    dt : float [s]
        The sample period.
    source : str [-]
        The scenario's file (paths in a model's table are relative to it), or ``<string>``.
    """

    duration: float
    dt: float = math.nan
    source: str = "<scenario>"


def _mujoco_table(table: Any, context: Context) -> Any:
    """``[plant.mujoco]`` (DESIGN §3.7): ``wmr.robots.mujoco_robot.MujocoSpec`` (imported on use:
    MuJoCo loads only for a scenario that asks for it), ``file`` relative to the scenario's folder,
    and
    ``dt`` a whole multiple of ``timestep``."""
    from wmr.robots.mujoco_robot import MujocoSpec

    source = context.source
    base_dir = None if source.startswith("<") else Path(source).parent
    spec = MujocoSpec.from_table(table, base_dir=base_dir, source=source)
    if math.isfinite(context.dt):
        spec.check_dt(context.dt, source)
    return spec


def _mujoco_change(spec: Any, key: str, value: Any, where: str, context: Context) -> Any:
    return spec.change(key, value, where=where.rsplit(".", 1)[0], source=context.source)


#: The models of ``[plant] model``: the first is the default.  A new model is a row here (its
#: table a :func:`plant_table` class) and its physics (``wmr.robots.plant``, or a Python plant).
MODELS: dict[str, Model] = {m.name: m for m in (
    Model("kinematic", None, doc="the default: the commanded velocities act directly, possibly "
          "lagged"),
    Model("lagged-velocity", LaggedVelocity, ("actuator_tau",),
          "it has its own lag, the inner velocity loop",
          "an inner velocity loop with inertia: a first-order lag whose time constant follows "
          "the mass"),
    Model("mujoco", None, ("v_gain", "w_gain", "v_from_w", "w_from_v", "actuator_tau", "slip"),
          "the physics engine gives the robot's response: wheels, contact, servos",
          "a MuJoCo rigid-body differential drive with wheel-ground contact (DESIGN §3.7)",
          parse_table=_mujoco_table, change_keys=("mass", "com_offset", "friction"),
          change_rule=_mujoco_change),
)}  # fmt: skip
#: Earlier model names: an error that names the new one.
RENAMED = {"dynamic": "lagged-velocity"}


def _model_rule(key: str, value: Any) -> None:
    if isinstance(value, str) and value in RENAMED:
        raise SettingError(key, value, f'was renamed: use model = "{RENAMED[value]}" '
                           "(DESIGN §3.3)")  # fmt: skip
    check(isinstance(value, str) and value in MODELS, key, value,
          "must be " + " or ".join(f'"{m}"' for m in MODELS))  # fmt: skip


@dataclass(frozen=True)
class PlantChange:
    """A ``[[plant.change]]``: from the first step with ``t_k >= at`` [s] the keys of ``values``
    take their new values (on top of the parameters in force before)."""

    at: float
    values: Mapping[str, Any]

    def __post_init__(self):
        object.__setattr__(self, "values", FrozenMap(self.values))


@plant_table
class Plant:
    """The true robot (``[plant]``, DESIGN §3.3; the physics is in ``wmr.robots.plant``).
    Controllers and the pose EKF keep the nominal model; only the plant reads this.

    ``model_table`` is the model's own table (``[plant.<model>]``, e.g. :class:`LaggedVelocity`;
    None for a model without one; filled with its defaults when left out in code) and
    ``changes`` the ``[[plant.change]]`` events, sorted by time.
    """

    model: str = param("kinematic", unit="-", rule=_model_rule, doc=" or ".join(
        f'``"{m.name}"`` ({m.doc}{"; needs ``[plant." + m.name + "]``" if m.table else ""})'
        for m in MODELS.values()) + "; the earlier " + ", ".join(
        f'``"{old}"`` is an error that names ``"{new}"``' for old, new in RENAMED.items()) + ".")
    v_gain: float = param(1.0, unit="-", column=True, changeable=True, doc="Applied ``v = v_gain "
                          "v_cmd + v_from_w w_cmd`` (a wheel-radius error scales both gains).")
    w_gain: float = param(1.0, unit="-", column=True, changeable=True, doc="Applied ``w = w_gain "
                          "w_cmd + w_from_v v_cmd`` (a radius or axle-length error).")
    v_from_w: float = param(0.0, unit="m/rad", column=True, changeable=True,
                            doc="Cross-coupling; unequal wheels of radii ``r (1 +- eps)`` and "
                            "half-axle ``b`` give ``v_from_w = eps b``.")  # fmt: skip
    w_from_v: float = param(0.0, unit="rad/m", column=True, changeable=True,
                            doc="Cross-coupling; unequal wheels give ``w_from_v = eps / b``.")
    actuator_tau: float = param(
        0.0, unit="s", rule=nonnegative, column=True, changeable=True,
        doc="First-order lag of the actual ``(v, w)`` behind the mapped command (>= 0; "
        "kinematic model only; 0: none).  With a lag the robot starts at rest.")
    delay_steps: int = param(0, unit="-", rule=_count, label="delay {value} steps",
                             doc="Whole-sample input delay ``d >= 0``: the command computed at "
                             "step ``k`` is applied at step ``k + d`` (zero before the first one "
                             "arrives).")  # fmt: skip
    slip: float = param(0.0, unit="s", column=True, changeable=True, example=0.1,
                        doc="Lateral skid, signed: side velocity ``v_s = -slip v w`` in the robot "
                        "frame, left positive; ``slip > 0`` skids outward of the turn, as a tyre "
                        "does under load.")  # fmt: skip
    model_table: Any = field(default=None, metadata={"toml": False})
    changes: tuple[PlantChange, ...] = field(default=(), metadata={"toml": False})

    def __post_init__(self):  # after the fields' rules (plant_table)
        model = MODELS[self.model]
        for f in spec_fields(type(self)):
            value = getattr(self, f.name)
            check(f.name not in model.excluded or value == f.default, f.name, value,
                  f'is not a key of model = "{model.name}" ({model.why})')  # fmt: skip
        if model.parse_table is not None:
            pass  # its spec is validated by parse_table (parse() requires its table)
        elif model.table is None:
            check(self.model_table is None, "model_table", self.model_table,
                  f'model = "{model.name}" has no table')  # fmt: skip
        elif self.model_table is None:
            object.__setattr__(self, "model_table", model.table())
        else:
            check(isinstance(self.model_table, model.table), "model_table", self.model_table,
                  f'must be a {model.table.__name__} with model = "{model.name}"')  # fmt: skip

    # read at every step of the probed loop (``wmr.closedloop.step.actuate``)
    @functools.cached_property
    def ideal(self) -> bool:
        """The paper's plant: every field at its ``ideal`` value, no change."""
        return not self.changes and all(getattr(self, f.name) == f.metadata["ideal"]
                                        for f in spec_fields(type(self)))  # fmt: skip

    def row(self, previous: list | None = None, values: Mapping | None = None) -> list[float]:
        """A row of :data:`COLUMNS`: these parameters (the tables of other models at their
        defaults), or ``previous`` with a change's ``values`` applied."""
        cols = columns(type(self))
        if previous is None:
            current = {}
            for spec in (self, *_column_tables(self)):
                for f in spec_fields(type(spec)):
                    current.update(_cells(f, getattr(spec, f.name)))
        else:
            current = dict(zip(cols, previous, strict=True))
        table, own = MODELS[self.model].table, MODELS[self.model].change_keys
        for key, value in (values or {}).items():
            if key in own:  # a Python-level robot's own parameter: not a column
                continue
            cls = type(self) if key in _names(type(self)) else table
            current.update(_cells(_field(cls, key), value))
        return [float(current[c]) for c in cols]

    def to_json(self) -> dict:
        """The parameters in force at ``t = 0`` and the change schedule (``summary.json``), as
        the file has them: the keys of ``[plant]`` that apply to the model, its table under its
        name, the changes (``changes``)."""
        excluded = MODELS[self.model].excluded
        out = {f.name: _json(getattr(self, f.name)) for f in spec_fields(type(self))
               if f.name not in excluded}  # fmt: skip
        if hasattr(self.model_table, "to_json"):  # a Python-level robot's spec says itself
            out[self.model] = self.model_table.to_json()
        elif self.model_table is not None:
            out[self.model] = {f.name: _json(getattr(self.model_table, f.name))
                               for f in spec_fields(type(self.model_table))}  # fmt: skip
        out["changes"] = [{"at": c.at, **{k: _json(v) for k, v in c.values.items()}}
                          for c in self.changes]  # fmt: skip
        return out

    def describe(self) -> str:
        """One line for table headers and figure titles ("ideal plant" for the paper's)."""
        if self.ideal:
            return "ideal plant"
        parts = [self.model]
        for spec in (self, self.model_table):
            for f in spec_fields(type(spec)) if spec is not None else ():
                value = getattr(spec, f.name)
                if f.name != "model" and (value != f.default or f.metadata["describe"]):
                    parts.append(f.metadata["label"].format(name=f.name, value=_fmt(value)))
        for c in self.changes:
            parts.append(f"at {c.at:g} s: " + ", ".join(
                f"{k} {list(v) if isinstance(v, tuple) else v}" for k, v in c.values.items()))
        return "plant: " + "; ".join(parts)


def _names(cls: type) -> set[str]:
    return {f.name for f in spec_fields(cls)}


def _field(cls: type, name: str) -> dataclasses.Field:
    return next(f for f in spec_fields(cls) if f.name == name)


def _columns(f: dataclasses.Field) -> tuple[str, ...]:
    col = f.metadata["column"]
    return (f.name,) if col is True else tuple(col or ())


def _cells(f: dataclasses.Field, value: Any) -> dict[str, Any]:
    """``{column: value}`` of field ``f`` (a tuple field fills one column per element)."""
    cols = _columns(f)
    if not cols:
        return {}
    return dict(zip(cols, value if isinstance(value, tuple) else (value,), strict=True))


def _column_tables(plant: Plant) -> list:
    """The model tables with columns, in :data:`MODELS` order: the plant's own, the others at
    their defaults (their columns are in every row, unread by the other models)."""
    return [plant.model_table if isinstance(plant.model_table, m.table) else m.table()
            for m in MODELS.values()
            if m.table is not None and any(_columns(f) for f in spec_fields(m.table))]


def columns(plant: type = Plant) -> tuple[str, ...]:
    """The columns of the compiled plant's parameter table: the ``column`` fields of ``plant``
    (:class:`Plant`), then those of each model's table, in declaration order."""
    tables = [m.table for m in MODELS.values() if m.table is not None]
    return tuple(c for cls in (plant, *tables) for f in spec_fields(cls) for c in _columns(f))


#: Columns of a row of the compiled plant's parameter table (``wmr.robots.plant.PARAMS`` adds
#: ``substeps``).
COLUMNS: tuple[str, ...] = columns()


def changeable(model: str, plant: type = Plant) -> tuple[str, ...]:
    """The keys a ``[[plant.change]]`` may set with ``model``: the changeable keys of
    ``[plant]`` (the fields of ``plant``) that apply to it, then those of its table."""
    m = MODELS[model]
    keys = [f.name for f in spec_fields(plant)
            if f.metadata["changeable"] and f.name not in m.excluded]  # fmt: skip
    if m.table is not None:
        keys += [f.name for f in spec_fields(m.table) if f.metadata["changeable"]]
    keys += [k for k in m.change_keys if k not in keys]
    return tuple(keys)


#: Every key a ``[[plant.change]]`` may set with some model (``model``, ``delay_steps``,
#: ``nominal_*`` and ``bandwidth`` describe the robot's build and its inner loop: they cannot
#: change mid-run).
PLANT_CHANGEABLE: tuple[str, ...] = tuple(dict.fromkeys(k for m in MODELS for k in changeable(m)))


def _required(table: Mapping, key: str, where: str):
    if key not in table:
        raise SettingError(f"{where}.{key}", None, "required key is missing")
    return table[key]


def _change(table: Any, where: str, context: Context, model: Model, base: Mapping,
            own: Mapping, spec: Any = None) -> PlantChange:
    """One ``[[plant.change]]`` table, validated against the plant's ``model``: each key with
    the type and rule it has in ``[plant]`` (``base``) or in the model's table (``own``)."""
    check(isinstance(table, Mapping), where, table, "must be a table")
    duration = context.duration
    at = number(f"{where}.at", _required(table, "at", where))
    check(0.0 <= at < duration, f"{where}.at", at, f"must be in [0, duration = {duration})")
    allowed = changeable(model.name)
    values = {}
    for key, value in table.items():
        if key == "at":
            continue
        if key not in allowed:
            owner = next((m for m in MODELS if m != model.name and key in changeable(m)), None)
            reason = f'is a key of model = "{owner}"' if owner else "cannot change mid-run"
            raise SettingError(f"{where}.{key}", value, f'{reason} (changeable with model = '
                               f'"{model.name}": {", ".join(allowed)})')  # fmt: skip
        if key in model.change_keys:  # a Python-level robot's own key: the robot applies it
            values[key] = model.change_rule(spec, key, value, f"{where}.{key}", context)
            continue
        if key in _names(Plant):  # the fields of [plant] (base), else the model's table (own)
            checked = from_table(Plant, {**base, key: value}, where)
        else:
            checked = from_table(model.table, {**own, key: value}, where)
        values[key] = getattr(checked, key)
    check(values != {}, where, dict(table), "changes nothing (give at least one key)")
    return PlantChange(at, values)


def parse(data: Any, context: Context) -> Plant:
    """``[plant]`` with its model's table and ``[[plant.change]]``, validated (DESIGN §3.3), in
    the scenario's ``context``.

    Raises :class:`SettingError` naming the dotted key (``plant.<...>``) and the value.
    """
    check(isinstance(data, Mapping), "plant", data, "must be a table")
    for old, new in RENAMED.items():
        if old in data:
            raise SettingError(f"plant.{old}", None, f'was renamed: use [plant.{new}] with '
                               f'model = "{new}" (DESIGN §3.3)')  # fmt: skip
    tables = [m for m in MODELS.values() if m.has_table]
    base = {k: v for k, v in data.items() if k != "change" and k not in {m.name for m in tables}}
    name = base.get("model", next(iter(MODELS)))
    _model_rule("plant.model", name)
    model = MODELS[name]
    for key in model.excluded:
        if key in base:
            raise SettingError(f"plant.{key}", base[key], f'is not a key of model = "{name}" '
                               f"({model.why})")  # fmt: skip
    plant = from_table(Plant, base, "plant")
    own, model_table = {}, None
    for m in tables:
        given = data.get(m.name)
        if m is model:
            check(given is not None, f"plant.{m.name}", None,
                  f'is required with model = "{m.name}"')  # fmt: skip
            own = given
            if m.parse_table is not None:
                model_table = m.parse_table(given, context)
            else:
                model_table = from_table(m.table, given, f"plant.{m.name}")
            if m.finish is not None:
                model_table = m.finish(model_table, context)
        else:
            check(given is None, f"plant.{m.name}", given,
                  f'is only allowed with model = "{m.name}"')  # fmt: skip
    events = data.get("change", [])
    check(isinstance(events, list), "plant.change", events,
          "must be an array of tables ([[plant.change]])")  # fmt: skip
    changes = [_change(t, f"plant.change[{i}]", context, model, base, own, model_table)
               for i, t in enumerate(events)]  # fmt: skip
    changes.sort(key=lambda c: c.at)  # stable: changes at the same time apply in file order
    return dataclasses.replace(plant, model_table=model_table, changes=tuple(changes))
