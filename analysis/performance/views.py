"""The performance record as the report's section: its answer first, then the tables, then how
each figure was measured (``analysis.performance`` measures; this module only renders).

Every sentence is generated from the record and kept within the report's sentence rule
(``analysis.prose``: at most 60 words).
"""

from __future__ import annotations

from analysis.performance import against as _against
from analysis.performance import bench as _bench
from analysis.performance import phases as _phases
from analysis.performance import py_controllers as _py_controller_bench

__all__ = ["opening", "notes", "tables", "table"]


def _perf():
    from analysis import performance  # the targets and their rule live with the measurements

    return performance


#: Each target's name in the section's opening (keys of ``performance.targets_met``).
LABELS = {
    "floor_ratio": "IAPID-NN-DEKF within 4x the floor",
    "paper_runs_one_seed": "the paper's 12 runs in 1 s",
    "monte_carlo_1000": "1,000 runs in 30 s",
    "parallel_equals_serial": "parallel rows equal to serial rows",
    "python_control_same_computation": "the python-control loop's trajectory",
    "floor_correct": "the floor's correctness",
    "sweep_local_efficiency": "the 2-worker sweep efficiency (local cluster)",
    "sweep_dask_efficiency": "the 2-worker sweep efficiency (loopback scheduler)",
    "large_sweep": "the 100,000-run sweep",
    "plant_overhead": "plant effects within 1.3x the ideal step",
    "iapid_floor_ratio_25": "IAPID-NN-DEKF within 1.5x the floor",
    "run_overhead_25": "the set-up per run",
    "nmpc_step_median": "nmpc's median step",
    "mujoco_plant": "the MuJoCo plant per control step",
    "mujoco_sweep_efficiency": "the MuJoCo 2-worker sweep efficiency",
    "quick_under_2_min": "the quick level under 2 minutes",
}


def _label(key: str) -> str:
    if key.startswith("us_per_step_"):
        return f"{key.removeprefix('us_per_step_')}'s CPU µs per step"
    return LABELS.get(key, key)


def _missed_names(missed: list[str]) -> list[str]:
    """The missed targets' names, the per-controller step costs and the sweep efficiencies
    each named once as a group."""
    steps = [k.removeprefix("us_per_step_") for k in missed if k.startswith("us_per_step_")]
    sweeps = [k for k in missed if k in ("sweep_local_efficiency", "sweep_dask_efficiency")]
    out = []
    for k in missed:
        if k in sweeps[1:] or k.startswith("us_per_step_") and k != f"us_per_step_{steps[0]}":
            continue
        if k in sweeps and len(sweeps) == 2:
            out.append("the 2-worker sweep efficiency (local cluster and loopback scheduler)")
        elif k.startswith("us_per_step_"):
            out.append(f"the CPU µs per step of {', '.join(steps)}")
        else:
            out.append(_label(k))
    return out


def opening(rec: dict) -> str:
    """The section's answer: how many targets the record meets, which it misses, and the MuJoCo
    robot's cost, in a few short sentences."""
    perf = _perf()
    met = perf.targets_met(rec)
    judged = {k: v for k, v in met.items() if v is not None}
    missed = [k for k, v in judged.items() if not v]
    mach = rec["machine"]
    text = [f"This record meets {len(judged) - len(missed)} of its {len(judged)} measured "
            f"targets on a {mach['usable_cpus']}-CPU {mach['cpu_model']} "
            f"(load average {mach['load_average_start'][0]:.2f} at the start)."]  # fmt: skip
    if missed:
        names = _missed_names(missed)
        for i in range(0, len(names), 4):  # a few per sentence (the report's sentence rule)
            text.append(f"It {'also ' if i else ''}misses {'; '.join(names[i:i + 4])}.")
        text.append("The targets table gives each figure.")
    failed = [k for k in perf.CHECKED if not met[k]]
    text.append("The ratios and correctness checks that `check` asserts "
                + (f"fail: {'; '.join(map(_label, failed))}." if failed else "all hold."))
    mj = rec.get("mujoco")
    if mj:
        p = mj["plant"][0]
        text.append(f"The MuJoCo robot's plant costs {p['median_us']:.0f} µs per "
                    f"{1e3 * p['control_dt']:g} ms control step at its shipped "
                    f"{1e3 * p['timestep']:g} ms physics step (median; target <= "
                    f"{rec['targets']['mujoco_plant_us_max']:g} µs).")  # fmt: skip
        if mj.get("sweep"):
            e = mj["sweep"]["local"]["efficiency"]
            text.append(f"Its 2-worker sweep efficiency is {e:.2f} (target >= "
                        f"{rec['targets']['mujoco_sweep_efficiency_min']:g}).")
    return " ".join(text)


