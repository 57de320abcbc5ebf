"""The regime study as a matched design (issue 22): the matched-arms check, the endpoints, the
model on planted truth, a quick run through the engine, and the committed record's cells rerun."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from analysis import prose, regimes, tuning
from analysis.regimes import coverage as rcov
from analysis.regimes import design, pairs, report
from analysis.regimes import stats as rstats

PAPER = Path(__file__).resolve().parents[1] / "paper"
RECORD = PAPER / "results" / "regimes.json"
#: Initial PID gains other than the defaults (a fifth of them).
WEAK = [1.0, 1.0, 0.0, 2.0, 0.4, 0.0]


def _entry(controller: str, pose: str, table: dict | None = None, mech: str = "slip") -> dict:
    a = tuning.arm(controller, pose)
    runs = {t: tuning.scenario(design.document(t, mech), a, table, name=f"{t}@{mech}")
            for t in ("lemniscate", "circle")}  # fmt: skip
    return design.arm_entry(runs, controller)


# ---------------------------------------------------------------------------------------------
# Matched arms


def test_a_matched_pair_passes_and_a_pair_differing_in_pose_source_fails():
    design.matched(_entry("iapid-nn-dekf", "raw"), _entry("adaptive-pid", "raw"), factor="jacobian")
    design.matched(_entry("adaptive-pid", "filtered"), _entry("pid", "filtered"), factor="adapt")
    with pytest.raises(design.MatchError, match="pose source differs"):
        design.matched(_entry("iapid-nn-dekf", "filtered"), _entry("adaptive-pid", "raw"),
                       factor="jacobian")  # fmt: skip
    # the paper's own configuration is exactly that pair: IAPID filtered, APID raw
    with pytest.raises(design.MatchError, match="pose source differs"):
        design.matched(_entry("iapid-nn-dekf", "paper"), _entry("adaptive-pid", "paper"),
                       factor="jacobian")  # fmt: skip


def test_the_check_catches_other_differences():
    a = _entry("iapid-nn-dekf", "raw")
    with pytest.raises(design.MatchError, match="settings differ in \\['gains'\\]"):
        design.matched(a, _entry("adaptive-pid", "raw", {"gains": WEAK}), factor="jacobian")
    # a tuned setting of the arms may differ; a plant may not
    design.matched(a, _entry("adaptive-pid", "raw", {"gains": WEAK}), {"gains"}, "jacobian")
    with pytest.raises(design.MatchError, match="context differs"):
        design.matched(a, _entry("adaptive-pid", "raw", mech="lag-delay"), factor="jacobian")
    # adaptation on/off is the APID - PID factor, not the IAPID - APID one
    with pytest.raises(design.MatchError, match="adapt"):
        design.matched(_entry("adaptive-pid", "raw"), _entry("pid", "raw"), factor="jacobian")
    # the same arm on the two pose sources: only the pose may differ
    design.matched(_entry("pid", "raw"), _entry("pid", "filtered"), factor="pose")
    with pytest.raises(design.MatchError, match="same pose source"):
        design.matched(_entry("pid", "raw"), _entry("pid", "raw"), factor="pose")


# ---------------------------------------------------------------------------------------------
# Endpoints


def test_clopper_pearson_and_exact_mcnemar_closed_forms():
    """0 of n: the upper bound is 1 - (alpha/2)^(1/n); n of n: the lower is (alpha/2)^(1/n);
    McNemar with 0 and 6 discordant pairs: p = 2 * 0.5^6."""
    z = rstats.divergence([False] * 20)
    assert z["diverged"] == 0 and z["ci_low"] == 0.0
    assert z["ci_high"] == pytest.approx(1 - 0.025 ** (1 / 20), rel=1e-9)
    f = rstats.divergence([True] * 20)
    assert f["ci_high"] == 1.0 and f["ci_low"] == pytest.approx(0.025 ** (1 / 20), rel=1e-9)
    m = rstats.mcnemar([False] * 6 + [True] * 4, [True] * 6 + [True] * 4)
    assert (m["a_only"], m["b_only"], m["both"]) == (0, 6, 4)
    assert m["p"] == pytest.approx(2 * 0.5**6, rel=1e-12)
    assert rstats.mcnemar([True, False], [True, False])["p"] == 1.0


def test_the_seed_sign_flip_test_against_enumeration_and_clustered_failures():
    """The convolution's p-value equals the share of the 2^S sign assignments (an independent
    enumeration), bit for bit, on random per-seed differences; closed forms: S seeds each +1
    give 2 * 0.5^S, no difference gives 1. Failures clustered in one seed (a diverges on all
    6 trajectories of seed 0, b on none; no other discordance): McNemar over the runs says
    p = 2 * 0.5^6 (significant), the seed test says 1 (one seed decides nothing)."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        d = rng.integers(-3, 4, rng.integers(1, 12))
        nz = d[d != 0]
        signs = 1 - 2 * ((np.arange(2**nz.size)[:, None] >> np.arange(nz.size)) & 1)
        want = float(np.mean(np.abs(signs @ nz) >= abs(d.sum()))) if nz.size else 1.0
        assert rstats.sign_flip(d) == want, d
    assert rstats.sign_flip([1] * 8) == 2 * 0.5**8 and rstats.sign_flip([0, 0]) == 1.0
    with pytest.raises(ValueError):
        rstats.sign_flip([0.5, 0.5])  # not a count: truncating it would say p = 1
    seeds = np.repeat(np.arange(10), 6)
    a = seeds == 0
    r = rstats.paired_failures(a, np.zeros(60, bool), seeds)
    assert r["p_mcnemar"] == pytest.approx(2 * 0.5**6) and r["p"] == 1.0
    assert r["per_seed"] == [6] + [0] * 9 and (r["a_only"], r["b_only"]) == (6, 0)
    # the same six failures spread over six seeds: both tests agree
    r = rstats.paired_failures(np.isin(np.arange(60), np.arange(0, 36, 6)), np.zeros(60, bool),
                               seeds)  # fmt: skip
    assert r["p"] == pytest.approx(2 * 0.5**6) == r["p_mcnemar"]


