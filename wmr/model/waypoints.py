"""Waypoint references (DESIGN §3.4): a time-parametrised spline through ``(t, x, y)`` points.

```toml
[reference]
kind = "waypoints"
file = "path.csv"            # columns t,x,y with a header; relative to the scenario file
# or: points = [[t, x, y], ...]   at least 6 rows, t strictly increasing
```

The path is the interpolating quintic B-spline of ``(x, y)`` in ``t`` (``scipy.interpolate.
make_interp_spline``, ``k = 5``, not-a-knot ends: C⁴, so ``theta_r``, ``v_r`` and ``w_r`` come from
continuous analytic first and second derivatives as in ``wmr.model.references``).  Six points is the
least a quintic needs.  The points must cover the run (first ``t <= 0``, last ``t >= duration``;
the spline is not extrapolated), and the path's speed must stay above :data:`MIN_SPEED` at every
sample time (``theta_r`` is undefined where the robot would stand still).
"""

from __future__ import annotations

import csv
import functools
import io
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from wmr._settings import SettingError, check, number

__all__ = ["MIN_ROWS", "MIN_SPEED", "parse", "path", "validate", "spline"]

#: Fewest points: a quintic spline needs six.
MIN_ROWS = 6
#: Lowest path speed [m/s] allowed at a sample time.
MIN_SPEED = 1e-6
_KEYS = ("file", "points")


def _rows_from_file(name: Any, source: str) -> list[list[float]]:
    check(isinstance(name, str) and name != "", "reference.file", name,
          "must be a file name (columns t,x,y with a header)")  # fmt: skip
    base = Path(source).parent if source and not source.startswith("<") else Path(".")
    path = base / name
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        reason = err.strerror if isinstance(err, OSError) and err.strerror else "not UTF-8 text"
        raise SettingError("reference.file", name, f"cannot read {path}: {reason}") from None
    rows = list(csv.reader(io.StringIO(text)))
    check(len(rows) > 0, "reference.file", name, "is empty (needs a header t,x,y)")
    header = [c.strip() for c in rows[0]]
    check(header == ["t", "x", "y"], "reference.file", name,
          f"header must be t,x,y, is {','.join(header)}")  # fmt: skip
    out = []
    for i, row in enumerate(rows[1:], start=2):
        if not any(c.strip() for c in row):
            continue  # blank line
        check(len(row) == 3, f"reference.file {name} row {i}", ",".join(row),
              f"must have 3 cells (t,x,y), has {len(row)}")  # fmt: skip
        cells = []
        for col, cell in zip(("t", "x", "y"), row, strict=True):
            try:
                value = float(cell)
            except ValueError:
                value = math.nan
            check(math.isfinite(value), f"reference.file {name} row {i} column {col}", cell,
                  "must be a finite number")  # fmt: skip
            cells.append(value)
        out.append(cells)
    return out


def _rows_from_points(points: Any) -> list[list[float]]:
    check(isinstance(points, list), "reference.points", points,
          "must be an array of [t, x, y] rows")  # fmt: skip
    out = []
    for i, row in enumerate(points):
        check(isinstance(row, list) and len(row) == 3, f"reference.points[{i}]", row,
              "must be [t, x, y]")  # fmt: skip
        out.append([number(f"reference.points[{i}][{j}]", v) for j, v in enumerate(row)])
    return out


def parse(table: Mapping[str, Any], source: str) -> dict:
    """``{"points": ((t, x, y), ...)}`` from the ``[reference]`` table (``file`` or ``points``);
    :class:`SettingError` naming the file, row or key otherwise."""
    for key in table:
        if key != "kind":
            check(key in _KEYS, f"reference.{key}", table[key],
                  "unknown key for kind 'waypoints' (known: kind, file, points)")  # fmt: skip
    has_file, has_points = "file" in table, "points" in table
    check(has_file != has_points, "reference", None, "give exactly one of file or points")
    where = f"reference.file {table['file']}" if has_file else "reference.points"
    rows = _rows_from_file(table["file"], source) if has_file else _rows_from_points(
        table["points"])  # fmt: skip
    check(len(rows) >= MIN_ROWS, where, len(rows), f"needs at least {MIN_ROWS} rows")
    for i in range(1, len(rows)):
        check(rows[i][0] > rows[i - 1][0], f"{where} row {i + (2 if has_file else 0)}",
              rows[i][0], f"t must be strictly increasing (previous {rows[i - 1][0]})")
    return {"points": tuple(tuple(r) for r in rows)}


@functools.lru_cache(maxsize=32)
def spline(points: tuple):
    """The quintic interpolating spline of ``(x, y)`` over ``t`` through ``points`` (cached)."""
    from scipy.interpolate import make_interp_spline

    a = np.array(points, dtype=float)
    return make_interp_spline(a[:, 0], a[:, 1:], k=5)


def path(params: Mapping, t):
    """Through the waypoints ``params["points"]``: the spline and its analytic derivatives."""
    s = spline(params["points"])
    p, d1, d2 = s(t), s(t, nu=1), s(t, nu=2)
    return p[..., 0], p[..., 1], d1[..., 0], d1[..., 1], d2[..., 0], d2[..., 1]


def validate(params: Mapping, duration: float, dt: float) -> None:
    """The points cover ``[0, duration]`` and the speed stays above :data:`MIN_SPEED` at every
    sample time ``k dt``, ``k = 0 .. N``."""
    t = np.array([r[0] for r in params["points"]])
    check(t[0] <= 0.0, "reference", float(t[0]),
          "the first waypoint time must be <= 0 (the path must cover the run)")  # fmt: skip
    check(duration <= t[-1], "duration", duration,
          f"is beyond the last waypoint time t = {t[-1]:g}")  # fmt: skip
    s = spline(params["points"]).derivative(1)
    n = round(duration / dt)
    for k0 in range(0, n + 1, 1_000_000):
        ts = np.arange(k0, min(k0 + 1_000_000, n + 1)) * dt
        d = s(ts)
        speed = np.hypot(d[:, 0], d[:, 1])
        i = int(np.argmin(speed))
        check(speed[i] >= MIN_SPEED, "reference", f"speed {speed[i]:.3g} m/s at t = {ts[i]:g} s",
              f"the path's speed must stay above {MIN_SPEED} m/s (theta_r is undefined)")
