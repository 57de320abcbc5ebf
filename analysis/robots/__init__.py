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

The MuJoCo rung runs at a 0.5 ms physics step (:data:`MJ_TIMESTEP`), over :data:`MJ_SEEDS`
seeds (~5 s a run): at the shipped 2 ms the contact physics is not converged (an independent
audit measured backstepping's lemniscate error at 2.26 / 1.53 / 1.35 / 1.30 mm for 2 / 1 / 0.5 /
0.25 ms against 1.19 on the unicycle), and the **convergence check** reruns every controller at
2 ms and at 0.25 ms (seed 0) to say, per controller, whether the rung's numbers are converged
(within :data:`CONVERGED`).

Beside the ladder: (a) **agreement** -- with high friction and stiff servos the MuJoCo robot
under backstepping should agree with the kinematic unicycle plus the servo's lag (measured from
the physics' small-step response, unsaturated) within 5 % of position RMSE or 2 mm, whichever is
larger, checked at the physics steps :data:`AGREEMENT_STEPS`; the rule's power is shown on a
planted discrepant robot (the nominal one at the shipped 2 ms step), and the record says when the
2 mm floor, not the 5 %, decides; (b) **where sliding sets in** -- steady circles over friction
and lateral acceleration ``|v w|`` as a fraction of the Coulomb bound ``mu g``, with the
side-slip angle, the wheel slip ratio and the forward speed kept.

Statistics (DESIGN §7): per (trajectory, rung, controller) the mean +- std of the position RMSE
after the transient over the seeds that stayed stable, the diverged count with its exact
(Clopper-Pearson) interval; the ranking on the seeds stable for every arm; per (trajectory,
rung) paired Wilcoxon tests of every pair of controllers over the seeds where both stayed
stable, Holm-adjusted within the rung, and TOST at +-5 % of the better mean (two controllers are
*tied* only when equivalent); a pair's **order changes** between two rungs when it is significant
on both with opposite signs and both differences exceed 5 % of the better mean.

The runs go through the one engine (``wmr.engine.driver.execute``) into the one shard store
(``wmr.engine.store.ShardStore``, one row per run, ``job_id`` = trajectory/variant/controller/
seed): ``make robots`` keeps it in ``$WMR_STORES/robots/full`` (the quick level beside its
record), an interrupted computation resumes from the runs already stored, and a store whose
digests (:func:`store_digests`: wmr's code, the design and the job-building code, the scenario
files) are not the current ones is set aside with one line and rebuilt.  The side measurements
(servo lag, sliding map, the fitted plants; deterministic) are recomputed on a resume.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from analysis import common
from wmr import scenario as scn
from wmr import stats
from wmr.engine.study import Job
from wmr.stats import clopper_pearson

__all__ = ["STEM", "TITLE", "CONTROLLERS", "RUNGS", "run", "check", "render", "table",
           "servo_lag", "sliding_point", "order_changes", "clopper_pearson"]  # fmt: skip

STEM = "robots"
TITLE = "Which robot model predicts the physics? The robot ladder"
#: The arms: every registered controller but the diagnostic oracle and ``nmpc``
#: (:data:`LEFT_OUT`).
CONTROLLERS = ("pid", "adaptive-pid", "iapid-nn-dekf", "backstepping", "adaptive-nn",
               "adaptive-bsc")  # fmt: skip
_MJ = '[plant]\nmodel = "mujoco"\n[plant.mujoco]\nrobot = "diff-drive"\n'
#: Registered controllers the ladder leaves out, and why (the record was computed before
#: ``nmpc`` was registered; ~1-2 s a run, ~6 s on the MuJoCo rung: ~10 more minutes).
LEFT_OUT = {"iapid-oracle": "a diagnostic arm, not a controller one would deploy",
            "nmpc": "registered after this record was computed; joins at the next make robots"}
