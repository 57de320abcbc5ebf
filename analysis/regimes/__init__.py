"""When does adaptation pay?  The regime study as a matched design (issue 22; DESIGN §7).

1. **Matched arms**: every arm (the fixed PID, APID, IAPID-NN-DEKF, the oracle IAPID, BSC,
   DA-NN, adaptive BSC, NMPC) runs on the same pose, with the pose source a factor (``raw``: the
   measurement; ``filtered``: the pose EKF's estimate, for every arm).  The paper's asymmetric
   comparison (IAPID on the filtered pose against APID on the raw one) is a separate, labelled
   row.  :func:`check` reads each arm's settings from the scenarios its runs were made from and
   fails if a compared pair differs in anything but the compared factor
   (``analysis.regimes.design.matched``).
2. **Equal tuning** (``analysis.tuning``): each arm tuned once per pose source on training
   plants and trajectories disjoint from the evaluation, with the same evaluations per free
   setting; results at the tuned settings and at the defaults.
3. **Mechanisms** and trajectories: ``analysis.regimes.design``.
4. **Endpoints** and 5. **one model**: ``analysis.regimes.stats``, for :data:`CONTRASTS`; each
   adaptive arm against itself frozen: ``analysis.regimes.frozen``.

Runs: one sweep (``wmr.engine.sweep``) per (settings level, pose source) over the mechanism x
trajectory scenarios and every arm, the tuned settings as single-level factors; the MuJoCo
robot in its own sweeps (fewer seeds, the lemniscate only: ~10x the cost per step).  Stores
under the studies' cache folder (resumable; a store of other code is set aside).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from analysis import common, tuning
from analysis.regimes import coverage as rcov
from analysis.regimes import design, frozen, rates, report
from analysis.regimes import stats as rstats
from analysis.regimes.pairs import (
    ADAPTIVE,
    FIXED,
    PAIRINGS,
    POSES,
    best_arm,
    endpoints,
    join,
    model_frame,
    pairs_of,
    paper_pairs,
    stable,
)
from wmr.engine import sweep

__all__ = ["STEM", "TITLE", "ARMS", "LEVELS", "CONTRASTS", "run", "check", "render", "table",
           "analyse", "rederive", "StaleStore", "tracking",
           "model_frame", "COVERED"]  # fmt: skip

STEM = "regimes"
TITLE = "When does adaptation pay? A matched design with equal tuning"
#: The arms (the tuning stage's controllers), in table order.
ARMS = tuning.ARMS
#: The contrasts of the model (a, b): "best-adaptive" / "best-fixed" are chosen per pose source
#: by the tuning objective on the training set (not by the evaluation).
CONTRASTS = (("iapid-nn-dekf", "adaptive-pid"), ("adaptive-pid", "pid"),
             ("best-adaptive", "best-fixed"), ("iapid-oracle", "iapid-nn-dekf"),
             ("adaptive-bsc", "backstepping"))  # fmt: skip
#: The contrasts whose rule is measured on planted truth at the defaults' layout (6 seeds).
COVERED = (("iapid-nn-dekf", "adaptive-pid"), ("best-adaptive", "best-fixed"))
COVERED_TUNED = (*COVERED, ("adaptive-bsc", "backstepping"))  #: ... at the tuned layout too
#: Study levels: the quick one (make test), the committed record's, the full design.
LEVELS = {
    "quick": {"arms": ("pid", "adaptive-pid", "iapid-nn-dekf", "iapid-oracle", "backstepping"),
              "mechanisms": ("ideal", "lag-delay"), "mujoco": (), "trajectories": ("sinusoid",),
              "seeds": 3, "default_seeds": 3, "duration": 7.0, "mujoco_seeds": 0,
              "mujoco_duration": None, "per_setting": 1, "train_seeds": (100,),
              "train_duration": 3.0, "training": 1, "coverage_replicates": 4, "rate_seeds": 2},
    "record": {"arms": ARMS, "mechanisms": tuple(design.MECHANISMS),
               "mujoco": tuple(design.MUJOCO), "trajectories": design.TRAJECTORIES, "seeds": 20,
               "default_seeds": 6, "duration": None, "mujoco_seeds": 3, "mujoco_duration": None,
               "per_setting": 3, "train_seeds": (100,), "train_duration": 20.0, "training": 5,
               "recovery_seeds": 10, "known_pid": True, "coverage_replicates": 100,
               "rate_seeds": 6},
    "full": {"arms": ARMS, "mechanisms": tuple(design.MECHANISMS),
             "mujoco": tuple(design.MUJOCO), "trajectories": design.TRAJECTORIES, "seeds": 20,
             "default_seeds": 20, "duration": None, "mujoco_seeds": 10, "mujoco_duration": None,
             "per_setting": 30, "train_seeds": (100, 101), "train_duration": 20.0,
             "training": 5, "recovery_seeds": 20, "known_pid": True, "coverage_replicates": 200,
             "rate_seeds": 10},
}  # fmt: skip


def _store(out: Path, level: str) -> Path:
    from wmr.engine.store import studies_folder

    return Path(out) / ".regimes-store" if level == "quick" else studies_folder() / STEM / level


def _tune(d: dict, eng, cache: Path) -> dict:
    """Every arm tuned on each pose source (``analysis.tuning``; resumable, records in cache)."""
    training = design.training_documents(d["train_duration"], d["training"])
    budget = tuning.Budget(per_setting=d["per_setting"], seeds=tuple(d["train_seeds"]))
    return {pose: {c: tuning.tune_arm(tuning.arm(c, pose), training, budget, eng,
                                      cache=cache) for c in d["arms"]}
            for pose in POSES}  # fmt: skip


def _known_pid(d: dict, eng, cache: Path) -> dict:
    """The fixed PID tuned per mechanism on each pose source ("PID tuned on the test mechanism":
    what tuning for the robot's known defect buys a fixed PID at the same budget, no bound of
    anything): the training trajectories on that mechanism's plant, the same budget rule."""
    budget = tuning.Budget(per_setting=d["per_setting"], seeds=tuple(d["train_seeds"]))
    out: dict = {}
    for pose in POSES:
        for m in d["mechanisms"]:
            a = tuning.Arm(f"pid-known-{m}@{pose}", "pid", tuning.FREE["pid"],
                           {"estimator.pose_source": pose})  # fmt: skip
            train = design.training_on(m, d["train_duration"])
            out.setdefault(pose, {})[m] = tuning.tune_arm(a, train, budget, eng, cache=cache)
    return out


