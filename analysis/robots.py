"""Which robot model predicts the physics?  The robot ladder (issue 20, item 3).

The same controllers, at their default settings (tuning is the regime study's job), on the
paper's three trajectories and four rungs of robot model:

- ``kinematic``: the ideal unicycle (the model every controller assumes);
- ``lagged-velocity``: an inner velocity loop with inertia (``[plant] model =
  "lagged-velocity"``, the shipped payload scenario's table without its change);
- ``mujoco``: the MuJoCo differential drive at its nominal parameters (DESIGN §3.7: wheels,
  contact, servos and their torque limit from the physics engine);
- ``fitted``: the kinematic ``[plant]`` that ``wmr identify`` fits to the MuJoCo robot's log
  (backstepping, seed 0, per trajectory): how much of the kinematic-vs-MuJoCo difference a
  fitted kinematic model closes.

Beside the ladder: (a) **agreement** -- with high friction and stiff servos the MuJoCo robot
under backstepping should agree with the kinematic unicycle plus the servo's lag (measured from
the physics' step response) within 5 % of position RMSE or 2 mm, whichever is larger;
(b) **where sliding sets in** -- constant commands on circles over friction, speed and
curvature, the side-slip angle and the wheel slip ratio against the lateral acceleration
``|v w|`` over the Coulomb bound ``mu g``; (c) the **timestep** rule of §3.7 -- how the RMSE
moves when MuJoCo's ``timestep`` is halved.  The agreement is checked at the shipped 2 ms
physics step and at :data:`FINE_TIMESTEP`, backstepping over the first ``side_seeds`` seeds.

Statistics (DESIGN §7): per (trajectory, rung, controller) the mean +- std of the position RMSE
after the transient over the seeds that stayed stable, the diverged count with its exact
(Clopper-Pearson) interval; per (trajectory, rung) paired Wilcoxon tests of every pair of
controllers over the seeds where both stayed stable, Holm-adjusted within the rung; a pair's
**order changes** between two rungs when it is significant on both with opposite signs.
"""

from __future__ import annotations

import itertools
import math
import sys
import time
from pathlib import Path

import numpy as np

from analysis import common
from wmr import scenario as scn
from wmr import stats
from wmr.study import Job, run_jobs

__all__ = ["STEM", "TITLE", "CONTROLLERS", "RUNGS", "run", "check", "render", "table",
           "servo_lag", "sliding_point", "order_changes", "clopper_pearson"]  # fmt: skip

STEM = "robots"
TITLE = "Which robot model predicts the physics? The robot ladder"
#: The arms (every registered controller but the diagnostic oracle; ``nmpc`` joins when it is
#: registered, at ~1 s per run).
CONTROLLERS = ("pid", "adaptive-pid", "iapid-nn-dekf", "backstepping", "adaptive-nn",
               "adaptive-bsc")  # fmt: skip
#: The rungs' ``[plant]`` tables (``fitted`` is made per trajectory by ``wmr identify``).
RUNGS = {
    "kinematic": "",
    "lagged-velocity": ('[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\n'
                        "mass = 10.0\ninertia = 0.5\nfriction = [0.5, 0.02]\n"),
    "mujoco": '[plant]\nmodel = "mujoco"\n[plant.mujoco]\nrobot = "diff-drive"\n',
    "fitted": None,
}  # fmt: skip
#: The stiff robot of the agreement check: high friction and servos 5x stiffer than nominal
#: (motor_gain 10; at 50 the wheel servo oscillates at the 2 ms physics step: a 0.05 rad/s yaw
#: step settles at 0.12 rad/s), the nominal torque limit.
STIFF = {"friction": 2.0, "motor_gain": 10.0}
#: The finer physics step [s] at which the agreement check is repeated (a quarter of the
#: shipped 2 ms): the contact and servo dynamics resolved well below the 10 ms control step.
FINE_TIMESTEP = 0.0005
#: Agreement tolerance of the stiff robot with the kinematic unicycle plus the servo's lag.
AGREE_REL, AGREE_ABS = 0.05, 2e-3
#: The sliding grid: floor friction and constant commands (v [m/s], w [rad/s]).
FRICTIONS = (0.05, 0.1, 0.2, 0.5, 1.0)
COMMANDS = ((0.3, 0.5), (0.5, 1.0), (1.0, 1.0), (1.0, 2.0), (1.5, 2.0), (1.5, 3.0))
#: Servo torque limit [N m] of the sliding map: torque to spare, so that what limits a circle is
#: the floor, not the motor.
SLIDE_TORQUE = 20.0
#: Side-slip angle [rad] above which a steady circle counts as sliding.
SLIDING = 0.02
SEEDS = 20
ALPHA = 0.05
OUTCOME = "tail_position"


