"""The settings reference (``docs/settings.md``), generated from the settings dataclasses.

Every key a scenario file accepts, with its type, default, unit and meaning, is read from the
code that validates it: the fields of the frozen dataclasses (``wmr.scenario``, each
controller's ``Settings``), their numpydoc ``Attributes`` sections (``name : type [unit]`` then
the meaning), and the reference-kind registry.  A field without documentation is an error here,
so the reference cannot silently fall behind the code; ``tests/test_settings_reference.py``
checks that ``docs/settings.md`` is current.  Regenerate it with
``wmr settings --out docs/settings.md``.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import re
import typing

from wmr import controllers
from wmr import scenario as scn
from wmr.model import references
from wmr.robots import plantspec

__all__ = ["attribute_docs", "markdown"]

_ENTRY = re.compile(r"^(?P<names>[A-Za-z_][\w, ]*?)\s*:\s*(?P<type>[^\[]*?)\s*(\[(?P<unit>.*)\])?$")


def attribute_docs(cls: type) -> dict[str, tuple[str, str]]:
    """``{field: (unit, meaning)}`` from the numpydoc ``Attributes`` sections of ``cls`` and its
    bases (a subclass documents only what it adds)."""
    out: dict[str, tuple[str, str]] = {}
    for klass in reversed(cls.__mro__):
        doc = inspect.cleandoc(klass.__dict__.get("__doc__") or "")
        lines = doc.splitlines()
        if "Attributes" not in lines:
            continue
        i = lines.index("Attributes") + 2
        names: list[str] = []
        unit, text = "", []
        for line in [*lines[i:], ""]:
            if line and not line.startswith(" "):  # a new entry (or the end of the section)
                if names:
                    for n in names:
                        out[n] = (unit, " ".join(text))
                m = _ENTRY.match(line)
                if m is None:
                    break
                names = [n.strip() for n in m["names"].split(",")]
                unit, text = (m["unit"] or "").strip(), []
            elif line.strip():
                text.append(line.strip())
            elif names:
                for n in names:
                    out[n] = (unit, " ".join(text))
                names = []
    return out


def _type_name(annotation, default) -> str:
    if annotation in (float, "float"):
        return "float"
    if annotation in (int, "int"):
        return "integer"
    if annotation in (bool, "bool"):
        return "boolean"
    if annotation in (str, "str"):
        return "string"
    if typing.get_origin(annotation) is tuple:
        n = len(default) if isinstance(default, tuple) else None
        return f"{n} floats (or one for all)" if n else "array of floats"
    return str(annotation)


def _toml(value) -> str:
    if value is dataclasses.MISSING:
        return "required"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float) and math.isinf(value):
        return "inf (none)"
    if isinstance(value, tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return repr(value)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def _table(cls: type, prefix: str, skip: tuple[str, ...] = ()) -> list[str]:
    """The Markdown table of the fields of ``cls`` (keys ``prefix + field``)."""
    docs = attribute_docs(cls)
    hints = typing.get_type_hints(cls)
    lines = ["| key | type | default | unit | meaning |", "|---|---|---|---|---|"]
    for f in dataclasses.fields(cls):
        if not f.init or f.name in skip or not f.metadata.get("toml", True):
            continue
        if f.name not in docs:
            raise ValueError(f"{cls.__module__}.{cls.__qualname__}.{f.name} is not documented "
                             "in its Attributes section")  # fmt: skip
        unit, meaning = docs[f.name]
        default = f.default
        if default is dataclasses.MISSING and f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        lines.append(f"| `{prefix}{f.name}` | {_type_name(hints[f.name], default)} | "
                     f"{_cell(_toml(default))} | {_cell(unit or '-')} | {_cell(meaning)} |")
    return lines


def _references() -> list[str]:
    lines = ["| kind | key | unit | must be | path |", "|---|---|---|---|---|"]
    for kind in references.KINDS.values():
        path = " ".join(inspect.cleandoc(kind.path.__doc__ or "").split())
        for i, (p, u) in enumerate(zip(kind.params, kind.units, strict=True)):
            rule = "> 0" if p in kind.positive else ("see DESIGN §3.4" if kind.parse else "finite")
            lines.append(f"| `{kind.name}` | `reference.{p}` | {u} | {rule} | "
                         f"{_cell(path) if i == 0 else ''} |")
    return lines


def markdown() -> str:
    """The whole settings reference, as Markdown."""
    out = [
        "# Settings reference",
        "",
        "Generated by `wmr settings` from the settings dataclasses and their docstrings (do not "
        "edit by hand; `tests/test_settings_reference.py` checks it is current).  Every key of a "
        "scenario file, with its type, default, unit and meaning.  Unknown keys are errors; a "
        "vector setting given one number sets every entry.  Units: `SI` = the SI unit that makes "
        "the equation dimensionally consistent; `-` = dimensionless.",
        "",
        "## Scenario (top level)",
        "",
        *_table(scn.Scenario, "", skip=("reference", "noise", "disturbances", "limits",
                                        "estimator", "plant", "controllers", "source")),
        "",
        "## `[reference]`",
        "",
        "`kind` is one of " + ", ".join(f"`{k}`" for k in references.KINDS) + "; each kind "
        "takes exactly its keys.  θ_r, v_r, w_r follow from the path's analytic derivatives "
        "(DESIGN §3.1).",
        "",
        *_references(),
        "",
        "## `[noise]`",
        "",
        *_table(scn.Noise, "noise."),
        "",
        "## `[[disturbance]]` (zero or more)",
        "",
        *_table(scn.Disturbance, "disturbance."),
        "",
        "## `[limits]`",
        "",
        *_table(scn.Limits, "limits."),
        "",
        "## `[estimator]`",
        "",
        *_table(scn.Estimator, "estimator."),
        "",
        "## `[plant]`: the true robot (DESIGN §3.3)",
        "",
        "Absent, the plant is the ideal unicycle the controllers assume (the paper's).  "
        "Controllers and the pose filter always keep the nominal model.",
        "",
        *_table(scn.Plant, "plant."),
        "",
    ]
    for m in plantspec.MODELS.values():
        if m.table is not None:
            excluded = ", ".join(f"`{k}`" for k in m.excluded)
            out += [f"## `[plant.{m.name}]` (with `model = \"{m.name}\"` only, and required then)",
                    "", f"{m.doc[0].upper()}{m.doc[1:]}."
                    + (f"  With this model these keys of `[plant]` are errors: {excluded} "
                       f"({m.why})." if excluded else ""),
                    "", *_table(m.table, f"plant.{m.name}."), ""]  # fmt: skip
    out += [
        "## `[[plant.change]]` (zero or more)",
        "",
        "`at` [s] (finite, 0 <= at < duration): from the first step with t_k >= at the other keys "
        "of the table take their new values, each with the type and rule of the same key above.  "
        "Changeable: " + "; ".join(f"with `model = \"{m}\"` " + ", ".join(
            f"`{k}`" for k in plantspec.changeable(m)) for m in plantspec.MODELS) + ".",
        "",
    ]
    for name, ctrl in controllers.REGISTRY.items():
        out += [f"## `[controllers.{name}]` ({ctrl.label})", "",
                *_table(ctrl.Settings, f"controllers.{name}."), ""]  # fmt: skip
    return "\n".join(out)