def test_two_always_diverging_arms_are_not_equivalent():
    r = rstats.pair_rmse([np.nan] * 10, [True] * 10, [np.nan] * 10, [True] * 10)
    assert r["n_stable"] == 0 and r["mean_diff"] is None and r["mean_a"] is None
    assert not r["equivalent_rel"] and not r["equivalent_abs"]
    # one arm always diverging: no stable pair either, and no placeholder in any mean
    r = rstats.pair_rmse([0.01] * 10, [False] * 10, [50.0] * 10, [True] * 10)
    assert r["n_stable"] == 0 and r["mean_b"] is None


def test_rmse_on_both_stable_pairs_and_equivalence_margins():
    rng = np.random.default_rng(0)
    b = 0.02 + 0.001 * rng.standard_normal(20)
    a = b + 0.0002 + 0.0001 * rng.standard_normal(20)  # +1 %: inside 5 % and inside 1 mm
    da = np.zeros(20, bool)
    da[:3] = True  # three of a's runs diverged: their pairs leave
    r = rstats.pair_rmse(np.where(da, 99.0, a), da, b, np.zeros(20, bool))
    assert r["n_stable"] == 17 and r["mean_a"] == float(a[3:].mean())
    assert r["mean_diff"] == pytest.approx(float((a[3:] - b[3:]).mean()), abs=1e-15)
    assert r["equivalent_rel"] and r["equivalent_abs"]
    far = rstats.pair_rmse(b * 1.3, np.zeros(20, bool), b, np.zeros(20, bool))  # +30 %
    assert not far["equivalent_rel"] and not far["equivalent_abs"]
    assert far["ci_low"] > 0


# ---------------------------------------------------------------------------------------------
# The model on planted truth


def _synthetic(seed: int = 0, n_seeds: int = 20) -> tuple[pd.DataFrame, dict]:
    """Paired log ratios with a planted contrast per (mechanism, pose), a trajectory effect
    (sum zero), a shared effect per seed (the cluster) and noise."""
    rng = np.random.default_rng(seed)
    truth = {("ideal", "raw"): 0.0, ("ideal", "filtered"): 0.0, ("lag", "raw"): -0.30,
             ("lag", "filtered"): -0.10, ("slip", "raw"): 0.15, ("slip", "filtered"): 0.15}
    traj = {"a": 0.05, "b": -0.05}
    seed_eff = 0.05 * rng.standard_normal(n_seeds)
    rows = [{"mechanism": m, "pose": p, "trajectory": t, "seed": s,
             "delta": v + traj[t] + seed_eff[s] + 0.03 * rng.standard_normal()}
            for (m, p), v in truth.items() for t in traj for s in range(n_seeds)]  # fmt: skip
    return pd.DataFrame(rows), truth


def test_the_model_recovers_a_planted_contrast():
    df, truth = _synthetic()
    fit = rstats.contrast_model(df)
    assert fit["clusters"] == 20 and fit["n"] == len(df)
    for (m, p), v in truth.items():
        e = fit["cells"][m][p]
        assert e["log_ci"][0] < v < e["log_ci"][1], (m, p, e)
        assert abs(e["log"] - v) < 0.05  # 0.03 noise / sqrt(40) + the seeds' mean: << 0.05
    lag = fit["mechanisms"]["lag"]
    assert lag["log_ci"][0] < -0.2 < lag["log_ci"][1] and lag["ratio_ci"][1] < 1.0
    assert fit["tests"]["pose_source"]["p"] < 1e-6  # lag's pose difference is planted
    assert fit["tests"]["mechanism"]["p"] < 1e-6
    # no pose interaction planted: the test does not find one (planted on lag only, removed)
    df2 = df[df.mechanism != "lag"]
    assert rstats.contrast_model(df2)["tests"]["pose_source"]["p"] > 0.01
    assert report.classify(fit["mechanisms"]["lag"], False) == "pays"
    assert report.classify(fit["mechanisms"]["slip"], False) == "costs"
    assert report.classify(fit["mechanisms"]["ideal"], False) == "same within 5 %"
    assert report.classify(fit["mechanisms"]["ideal"], True) == "costs (divergence)"
    assert report.classify(fit["mechanisms"]["ideal"], -1) == "pays (divergence)"  # b diverges more
    assert report.classify({**fit["mechanisms"]["lag"], "n": 5}, False) == "undecided"


def _layout(n_seeds: int, seed_sd: float, pair_sd: float, seed: int = 1) -> pd.DataFrame:
    """Units of the defaults' kind (mechanisms x poses x trajectories x seeds) with delta from
    :func:`analysis.regimes.coverage.simulate` at a planted 1.0 and the given noise."""
    units = pd.DataFrame([{"mechanism": m, "pose": p, "trajectory": t, "seed": s}
                          for m in ("ideal", "lag") for p in ("raw", "filtered")
                          for t in ("a", "b", "c") for s in range(n_seeds)])  # fmt: skip
    sd = {m: {"seed_sd": seed_sd, "pair_sd": pair_sd} for m in ("ideal", "lag")}
    return rcov.simulate(units, sd, 1.0, np.random.default_rng(seed))