def _design(quick: bool) -> dict:
    if quick:
        return {"trajectories": ("lemniscate",), "controllers": ("pid", "backstepping"),
                "seeds": 2, "duration": 10.0, "frictions": (0.1, 1.0),
                "commands": COMMANDS[1:4:2], "side_seeds": 1}  # fmt: skip
    return {"trajectories": scn.PAPER_SCENARIOS, "controllers": CONTROLLERS, "seeds": SEEDS,
            "duration": None, "frictions": FRICTIONS, "commands": COMMANDS,
            "side_seeds": 5}  # fmt: skip


def _scenario(traj: str, rung: str, plant: str, duration: float | None) -> scn.Scenario:
    """The paper's ``traj`` with ``plant`` (a ``[plant]`` table's text) as rung ``rung``."""
    text = scn.builtin(traj).read_text().replace(f'name = "{traj}"', f'name = "{traj}@{rung}"')
    if duration:
        text = text.replace("duration = 40.0", f"duration = {duration}")
    return scn.loads(text + "\n" + plant, source=f"{traj}@{rung}")


def _mujoco(**keys) -> str:
    return RUNGS["mujoco"] + "".join(f"{k} = {v!r}\n" for k, v in keys.items())


def servo_lag(table: dict | None = None, v: float = 0.05, w: float = 0.05) -> dict:
    """The MuJoCo robot's servo lag: the 63 % rise time [s] of its forward speed and yaw rate
    after a step command ``(v, w)`` from rest, at the physics' own timestep (the robot of
    ``[plant.mujoco]`` ``table``, shipped diff-drive by default).

    The default step is small, so the servo stays below its torque limit (its linear regime,
    the one a tracking loop's smooth commands see): a 0.5 m/s step saturates the nominal servos
    and measures their acceleration limit instead (0.066 s against 0.006 s here)."""
    from wmr.mujoco_robot import MujocoRobot, MujocoSpec

    spec = MujocoSpec.from_table({"robot": "diff-drive", **(table or {})}, base_dir=None,
                                 source="servo_lag")  # fmt: skip
    h = spec.timestep
    robot = MujocoRobot(spec, h)
    robot.reset((0.0, 0.0, 0.0))
    vel, out = np.empty(2), []
    n = int(round(0.5 / h))
    for k in range(n):
        robot.advance(k, (v, w))
        robot.velocity(vel)
        out.append(vel.copy())
    y = np.array(out)
    t = h * np.arange(1, n + 1)
    tau = [float(t[np.argmax(y[:, i] >= (1 - math.exp(-1)) * y[-1, i])]) for i in range(2)]
    return {"tau_v": tau[0], "tau_w": tau[1], "final": y[-1].tolist(), "timestep": h}