def _spec_text(name: str, files: list[str], seeds: int, pose: str, tables: dict | None,
               arms: tuple[str, ...], measures: tuple[str, ...] = ()) -> str:  # fmt: skip
    """A sweep spec: every arm on ``files``, the pose source and each arm's tuned settings as
    single-level factors (JSON values are TOML values here); ``measures``
    (``wmr.closedloop.measures``)."""
    lines = [f'name = "{name}"', f"scenarios = {json.dumps(files)}",
             f"controllers = {json.dumps(list(arms))}", f"seeds = {seeds}",
             *([f"measures = {json.dumps(list(measures))}"] if measures else []), "[design]",
             'kind = "grid"', "[factors]", f'"estimator.pose_source" = ["{pose}"]']  # fmt: skip
    for c, table in (tables or {}).items():
        for key, value in table.items():
            lines.append(f'"controllers.{c}.{key}" = [{json.dumps(value)}]')
    return "\n".join(lines) + "\n"


def _specs(d: dict, tuned: dict, folder: Path, known: dict | None = None
           ) -> list[tuple[str, str, Path]]:  # fmt: skip
    """Write the scenario files and the specs; returns ``(level, pose, spec path)``."""
    folder.mkdir(parents=True, exist_ok=True)
    files, mj = [], []
    for t in d["trajectories"]:
        for m in d["mechanisms"]:
            (folder / f"{t}@{m}.toml").write_text(design.evaluation_text(t, m, d["duration"]))
            files.append(f"{t}@{m}.toml")
    for m in d["mujoco"]:
        (folder / f"lemniscate@{m}.toml").write_text(
            design.evaluation_text("lemniscate", m, d["mujoco_duration"]))
        mj.append(f"lemniscate@{m}.toml")
    events = [f for f in files if "@lagged-velocity-change" in f or "sinusoid-perturbed@" in f]
    out = []
    for pose in POSES:
        tables = {c: tuned[pose][c]["table"] for c in d["arms"]}
        runs = [("tuned", files, d["seeds"], tables), ("default", files, d["default_seeds"], None)]
        if d.get("other_restart", True):  # each arm at its runner-up restart: PAIRINGS
            other = {c: tuning.other_restart(tuning.arm(c, pose), tuned[pose][c])
                     for c in d["arms"]}  # fmt: skip
            runs.append(("tuned-other", files, d["seeds"], other))
        if mj:
            runs.append(("tuned-mujoco", mj, d["mujoco_seeds"], tables))
        if d.get("frozen", True):  # the adaptive arms with their adaptation off
            off = frozen.tables(tables)
            runs.append((frozen.LEVEL, files, d["seeds"], off))
            if mj:
                runs.append((f"{frozen.LEVEL}-mujoco", mj, d["mujoco_seeds"], off))
        for level, names, seeds, tab in runs:
            p = folder / f"{level}-{pose}.toml"
            p.write_text(_spec_text(f"regimes-{level}-{pose}", names, seeds, pose, tab,
                                    tuple(c for c in d["arms"] if c in tab)
                                    if level.startswith(frozen.LEVEL) else d["arms"]))
            out.append((level, pose, p))
        for m, t in (known or {}).get(pose, {}).items():
            names = [f for f in files if f.endswith(f"@{m}.toml")]
            p = folder / f"known-pid-{m}-{pose}.toml"
            p.write_text(_spec_text(f"regimes-known-pid-{m}-{pose}", names, d["seeds"], pose,
                                    {"pid": t["table"]}, ("pid",)))  # fmt: skip
            out.append((f"known-pid-{m}", pose, p))
        for m in rates.RATES if d.get("rate_seeds") else ():  # the sensitivity figure's runs
            lv = rates.level(m)
            p = folder / f"{lv}-{pose}.toml"
            p.write_text(_spec_text(f"regimes-{lv}-{pose}", files, d["rate_seeds"], pose,
                                    rates.tables(m), rates.ARMS))  # fmt: skip
            out.append((lv, pose, p))
        if events and d.get("recovery_seeds"):
            p = folder / f"recovery-{pose}.toml"
            p.write_text(_spec_text(f"regimes-recovery-{pose}", events, d["recovery_seeds"], pose,
                                    tables, d["arms"], ("recovery",)))  # fmt: skip
            out.append(("recovery", pose, p))
    return out