#: The rungs' ``[plant]`` tables (``fitted`` is made per trajectory by ``wmr identify``).
RUNGS = {
    "kinematic": "",
    "lagged-velocity": ('[plant]\nmodel = "lagged-velocity"\n[plant.lagged-velocity]\n'
                        "mass = 10.0\ninertia = 0.5\nfriction = [0.5, 0.02]\n"),
    "mujoco": _MJ + "timestep = 0.0005\n",
    "fitted": None,
}  # fmt: skip
#: The MuJoCo rung's physics step [s]: a quarter of the shipped 2 ms, at which the contact and
#: servo dynamics are resolved (at 2 ms backstepping's lemniscate error is 2.26 mm against 1.35
#: at 0.5 ms and 1.30 at 0.25 ms; the convergence check measures it for every controller).
MJ_TIMESTEP = 0.0005
#: Physics steps of the convergence check [s] (the shipped step and a half of the rung's).
CONVERGENCE_STEPS = (0.002, 0.00025)
#: Relative change of a controller's error from the rung's step to half of it below which the
#: rung counts as converged for that controller.
CONVERGED = 0.05
#: The stiff robot of the agreement check: high friction and servos 5x stiffer than nominal
#: (motor_gain 10; at 50 the wheel servo oscillates at the 2 ms physics step: a 0.05 rad/s yaw
#: step settles at 0.12 rad/s), the nominal torque limit.
STIFF = {"friction": 2.0, "motor_gain": 10.0}
#: Physics steps [s] of the agreement check: the shipped one, the rung's, and an eighth of it
#: (the stiff servo needs a finer step than the nominal one).
AGREEMENT_STEPS = (0.002, 0.0005, 0.000125)
#: Agreement tolerance of the stiff robot with the kinematic unicycle plus the servo's lag.
AGREE_REL, AGREE_ABS = 0.05, 2e-3
#: The sliding grid: floor friction and constant commands (v [m/s], w [rad/s]).
FRICTIONS = (0.05, 0.1, 0.2, 0.3)
#: Lateral accelerations of the sliding grid, as fractions of the Coulomb bound mu g; every
#: circle turns at SLIDE_W and runs at the speed that gives its demand.
DEMANDS = (0.5, 0.7, 0.8, 0.9, 1.0, 1.1, 1.3, 1.6, 2.0)
SLIDE_W = 1.5
#: Servo torque limit [N m] of the sliding map: torque to spare, so that what limits a circle is
#: the floor, not the motor.
SLIDE_TORQUE = 20.0
#: A steady circle slides when its side-slip angle exceeds SLIDING [rad] or its forward speed
#: falls below SPEED_KEPT of the command (at the lowest friction a sliding robot barely moves
#: forward, and its slip angle alone is ill-defined).
SLIDING = 0.02
SPEED_KEPT = 0.9
#: Seeds of the MuJoCo rung (its fine physics step costs ~5 s per run), of the side checks.
MJ_SEEDS = 10
SEEDS = 20
ALPHA = 0.05
OUTCOME = "tail_position"


def _design(quick: bool) -> dict:
    if quick:
        return {"quick": True, "trajectories": ("lemniscate",),
                "controllers": ("pid", "backstepping"),
                "seeds": 2, "mj_seeds": 2, "duration": 6.0, "mj_timestep": 0.002,
                "frictions": (0.1,), "demands": (0.5, 2.0), "side_seeds": 1,
                "convergence_steps": (0.002, 0.001), "agreement_steps": (0.002,)}  # fmt: skip
    return {"quick": False, "trajectories": scn.PAPER_SCENARIOS, "controllers": CONTROLLERS,
            "seeds": SEEDS,
            "mj_seeds": MJ_SEEDS, "duration": None, "mj_timestep": MJ_TIMESTEP,
            "frictions": FRICTIONS, "demands": DEMANDS, "side_seeds": 3,
            "convergence_steps": CONVERGENCE_STEPS, "agreement_steps": AGREEMENT_STEPS}


def _scenario(traj: str, rung: str, plant: str, duration: float | None) -> scn.Scenario:
    """The paper's ``traj`` with ``plant`` (a ``[plant]`` table's text) as rung ``rung``."""
    text = scn.builtin(traj).read_text().replace(f'name = "{traj}"', f'name = "{traj}@{rung}"')
    if duration:
        text = text.replace("duration = 40.0", f"duration = {duration}")
    return scn.loads(text + "\n" + plant, source=f"{traj}@{rung}")