def test_the_noise_estimate_recovers_planted_noise_levels():
    df = _layout(200, 0.02, 0.01)
    sd = rcov.noise(df)
    for m in ("ideal", "lag"):  # 200 seeds: the SDs' sampling error ~ 1/sqrt(2 * 200) = 5 %
        assert abs(sd[m]["seed_sd"] / 0.02 - 1) < 0.2 and abs(sd[m]["pair_sd"] / 0.01 - 1) < 0.1
    assert rcov.noise(_layout(30, 0.0, 0.01))["lag"]["seed_sd"] < 0.004  # none planted: ~0


def test_the_rule_on_planted_truth_gives_the_planted_verdict():
    """At the defaults' 6 seeds, noise of the record's IAPID - APID size (0.01 per pair): a
    planted 1.0 and 0.97 come out "same within 5 %", 0.90 "pays", 1.10 "costs"."""
    frame = _layout(6, 0.003, 0.01)
    c = rcov.coverage(frame, replicates=8, seed=3)
    assert c["clusters"] == 6 and c["pairs"] == len(frame)
    for interval in ("normal", "t(G-1)"):
        by = c["intervals"][interval]
        for ratio, word in rcov.TRUTH.items():
            assert by[f"{ratio:g}"]["verdicts"][word] >= 0.8, (interval, ratio, by)
            assert by[f"{ratio:g}"]["correct"] == by[f"{ratio:g}"]["verdicts"][word]
    t = c["intervals"]["t(G-1)"]
    assert all(0.75 <= x["coverage_cells"] <= 1.0 for x in t.values())  # 32 intervals each
    # a larger noise: a planted 0.90 is no longer found every time (the rule is not a constant)
    loud = rcov.coverage(_layout(6, 0.05, 0.3), replicates=8, seed=3, use_t=(True,))
    assert loud["intervals"]["t(G-1)"]["0.9"]["verdicts"]["pays"] < 0.8


def test_tracking_failure_counts_on_known_runs():
    failed = [False, False, True, False, False, False]
    rmse = [0.01, 0.3, 0.02, math.nan, rstats.TRACKING_M, 0.2000001]
    got = rstats.failed_to_track(failed, rmse)
    assert got.tolist() == [False, True, True, True, False, True]  # at the threshold: tracks
    d = rstats.divergence(got)
    assert (d["n"], d["diverged"]) == (6, 4)


def test_mujoco_mechanisms_are_tested_apart():
    """A mechanism given as ``apart`` stays out of the joint mechanism test: planting a large
    contrast on it moves that test only when it is pooled."""
    df, _ = _synthetic()
    mj = df[df.mechanism == "ideal"].assign(mechanism="mujoco", delta=lambda x: x.delta + 1.0)
    base = df[df.mechanism != "lag"]  # ideal and slip only
    both = pd.concat([base, mj[mj.seed < 3]], ignore_index=True)
    pooled = rstats.contrast_model(both)["tests"]
    apart = rstats.contrast_model(both, apart=("mujoco",))["tests"]
    alone = rstats.contrast_model(base)["tests"]
    assert apart["mechanism"]["df"] == 1 and pooled["mechanism"]["df"] == 2
    assert apart["mechanism"]["p"] == pytest.approx(alone["mechanism"]["p"], rel=0.05)
    assert apart["apart"]["mechanisms"] == ["mujoco"] and apart["apart"]["mechanism"] is None
    assert "apart" not in pooled


# ---------------------------------------------------------------------------------------------
# A quick run through the engine


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("regimes")
    return regimes.run(out, quick=True, workers=1), out


@pytest.mark.slow
def test_quick_run_is_whole_consistent_and_renders(quick):
    record, out = quick
    regimes.check(record)
    stored = json.loads((out / "results" / "regimes.json").read_text())
    assert stored == json.loads(json.dumps(record))
    regimes.check(stored)
    assert (out / "tables" / "regimes.md").read_text() == regimes.table(stored)
    text = regimes.render(stored)
    assert text.startswith(f"## {regimes.TITLE}\n")
    assert prose.long_sentences(text) == []  # the prose rule at this level's record too
    assert "+23346" not in text and "pays by staying stable" not in text
    for pose in regimes.POSES:
        for _c, t in record["tuning"]["arms"][pose].items():
            assert t["evaluations"] == 2 * record["design"]["per_setting"] * len(t["free"])
    # the check fails when an arm pair ran on different pose sources
    bad = json.loads(json.dumps(stored))
    bad["arms_run"]["tuned"]["raw"]["adaptive-pid"]["filtered"] = True
    with pytest.raises(AssertionError):
        regimes.check(bad)
    # tracking failure counted from the store's rows directly (diverged, an error, or a tail
    # RMSE above the threshold or not a number)
    from wmr.engine import sweep

    for pose in regimes.POSES:
        rows = sweep.read_rows(out / ".regimes-store" / f"tuned-{pose}").to_pandas()
        rows["mechanism"] = rows.scenario.str.split("@").str[1]
        for (m, c), g in rows.groupby(["mechanism", "controller"]):
            k = int((g.diverged | (g.status != "ok") | ~(g.tail_position <= 0.2)).sum())
            x = record["tracking"]["counts"]["tuned"][pose][m][c]
            assert (x["diverged"], x["n"]) == (k, len(g)), (m, c)


def test_the_record_is_rederived_from_its_stores_and_a_stale_one_refused(quick):
    """``rederive`` reads the stores only: the same record (but for its cost's flag), and a
    store whose spec is not the one the record's settings give is refused, not rerun (in the
    quick study's folder: a store's digest names its files' paths; the files are restored)."""
    record, out = quick
    path = out / "results" / "regimes.json"
    spec = out / ".regimes-store" / "specs" / "tuned-raw.toml"
    kept, text = path.read_bytes(), spec.read_text()
    try:
        again = regimes.rederive(out, "quick", base=out)
        assert again["cost"].pop("rederived") is True
        assert json.loads(json.dumps(again)) == json.loads(json.dumps(record))
        spec.write_text(text.replace("seeds = 3", "seeds = 4"))
        with pytest.raises(regimes.StaleStore, match="tuned-raw"):
            regimes.rederive(out, "quick", base=out)
    finally:
        path.write_bytes(kept)
        spec.write_text(text)