def sliding_point(friction: float, v: float, w: float, seconds: float = 6.0) -> dict:
    """A steady circle of the MuJoCo robot under the constant command ``(v, w)`` on a floor of
    ``friction``: the mean side-slip angle [rad] and wheel slip ratio over the second half,
    the achieved ``(v, w)``, and the lateral acceleration over the Coulomb bound."""
    from wmr.mujoco_model import GRAVITY
    from wmr.mujoco_robot import MujocoRobot, MujocoSpec

    spec = MujocoSpec.from_table({"robot": "diff-drive", "friction": friction,
                                  "torque_limit": SLIDE_TORQUE}, base_dir=None,
                                 source="sliding")  # fmt: skip
    dt = 0.01
    robot = MujocoRobot(spec, dt)
    robot.reset((0.0, 0.0, 0.0))
    diag, vel = np.empty(9), np.empty(2)
    n = int(round(seconds / dt))
    acc = []
    for k in range(n):
        robot.advance(k, (v, w))
        if k >= n // 2:
            robot.diagnostics(diag)
            robot.velocity(vel)
            acc.append([abs(diag[1]), 0.5 * (abs(diag[2]) + abs(diag[3])), vel[0], vel[1]])
    a = np.mean(acc, axis=0)
    return {"friction": friction, "v": v, "w": w, "demand": abs(v * w) / (friction * GRAVITY),
            "slip_angle": float(a[0]), "slip_ratio": float(a[1]), "v_actual": float(a[2]),
            "w_actual": float(a[3]), "sliding": bool(a[0] > SLIDING)}  # fmt: skip


def clopper_pearson(k: int, n: int, level: float = 0.95) -> list[float]:
    """The exact interval of a proportion ``k / n`` (scipy's ``binomtest``)."""
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(confidence_level=level, method="exact")
    return [float(ci.low), float(ci.high)]


def _fitted_plants(d: dict) -> dict:
    """Per trajectory, the ``[plant]`` that ``wmr identify`` fits to the MuJoCo robot's log of
    backstepping at seed 0 (the full run), with the fit's report."""
    from wmr import identify
    from wmr.sim import simulate

    out = {}
    for traj in d["trajectories"]:
        r = simulate(_scenario(traj, "mujoco", RUNGS["mujoco"], d["duration"]), "backstepping", 0)
        log = identify.Log(source=f"{traj}@mujoco", dt=r.dt, u=r.u, z=r.z, dist=r.disturbance)
        ident = identify.identify(log)
        out[traj] = {"toml": identify.to_toml(ident),
                     "values": {k: float(v) for k, v in ident.values.items()},
                     "delay": int(ident.delay),
                     "not_identifiable": sorted(ident.not_identifiable)}  # fmt: skip
    return out


def _jobs(d: dict, fitted: dict, lag: dict) -> list[Job]:
    """The ladder (every rung x controller x trajectory x seed), the stiff pair of the agreement
    check (backstepping), and the halved timestep (backstepping)."""
    jobs = []
    for traj in d["trajectories"]:
        plants = {**{r: p for r, p in RUNGS.items() if p is not None},
                  "fitted": fitted[traj]["toml"]}  # fmt: skip
        for rung, plant in plants.items():
            sc = _scenario(traj, rung, plant, d["duration"])
            jobs += [Job(sc, c, s, variant=rung) for c in d["controllers"]
                     for s in range(d["seeds"])]  # fmt: skip
        tau = 0.5 * (lag["tau_v"] + lag["tau_w"])
        extra = {"stiff-mujoco": _mujoco(**STIFF),
                 "stiff-mujoco-fine": _mujoco(**STIFF, timestep=FINE_TIMESTEP),
                 "kinematic+lag": f"[plant]\nactuator_tau = {tau!r}\n",
                 "mujoco-half-timestep": _mujoco(timestep=0.001)}  # fmt: skip
        for rung, plant in extra.items():
            sc = _scenario(traj, rung, plant, d["duration"])
            jobs += [Job(sc, "backstepping", s, variant=rung) for s in range(d["side_seeds"])]
    return jobs