def notes(rec: dict) -> list[str]:
    """How each figure was measured, one bullet per figure."""
    perf = _perf()
    n, subject = rec["n_weights"], perf.SUBJECT
    steps = rec["python_control"][f"{subject}/jit"]["steps"]
    plant = ", ".join(f"{k} = {v}" for k, v in perf.PLANT.items())
    return [
        "Per-step figures: the minimum over interleaved repeats, the median beside it, "
        "compilation excluded. us_per_step includes a run's Python set-up (run_overhead_ms).",
        f"Floor: floor_update, a standard-form EKF update (P += Q; HP = H P; S; K = (S^-1 HP)^T; "
        f"P -= K HP) with n = {n} and m = 3. It is loop-based, fuses the 3 output rows and "
        "updates two rows of P per pass, as wmr.estimation.ekf does. It is timed inside a jitted "
        "loop with "
        "the H, P0, Q and R of iapid-nn-dekf at its initial weights. "
        "floor_generic_m_us_per_step does not fuse the output rows.",
        "Ratios are judged on this thread's CPU time (time.thread_time), which leaves out the "
        "time other processes hold the core; wall-clock figures are beside them. "
        "ratios.iapid_over_floor is the median over rounds of the iapid-nn-dekf step over the "
        "median of the 3 floor timings taken right before it (each round: the floor, then the "
        "controllers, iapid-nn-dekf first).",
        "weight_update_us_per_step: the library's wmr.estimation.ekf.weight_update (Joseph form, "
        "O(n^2 m)) timed the same way, the part of the step that the floor stands for.",
        "python_control_us_per_step: the iapid-nn-dekf closed loop as a python-control "
        "discrete-time nlsys (wmr.linear.nlsys.closed_loop), whose update calls the phases of "
        "wmr.closedloop.step. "
        f"control.input_output_response steps it over the first {steps} steps of the "
        "lemniscate, with the noise and reference of simulate as inputs. "
        "max_abs_q_difference checks that both give the same trajectory. "
        "Its ratio to the kernel is information, not a target.",
        "python_control_overhead: an nlsys with the same state whose update only copies it, "
        "stepped the same way. It is python-control's own cost per step, which no kernel speed "
        "removes.",
        "Monte-Carlo: run_jobs on a Dask LocalCluster of worker processes started for each call, "
        "so vs_workers and monte_carlo_1000_s include its start and stop. That is why 2 workers "
        "can be slower than 1 on 100 runs. Rows are compared with the serial path field by field.",
        "peak_rss_children_mb is the largest child's high-water mark (the worker processes).",
        "Absolute wall times depend on other load on the shared machine (machine.load_average_*).",
        "sweep: wmr sweep over seeds of the lemniscate, one controller at a time, interleaved on "
        "three engines: serial, a LocalCluster of 2 worker processes and a loopback scheduler "
        "with 2 worker processes started as separate programs. Runs/s are over each sweep's run "
        "phase (engine up, kernels warm), the best of the repeats. Efficiency is parallel runs/s "
        "over 2 x serial runs/s; rows_equal checks the three stores hold the same rows.",
        f"plant: the same runs on the ideal plant and on a true robot with {plant} "
        "(wmr.robots.plant), "
        "interleaved. The ratio is the median of the paired CPU-time ratios.",
        "The loop is compiled once per controller (wmr.closedloop.step.kernel) and cached on disk; "
        "advance_cache counts this process's loads from the cache (hits) and compilations "
        "(misses).",
        *([_py_controller_bench.NOTE] if rec.get("python_controllers") else []),
        *(note for key, note in _NOTES_25.items() if key in rec),
    ]  # fmt: skip


#: Notes on what only newer records measure (shown when the record has it).
_NOTES_25 = {"phases": _phases.NOTE, "against": _against.NOTE, "mujoco": (
    "mujoco: analysis.performance.mujoco on the shipped MuJoCo lemniscate. The plant's cost is one "
    "fixed-PID run's commands replayed through MujocoRobot.advance and pose, every control step "
    "timed alone (wall clock). The run's cost is a whole fixed-PID run through the loop's "
    "Python driver per step. The sweep is measured as for the lemniscate above.")}