def _recovery(done: list[tuple[str, str, Path]], store: Path, tuned: dict) -> dict | None:
    """Recovery after the run's first event (``wmr.closedloop.measures``: the position RMSE over the
    5 s after the plant change or the disturbance's start), tuned settings: per pose source,
    scenario and arm the mean over the stable runs with their count, and each contrast's paired
    difference on the both-stable pairs (:func:`analysis.regimes.stats.pair_rmse`)."""
    specs = [(pose, p) for level, pose, p in done if level == "recovery"]
    if not specs:
        return None
    out: dict = {"window_s": 5.0, "poses": {}}
    for pose, p in specs:
        rows = sweep.read_rows(store / p.stem).to_pandas().sort_values("job_id", kind="stable")
        rows["failed"] = rows.diverged | (rows.status != "ok")
        rows["tail_position"] = rows.recovery_rmse  # the pairs' statistic is the recovery RMSE
        rows["pose"], rows["level"] = pose, "recovery"
        sp = rows.scenario.str.split("@", expand=True)
        rows["trajectory"], rows["mechanism"] = sp[0], sp[1]
        best = {"best-adaptive": best_arm(tuned, pose, ADAPTIVE),
                "best-fixed": best_arm(tuned, pose, FIXED)}
        rec: dict = {"arms": {}, "contrasts": {}}
        for (sc, c), g in rows.groupby(["scenario", "controller"], sort=False):
            ok = g.recovery_rmse[~g.failed]
            rec["arms"].setdefault(sc, {})[c] = {"n_stable": int(len(ok)), "n": int(len(g)),
                                                 "mean": float(ok.mean()) if len(ok) else None}
        for a, b in CONTRASTS:
            ca, cb = best.get(a, a), best.get(b, b)
            if ca not in set(rows.controller) or cb not in set(rows.controller):
                continue
            key = ["scenario", "seed"]
            j = join(rows[rows.controller == ca].set_index(key),
                      rows[rows.controller == cb].set_index(key))
            rec["contrasts"][f"{a} - {b}"] = {
                sc: rstats.pair_rmse(g.tail_position_a, g.failed_a, g.tail_position_b,
                                     g.failed_b) for sc, g in j.groupby("scenario", sort=False)}
        out["poses"][pose] = rec
    return out


