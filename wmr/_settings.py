"""Validated frozen settings: TOML tables to dataclasses, with errors that name key and value.

A settings class is a ``@dataclass(frozen=True)`` whose fields are annotated ``float``, ``int``,
``bool``, ``str`` or ``tuple[float, ...]`` (the length of a tuple field is that of its default;
one number given for such a field sets every entry).
:func:`from_table` converts a TOML table into it, rejecting unknown keys, wrong types, NaN/inf and
wrong lengths; the class's ``__post_init__`` checks meaning (signs, ranges) and raises
:class:`SettingError` naming the field.
"""

from __future__ import annotations

import dataclasses
import math
import typing
from collections.abc import Mapping
from typing import Any

__all__ = [
    "FrozenMap",
    "InputError",
    "SettingError",
    "from_table",
    "check",
    "number",
    "finite",
    "positive",
    "nonnegative",
    "one_line",
]


class FrozenMap(Mapping):
    """A read-only, picklable mapping (``types.MappingProxyType`` cannot be pickled to workers)."""

    __slots__ = ("_data",)

    def __init__(self, data=()):
        object.__setattr__(self, "_data", dict(data))

    def __getitem__(self, key):
        return self._data[key]

    def __iter__(self):
        return iter(self._data)

    def __len__(self):
        return len(self._data)

    def __repr__(self):
        return f"FrozenMap({self._data!r})"

    def __eq__(self, other):
        return isinstance(other, Mapping) and dict(self.items()) == dict(other.items())

    def __hash__(self):
        return hash(tuple(sorted(self._data.items(), key=repr)))

    def __getstate__(self):
        return self._data

    def __setstate__(self, state):
        object.__setattr__(self, "_data", dict(state))


def one_line(text: str) -> str:
    """``text`` with non-printable characters escaped, so a message naming it stays one line.

    TOML allows any character in quoted keys and file names may hold newlines; the error contract
    (DESIGN §3.2) is a single line.
    """
    text = str(text)
    return text if text.isprintable() else text.encode("unicode_escape").decode("ascii")


class InputError(ValueError):
    """Bad input from a file: ``source`` file, dotted ``key``, offending ``value`` (None: not
    shown) and the ``reason``, as one line ``source: key = value: reason`` (DESIGN §3.2)."""

    def __init__(self, source: str, key: str, value: Any, reason: str):
        self.source, self.key, self.value, self.reason = source, key, value, reason
        shown = "" if value is None else f" = {value!r}"
        super().__init__(f"{one_line(source)}: {one_line(key)}{shown}: {reason}")


class SettingError(ValueError):
    """An invalid setting: ``key`` (dotted path), offending ``value`` and the ``reason``."""

    def __init__(self, key: str, value: Any, reason: str):
        self.key, self.value, self.reason = key, value, reason
        super().__init__(f"{one_line(key)} = {value!r}: {reason}")


def check(ok: bool, key: str, value: Any, reason: str) -> None:
    """Raise :class:`SettingError` unless ``ok``."""
    if not ok:
        raise SettingError(key, value, reason)


def number(key: str, value: Any) -> float:
    """``value`` as a finite float.

    :class:`SettingError` for non-numbers (bools included), NaN/inf and integers too large for a
    float.
    """
    ok = isinstance(value, int | float) and not isinstance(value, bool)
    check(ok, key, value, "must be a number")
    try:
        out = float(value)
    except OverflowError:  # a Python int beyond 1.8e308 (from_dict callers; TOML ints are 64-bit)
        out = math.inf
    check(math.isfinite(out), key, value, "must be a finite number")
    return out


def finite(key: str, value: float) -> None:
    check(math.isfinite(value), key, value, "must be a finite number")


def positive(key: str, value: float) -> None:
    check(math.isfinite(value) and value > 0, key, value, "must be a finite number > 0")


def nonnegative(key: str, value: float) -> None:
    check(math.isfinite(value) and value >= 0, key, value, "must be a finite number >= 0")


def _convert(key: str, value: Any, annotation: Any, default: Any) -> Any:
    origin = typing.get_origin(annotation)
    if annotation is bool:
        check(isinstance(value, bool), key, value, "must be true or false")
        return value
    if annotation is int:
        is_int = isinstance(value, int) and not isinstance(value, bool)
        check(is_int, key, value, "must be an integer")
        return value
    if annotation is float:
        return number(key, value)
    if annotation is str:
        check(isinstance(value, str), key, value, "must be a string")
        return value
    if origin is tuple:
        has_length = default is not dataclasses.MISSING and default is not None
        if has_length and isinstance(value, int | float) and not isinstance(value, bool):
            value = [value] * len(default)  # one number sets every entry (mu = 0.9)
        check(isinstance(value, list | tuple), key, value,
              "must be an array of numbers" + (" or one number for all" if has_length else ""))
        if has_length:
            n = len(default)
            check(len(value) == n, key, value, f"must have {n} elements, has {len(value)}")
        out = []
        for i, item in enumerate(value):
            out.append(_convert(f"{key}[{i}]", item, float, dataclasses.MISSING))
        return tuple(out)
    raise TypeError(f"unsupported settings annotation {annotation!r} for {key}")


def from_table(cls: type, table: Mapping[str, Any], where: str) -> Any:
    """Build the frozen dataclass ``cls`` from a TOML ``table`` found at dotted path ``where``.

    Fields with ``metadata={"toml": False}`` are not keys of the table (the caller builds them).
    Unknown keys, wrong types, non-finite numbers and wrong tuple lengths raise
    :class:`SettingError` with the full dotted key; so does any :class:`SettingError` or
    ``ValueError`` raised by the class's ``__post_init__`` (a plain ``ValueError`` is reported
    against the table ``where``).
    """
    if not isinstance(table, Mapping):
        raise SettingError(where, table, "must be a table")
    hints = typing.get_type_hints(cls)
    # a field with metadata {"toml": False} is built by the caller, not read from the table
    fields = {f.name: f for f in dataclasses.fields(cls)
              if f.init and f.metadata.get("toml", True)}  # fmt: skip
    prefix = f"{where}." if where else ""
    for name in table:
        if name not in fields:
            raise SettingError(
                f"{prefix}{name}", table[name], f"unknown key (known: {', '.join(sorted(fields))})"
            )
    kwargs = {}
    for name, f in fields.items():
        if name in table:
            default = f.default
            if default is dataclasses.MISSING and f.default_factory is not dataclasses.MISSING:
                default = f.default_factory()
            kwargs[name] = _convert(f"{prefix}{name}", table[name], hints[name], default)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            raise SettingError(f"{prefix}{name}", None, "required key is missing")
    try:
        return cls(**kwargs)
    except SettingError as err:
        key = err.key if err.key.startswith(prefix) or not prefix else f"{prefix}{err.key}"
        raise SettingError(key, err.value, err.reason) from None
    except ValueError as err:  # e.g. zip(strict=True) in a __post_init__: still a bad table
        reason = (str(err).splitlines() or ["invalid settings"])[0]
        raise SettingError(where, dict(table), reason) from None