def _targets_table(rec: dict) -> list[str]:
    perf = _perf()
    r, t, m = rec["ratios"], rec["targets"], perf.targets_met(rec)

    def ok(key):
        return {True: "yes", False: "**no**", None: "—"}[m.get(key)]

    mc = rec["monte_carlo_1000_s"]
    return [
        "| target | measured | target | met |", "|---|---:|---:|:---:|",
        f"| iapid-nn-dekf step / floor | {r['iapid_over_floor']:.2f}x "
        f"| <= {t['floor_ratio_max']:g}x | {ok('floor_ratio')} |",
        "| python-control nlsys step / iapid-nn-dekf step (information) "
        f"| {r['python_control_over_iapid']:.1f}x | — | — |",
        f"| paper's 12 runs, one seed [s] | {rec['paper_runs_one_seed_s']:.3f} "
        f"| <= {t['paper_runs_one_seed_s_max']:g} | {ok('paper_runs_one_seed')} |",
        f"| 1,000 iapid-nn-dekf runs, {rec['workers']} workers [s] "
        f"| {'—' if mc is None else f'{mc:.2f}'} "
        f"| <= {t['monte_carlo_1000_s_max']:g} | {ok('monte_carlo_1000')} |",
        f"| parallel rows == serial rows | {rec['parallel_equals_serial']} | true "
        f"| {ok('parallel_equals_serial')} |",
        *(f"| sweep runs/s, {s['workers']} workers / ({s['workers']} x serial), {e}, worst "
          f"controller | {s[key]['efficiency']:.2f} | >= {t['sweep_efficiency_min']:g} "
          f"| {ok('sweep_' + key + '_efficiency')} |"
          for s in [rec.get("sweep")] if s
          for key, e in (("local", "local cluster"), ("dask", "loopback scheduler"))),
        *(f"| a sweep of {g['runs']:,} runs ({g['controller']}, {g['workers']} workers) "
          f"| {g['seconds']:.0f} s, {g['runs_per_s']:.0f} runs/s | >= "
          f"{t['large_sweep_runs_min']:,} runs complete | {ok('large_sweep')} |"
          for g in [rec.get("sweep", {}).get("large_sweep")] if g),
        *(f"| {name} step, plant with lag + delay + slip / ideal plant "
          f"| {rec['plant'][name]['ratio']:.2f}x | <= {t['plant_ratio_max']:g}x "
          f"| {ok('plant_overhead')} |" for name in ("backstepping", perf.SUBJECT)
          if "plant" in rec),
        *_targets_25(rec, ok),
        *(f"| nmpc's step, median [ms] | {v['step_ms']['median']:.3f} "
          f"| <= {t['nmpc_step_median_ms_max']:g} | {ok('nmpc_step_median')} |"
          for v in [(rec.get("python_controllers") or {}).get("nmpc")] if v),
        *_targets_mujoco(rec, ok),
        "",
    ]  # fmt: skip


def _targets_25(rec: dict, ok) -> list[str]:
    """The issue 25 rows of the targets table (records that have the phases only)."""
    if "phases" not in rec:
        return []
    r, t = rec["ratios"], rec["targets"]
    return [*(f"| {name} CPU µs per step (issue 25) | {rec['cpu_us_per_step'][name]:.3f} "
              f"| <= {limit:g} | {ok('us_per_step_' + name)} |"
              for name, limit in t["us_per_step_max"].items() if name in rec["cpu_us_per_step"]),
            f"| iapid-nn-dekf step / floor (issue 25) | {r['iapid_over_floor']:.2f}x "
            f"| <= {t['iapid_floor_ratio_max']:g}x | {ok('iapid_floor_ratio_25')} |",
            f"| set-up of one iapid-nn-dekf run [ms] | {rec['run_overhead_ms']:.3f} "
            f"| <= {t['run_overhead_ms_max']:g} | {ok('run_overhead_25')} |"]  # fmt: skip


def _targets_mujoco(rec: dict, ok) -> list[str]:
    """The issue 20 rows: the MuJoCo plant per control step and its 2-worker sweep."""
    mj, t = rec.get("mujoco"), rec["targets"]
    if not mj:
        return []
    p = mj["plant"][0]
    rows = [f"| MuJoCo plant per {1e3 * p['control_dt']:g} ms control step at "
            f"{1e3 * p['timestep']:g} ms physics step, median [µs] | {p['median_us']:.1f} "
            f"| <= {t['mujoco_plant_us_max']:g} | {ok('mujoco_plant')} |"]
    if mj.get("sweep"):
        rows.append(f"| MuJoCo sweep runs/s, 2 workers / (2 x serial), local cluster "
                    f"| {mj['sweep']['local']['efficiency']:.2f} "
                    f"| >= {t['mujoco_sweep_efficiency_min']:g} "
                    f"| {ok('mujoco_sweep_efficiency')} |")
    return rows