def _mujoco(**keys) -> str:
    return _MJ + "".join(f"{k} = {v!r}\n" for k, v in keys.items())


def servo_lag(table: dict | None = None, v: float = 0.005, w: float = 0.005,
              timestep: float = 0.000125) -> dict:  # fmt: skip
    """The MuJoCo robot's servo lag: the 63 % rise time [s] of its forward speed and yaw rate
    after a step command ``(v, w)`` from rest, at the physics step ``timestep`` (the robot of
    ``[plant.mujoco]`` ``table``, shipped diff-drive by default), and the largest servo torque
    over its limit.

    The default step is small, so the servos stay below their torque limit (their linear
    regime, the one a tracking loop's smooth commands see; ``max_torque_ratio`` < 1 says so): a
    0.5 m/s step saturates them and measures their acceleration limit instead; the fine step
    resolves a lag of a few ms (the rise time is read on the physics step's grid)."""
    from wmr.robots.mujoco_robot import MujocoRobot, MujocoSpec

    spec = MujocoSpec.from_table({"robot": "diff-drive", **(table or {}), "timestep": timestep},
                                 base_dir=None, source="servo_lag")  # fmt: skip
    h = spec.timestep
    robot = MujocoRobot(spec, h)
    robot.reset((0.0, 0.0, 0.0))
    vel, diag, out, torque = np.empty(2), np.empty(9), [], 0.0
    n = int(round(0.3 / h))
    for k in range(n):
        robot.advance(k, (v, w))
        robot.velocity(vel)
        robot.diagnostics(diag)
        torque = max(torque, abs(diag[6]), abs(diag[7]))
        out.append(vel.copy())
    y = np.array(out)
    t = h * np.arange(1, n + 1)
    tau = [float(t[np.argmax(y[:, i] >= (1 - math.exp(-1)) * y[-1, i])]) for i in range(2)]
    return {"tau_v": tau[0], "tau_w": tau[1], "final": y[-1].tolist(), "timestep": h,
            "max_torque_ratio": torque / spec.torque_limit}


def sliding_point(friction: float, v: float, w: float, seconds: float = 6.0) -> dict:
    """A steady circle of the MuJoCo robot under the constant command ``(v, w)`` on a floor of
    ``friction``: the mean side-slip angle [rad] and wheel slip ratio over the second half,
    the achieved ``(v, w)``, and the lateral acceleration over the Coulomb bound."""
    from wmr.robots.mujoco_model import GRAVITY
    from wmr.robots.mujoco_robot import MujocoRobot, MujocoSpec

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
            "w_actual": float(a[3]),
            "sliding": bool(a[0] > SLIDING or a[2] < SPEED_KEPT * v)}  # fmt: skip


def _fitted_plants(d: dict) -> dict:
    """Per trajectory, the ``[plant]`` that ``wmr identify`` fits to the MuJoCo robot's log of
    backstepping at seed 0 (the full run), with the fit's report."""
    from wmr.closedloop.sim import simulate
    from wmr.estimation import identify

    out = {}
    for traj in d["trajectories"]:
        mj = _mujoco(timestep=d["mj_timestep"])
        r = simulate(_scenario(traj, "mujoco", mj, d["duration"]), "backstepping", 0)
        log = identify.Log(source=f"{traj}@mujoco", dt=r.dt, u=r.u, z=r.z, dist=r.disturbance)
        ident = identify.identify(log)
        out[traj] = {"toml": identify.to_toml(ident),
                     "values": {k: float(v) for k, v in ident.values.items()},
                     "se": {k: float(v) for k, v in ident.se.items()},
                     "delay": int(ident.delay),
                     "lag_at_bound": bool(ident.values.get("actuator_tau", 1.0) == 0.0),
                     "not_identifiable": sorted(ident.not_identifiable)}  # fmt: skip
    return out