def _frame(done: list[tuple[str, str, Path]], store: Path):
    import pandas as pd

    parts = []
    for level, pose, p in done:
        if level == "recovery":
            continue
        if level.startswith("known-pid"):
            level = "known-pid"
        rows = sweep.read_rows(store / p.stem).to_pandas().sort_values("job_id", kind="stable")
        rows = rows[["scenario", "controller", "seed", "tail_position", "effort", "diverged",
                     "status"]].copy()  # fmt: skip
        rows["level"] = level.replace("-mujoco", "")
        rows["pose"] = pose
        parts.append(rows)
    rows = pd.concat(parts, ignore_index=True)
    sp = rows.scenario.str.split("@", expand=True)
    rows["trajectory"], rows["mechanism"] = sp[0], sp[1]
    rows["failed"] = rows.diverged | (rows.status != "ok")
    return rows


def _arm_entries(done: list[tuple[str, str, Path]]) -> dict:
    """Each arm's settings as read from the scenarios its runs were made from (the specs'
    validated scenarios: what ``wmr.engine`` ran)."""
    out: dict = {}
    for level, pose, p in done:
        spec = sweep.load_spec(p)
        for c in spec.controllers:
            runs = {sc.name: sc for sc in spec.runs[0]}
            out.setdefault(level, {}).setdefault(pose, {})[c] = design.arm_entry(runs, c)
    return out


#: The repository's results (the committed record).
COMMITTED = Path(__file__).resolve().parents[2] / "paper"


def run(out, *, quick: bool = False, workers: int | None = None, level: str | None = None
        ) -> dict:  # fmt: skip
    """The study into ``out`` at ``level`` (:data:`LEVELS`; ``quick``: the quick one): tune,
    run the sweeps (resuming their stores), analyse, write record, table and figures.  With
    neither, a record in ``out`` or the repository's committed one is re-rendered (``wmr
    reproduce`` stays short); only without any record is the ``record`` level computed."""
    if level is None and not quick:
        for base in (Path(out), COMMITTED):
            rec = common.load_record(base, STEM)
            if rec and rec.get("level") in LEVELS and "arms_run" in rec:
                rec["verdict"] = report.verdicts(rec)  # the rule of this code, on the record
                rec["figures"] = _figures(out, rec)
                common.write_record(out, STEM, rec)
                common.write_table(out, STEM, table(rec))
                return rec
    return compute(out, level or ("quick" if quick else "record"), workers)


def _figures(out, record: dict) -> list[str]:
    """The section's figures: the contrasts, and the rate sensitivity where the record has it."""
    figs = [common.save_figure(out, f"{STEM}_contrasts.png", report.figure(record))]
    if record.get("rates"):
        figs.append(common.save_figure(out, f"{STEM}_rates.png", rates.figure(record["rates"])))
    return figs