def _rerun(record: dict, level: str, pose: str, mech: str, traj: str, arms) -> dict:
    """The runs of ``arms`` on (mechanism, trajectory) at ``level``/``pose`` from their scenario
    text and the record's settings, through the engine's run-to-row mapping."""
    from wmr.engine import Job, run_job

    d = record["design"]
    mujoco = mech in design.MUJOCO
    duration = d["mujoco_duration"] if mujoco else d["duration"]
    seeds = d["mujoco_seeds"] if mujoco else d["seeds" if level == "tuned" else "default_seeds"]
    doc = design.document(traj, mech, duration)
    out = {}
    for c in arms:
        table = record["tuning"]["arms"][pose][c]["table"] if level == "tuned" else None
        sc = tuning.scenario(doc, tuning.arm(c, pose), table)
        out[c] = [run_job(Job(sc, c, s)) for s in range(seeds)]
    return out


def _same_cell(record, contrast, level, pose, mech, traj):
    a, b = contrast.split(" - ")
    best = record["best"][pose]
    ca, cb = best.get(a, a), best.get(b, b)
    runs = _rerun(record, level, pose, mech, traj, (ca, cb))
    got = rstats.pair_rmse([r.tail_position for r in runs[ca]], [r.diverged for r in runs[ca]],
                           [r.tail_position for r in runs[cb]], [r.diverged for r in runs[cb]])
    want = record["contrasts"][contrast][level][pose][mech]["trajectories"][traj]
    assert got == want  # made on this machine: exact


@pytest.mark.slow
def test_a_quick_cell_is_its_runs(quick):
    record, _ = quick
    _same_cell(record, "adaptive-pid - pid", "tuned", "raw", "lag-delay", "sinusoid")
    _same_cell(record, "iapid-nn-dekf - adaptive-pid", "default", "filtered", "ideal", "sinusoid")


def test_paper_pose_source_gives_each_arm_the_pose_of_its_arm():
    """The paper's asymmetric row uses the filtered IAPID and the raw APID runs: under
    ``pose_source = "paper"`` each acts on exactly that pose (the same run, bit for bit)."""
    from wmr.engine import Job, run_job

    doc = design.document("sinusoid", "lag-delay", 7.0)
    for c, pose in (("iapid-nn-dekf", "filtered"), ("adaptive-pid", "raw")):
        paper = run_job(Job(tuning.scenario(doc, tuning.arm(c, "paper"), None), c, 4))
        same = run_job(Job(tuning.scenario(doc, tuning.arm(c, pose), None), c, 4))
        assert paper.tail_position == same.tail_position and np.isfinite(same.tail_position)


# ---------------------------------------------------------------------------------------------
# The committed record


def _matched_record() -> bool:
    return RECORD.exists() and "arms_run" in json.loads(RECORD.read_text())


committed = pytest.mark.skipif(not _matched_record(), reason="no record of the matched design "
                               "committed (the earlier one, retracted, is being replaced)")


@committed
def test_the_committed_record_passes_its_check_and_is_in_the_report():
    record = json.loads(RECORD.read_text())
    regimes.check(record)
    assert regimes.render(record).rstrip() in (PAPER / "report.md").read_text()
    assert record["level"] in regimes.LEVELS and record["level"] in regimes.render(record)
    assert report.verdicts(record) == record["verdict"]  # the record's verdicts are the rule's
    # a paired failure test whose p is not its per-seed differences' fails the check
    bad = json.loads(json.dumps(record))
    bad["contrasts"][report.BSC]["tuned"]["raw"]["lag-delay"]["divergence"]["p"] = 0.5
    with pytest.raises(AssertionError):
        regimes.check(bad)
    # a rule that rejects the planted truth at the tuned layout fails the check (DESIGN §7.6)
    row = record["coverage_tuned"]["contrasts"][report.BSC]["intervals"]["t(G-1)"]["1"]
    row["accepts"] = 0.85
    with pytest.raises(AssertionError):
        regimes.check(record)


@committed
@pytest.mark.slow
def test_a_sample_of_the_committed_cells_is_rerun_to_the_same_numbers():
    """Two cells of cheap arms (every seed), one at the defaults: the same numbers, exactly
    (the record was made on this kind of machine; see tests/cases.CROSS_MACHINE_RTOL)."""
    record = json.loads(RECORD.read_text())
    _same_cell(record, "adaptive-pid - pid", "tuned", "raw", "lag-delay", "lemniscate")
    _same_cell(record, "adaptive-pid - pid", "default", "filtered", "slip", "circle")


@committed
@pytest.mark.slow
def test_a_committed_run_is_reproduced_by_wmr_run(tmp_path):
    """A run of the record from its scenario file by ``wmr run``: the tuned APID on the raw pose
    on lag plus delay, lemniscate, seed 0."""
    record = json.loads(RECORD.read_text())
    table = record["tuning"]["arms"]["raw"]["adaptive-pid"]["table"]
    doc = design.evaluation_text("lemniscate", "lag-delay")
    lines = [doc, '[estimator]\npose_source = "raw"', "[controllers.adaptive-pid]"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in table.items()]
    path = tmp_path / "cell.toml"
    path.write_text("\n".join(lines) + "\n")
    out = tmp_path / "run"
    subprocess.run([str(Path(sys.executable).parent / "wmr"), "run", str(path), "--controller",
                    "adaptive-pid", "--seed", "0", "--out", str(out)], check=True,
                   capture_output=True)  # fmt: skip
    summary = json.loads((out / "summary.json").read_text())["runs"][0]
    want = _rerun(record, "tuned", "raw", "lag-delay", "lemniscate", ("adaptive-pid",))
    r = want["adaptive-pid"][0]
    assert summary["rmse"]["position"] == r.rmse_position and summary["diverged"] == r.diverged
    # and that run is the record's: the cell's both-stable mean includes it when it is stable
    cell = record["contrasts"]["adaptive-pid - pid"]["tuned"]["raw"]["lag-delay"]
    assert cell["trajectories"]["lemniscate"]["pairs"] == record["design"]["seeds"]
    assert math.isfinite(r.rmse_position)


