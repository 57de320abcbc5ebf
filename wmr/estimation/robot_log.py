"""A robot's log as ``wmr identify`` reads it: the columns, the checks, the :class:`Log`.

A log is a CSV text file with a header: ``t`` [s] (uniformly sampled), the command ``v``, ``w``
[m/s, rad/s] sent at ``t``, the measured pose ``x_meas``, ``y_meas``, ``theta_meas`` [m, m, rad]
and, optionally, the disturbance in force ``dv``, ``dw`` (``wmr run``'s trajectory CSV has them
all).  Any problem is a :class:`LogError`: one line naming the file, line/column and value.  The
names are also reachable as ``wmr.estimation.identify.<name>``.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass

import numpy as np

from wmr._settings import InputError

__all__ = ["LogError", "Log", "read_log", "REQUIRED", "OPTIONAL", "MIN_ROWS", "DT_RTOL"]

#: Columns a log must have, and those that default to 0.
REQUIRED = ("t", "v", "w", "x_meas", "y_meas", "theta_meas")
OPTIONAL = ("dv", "dw")
#: Fewest rows with a measured pose (0.5 s at 10 ms: enough residuals for 9 parameters).
MIN_ROWS = 50
#: Time steps of ``dt`` may differ by this much (relative) and still count as uniform.
DT_RTOL = 1e-6

class LogError(InputError):
    """A log ``wmr identify`` cannot use: one line naming the file, line/column and value."""


@dataclass(frozen=True)
class Log:
    """A robot's log as :func:`identify` reads it: ``n`` rows ``t_k = t_0 + k dt`` (``dt`` [s]),
    the command ``u`` (n, 2) [m/s, rad/s] sent at ``t_k``, the measured pose ``z`` (n, 3)
    [m, m, rad] and the disturbance ``dist`` (n, 2) in force (zeros if none); ``source`` names it
    in messages."""

    source: str
    dt: float
    u: np.ndarray
    z: np.ndarray
    dist: np.ndarray

    @property
    def n(self) -> int:
        return len(self.u)


def read_log(path) -> Log:
    """Read and check a log (the module's columns); :class:`LogError` on any problem."""
    source = str(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.reader(fh))
    except OSError as err:
        raise LogError(source, "(file)", None, f"cannot read: {err.strerror}") from None
    except (UnicodeDecodeError, csv.Error) as err:
        raise LogError(source, "(file)", None, f"not a CSV text file: {err}") from None
    if not rows:
        raise LogError(source, "(header)", None, "empty file: no header")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise LogError(source, "(header)", None,
                       f"missing column(s) {', '.join(missing)} (needs {', '.join(REQUIRED)}; "
                       f"optional {', '.join(OPTIONAL)})")  # fmt: skip
    names = [c for c in (*REQUIRED, *OPTIONAL) if c in header]
    index = [header.index(c) for c in names]
    body = rows[1:]
    while body and all(i >= len(body[-1]) or not body[-1][i].strip() for i in index[1:]):
        body.pop()  # the last instant of `wmr run`'s CSV has no step after it
    data = np.empty((len(body), len(names)))
    for r, row in enumerate(body):
        line = r + 2
        if len(row) < len(header):
            raise LogError(source, f"line {line}", None,
                           f"has {len(row)} cells, the header {len(header)}")  # fmt: skip
        for c, (i, name) in enumerate(zip(index, names, strict=True)):
            try:
                data[r, c] = float(row[i])
            except ValueError:
                data[r, c] = math.nan
            if not math.isfinite(data[r, c]):
                raise LogError(source, f"line {line} column {name}", row[i].strip(),
                               "not a finite number")  # fmt: skip
    if len(data) < MIN_ROWS:
        raise LogError(source, "(rows)", len(data),
                       f"too short: at least {MIN_ROWS} rows with a command and a measured "
                       "pose are needed")  # fmt: skip
    col = {name: data[:, c] for c, name in enumerate(names)}
    t = col["t"]
    steps = np.diff(t)
    dt = float((t[-1] - t[0]) / (len(t) - 1))
    for bad, why in ((steps <= 0, "not after the previous t = {}"),
                     (np.abs(steps - dt) > DT_RTOL * dt, "not uniformly sampled (the previous t = "
                      "{}, mean step " + repr(dt) + "): the plant's delay is in whole steps")):
        if np.any(bad):
            k = int(np.argmax(bad)) + 1
            raise LogError(source, f"line {k + 2} column t", float(t[k]),
                           why.format(repr(float(t[k - 1]))))  # fmt: skip
    zeros = np.zeros(len(t))
    return Log(source=source, dt=dt, u=np.column_stack((col["v"], col["w"])),
               z=np.column_stack((col["x_meas"], col["y_meas"], col["theta_meas"])),
               dist=np.column_stack((col.get("dv", zeros), col.get("dw", zeros))))  # fmt: skip