def compute(out, level: str, workers: int | None = None) -> dict:
    """Tune, run, analyse and write the study at ``level``."""
    from wmr.engine import engine

    d = LEVELS[level]
    store = _store(Path(out), level)
    t0 = time.perf_counter()
    manifests = []
    with engine(workers) as eng:
        cache = store / "tuning" if level == "quick" else tuning.shared_cache()
        tuned = _tune(d, eng, cache)
        known = _known_pid(d, eng, cache) if d.get("known_pid") else None
        t_tune = time.perf_counter() - t0
        done = _specs(d, tuned, store / "specs", known)
        for _, _, p in done:
            manifests.append(sweep.run_sweep(sweep.load_spec(p), store / p.stem, progress=None,
                                             stale="set-aside", eng=eng))  # fmt: skip
    seconds = time.perf_counter() - t0
    cost = {"runs": int(sum(m["jobs"] for m in manifests)),
            "runs_this_time": int(sum(m["runs_this_time"] for m in manifests)),
            "run_seconds_total": float(sum(m["run_seconds_total"] for m in manifests)),
            "seconds": seconds, "tuning_seconds": t_tune,
            "engine": manifests[0]["engine"], "workers": manifests[0]["workers"]}  # fmt: skip
    return _assemble(out, level, d, done, store, tuned, known, cost)


def _assemble(out, level: str, d: dict, done, store: Path, tuned: dict, known: dict | None,
              cost: dict) -> dict:  # fmt: skip
    """The record from the stores of ``done`` (analyse, recovery, the known-PID contrast, the
    arms' settings), written with its table and figure."""
    rows = _frame(done, store)
    record = analyse(rows, tuned)
    record["recovery"] = _recovery(done, store, tuned)
    if known:
        record["known_pid"] = _known(rows, tuned, known)
    record.update(level=level, design={k: (list(v) if isinstance(v, tuple) else v)
                                       for k, v in d.items()},
                  arms_run=_arm_entries(done),
                  tuning={"budget": {"per_setting": d["per_setting"], "restarts": 2,
                                     "train_seeds": list(d["train_seeds"]),
                                     "training": list(design.training_documents(
                                         d["train_duration"], d["training"])),
                                     "train_duration": d["train_duration"],
                                     "objective": f"mean of r / (r + {tuning.RMSE_SCALE} m) over"
                                                  " the training runs; a diverged run scores "
                                                  f"{tuning.DIVERGED_SCORE:g}",
                                     "optimiser": "CMA-ES (cma), default population, seeds 0 "
                                                  "and 1, restart 0 from the defaults"},
                          "arms": tuned},
                  cost=cost)
    record["tracking"] = tracking(rows, tuned, record)
    record["coverage"] = {"setting": "default", "contrasts": {
        f"{a} - {b}": rcov.coverage(model_frame(rows, tuned, (a, b), "default"),
                                    d.get("coverage_replicates", 20))
        for a, b in COVERED}}  # fmt: skip
    kin = tuple(m for m in record["mechanisms"] if m not in design.MUJOCO)
    record["coverage_tuned"] = {"setting": "tuned", "contrasts": {  # where tuned verdicts stand
        f"{a} - {b}": rcov.coverage(model_frame(rows, tuned, (a, b), "tuned"),
                                    d.get("coverage_replicates", 20), mechanisms=kin)
        for a, b in COVERED_TUNED if _ran(rows, a, b)}}  # fmt: skip
    record["rates"] = rates.analyse(rows)
    record["verdict"] = report.verdicts(record)
    record["figures"] = _figures(out, record)
    common.write_record(out, STEM, record)
    common.write_table(out, STEM, table(record))
    return record


class StaleStore(RuntimeError):
    """A store of the record does not hold the runs of its spec (re-deriving would rerun)."""


