"""The regime study's design (issue 22): mechanisms, trajectories, the training set, the arms'
scenarios and the matched-arms check (DESIGN §7.1).

Evaluation: the mechanisms of :data:`MECHANISMS` (the plant tables of DESIGN §3.3 and the
MuJoCo robot of §3.7) on the trajectories of :data:`TRAJECTORIES` (the paper's three plus two
held out: the shipped waypoint lane change and a circle).  Training (the tuning stage,
``analysis.tuning``): other trajectories on other plants (:data:`TRAINING`), disjoint from the
evaluation in both: no trajectory and no plant parameter of the one is in the other.
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path

from wmr import scenario as scn

__all__ = ["MECHANISMS", "MUJOCO", "TRAJECTORIES", "TRAINING", "document", "evaluation_text",
           "training_documents", "training_on", "context", "arm_entry", "COMPARED", "matched",
           "MatchError", "FROZEN"]  # fmt: skip

#: The evaluation's plant mechanisms: the ``[plant]`` table of each (TOML text).
MECHANISMS = {
    "ideal": "",
    "wheel-radius": "[plant]\nv_gain = 0.8\nw_gain = 0.8\n",
    "unequal-wheels": "[plant]\nv_from_w = 0.0075\nw_from_v = 0.3333333333333333\n",
    "lag-delay": "[plant]\nactuator_tau = 0.1\ndelay_steps = 2\n",
    "slip": "[plant]\nslip = 0.1\n",
    "lagged-velocity-change": ('[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\n'
                               "mass = 10.0\ninertia = 0.5\nfriction = [0.5, 0.02]\n"
                               "[[plant.change]]\nat = 20.0\nmass = 15.0\ninertia = 0.75\n"),
}  # fmt: skip
#: The MuJoCo robot's mechanisms: the shipped scenario whose ``[plant]`` each takes.
MUJOCO = {"mujoco": "mujoco/lemniscate", "mujoco-low-friction": "mujoco/lemniscate-low-friction",
          "mujoco-payload": "mujoco/lemniscate-payload"}  # fmt: skip
#: Evaluation trajectories: the paper's three, the shipped lane change, a circle (TOML of the
#: circle's scenario; the others are shipped).
TRAJECTORIES = ("lemniscate", "sinusoid", "sinusoid-perturbed", "waypoints-lane-change",
                "circle")  # fmt: skip
_CIRCLE = ('name = "circle"\nduration = 40.0\ndt = 0.01\ninitial_pose = [1.0, -0.3, 1.2]\n'
           '[reference]\nkind = "circle"\nradius = 1.0\nperiod = 20.0\n'
           "[noise]\npose_std = [0.01, 0.01, 0.01]\n")  # fmt: skip
#: Training pairs (trajectory, plant): a smaller faster lemniscate, a sinusoid of other
#: geometry with another disturbance, an S-shaped waypoint path; plants at other magnitudes
#: of the mechanisms (and the ideal one).
_TRAIN_REF = {
    "train-lemniscate": ('kind = "lemniscate"\nsize = 1.5\nperiod = 30.0\n', [0.0, -0.5, 1.2],
                         None),
    "train-sinusoid": ('kind = "sinusoid"\nspeed = 0.4\namplitude = 0.7\nomega = 0.7\n',
                       [0.0, 0.2, 0.0], (0.15, -0.2)),
    "train-s-curve": ('kind = "waypoints"\npoints = ' + str(
        [[t, 0.4 * t, 0.6 * __import__("math").sin(0.35 * t)] for t in range(-2, 26, 2)]) + "\n",
        [0.0, -0.15, 0.1], None),
}  # fmt: skip
_TRAIN_PLANT = {
    "ideal": "",
    "gains": "[plant]\nv_gain = 0.9\nw_gain = 1.15\n",
    "lag": "[plant]\nactuator_tau = 0.05\ndelay_steps = 1\n",
    "slip": "[plant]\nslip = 0.05\n",
    "coupling": "[plant]\nv_from_w = 0.004\nw_from_v = 0.15\n",
}  # fmt: skip
TRAINING = (("train-lemniscate", "ideal"), ("train-sinusoid", "gains"), ("train-s-curve", "lag"),
            ("train-lemniscate", "slip"), ("train-sinusoid", "coupling"))  # fmt: skip


def _points_text(path: Path) -> str:
    """A waypoint file's rows as a TOML ``points = [[t, x, y], ...]`` line."""
    with path.open(newline="") as fh:
        rows = [[float(v) for v in r] for r in list(csv.reader(fh))[1:] if r]
    return f"points = {rows}"