def _jobs(d: dict, fitted: dict, lag: dict) -> list[Job]:
    """The ladder (every rung x controller x trajectory x seed; the MuJoCo rung over
    ``mj_seeds``), the convergence check (every controller at the shipped and at a finer physics
    step, seed 0), and the agreement check (backstepping on the kinematic unicycle plus the
    stiff servo's lag and on the stiff robot at :data:`AGREEMENT_STEPS`).  Each job carries
    its store identity (:func:`_job_id`) and the labels ``trajectory`` and ``variant``."""
    jobs = []
    for traj in d["trajectories"]:
        start = len(jobs)
        plants = {**{r: p for r, p in RUNGS.items() if p is not None},
                  "mujoco": _mujoco(timestep=d["mj_timestep"]),
                  "fitted": fitted[traj]["toml"]}  # fmt: skip
        for rung, plant in plants.items():
            sc = _scenario(traj, rung, plant, d["duration"])
            n = d["mj_seeds"] if rung == "mujoco" else d["seeds"]
            jobs += [Job(sc, c, s, variant=rung) for c in d["controllers"] for s in range(n)]
        for h in d["convergence_steps"]:  # every controller at the shipped and at a finer step
            sc = _scenario(traj, f"mujoco@{h:g}", _mujoco(timestep=h), d["duration"])
            jobs += [Job(sc, c, 0, variant=f"mujoco@{h:g}") for c in d["controllers"]]
        tau = 0.5 * (lag["tau_v"] + lag["tau_w"])
        extra = {"kinematic+lag": f"[plant]\nactuator_tau = {tau!r}\n",
                 **{f"stiff@{h:g}": _mujoco(**STIFF, timestep=h) for h in d["agreement_steps"]}}
        for rung, plant in extra.items():
            sc = _scenario(traj, rung, plant, d["duration"])
            jobs += [Job(sc, "backstepping", s, variant=rung) for s in range(d["side_seeds"])]
        jobs[start:] = [replace(j, job_id=_job_id(traj, j),
                                labels=(("trajectory", traj), ("variant", j.variant)))
                        for j in jobs[start:]]  # fmt: skip
    return jobs  # the nominal robot at 2 ms (planted discrepancy): the convergence runs


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
        ma = float(np.mean([va[s] for s in seeds])) if seeds else None
        mb = float(np.mean([vb[s] for s in seeds])) if seeds else None
        out[f"{a} vs {b}"] = {"n": len(seeds), "mean_diff": float(diff.mean()) if len(diff) else
                              None, "p": float(p), "scale": min(ma, mb) if seeds else None}
        if len(seeds) >= 2:  # TOST at +-RELEVANT of the better mean: "the same"
            t = stats.tost(np.array([va[s] for s in seeds]), np.array([vb[s] for s in seeds]),
                           RELEVANT * min(ma, mb), ALPHA)
            out[f"{a} vs {b}"]["equivalent"] = bool(t.equivalent)
        ps.append(p)
    for rec, q in zip(out.values(), stats.holm(ps) if ps else [], strict=True):
        rec["p_holm"] = float(q)
        rec["significant"] = bool(q < ALPHA)
    return out


#: A pair's difference counts for an order reversal only beyond this share of the better
#: controller's mean on that rung (DESIGN §7.4: a margin that means something).
RELEVANT = 0.05