def rederive(out, level: str = "record", base: Path | None = None) -> dict:
    """The record at ``level`` re-derived from its stores without running anything: the tuned
    settings and the cost read from the record in ``base`` (default: the committed one), the
    specs rebuilt from them the stores' own (the same text, spec and code digests, every job's
    row present; else :class:`StaleStore`), then :func:`compute`'s analysis of the rows."""
    from wmr.engine.sweeps import code_digest, finished_jobs

    old = common.load_record(base or COMMITTED, STEM)
    if not old or old.get("level") != level:
        raise StaleStore(f"no {level} record in {base or COMMITTED}")
    d, store = LEVELS[level], _store(Path(out), level)
    tuned, known = old["tuning"]["arms"], (old.get("known_pid") or {}).get("tuning")
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        fresh = _specs(d, tuned, Path(tmp), known)
        done = []
        for lv, pose, p in fresh:
            for f in [p, *Path(tmp).glob("*@*.toml")]:
                kept = store / "specs" / f.name
                if not kept.exists() or kept.read_text() != f.read_text():
                    raise StaleStore(f"{kept}: not the spec this record's settings give")
            done.append((lv, pose, store / "specs" / p.name))
    for _, _, p in done:
        spec = sweep.load_spec(p)
        man = json.loads((store / p.stem / "manifest.json").read_text())
        if man["spec_digest"] != spec.digest or man["code_digest"] != code_digest():
            raise StaleStore(f"{store / p.stem}: its digests are not this code's and spec's")
        if len(finished_jobs(store / p.stem)) != spec.n_jobs:
            raise StaleStore(f"{store / p.stem}: runs missing")
    return _assemble(out, level, d, done, store, tuned, known, {**old["cost"], "rederived": True})


def _known(rows, tuned: dict, known: dict) -> dict:
    """Best adaptive arm (tuned once) against the fixed PID tuned per mechanism: the contrast
    model on the both-stable pairs and each pose's paired divergence, per mechanism."""
    key = ["pose", "mechanism", "trajectory", "seed"]
    parts = []
    for pose in POSES:
        best = best_arm(tuned, pose, ADAPTIVE)
        x = rows[(rows.level == "tuned") & (rows.pose == pose) & (rows.controller == best)]
        y = rows[(rows.level == "known-pid") & (rows.pose == pose)]
        parts.append(join(x.set_index(key), y.set_index(key)))
    import pandas as pd

    p = pd.concat(parts, ignore_index=True)
    div = {pose: {m: rstats.paired_failures(g.failed_a, g.failed_b, g.seed)
                  for m, g in p[p.pose == pose].groupby("mechanism", sort=False)}
           for pose in POSES}  # fmt: skip
    ok = p[~p.failed_a & ~p.failed_b].copy()
    ok["delta"] = np.log(ok.tail_position_a) - np.log(ok.tail_position_b)
    return {"label": "best adaptive arm (tuned once) - PID tuned on the test mechanism (same "
                     "budget; the training trajectories on that mechanism's plant)",
            "tuning": known, "divergence": div,
            "model": rstats.contrast_model(ok, apart=tuple(design.MUJOCO)) if len(ok) > 2
            else None}  # fmt: skip


def _ran(rows, a: str, b: str) -> bool:
    """Whether both arms of contrast (a, b) ran (the quick level has fewer arms)."""
    return {a, b} - {"best-adaptive", "best-fixed"} <= set(rows.controller)