def evaluation_text(trajectory: str, mechanism: str, duration: float | None = None) -> str:
    """The scenario (TOML text) of ``trajectory`` on ``mechanism``, named
    ``trajectory@mechanism``: the shipped trajectory's file (a waypoint table's points inlined,
    so the text stands alone) with the mechanism's ``[plant]`` appended (the MuJoCo robot's from
    its shipped scenario); ``duration`` [s] overrides the file's."""
    if trajectory == "circle":
        text = _CIRCLE
    else:
        path = scn.builtin(trajectory)
        text = path.read_text()
        m = re.search(r'^file = "([^"]+)".*$', text, flags=re.M)
        if m:
            text = text.replace(m.group(0), _points_text(path.parent / m.group(1)))
    text = re.sub(r'^name = ".*"', f'name = "{trajectory}@{mechanism}"', text, count=1,
                  flags=re.M)  # fmt: skip
    if duration:
        text = re.sub(r"^duration = [0-9.]+", f"duration = {float(duration)}", text, count=1,
                      flags=re.M)  # fmt: skip
    if mechanism in MUJOCO:
        robot = scn.builtin(MUJOCO[mechanism]).read_text()
        plant = robot[robot.index("\n[plant]") + 1:]
    else:
        plant = MECHANISMS[mechanism]
    return text + "\n" + plant


def document(trajectory: str, mechanism: str = "ideal", duration: float | None = None) -> dict:
    """:func:`evaluation_text` parsed (a TOML document)."""
    return tomllib.loads(evaluation_text(trajectory, mechanism, duration))


def training_documents(duration: float = 20.0, count: int | None = None) -> dict[str, dict]:
    """The training scenarios' documents (``trajectory@plant`` -> document), ``duration`` s;
    the first ``count`` of :data:`TRAINING` (None: all)."""
    out = {}
    for ref, plant in TRAINING[:count]:
        text, pose, dist = _TRAIN_REF[ref]
        body = (f'name = "{ref}@{plant}"\nduration = {duration}\ndt = 0.01\ninitial_pose = {pose}\n'
                f"[reference]\n{text}[noise]\npose_std = [0.01, 0.01, 0.01]\n")
        if dist:
            body += (f"[[disturbance]]\nstart = {0.4 * duration}\nstop = {0.6 * duration}\n"
                     f"velocity = [{dist[0]}, {dist[1]}]\n")  # 8-12 s of a 20 s run
        doc = tomllib.loads(body)
        if _TRAIN_PLANT[plant]:
            doc.update(tomllib.loads(_TRAIN_PLANT[plant]))
        out[f"{ref}@{plant}"] = doc
    return out


def training_on(mechanism: str, duration: float = 20.0) -> dict[str, dict]:
    """The training trajectories on the evaluation ``mechanism``'s plant (a controller tuned for
    a known robot: the trajectories stay disjoint from the evaluation's)."""
    out = {}
    for ref, (text, pose, dist) in _TRAIN_REF.items():
        body = (f'name = "{ref}@{mechanism}"\nduration = {duration}\ndt = 0.01\n'
                f"initial_pose = {pose}\n[reference]\n{text}[noise]\n"
                "pose_std = [0.01, 0.01, 0.01]\n")
        if dist:
            body += (f"[[disturbance]]\nstart = {0.4 * duration}\nstop = {0.6 * duration}\n"
                     f"velocity = [{dist[0]}, {dist[1]}]\n")
        plant = MECHANISMS[mechanism].replace("at = 20.0", f"at = {0.5 * duration}")  # mid-run
        out[f"{ref}@{mechanism}"] = tomllib.loads(body + "\n" + plant)
    return out


#: What switches each adaptive arm's adaptation off, written over its tuned settings (the run
#: level "tuned-frozen": ``analysis.regimes.frozen``): the SGD off for the PID family (the
#: identifier of IAPID still learns, its Jacobian unused); DA-NN's weight filter without
#: covariance (``P0 = 1e-12 I``, ``Q = 0``: its compensator, initialised to zero, stays ~0, so it
#: is backstepping at DA-NN's gains); adaptive BSC's ``P(0) = 0`` (every estimate frozen at the
#: nominal robot's).
FROZEN = {"adaptive-pid": {"adapt": False}, "iapid-nn-dekf": {"adapt": False},
          "iapid-oracle": {"adapt": False}, "adaptive-nn": {"p0": 1e-12, "q": 0.0},
          "adaptive-bsc": {"adaptation": [0.0, 0.0, 0.0, 0.0]}}  # fmt: skip