def _cell(rows) -> dict:
    stable = [r for r in rows if not r.diverged]
    x = np.array([getattr(r, OUTCOME) for r in stable])
    k = len(rows) - len(stable)
    return {"n": len(rows), "stable": len(stable), "diverged": k,
            "diverged_ci": clopper_pearson(k, len(rows)),
            "mean": float(x.mean()) if len(x) else None,
            "std": float(x.std(ddof=1)) if len(x) > 1 else None,
            "values": {int(r.seed): float(getattr(r, OUTCOME)) for r in stable}}  # fmt: skip


def _pairs(cells: dict, names) -> dict:
    """Paired Wilcoxon of every pair of controllers of one (trajectory, rung), over the seeds
    where both stayed stable, Holm-adjusted over the pairs."""
    out, ps = {}, []
    for a, b in itertools.combinations(names, 2):
        va, vb = cells[a]["values"], cells[b]["values"]
        seeds = sorted(set(va) & set(vb))
        diff = np.array([va[s] - vb[s] for s in seeds])
        p = stats.wilcoxon(diff) if len(diff) >= 2 and np.any(diff != 0) else 1.0
        out[f"{a} vs {b}"] = {"n": len(seeds), "mean_diff": float(diff.mean()) if len(diff) else
                              None, "p": float(p)}  # fmt: skip
        ps.append(p)
    for rec, q in zip(out.values(), stats.holm(ps) if ps else [], strict=True):
        rec["p_holm"] = float(q)
        rec["significant"] = bool(q < ALPHA)
    return out


def order_changes(pairs_a: dict, pairs_b: dict) -> list[str]:
    """The pairs significant on both rungs with opposite signs of the mean difference."""
    return [k for k, ra in pairs_a.items()
            if ra.get("significant") and pairs_b[k].get("significant")
            and np.sign(ra["mean_diff"]) != np.sign(pairs_b[k]["mean_diff"])]  # fmt: skip


def _summarise(rows, d: dict) -> dict:
    by = {}
    for r in rows:
        by.setdefault((r.scenario.split("@")[0], r.variant, r.controller), []).append(r)
    ladder = {}
    for traj in d["trajectories"]:
        ladder[traj] = {}
        for rung in RUNGS:
            cells = {c: _cell(by[(traj, rung, c)]) for c in d["controllers"]}
            ranked = sorted((c for c in cells if cells[c]["mean"] is not None),
                            key=lambda c: cells[c]["mean"])  # fmt: skip
            ladder[traj][rung] = {"cells": cells, "ranking": ranked,
                                  "pairs": _pairs(cells, d["controllers"])}  # fmt: skip
    changes = {traj: {rung: order_changes(ladder[traj]["kinematic"]["pairs"],
                                          ladder[traj][rung]["pairs"])
                      for rung in RUNGS if rung != "kinematic"}
               for traj in d["trajectories"]}  # fmt: skip
    agreement, timestep = {}, {}
    for traj in d["trajectories"]:
        kin = _cell(by[(traj, "kinematic+lag", "backstepping")])
        agreement[traj] = {}
        for rung in ("stiff-mujoco", "stiff-mujoco-fine"):
            stiff = _cell(by[(traj, rung, "backstepping")])
            diff = stiff["mean"] - kin["mean"]
            tol = max(AGREE_REL * kin["mean"], AGREE_ABS)
            agreement[traj][rung] = {"mujoco": stiff["mean"], "kinematic_plus_lag": kin["mean"],
                                     "difference": diff, "tolerance": tol,
                                     "agrees": bool(abs(diff) <= tol), "seeds": stiff["n"]}
        half = _cell(by[(traj, "mujoco-half-timestep", "backstepping")])
        base = ladder[traj]["mujoco"]["cells"]["backstepping"]["values"]
        rel = [half["values"][s] / base[s] - 1 for s in sorted(half["values"]) if s in base]
        timestep[traj] = {"seeds": len(rel), "mean_rel_change": float(np.mean(rel))
                          if rel else None}  # fmt: skip
    return {"ladder": ladder, "order_changes": changes, "agreement": agreement,
            "timestep_halved": timestep}