@committed
@pytest.mark.slow
def test_a_committed_recovery_cell_is_its_runs():
    """Recovery after the payload change (``wmr.closedloop.measures``' recovery RMSE) of the tuned
    APID and PID on the raw pose, every seed of the record, through the engine's job-to-row
    mapping."""
    from wmr.engine import Job
    from wmr.engine.jobs import job_row

    record = json.loads(RECORD.read_text())
    rec = record["recovery"]["poses"]["raw"]
    sc_name = "lemniscate@lagged-velocity-change"
    doc = design.document("lemniscate", "lagged-velocity-change")
    rows = {}
    for c in ("adaptive-pid", "pid"):
        sc = tuning.scenario(doc, tuning.arm(c, "raw"), record["tuning"]["arms"]["raw"][c]["table"])
        rows[c] = [job_row(Job(sc, c, s, measures=("recovery",)))
                   for s in range(record["design"]["recovery_seeds"])]  # fmt: skip
    a, b = rows["adaptive-pid"], rows["pid"]
    got = rstats.pair_rmse([r["recovery_rmse"] for r in a], [r["diverged"] for r in a],
                           [r["recovery_rmse"] for r in b], [r["diverged"] for r in b])
    assert got == rec["contrasts"]["adaptive-pid - pid"][sc_name]
    assert rec["arms"][sc_name]["pid"]["n"] == len(b)


def test_a_tuned_verdict_is_withheld_when_a_tuning_did_not_converge():
    """The earlier rule, kept for records without the runner-up restarts' runs: a tuned
    contrast whose arms' restarts disagree measures the tuning, so its verdict is withheld; the
    same record with agreeing restarts gets a verdict, and the defaults' verdict stands beside
    it either way."""
    import copy

    record = json.loads((Path(__file__).resolve().parents[1] / "paper" / "results"
                         / "regimes.json").read_text())  # fmt: skip
    for c in record["contrasts"].values():  # a record without the runner-up restarts' runs
        c.pop("restarts", None)
    record.pop("restart_pairings", None)
    ia = "iapid-nn-dekf - adaptive-pid"
    arms = record["tuning"]["arms"]["raw"]
    assert not arms["iapid-nn-dekf"]["agreement"]["agree"]  # as committed
    v = report.verdicts(record)["mechanisms"]["ideal"][ia]
    assert v["poses"]["raw"]["verdict"] == "withheld" and v["default"]["verdict"]
    fixed = copy.deepcopy(record)
    for a in ("iapid-nn-dekf", "adaptive-pid"):
        fixed["tuning"]["arms"]["raw"][a]["agreement"]["agree"] = True
    assert report.verdicts(fixed)["mechanisms"]["ideal"][ia]["poses"]["raw"]["verdict"] != \
        "withheld"
    assert report.verdicts(fixed)["mechanisms"]["mujoco"][ia]["poses"]["raw"]["verdict"] == \
        "withheld"  # MuJoCo stays withheld: tuned on kinematic plants


def test_a_tuned_verdict_stands_only_if_every_pairing_of_the_restarts_gives_it():
    """With the runner-up restarts' runs (``restarts`` in a contrast), the restart agreement
    flag no longer decides: a verdict the four pairings share stands even though the restarts'
    objectives disagree, and one pairing with another word withholds it."""
    import copy

    record = json.loads((Path(__file__).resolve().parents[1] / "paper" / "results"
                         / "regimes.json").read_text())  # fmt: skip
    ia = "iapid-nn-dekf - adaptive-pid"
    c = record["contrasts"][ia]
    c["restarts"] = {k: copy.deepcopy(c["tuned"]) for k in
                     ("tuned / tuned-other", "tuned-other / tuned", "tuned-other / tuned-other")}
    v = report.verdicts(record)["mechanisms"]["ideal"][ia]["poses"]["raw"]
    assert v["verdict"] != "withheld" and v["withheld"] is None  # restarts disagree, as committed
    cell = c["restarts"]["tuned-other / tuned"]["model"]["cells"]["ideal"]["raw"]
    lo, hi = cell["ratio_ci"]
    other = "pays" if v["verdict"] == "costs" else "costs"  # a word that pairing now says
    cell["ratio_ci"] = [lo * 0.3, lo * 0.5] if other == "pays" else [hi + 0.5, hi + 1.0]
    v2 = report.verdicts(record)["mechanisms"]["ideal"][ia]["poses"]["raw"]
    assert v2["verdict"] == "withheld" and other in v2["withheld"]
    assert report.verdicts(record)["mechanisms"]["mujoco"][ia]["poses"]["raw"]["verdict"] == \
        "withheld"  # MuJoCo stays withheld


# ---------------------------------------------------------------------------------------------
# The SGD rate's sensitivity runs