def order_changes(pairs_a: dict, pairs_b: dict) -> list[str]:
    """The pairs significant on both rungs, with opposite signs of the mean difference, and
    both differences beyond :data:`RELEVANT` of the better mean (``pairs`` carry ``scale``, the
    better controller's mean)."""
    def relevant(r):
        return r.get("significant") and abs(r["mean_diff"]) > RELEVANT * r["scale"]

    return [k for k, ra in pairs_a.items()
            if relevant(ra) and relevant(pairs_b[k])
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
            common_seeds = set.intersection(*(set(cells[c]["values"]) for c in cells))
            ranked = sorted((c for c in cells if common_seeds),
                            key=lambda c: np.mean([cells[c]["values"][s] for s in common_seeds]))
            ladder[traj][rung] = {"cells": cells, "ranking": ranked,
                                  "pairs": _pairs(cells, d["controllers"])}  # fmt: skip
    changes = {traj: {rung: order_changes(ladder[traj]["kinematic"]["pairs"],
                                          ladder[traj][rung]["pairs"])
                      for rung in RUNGS if rung != "kinematic"}
               for traj in d["trajectories"]}  # fmt: skip
    agreement, convergence = {}, {}
    for traj in d["trajectories"]:
        kin = _cell(by[(traj, "kinematic+lag", "backstepping")])
        agreement[traj] = {}
        for h in d["agreement_steps"]:
            stiff = _cell(by[(traj, f"stiff@{h:g}", "backstepping")])
            agreement[traj][f"{h:g}"] = _agree(stiff, kin)
        # the planted discrepant robot: the nominal one at the shipped step (seed 0)
        coarse = {c: by[(traj, f"mujoco@{d['convergence_steps'][0]:g}", c)][0]
                  for c in d["controllers"]}  # fmt: skip
        agreement[traj]["planted"] = _agree(_cell([coarse["backstepping"]]),
                                            _cell([r for r in by[(traj, "kinematic+lag",
                                                                   "backstepping")]
                                                   if r.seed == 0]))  # fmt: skip
        fine = {c: by[(traj, f"mujoco@{d['convergence_steps'][1]:g}", c)][0]
                for c in d["controllers"]}  # fmt: skip
        rung = ladder[traj]["mujoco"]["cells"]
        convergence[traj] = {}
        for c in d["controllers"]:
            at = rung[c]["values"].get(0)
            f, g = getattr(fine[c], OUTCOME), getattr(coarse[c], OUTCOME)
            convergence[traj][c] = {
                "shipped": g, "rung": at, "finer": f,
                "rel_change": None if at is None or fine[c].diverged else abs(f / at - 1),
                "converged": bool(at is not None and not fine[c].diverged
                                  and abs(f / at - 1) <= CONVERGED)}  # fmt: skip
    return {"ladder": ladder, "order_changes": changes, "agreement": agreement,
            "convergence": convergence}


def _agree(mj: dict, kin: dict) -> dict:
    """The agreement rule on two cells' means: within 5 % of the kinematic mean or 2 mm."""
    diff = mj["mean"] - kin["mean"]
    tol = max(AGREE_REL * kin["mean"], AGREE_ABS)
    return {"mujoco": mj["mean"], "kinematic_plus_lag": kin["mean"], "difference": diff,
            "relative": diff / kin["mean"], "tolerance": tol, "agrees": bool(abs(diff) <= tol),
            "floor_dominates": bool(AGREE_ABS > AGREE_REL * kin["mean"]), "seeds": mj["n"]}


#: The repository's results (the committed record ``wmr reproduce`` re-renders).
COMMITTED = Path(__file__).resolve().parents[2] / "paper"


def run(out, *, quick: bool = False, workers: int | None = None, full: bool = False) -> dict:
    """The study into ``out``: ``quick`` a short version (tests); ``full`` recomputes it (1,332
    runs; 1,313 s measured on 2 workers of a shared machine: ``make robots``); otherwise a full
    record stored in ``out`` or, failing that, the repository's committed one is re-rendered
    (table, figures), so ``wmr reproduce`` stays short, and only without any record is the study
    computed.

    The runs go through the one engine into a shard store (:func:`store_folder`): an
    interrupted computation resumes (the finished runs are read back, only the missing ones
    run); a store of other inputs (:func:`store_digests`) is set aside with one line on stderr
    and rebuilt."""
    if not (quick or full):
        for base in (Path(out), COMMITTED):
            record = common.load_record(base, STEM)
            if record and not record["quick"]:
                return _write(out, record)
    return _write(out, _compute(_design(quick), workers, store_folder(out, quick)))


def _write(out, record: dict) -> dict:
    from analysis.robots import views

    record["figures"] = views.figures(out, record)
    common.write_record(out, STEM, record)
    common.write_table(out, STEM, table(record))
    return record


# -- the store ------------------------------------------------------------------------------------

#: The store's ``kind`` (``wmr.engine.store``).
KIND = "wmr robots store"


def store_folder(out, quick: bool) -> Path:
    """Where the ladder's runs are kept: ``out/.robots-store`` at the quick level (beside its
    record), ``$WMR_STORES/robots/full`` for the full study
    (``wmr.engine.store.studies_folder``)."""
    from wmr.engine.store import studies_folder

    return Path(out) / ".robots-store" if quick else studies_folder() / STEM / "full"


def store_digests(d: dict, scenario_files=None) -> dict[str, str]:
    """What the ladder's runs read, as the store's digests: ``code_digest`` (wmr's sources,
    ``wmr._jit.source_digest``), ``design_digest`` (the design ``d``, the rungs' plant tables,
    the stiff robot, the source of the functions that build the jobs -- the fitted plant and
    the servo lag included -- and the versions of the libraries whose numbers they take:
    mujoco, numba, numpy, scipy) and ``scenario_digest`` (the trajectories' scenario files,
    ``scenario_files`` if given, else the shipped ones).  The stages that only summarise the
    runs are not in them: changing those reuses the store."""
    import inspect

    import mujoco
    import numba
    import scipy

    from wmr._jit import source_digest
    from wmr.engine.store import digest_files

    files = scenario_files or [scn.builtin(t) for t in d["trajectories"]]
    code = "".join(inspect.getsource(f) for f in (_design, _scenario, _mujoco, servo_lag,
                                                  _fitted_plants, _jobs, _job_id))  # fmt: skip
    design = repr((sorted(d.items()), RUNGS, _MJ, STIFF, OUTCOME, mujoco.__version__,
                   numba.__version__, np.__version__, scipy.__version__))  # fmt: skip
    return {"code_digest": source_digest(),
            "design_digest": digest_files([], "\0".join((code, design))),
            "scenario_digest": digest_files(files)}  # fmt: skip


def _schema():
    import pyarrow as pa

    from wmr.engine.jobs import COLUMN_TYPES, COLUMNS

    cols = [("job_id", pa.string()), ("trajectory", pa.string()), ("variant", pa.string()),
            ("scenario", pa.string()), ("controller", pa.string()), ("seed", pa.int64())]
    return pa.schema(cols + [(c, getattr(pa, COLUMN_TYPES[c])()) for c in COLUMNS])


def _job_id(traj: str, job: Job) -> str:
    return f"{traj}/{job.variant}/{job.controller}/{job.seed}"


def _stored_rows(store, jobs: list[Job]) -> list:
    """The store's rows of ``jobs``, in job order, as objects with the fields the summary reads
    (``scenario``, ``variant``, ``controller``, ``seed``, the result columns)."""
    from types import SimpleNamespace

    t = store.read().to_pydict()
    by_id = {i: k for k, i in enumerate(t["job_id"])}
    rows = []
    for j in jobs:
        k = by_id[j.job_id]
        rows.append(SimpleNamespace(**{name: t[name][k] for name in t}))
    return rows


def run_ladder(jobs: list[Job], workers: int | None, folder, digests: dict[str, str],
               flush_seconds: float = 30.0) -> tuple[list, dict]:
    """Run ``jobs`` (each with its ``job_id``) on the engine into the store at ``folder``,
    resuming it: a job with an ``ok`` row there is not run again (an error row is).  Returns
    the rows in job order (:func:`_stored_rows`) and the store's manifest (``runs_this_time``,
    ``run_seconds_total`` summed over the invocations).  A run that raised stops the study
    with its error (the row stays stored: a rerun retries it)."""
    from wmr.engine.driver import execute
    from wmr.engine.executors import engine
    from wmr.engine.jobs import job_row
    from wmr.engine.store import ShardStore

    store = ShardStore.open(folder, _schema(), digests, kind=KIND, study=STEM)
    done = store.ids("ok")
    todo = [j for j in jobs if j.job_id not in done]
    manifest = store.manifest
    total = float(manifest.get("run_seconds_total", 0.0))
    t0 = time.perf_counter()
    try:
        if todo:
            with engine(1 if len(todo) <= 1 else workers) as eng:
                execute(todo, eng, job_row, store=store, keep=False,
                        flush_seconds=flush_seconds, progress=None, desc=STEM,
                        tag=f"{STEM}-{digests['design_digest']}")  # fmt: skip
    finally:
        ran = time.perf_counter() - t0
        manifest.update(jobs=len(jobs), done=len(store.ids("ok")), runs_this_time=len(todo),
                        run_seconds=round(ran, 3), run_seconds_total=round(total + ran, 3))
        store.write_manifest(manifest)
    rows = _stored_rows(store, jobs)
    failed = [r for r in rows if r.status != "ok"]
    if failed:
        raise RuntimeError(f"{len(failed)} ladder run(s) raised, the first "
                           f"{failed[0].job_id}: {failed[0].error}")
    return rows, manifest


def _compute(d: dict, workers: int | None, folder) -> dict:
    """Measure the servo lag, the sliding map, fit the kinematic plant to the MuJoCo logs, run
    the ladder through the run engine into the store at ``folder`` (resumed): the record
    (without its figures)."""
    t0 = time.perf_counter()
    lag = servo_lag(STIFF)
    nominal_lag = servo_lag()
    from wmr.robots.mujoco_model import GRAVITY

    sliding = [sliding_point(mu, q * mu * GRAVITY / SLIDE_W, SLIDE_W)
               for mu in d["frictions"] for q in d["demands"]]  # fmt: skip
    fitted = _fitted_plants(d)
    jobs = _jobs(d, fitted, lag)
    rows, manifest = run_ladder(jobs, workers, folder, store_digests(d))
    record = {"quick": d["quick"], "controllers": list(d["controllers"]),
              "trajectories": list(d["trajectories"]), "rungs": list(RUNGS),
              "seeds": d["seeds"], "mj_seeds": d["mj_seeds"], "mj_timestep": d["mj_timestep"],
              "outcome": OUTCOME, "alpha": ALPHA, "relevant": RELEVANT,
              "servo_lag": {"stiff": lag, "nominal": nominal_lag}, "stiff": STIFF,
              "sliding": sliding, "sliding_threshold_rad": SLIDING, "fitted": fitted,
              **_summarise(rows, d),
              "cost": {"runs": len(jobs), "seconds": time.perf_counter() - t0,
                       "runs_this_time": manifest["runs_this_time"],
                       "run_seconds_total": manifest["run_seconds_total"]}}  # fmt: skip
    return record


def check(record: dict) -> None:
    """The record is whole and its physics sensible: every (trajectory, rung, controller) cell
    counts every seed; a circle sliding more than the threshold needs a lateral acceleration
    near or above the Coulomb bound (demand >= 0.5), and every circle at twice the bound
    slides; the agreement verdict follows its numbers."""
    for traj, rungs in record["ladder"].items():
        assert set(rungs) == set(record["rungs"]), traj
        for rung, e in rungs.items():
            n = record["mj_seeds"] if rung == "mujoco" else record["seeds"]
            for c, cell in e["cells"].items():
                assert cell["n"] == n and cell["stable"] + cell["diverged"] == n, (traj, rung, c)
                lo, hi = cell["diverged_ci"]
                assert lo <= cell["diverged"] / n <= hi
    for p in record["sliding"]:
        if p["sliding"]:
            assert p["demand"] > 0.5, f"slides at half the Coulomb bound: {p}"
        if p["demand"] >= 1.3:
            assert p["sliding"], f"does not slide at 1.3 times the Coulomb bound: {p}"
    for traj, both in record["agreement"].items():
        for a in both.values():
            assert a["agrees"] == (abs(a["difference"]) <= a["tolerance"]), traj
    for lag in record["servo_lag"].values():
        assert lag["max_torque_ratio"] < 1.0, "the servo lag was measured saturated"


def table(record: dict) -> str:
    """Mean +- std of the outcome per controller (rows) and rung (columns), per trajectory,
    with the diverged count where there is one."""
    from analysis.robots import views

    return views.table(record)


def render(record: dict) -> str:
    """The report section: the answer first, then the table and the figures."""
    from analysis.robots import views

    return views.render(record)