def _mujoco_table(rec: dict) -> list[str]:
    mj = rec.get("mujoco")
    if not mj:
        return []
    lines = ["| MuJoCo physics step [ms] | physics steps per control step | plant µs per control "
             "step: median | p10 | p90 | µs per physics step |",
             "|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for p in mj["plant"]:
        lines.append(f"| {1e3 * p['timestep']:g} | {p['substeps']} | {p['median_us']:.1f} "
                     f"| {p['p10_us']:.1f} | {p['p90_us']:.1f} "
                     f"| {p['median_us_per_physics_step']:.1f} |")
    r = mj["run"]
    lines += ["", f"A whole {r['controller']} run on the MuJoCo robot through the Python driver "
              f"costs {r['us_per_step']:.1f} µs per control step ({r['steps']:,} steps)."]
    s = mj.get("sweep")
    if s:
        c = s["controllers"]["pid"]
        lines.append(f"Its sweep of {c['runs']} runs: serial {c['serial_runs_per_s']:.2f} runs/s, "
                     f"local cluster {c['local_runs_per_s']:.2f} (efficiency "
                     f"{c['local_efficiency']:.2f}), loopback scheduler {c['dask_runs_per_s']:.2f} "
                     f"({c['dask_efficiency']:.2f}); rows equal: {c['rows_equal']}.")
    return lines + [""]


def table(rec: dict) -> str:
    """``tables/performance.md``: a title, the tables (:func:`tables`) and the notes."""
    notes_md = [f"- {note}" for note in notes(rec)]
    return "\n".join(["# Performance", "", tables(rec).rstrip(), "", *notes_md]) + "\n"


def tables(rec: dict) -> str:
    """The machine, targets, costs, python-control, sizes, workers and memory (the report's
    section puts the notes below them, so they are not repeated here)."""
    perf = _perf()
    mach = rec["machine"]
    lines = [
        f"Machine: {mach['cpu_model']}, {mach['usable_cpus']} usable CPUs; numba {mach['numba']}; "
        f"load average {mach['load_average_start'][0]:.2f}"
        f" -> {mach['load_average_end'][0]:.2f}; quick = {rec['quick']}.", "",
    ]  # fmt: skip
    lines += _targets_table(rec) + _costs_table(rec) + _py_controller_bench.table_lines(rec)
    lines += _mujoco_table(rec)
    if "phases" in rec:
        lines += ["CPU µs per step, phase by phase (each phase alone on a real run's inputs; "
                  "kernel = the whole run, set-up included; loop = kernel - sum):", "",
                  *_phases.table(rec["phases"])]  # fmt: skip
    if "run_overhead_ms_by_controller" in rec:
        lines += ["Set-up of one run (a one-step run), CPU ms: " + ", ".join(
            f"{k} {v:.3f}" for k, v in rec["run_overhead_ms_by_controller"].items()) + ".", ""]
    if "against" in rec:
        lines += _against.table(rec["against"])
    lines += _bench.python_control_table(rec, perf.SUBJECT)
    lines += ["| hidden | n | loop µs/step | weight_update µs | floor µs | loop/floor |",
              "|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for v in rec["vs_weights"]:
        lines.append(f"| {v['hidden']} | {v['n_weights']} | {v['us_per_step']:.2f} "
                     f"| {v['weight_update_us_per_step']:.2f} | {v['floor_us_per_step']:.2f} "
                     f"| {v['ratio']:.2f} |")  # fmt: skip
    lines += ["", "| workers | runs | seconds | runs/s | speed-up |", "|---:|---:|---:|---:|---:|"]
    for v in rec["vs_workers"]:
        lines.append(f"| {v['workers']} | {v['runs']} | {v['seconds']:.2f} | {v['runs_per_s']:.1f} "
                     f"| {v['speedup']:.2f} |")  # fmt: skip
    lines += ["", f"Peak RSS {rec['peak_rss_mb']:.0f} MB (before the python-control runs "
              f"{rec['peak_rss_mb_before_python_control']:.0f} MB; largest child "
              f"{rec['peak_rss_children_mb']:.0f} MB). A study row takes "
              f"{rec['rows_bytes_per_run']:.0f} B pickled; a kept trajectory "
              f"{rec['trajectory_mb_per_run']:.2f} MB per run.", ""]  # fmt: skip
    return "\n".join(lines) + "\n"


def _costs_table(rec: dict) -> list[str]:
    lines = ["| controller | µs/step (min) | µs/step (median) | CPU µs/step (min) | warm-up [s] |",
             "|---|---:|---:|---:|---:|"]  # fmt: skip
    for name, v in rec["us_per_step"].items():
        cpu, warm = rec["cpu_us_per_step"][name], rec["warmup_s"][name]
        med = rec["us_per_step_median"][name]
        lines.append(f"| {name} | {v:.2f} | {med:.2f} | {cpu:.2f} | {warm:.2f} |")
    return lines + [
        f"| floor (n = {rec['n_weights']}) | {rec['floor_us_per_step']:.2f} "
        f"| {rec['floor_us_per_step_median']:.2f} | {rec['floor_cpu_us_per_step']:.2f} | |",
        f"| floor, m-generic | {rec['floor_generic_m_us_per_step']:.2f} | | | |",
        f"| wmr.estimation.ekf.weight_update alone | {rec['weight_update_us_per_step']:.2f} | "
        f"| {rec['weight_update_cpu_us_per_step']:.2f} | |", "",
    ]  # fmt: skip