def test_the_rate_levels_scale_the_default_mu_the_same_for_both_arms():
    from dataclasses import asdict

    from analysis.regimes import rates
    from wmr import controllers

    for m in rates.RATES:
        t = rates.tables(m)
        assert set(t) == set(rates.ARMS)
        for c in rates.ARMS:
            mu = asdict(controllers.get(c).Settings())["mu"]
            assert t[c]["mu"] == pytest.approx([m * x for x in mu], rel=1e-15)
        assert t[rates.ARMS[0]] == t[rates.ARMS[1]]  # one rate: the arms differ in the Jacobian


def test_the_rate_analysis_recovers_a_planted_ratio_and_counts_divergence():
    """Synthetic rows: IAPID's RMSE a planted 1.3 times APID's (log-normal noise) on the
    both-stable pairs, 3 of APID's 40 runs diverged at x1000 only."""
    from analysis.regimes import rates

    rng = np.random.default_rng(5)
    rows = []
    for lv in (rates.level(m) for m in rates.RATES):
        for t in ("lemniscate", "circle"):
            for s in range(20):
                base = 0.02 * math.exp(rng.normal(0, 0.3))
                for c, r in (("adaptive-pid", base), ("iapid-nn-dekf",
                                                      base * 1.3 * math.exp(rng.normal(0, 0.02)))):
                    failed = c == "adaptive-pid" and lv == "rate-x1000" and s < 3 and t == "circle"
                    rows.append({"level": lv, "pose": "raw", "mechanism": "ideal",
                                 "trajectory": t, "seed": s, "controller": c,
                                 "tail_position": r, "failed": failed})  # fmt: skip
    rec = rates.analyse(pd.DataFrame(rows))
    for x in ("x1", "x10", "x100", "x1000"):
        e = rec["poses"]["raw"]["ideal"][x]
        h = math.log(e["ratio_ci"][1] / e["ratio_ci"][0]) / 2  # the interval's half-width
        assert abs(math.log(e["ratio"] / 1.3)) < 2 * h < 0.02  # (a 95 % interval misses 1 in 20)
        k = 3 if x == "x1000" else 0
        assert e["divergence"]["adaptive-pid"]["diverged"] == k
        assert e["divergence"]["iapid-nn-dekf"]["diverged"] == 0 and e["n_stable"] == 40 - k
        assert e["paired"]["b_only"] == k


@pytest.mark.slow
def test_the_rate_levels_run_matched_and_a_differing_rate_fails_the_check(quick):
    """At a rate level the two arms share every setting (one mu): the check refuses a record
    whose IAPID ran at another rate than APID there."""
    record, _ = quick
    assert record["rates"] and set(record["rates"]["poses"]) == set(regimes.POSES)
    bad = json.loads(json.dumps(record))
    e = bad["arms_run"]["rate-x10"]["raw"]["iapid-nn-dekf"]
    e["settings"]["mu"] = [2 * x for x in e["settings"]["mu"]]
    with pytest.raises(AssertionError):
        regimes.check(bad)


def test_a_best_arm_the_tuning_did_not_tell_apart_withholds_its_contrast():
    """Best adaptive - best fixed is withheld where the runner-up arm's training objective is
    closer to the best arm's than the two arms' restarts are to each other, and stands (as far
    as this clause goes) once the margin exceeds the spread."""
    import copy

    record = json.loads(RECORD.read_text())
    arms = record["tuning"]["arms"]["raw"]
    for c, f in (("adaptive-bsc", 0.10), ("adaptive-nn", 0.1005), ("adaptive-pid", 0.3),
                 ("iapid-nn-dekf", 0.3), ("backstepping", 0.10), ("pid", 0.3)):
        arms[c]["objective"] = f
        arms[c]["agreement"]["spread"] = 0.001
    assert "best arm not chosen" in pairs.selection_too_close(record, "raw")
    apart = copy.deepcopy(record)
    apart["tuning"]["arms"]["raw"]["adaptive-nn"]["objective"] = 0.2
    assert pairs.selection_too_close(apart, "raw") is None


# ---------------------------------------------------------------------------------------------
# The rule's combination of the pose sources, and the adaptation switched off


def test_pose_sources_are_combined_without_inventing_a_dependence():
    from analysis.regimes import rule

    def entry(**words):
        return rule._combine({p: {"verdict": w, "diverges_more": False} for p, w in
                              words.items()}, {})["verdict"]  # fmt: skip

    assert entry(raw="pays", filtered="pays") == "pays"
    assert entry(raw="same within 5 %", filtered="undecided") == \
        "same within 5 % (raw; undecided on filtered)"  # a wider interval is no dependence
    assert entry(raw="withheld", filtered="costs") == "costs (filtered; withheld on raw)"
    assert entry(raw="same within 5 %", filtered="pays") == \
        "same within 5 % (raw; pays on filtered)"  # both can hold of 0.97
    assert entry(raw="pays", filtered="costs") == "depends on the pose source"
    assert entry(raw="same within 5 %", filtered="costs (divergence)") == \
        "depends on the pose source"
    assert entry(raw="undecided", filtered="withheld") == "undecided (raw; withheld on filtered)"
    # what each word claims of a true ratio
    assert rule.compatible("pays", 0.97) and rule.compatible("same within 5 %", 0.97)
    assert not rule.compatible("pays", 1.0) and not rule.compatible("same within 5 %", 0.9)
    assert rule.compatible("undecided", 3.0) and not rule.compatible("costs (divergence)", 0.9)
    with pytest.raises(ValueError):
        rule.compatible("depends on the pose source", 1.0)