def analyse(rows, tuned: dict) -> dict:
    """The record's statistics from the rows and the tuning (see the module)."""
    mechs = list(dict.fromkeys(rows.mechanism))
    trajs = list(dict.fromkeys(rows.trajectory))
    best = {pose: {"best-adaptive": best_arm(tuned, pose, ADAPTIVE),
                   "best-fixed": best_arm(tuned, pose, FIXED)} for pose in POSES}
    div = {}
    for (lv, pose, m, c), g in rows.groupby(["level", "pose", "mechanism", "controller"],
                                            sort=False):  # fmt: skip
        eff = g.effort[~g.failed]
        div.setdefault(lv, {}).setdefault(pose, {}).setdefault(m, {})[c] = {
            **rstats.divergence(g.failed), "errors": int((g.status != "ok").sum()),
            "effort_stable_mean": float(eff.mean()) if len(eff) else None}  # fmt: skip
    contrasts = {}
    for a, b in CONTRASTS:
        if not _ran(rows, a, b):
            continue
        p = pairs_of(rows, a, b, best)
        name = f"{a} - {b}"
        contrasts[name] = {}
        for lv in ("tuned", "default"):
            pl = p[p.level == lv]
            contrasts[name][lv] = {pose: endpoints(pl[pl.pose == pose], mechs, trajs)
                                   for pose in POSES}  # fmt: skip
            ok = stable(pl)
            contrasts[name][lv]["model"] = (rstats.contrast_model(ok, apart=tuple(design.MUJOCO))
                                            if len(ok) > 2 else None)  # fmt: skip
        if (rows.level == "tuned-other").any():
            contrasts[name]["restarts"] = {}
            for la, lb in PAIRINGS:
                pl = pairs_of(rows, a, b, best, (la, lb))
                e = {pose: endpoints(pl[pl.pose == pose], mechs, trajs) for pose in POSES}
                ok = stable(pl)
                e["model"] = rstats.contrast_model(ok) if len(ok) > 2 else None
                contrasts[name]["restarts"][f"{la} / {lb}"] = e
    pp = paper_pairs(rows)
    paper = {"label": "the paper's asymmetric arm: IAPID-NN-DEKF on the filtered pose vs APID on "
                      "the raw pose, defaults", "endpoints": endpoints(pp, mechs, trajs)}
    return {"arms": list(tuned["raw"]), "poses": list(POSES), "mechanisms": mechs,
            "trajectories": trajs,
            "seeds": {lv: int(rows[rows.level == lv].seed.nunique()) for lv in
                      ("tuned", "default")},
            "restart_pairings": [f"{la} / {lb}" for la, lb in PAIRINGS
                                 if (rows.level == "tuned-other").any()],
            "best": best, "divergence": div, "contrasts": contrasts, "paper_arm": paper,
            "adaptation": frozen.analyse(rows, mechs, trajs),
            "margins": {"relative": rstats.REL_MARGIN, "absolute": rstats.ABS_MARGIN},
            "alpha": rstats.ALPHA}  # fmt: skip


def tracking(rows, tuned: dict, record: dict) -> dict:
    """The second endpoint, tracking failure (``_regimes_stats.TRACKING_M``): per setting level,
    pose source, mechanism and arm the count with its Clopper-Pearson interval (as
    divergence's); and each verdict that changes when "diverged" is replaced by "failed to
    track" (the model on the both-tracking pairs, the seed sign-flip test on tracking failure)."""
    r = rows.assign(failed=rstats.failed_to_track(rows.failed, rows.tail_position))
    alt = analyse(r, tuned)
    before = report.verdicts(record)["mechanisms"]
    after = report.verdicts({**record, "contrasts": alt["contrasts"]})["mechanisms"]
    changes = []
    for m, by in before.items():
        for name, v in by.items():
            for setting, x, y in (("tuned", v, after[m][name]),
                                  ("default", v.get("default"), after[m][name].get("default"))):
                if x and y and x["verdict"] != y["verdict"]:
                    changes.append({"mechanism": m, "contrast": name, "setting": setting,
                                    "both_stable": x["verdict"], "both_tracking": y["verdict"]})
    return {"threshold_m": rstats.TRACKING_M, "reason": rstats.TRACKING_REASON,
            "counts": alt["divergence"], "verdict_changes": changes}


def _untuned(level: str) -> bool:
    """Whether the arms of run level ``level`` share every setting (the defaults, and the rate
    sensitivity: one ``mu`` for both arms), so a matched pair differs in the compared factor
    alone; elsewhere each arm's tuned settings are its own."""
    return level == "default" or level.startswith("rate-")