#: The repository's results (the committed record ``wmr reproduce`` re-renders).
COMMITTED = Path(__file__).resolve().parents[1] / "paper"


def run(out, *, quick: bool = False, workers: int | None = None, full: bool = False) -> dict:
    """The study into ``out``: ``quick`` a short version (tests); ``full`` recomputes it (1,500
    runs; 773 s measured on 2 workers of a machine shared with four other engineers:
    ``make robots``); otherwise a full record stored in
    ``out`` or, failing that, the repository's committed one is re-rendered (table, figures), so
    ``wmr reproduce`` stays short, and only without any record is the study computed."""
    if not (quick or full):
        for base in (Path(out), COMMITTED):
            record = common.load_record(base, STEM)
            if record and not record["quick"]:
                return _write(out, record)
    return _write(out, _compute(quick, workers))


def _write(out, record: dict) -> dict:
    from analysis import _robots_views as views

    record["figures"] = views.figures(out, record)
    common.write_record(out, STEM, record)
    common.write_table(out, STEM, table(record))
    return record


def _compute(quick: bool, workers: int | None) -> dict:
    """Measure the servo lag, the sliding map, fit the kinematic plant to the MuJoCo logs, run
    the ladder through the run engine: the record (without its figures)."""
    d = _design(quick)
    t0 = time.perf_counter()
    lag = servo_lag(STIFF)
    nominal_lag = servo_lag()
    sliding = [sliding_point(mu, v, w) for mu in d["frictions"] for v, w in d["commands"]]
    fitted = _fitted_plants(d)
    jobs = _jobs(d, fitted, lag)
    rows = run_jobs(jobs, workers, progress=None, desc=STEM)
    record = {"quick": quick, "controllers": list(d["controllers"]),
              "trajectories": list(d["trajectories"]), "rungs": list(RUNGS),
              "seeds": d["seeds"], "outcome": OUTCOME, "alpha": ALPHA,
              "servo_lag": {"stiff": lag, "nominal": nominal_lag}, "stiff": STIFF,
              "sliding": sliding, "sliding_threshold_rad": SLIDING, "fitted": fitted,
              **_summarise(rows, d),
              "cost": {"runs": len(jobs), "seconds": time.perf_counter() - t0}}  # fmt: skip
    return record


def check(record: dict) -> None:
    """The record is whole and its physics sensible: every (trajectory, rung, controller) cell
    counts every seed; a circle sliding more than the threshold needs a lateral acceleration
    near or above the Coulomb bound (demand >= 0.5), and every circle at twice the bound
    slides; the agreement verdict follows its numbers."""
    n = record["seeds"]
    for traj, rungs in record["ladder"].items():
        assert set(rungs) == set(record["rungs"]), traj
        for rung, e in rungs.items():
            for c, cell in e["cells"].items():
                assert cell["n"] == n and cell["stable"] + cell["diverged"] == n, (traj, rung, c)
                lo, hi = cell["diverged_ci"]
                assert lo <= cell["diverged"] / n <= hi
    for p in record["sliding"]:
        if p["sliding"]:
            assert p["demand"] >= 0.5, f"slides below half the Coulomb bound: {p}"
        if p["demand"] >= 2.0:
            assert p["sliding"], f"does not slide at twice the Coulomb bound: {p}"
    for traj, both in record["agreement"].items():
        for a in both.values():
            assert a["agrees"] == (abs(a["difference"]) <= a["tolerance"]), traj


def table(record: dict) -> str:
    """Mean +- std of the outcome per controller (rows) and rung (columns), per trajectory,
    with the diverged count where there is one."""
    from analysis import _robots_views as views

    return views.table(record)


def render(record: dict) -> str:
    """The report section: the answer first, then the table and the figures."""
    from analysis import _robots_views as views

    return views.render(record)


if __name__ == "__main__":
    sys.exit(common.main(sys.modules[__name__]))