def test_the_coverage_counts_acceptance_and_power_on_planted_truth():
    """At the IAPID - APID noise (small) the rule accepts and decides every planted truth; at a
    noise where one pose source's interval is often too wide, it still accepts the truth (an
    undecided word rejects nothing) while its power drops, and no mechanism reads "depends"."""
    quiet = rcov.coverage(_layout(6, 0.003, 0.01), replicates=6, seed=3, use_t=(True,))
    for x in quiet["intervals"]["t(G-1)"].values():
        assert x["accepts"] == 1.0 and x["correct"] == 1.0 and x["depends"] == 0.0
    loud = rcov.coverage(_layout(6, 0.01, 0.12), replicates=20, seed=3, use_t=(True,))
    at1 = loud["intervals"]["t(G-1)"]["1"]
    assert at1["correct"] < 0.9 <= at1["accepts"], at1  # power short, the truth accepted
    assert at1["depends"] <= 0.05


def test_the_frozen_settings_switch_the_adaptation_off():
    """Each adaptive arm with :data:`design.FROZEN` over its settings is its fixed law: APID
    frozen is the fixed PID at the same gains (bit for bit), DA-NN frozen is backstepping at its
    gains (to 1e-9: its compensator stays ~0, also at the largest Kalman gain of its box and on
    the filtered pose), Adaptive BSC frozen is backstepping (to 1e-9); IAPID frozen does not
    move its gains (the same run as APID frozen); unfrozen, each differs."""
    from wmr.engine import Job, run_job

    doc = design.document("sinusoid", "wheel-radius", 6.0)

    def rmse(c, table, pose="raw"):
        return run_job(Job(tuning.scenario(doc, tuning.arm(c, pose), table), c, 3)).tail_position

    gains = [3.0, 2.0, 0.0, 6.0, 1.0, 0.0]
    pid = rmse("pid", {"gains": gains})
    for c in ("adaptive-pid", "iapid-nn-dekf"):
        assert rmse(c, {"gains": gains, **design.FROZEN[c]}) == pid
        assert rmse(c, {"gains": gains, "mu": [9.0] * 6}) != pid
    k = [1.5, 20.0, 5.0]
    bsc = rmse("backstepping", {"gains": k})
    assert abs(rmse("adaptive-nn", {"gains": k, **design.FROZEN["adaptive-nn"]}) / bsc - 1) < 1e-9
    assert abs(rmse("adaptive-nn", {"gains": k}) / bsc - 1) > 1e-6
    # at the bottom of DA-NN's r box (the largest Kalman gain) and on the filtered pose too
    bsc_f = rmse("backstepping", {"gains": k}, "filtered")
    frozen = {"gains": k, "r": 10.0, **design.FROZEN["adaptive-nn"]}
    assert abs(rmse("adaptive-nn", frozen, "filtered") / bsc_f - 1) < 1e-9
    # Adaptive BSC frozen: its estimates stay at the nominal plant, so it is backstepping
    absc = rmse("adaptive-bsc", {"gains": k, **design.FROZEN["adaptive-bsc"]})
    assert abs(absc / bsc - 1) < 1e-9
    assert abs(rmse("adaptive-bsc", {"gains": k}) / bsc - 1) > 1e-6
    assert set(design.FROZEN) == set(pairs.ADAPTIVE) | {"iapid-oracle"}


def test_an_inert_best_adaptive_arm_withholds_its_contrast_and_a_frozen_mismatch_fails(quick):
    record, _ = quick
    assert set(record["arms_run"]["tuned-frozen"]["raw"]) == \
        {c for c in record["arms"] if c in design.FROZEN}
    regimes.check(record)
    ad = record["adaptation"]["arms"]
    assert set(ad) == set(record["arms_run"]["tuned-frozen"]["raw"])
    # plant an inert adaptation for the best adaptive arm on ideal/raw: the KEY verdict withheld
    rec = json.loads(json.dumps(record))
    best = rec["best"]["raw"]["best-adaptive"]
    if best not in rec["adaptation"]["arms"]:
        rec["adaptation"]["arms"][best] = json.loads(json.dumps(ad[next(iter(ad))]))
    e = rec["adaptation"]["arms"][best]
    e["raw"]["ideal"]["divergence"]["p"] = 1.0
    e["model"]["cells"]["ideal"]["raw"].update(n=40, ratio=1.0, ratio_ci=[0.99, 1.01])
    assert report.frozen_word(rec, best, "ideal", "raw") == "same within 5 %"
    v = report.verdicts(rec)["mechanisms"]["ideal"][report.KEY]["poses"]["raw"]
    assert v["verdict"] == "withheld" and "inert" in v["withheld"], v
    e["model"]["cells"]["ideal"]["raw"].update(ratio=0.5, ratio_ci=[0.4, 0.6])  # it pays
    v = report.verdicts(rec)["mechanisms"]["ideal"][report.KEY]["poses"]["raw"]
    assert "inert" not in (v["withheld"] or "")
    # a frozen arm that ran with another tuned gain than its adapting self fails the check
    bad = json.loads(json.dumps(record))
    arm = next(iter(bad["arms_run"]["tuned-frozen"]["raw"]))
    bad["arms_run"]["tuned-frozen"]["raw"][arm]["settings"]["gains"][0] += 1.0
    with pytest.raises(AssertionError):
        regimes.check(bad)


def _plant(level: dict, mech: str, pose: str, ratio: float, div_p: float = 1.0) -> None:
    """Set one cell of a contrast level (or a frozen arm's entry) to a planted ratio."""
    level[pose][mech]["divergence"]["p"] = div_p
    level["model"]["cells"][mech][pose].update(n=40, ratio=ratio,
                                               ratio_ci=[0.9 * ratio, 1.1 * ratio])