def check(record: dict) -> None:
    """The record's claims hold: every compared pair of arms ran matched (the same scenarios'
    context, pose and shared settings but the compared factor and each arm's tuned settings),
    each arm on the two pose sources differs only in the pose, the counts and paired tests add
    up, and no stable-pair statistic or "equivalent" exists without stable pairs."""
    free = {c: {f["key"].split(".")[2].split("[")[0].split(" ")[0] for f in t["free"]}
            for c, t in record["tuning"]["arms"]["raw"].items()}  # fmt: skip
    for level, by_pose in record["arms_run"].items():
        for pose, arms in by_pose.items():
            for a, b, factor in design.COMPARED:
                if a not in arms or b not in arms:  # (the quick level has fewer arms)
                    continue
                allowed = set() if _untuned(level) else free[a] | free[b]
                design.matched(arms[a], arms[b], allowed, factor)
            assert all(e["filtered"] == (pose == "filtered") for e in arms.values()), pose
        for c in by_pose["raw"]:
            allowed = set() if _untuned(level) else free[c]
            design.matched(by_pose["raw"][c], by_pose["filtered"][c], allowed, "pose")
        if level.startswith(frozen.LEVEL):  # each arm frozen against itself: the adaptation only
            on = record["arms_run"][level.replace(frozen.LEVEL, "tuned")]
            for pose, arms in by_pose.items():
                for c, e in arms.items():
                    design.matched(on[pose][c], e, set(design.FROZEN[c]), "arm")
    for lv in record["divergence"].values():
        for pose in lv.values():
            for arms in pose.values():
                for x in arms.values():
                    assert 0 <= x["diverged"] <= x["n"] and x["errors"] == 0, x
    for c in record["contrasts"].values():
        for lv in ("tuned", "default"):
            for pose in record["poses"]:
                for m in c[lv][pose].values():
                    for t in m["trajectories"].values():
                        if t["n_stable"] == 0:
                            assert t["mean_diff"] is None and not t["equivalent_rel"]
                            assert not t["equivalent_abs"]
    assert set(record["verdict"]["mechanisms"]) == set(record["mechanisms"])
    assert set(cov := record["coverage"]["contrasts"]) == {f"{a} - {b}" for a, b in COVERED}
    for c in [*cov.values(), *record.get("coverage_tuned", {}).get("contrasts", {}).values()]:
        assert set(c["intervals"]) == {"normal", "t(G-1)"} and c["replicates"] > 0
        for iv, by in c["intervals"].items():  # the rule's (t) accepts the truth (DESIGN §7.6)
            assert set(by) == {f"{r:g}" for r in rcov.RATIOS}
            for x in by.values():
                assert 0 <= x["coverage_cells"] <= 1 and abs(sum(x["verdicts"].values()) - 1) < 1e-9
                assert iv != "t(G-1)" or c["replicates"] < 100 or x["accepts"] >= 0.9, x
    rstats.check_paired(record)  # every paired failure test's p from its per-seed differences
    tr = record["tracking"]
    for lv, by in tr["counts"].items():  # a diverged run failed to track: counts at least those
        for pose, mechs in by.items():
            for m, arms in mechs.items():
                for c, x in arms.items():
                    d = record["divergence"][lv][pose][m][c]
                    assert x["n"] == d["n"] and d["diverged"] <= x["diverged"] <= x["n"], (m, c)


def table(record: dict) -> str:
    return report.table(record)


def render(record: dict) -> str:
    return common.section(TITLE, report.notes(record), table(record), record["figures"])


def main(argv: list[str] | None = None) -> int:
    """``python -m analysis.regimes [--out DIR] [--level quick|record|full] [--workers N]
    [--rederive]``: compute the study at that level (``make regimes``: full), or with
    ``--rederive`` re-derive the committed record's level from its stores without running
    (:func:`rederive`; exit 1 if a store is stale), check it, say where it went."""
    import argparse

    import matplotlib

    matplotlib.use("Agg")
    parser = argparse.ArgumentParser(prog="python -m analysis.regimes", description=TITLE)
    parser.add_argument("--out", default="paper")
    parser.add_argument("--level", choices=list(LEVELS), default="record")
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--rederive", action="store_true",
                        help="re-derive the record from its stores; never run")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    if args.rederive:
        try:
            record = rederive(args.out, args.level)
        except StaleStore as err:
            print(f"{STEM}: not re-derived: {err}", file=sys.stderr)
            return 1
    else:
        record = compute(args.out, args.level, args.workers)
    try:
        check(record)
    except AssertionError as err:
        print(f"{STEM}: check failed: {err}", file=sys.stderr)
        return 1
    print(f"{STEM}: wrote {args.out}/results/{STEM}.json ({args.level}) in "
          f"{time.perf_counter() - t0:.1f} s")
    return 0