# ---------------------------------------------------------------------------------------------
# What each arm ran with, and the matched-arms check


class MatchError(AssertionError):
    """A compared pair of arms differs in more than the compared factor."""


def _plain(x):
    if dataclasses.is_dataclass(x):
        return {f.name: _plain(getattr(x, f.name)) for f in dataclasses.fields(x)}
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, tuple | list):
        return [_plain(v) for v in x]
    return x if isinstance(x, str | int | float | bool | type(None)) else repr(x)


def context(sc: scn.Scenario, controller: str) -> dict:
    """Everything a run of ``controller`` on ``sc`` is made of besides the controller's own
    settings: the scenario's fields (plant, noise, limits, estimator, reference, ...) without
    the controllers' tables and the ``pose_source`` label (which pose ``controller`` acts on is
    :func:`arm_entry`'s ``filtered``: ``Estimator.filters``, the one place of the rule)."""
    d = _plain(sc)
    d.pop("controllers")
    d.pop("source")
    d["estimator"].pop("pose_source")
    return d


def _digest(d) -> str:
    return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()[:16]


def arm_entry(runs: Mapping[str, scn.Scenario], controller: str) -> dict:
    """What an arm ran with, read from the scenarios its runs were made from (``name ->
    Scenario``): its settings (one set for every scenario, else an error), whether it filtered
    the pose, and each scenario's context digest (:func:`context`)."""
    settings = {json.dumps(_plain(sc.settings(controller)), sort_keys=True) for sc in runs.values()}
    if len(settings) != 1:
        raise MatchError(f"{controller} ran with {len(settings)} different settings")
    filtered = {sc.estimator.filters(controller) for sc in runs.values()}
    return {"controller": controller, "settings": json.loads(settings.pop()),
            "filtered": filtered.pop() if len(filtered) == 1 else None,
            "contexts": {n: _digest(context(sc, controller)) for n, sc in runs.items()}}


#: The compared pairs (a, b, factor): ``factor`` names what may differ besides the arms' own
#: tuned settings ("jacobian": the SGD's Jacobian, i.e. the controller; "adapt": adaptation on
#: or off; "arm": a different controller; "oracle": the identifier's training poses).
COMPARED = (("iapid-nn-dekf", "adaptive-pid", "jacobian"), ("adaptive-pid", "pid", "adapt"),
            ("iapid-oracle", "iapid-nn-dekf", "oracle"), ("adaptive-nn", "backstepping", "arm"),
            ("adaptive-bsc", "backstepping", "arm"), ("nmpc", "backstepping", "arm"))  # fmt: skip


def matched(a: dict, b: dict, free: set[str] = frozenset(), factor: str = "arm") -> None:
    """Raise :class:`MatchError` unless arms ``a`` and ``b`` (:func:`arm_entry`) ran on the same
    scenarios with the same context (plant, noise, limits, estimator, reference, seeds' noise)
    and the same pose (both filtered or both raw), and their shared settings agree except the
    ``free`` ones (their tuned settings; empty at the defaults) and ``adapt`` for
    ``factor = "adapt"``; ``factor = "pose"``: the same arm on the two pose sources (then
    ``filtered`` must differ and nothing else)."""
    name = f"{a['controller']} vs {b['controller']}"
    if set(a["contexts"]) != set(b["contexts"]):
        raise MatchError(f"{name}: different scenarios")
    if factor == "pose":
        if a["filtered"] == b["filtered"]:
            raise MatchError(f"{name}: the pose-source pair has the same pose source")
    elif a["filtered"] != b["filtered"] or a["filtered"] is None:
        raise MatchError(f"{name}: pose source differs (filtered {a['filtered']} vs "
                         f"{b['filtered']})")  # fmt: skip
    diff = [n for n in a["contexts"] if a["contexts"][n] != b["contexts"][n]]
    if diff:
        raise MatchError(f"{name}: scenario context differs in {diff[:3]}")
    allowed = set(free) | ({"adapt"} if factor == "adapt" else set())
    shared = set(a["settings"]) & set(b["settings"])
    bad = sorted(k for k in shared - allowed if a["settings"][k] != b["settings"][k])
    if bad:
        raise MatchError(f"{name}: settings differ in {bad}")