def test_an_adaptive_law_against_its_fixed_one_is_withheld_where_its_adaptation_points_away(
        quick):  # fmt: skip
    """APID - PID (by its own name) says 'pays' on ideal/raw while APID switched off at its
    tuned settings does better than adapting (frozen: 'costs'): withheld, the tuned gains
    deciding it; 'costs' where frozen APID pays: withheld too; frozen pointing the same way:
    not withheld for that reason. The same for the best arms' contrast. The distinct count
    leaves out the best arms' contrast on a pose source where another contrast has its two
    arms."""
    record, _ = quick
    rec = json.loads(json.dumps(record))
    ad = rec["adaptation"]["arms"]["adaptive-pid"]
    name = "adaptive-pid - pid"
    c = rec["contrasts"][name]
    levels = [c["tuned"], *c.get("restarts", {}).values()]

    def said(n: str = name) -> dict:
        return report.verdicts(rec)["mechanisms"]["ideal"][n]["poses"]["raw"]

    for tuned, frozen, why in ((0.5, 1.5, "not shown to pay"), (1.5, 0.5, "not shown to cost"),
                               (0.5, 0.5, None), (1.5, 1.5, None)):  # fmt: skip
        for level in levels:
            _plant(level, "ideal", "raw", tuned)
        _plant(ad, "ideal", "raw", frozen)
        v = said()
        if why:
            assert v["verdict"] == "withheld" and why in v["withheld"], (tuned, frozen, v)
        else:
            assert "not shown" not in (v["withheld"] or ""), v
    # the best arms' contrast, with APID as the best adaptive arm on raw
    rec["best"]["raw"].update({"best-adaptive": "adaptive-pid", "best-fixed": "pid"})
    for level in [rec["contrasts"][report.KEY]["tuned"],
                  *rec["contrasts"][report.KEY].get("restarts", {}).values()]:
        _plant(level, "ideal", "raw", 0.5)
    _plant(ad, "ideal", "raw", 1.5)
    assert "not shown to pay" in (said(report.KEY)["withheld"] or "")
    # the distinct count: a contrast named for two arms no other contrast has
    a, b = "iapid-nn-dekf", "pid"
    assert f"{a} - {b}" not in rec["contrasts"]
    for p in rec["poses"]:
        rec["best"][p].update({"best-adaptive": a, "best-fixed": b})
    rec["verdict"] = report.verdicts(rec)
    _, n = report.standing_count(rec)
    rec["contrasts"][f"{a} - {b}"] = json.loads(json.dumps(rec["contrasts"][report.KEY]))
    rec["verdict"] = report.verdicts(rec)
    _, n2 = report.standing_count(rec)
    assert n2 == n, (n, n2)  # the new name's cells counted, the best arms' contrast's not


def test_the_rate_ratio_interval_is_clustered_by_seed():
    """Pairs sharing a seed effect (sd 0.05) and their own noise (0.005), 20 seeds x 5 pairs:
    the seed-clustered 95 % interval covers the planted log ratio in >= 90 % of 300 replicates;
    an interval treating the 100 pairs as independent (the earlier one) covers < 70 %."""
    from scipy.stats import t as student

    from analysis.regimes import rates

    rng = np.random.default_rng(11)
    seeds = np.repeat(np.arange(20), 5)
    hit = naive = 0
    for _ in range(300):
        d = 0.1 + rng.normal(0, 0.05, 20)[seeds] + rng.normal(0, 0.005, seeds.size)
        e = rates._ratio(pd.DataFrame({"delta": d, "seed": seeds}))
        hit += e["ratio_ci"][0] <= math.exp(0.1) <= e["ratio_ci"][1]
        h = student.ppf(0.975, d.size - 1) * d.std(ddof=1) / math.sqrt(d.size)
        naive += abs(d.mean() - 0.1) <= h
    assert hit >= 0.9 * 300 and naive < 0.7 * 300, (hit, naive)
    one = rates._ratio(pd.DataFrame({"delta": [0.1, 0.2], "seed": [3, 3]}))
    assert one["ratio_ci"] is None and one["n_stable"] == 2  # one seed: no interval


def test_the_smallest_detected_effect_is_read_from_the_planted_table_by_its_size():
    from analysis.regimes.planted import detectable

    def entry(pays=0.0, costs=0.0):
        return {"verdicts": {"pays": pays, "costs": costs}}

    by = {"1": entry(0.02, 0.02), "0.97": entry(pays=0.5), "1.1": entry(costs=0.8),
          "0.9": entry(pays=0.95)}  # fmt: skip
    # |log 0.97| < |log 1.1| < |log 0.9|: 0.9 is the first named in 90 %, 1.1 the one before it
    assert detectable(by) == "0.9 (95 %); the smaller 1.1 in 80 % of cells"
    assert detectable({**by, "0.97": entry(pays=0.91)}) == "0.97 (91 %)"
    assert detectable({**by, "0.9": entry(pays=0.5)}).startswith("none (no planted ratio")
    assert detectable({"1": entry()}) == ""


def test_the_coverage_at_a_subset_of_mechanisms_uses_only_their_pairs():
    """The tuned layout's coverage is measured on the simulated plants only: ``mechanisms``
    drops the others' pairs before the noise is estimated (a mechanism with loud noise left out
    does not widen the kept one's intervals)."""
    frame = _layout(6, 0.003, 0.01)
    loud = frame.mechanism == "lag"
    frame.loc[loud, "delta"] = rcov.simulate(frame[loud], {"lag": {"seed_sd": 0.3,
                                                                   "pair_sd": 0.3}},
                                             1.0, np.random.default_rng(5)).delta.to_numpy()
    c = rcov.coverage(frame, replicates=4, seed=3, use_t=(True,), mechanisms=("ideal",))
    assert c["mechanisms"] == ["ideal"] and c["pairs"] == int((~loud).sum())
    assert set(c["noise"]) == {"ideal"} and c["noise"]["ideal"]["pair_sd"] < 0.02
    assert c["intervals"]["t(G-1)"]["0.9"]["verdicts"]["pays"] == 1.0
