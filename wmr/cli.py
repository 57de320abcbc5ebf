"""Command line: ``wmr run | reproduce | report | analyze | bench | sweep | settings | cache |
identify`` (DESIGN §3.2, §3.5, §3.8).

Exit codes: 0 success; 2 bad input (one line ``error: ...`` on stderr naming the file, key and
value; nothing written); 1 an unexpected failure.  A diverged run is a result, not an error.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import traceback
from pathlib import Path

__all__ = ["main", "UsageError"]


class UsageError(Exception):
    """Bad input from the user: reported as one line, exit code 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(message)


def _nonnegative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid integer value: {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _positive_int(text: str) -> int:
    value = _nonnegative_int(text)
    if value == 0:
        raise argparse.ArgumentTypeError("must be >= 1, got 0")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid number: {text!r}") from None
    if not (value > 0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _controllers(requested: list[str] | None) -> list[str]:
    from wmr import controllers

    if not requested or "all" in requested:
        return list(controllers.NAMES)
    for name in requested:
        if name not in controllers.REGISTRY:
            raise UsageError(
                f"--controller {name!r}: unknown controller "
                f"(known: all, {', '.join(controllers.NAMES)})"
            )
    return list(dict.fromkeys(requested))


def _plugins(args, entry_points: bool = True) -> None:
    """Load the ``--plugin`` modules (and, unless told otherwise, the installed entry points of
    ``wmr.plugins.GROUP``) before anything reads the registry; a bad plugin is exit 2."""
    from wmr import plugins

    try:
        if entry_points:
            plugins.load_entry_points()
        plugins.load_all(getattr(args, "plugin", None) or ())
    except plugins.PluginError as err:
        raise UsageError(str(err)) from None


def _format_table(rows: list[dict]) -> str:
    head = f"{'controller':<16}{'rmse x':>10}{'rmse y':>10}{'rmse θ':>10}{'position':>10}  status"
    lines = [head, "-" * len(head)]
    for r in rows:
        cells = "".join(
            f"{'—':>10}" if v is None else f"{v:>10.4f}"
            for v in (r["rmse"][k] for k in ("x", "y", "theta", "position"))
        )
        status = f"diverged at {r['diverged_at']:.2f} s" if r["diverged"] else "ok"
        lines.append(f"{r['controller']:<16}{cells}  {status}")
    return "\n".join(lines)


#: Longest run whose trajectories (CSV, figure) ``wmr run`` keeps; longer ones: summary only.
MAX_TRAJECTORY_STEPS = 1_000_000


def cmd_run(args) -> int:
    import tempfile

    from wmr import scenario as scn
    from wmr.closedloop import sim
    from wmr.io import save_figure, write_json
    from wmr.plots import tracking_figure

    _plugins(args)
    try:
        sc = scn.load(args.scenario)
    except scn.ScenarioError as err:
        raise UsageError(str(err)) from None
    names = _controllers(args.controller)
    seed = sc.seed if args.seed is None else args.seed
    out = Path(args.out) if args.out else Path("wmr-runs") / sc.name
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {str(out)!r}: exists and is not a directory")

    keep = sc.n_steps <= MAX_TRAJECTORY_STEPS
    plant = "" if sc.plant.ideal else f"; {sc.plant.describe()}"
    print(f"scenario {sc.name} (seed {seed}, {sc.n_steps} steps of {sc.dt} s{plant})", flush=True)
    with tempfile.TemporaryDirectory(prefix="wmr-run-") as tmp:
        # One controller at a time: its trajectory goes to a CSV (streamed) and only a
        # decimated copy stays for the figure, so memory does not grow with the run length.
        runs = []
        for name in names:
            r = sim.simulate(sc, name, seed, keep_trajectory=keep)
            if keep:
                r.to_csv(Path(tmp) / f"trajectory-{r.controller}.csv")
                r = _for_figure(r)
            runs.append(r)
        summary = {"scenario": sc.name, "seed": seed, "plant": sc.plant.to_json(),
                   "runs": [r.summary() for r in runs]}  # fmt: skip
        print(_format_table(summary["runs"]))
        for r in runs:
            if r.diverged:
                print(f"note: {r.controller} diverged at t = {r.diverged_at:.2f} s: {r.cause}")
        fig = None
        if keep:  # render before writing into --out, so a plotting failure leaves nothing there
            # a literal "$" in the name would start matplotlib mathtext ("$\\frac$" fails)
            title = f"{sc.name} (seed {seed})" + (f"\n{sc.plant.describe()}" if plant else "")
            fig = tracking_figure(runs, title=title.replace("$", r"\$"))
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as err:  # e.g. a parent of --out is a file, or no permission: bad option
            raise UsageError(f"--out {str(out)!r}: cannot create the folder: {err.strerror}"
                             ) from None  # fmt: skip
        write_json(out / "summary.json", summary)
        if not keep:
            print(f"note: {sc.n_steps} steps > {MAX_TRAJECTORY_STEPS}: trajectories and figure "
                  f"not kept; wrote {out}/summary.json")  # fmt: skip
            return 0
        for path in sorted(Path(tmp).glob("trajectory-*.csv")):
            shutil.move(str(path), out / path.name)
    save_figure(fig, out / "tracking.png")
    import matplotlib.pyplot as plt

    plt.close(fig)
    print(f"wrote {out}/summary.json, trajectory-*.csv, tracking.png")
    return 0


def _for_figure(r):
    """``r`` with only what the figure draws, decimated to ``wmr.plots.MAX_POINTS`` samples."""
    import dataclasses

    from wmr.plots import MAX_POINTS

    every = max(1, -(-len(r.t) // MAX_POINTS))
    # copies, not views: a view would keep the whole trajectory alive
    return dataclasses.replace(r, t=r.t[::every].copy(), q=r.q[::every].copy(),
                               ref=r.ref[::every].copy(), q_hat=None, u=None, state=None,
                               final=None)  # fmt: skip


def _checkout() -> Path | None:
    """The wmr repository checkout this ``wmr`` belongs to (its ``analysis/`` beside ``wmr/``):
    the package's own folder's parent (an editable install), else the working folder or one of
    its parents."""
    import wmr

    here = Path(wmr.__file__).resolve().parent.parent
    for root in (here, *(p for p in (Path.cwd(), *Path.cwd().parents))):
        if (root / "analysis" / "__init__.py").is_file() and (root / "wmr").is_dir():
            return root
    return None


def _studies():
    """The study registry of ``analysis/`` (the CLI is the one place where wmr reaches into it).

    The studies are the repository's, not part of the installed package (a top-level package
    named ``analysis`` would clash with any other project's): they are found in the checkout
    (:func:`_checkout`); outside one this is exit 2 with one line."""
    root = _checkout()
    if root is None:
        raise UsageError("the studies (analysis/) live in the wmr repository: run this command "
                         "from a checkout of it (git clone, then make reproduce)")  # fmt: skip
    if str(root) not in sys.path:
        sys.path.insert(0, str(root))
    import analysis

    found = Path(analysis.__file__).resolve().parent
    if found != root / "analysis":
        raise UsageError(f"another package named 'analysis' ({found}) shadows the studies of "
                         f"{root}")  # fmt: skip
    return analysis


def _staged(out: Path):
    """A staging folder inside ``out``: studies write there; :func:`_publish` moves the files in.

    An interrupted run leaves the previous results in ``out`` intact (the staging folder is
    removed at the next start).
    """
    import shutil

    stage = out / ".staging"
    if stage.exists():
        shutil.rmtree(stage)
    stage.mkdir(parents=True)
    return stage


def _publish(stage: Path, out: Path) -> int:
    """Move every file of ``stage`` to the same place in ``out`` (each by an atomic rename)."""
    import shutil

    count = 0
    for path in sorted(p for p in stage.rglob("*") if p.is_file()):
        target = out / path.relative_to(stage)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(path, target)
        count += 1
    shutil.rmtree(stage)
    return count


def _check_out(out: Path) -> None:
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {str(out)!r}: exists and is not a directory")


def cmd_reproduce(args) -> int:
    _plugins(args, entry_points=False)  # the built-in controllers only, unless --plugin
    out = Path(args.out)
    _check_out(out)
    registry = _studies()
    names = [n for n in registry.STUDIES
             if (n == "reproduction" or not args.skip_analyses)
             and (n != "performance" or not args.skip_bench)]  # fmt: skip
    stage = _staged(out)
    from analysis.common import run_and_check

    for name in names:
        study = registry.get(name)
        print(f"{name}: {study.TITLE}", flush=True)
        options = {"seeds": args.seeds} if name == "reproduction" else {}
        run_and_check(study, stage, workers=args.workers, **options)
    n = _publish(stage, out)
    path = _report(out, html=True)
    print(f"wrote {n} files, {path} and {path.with_suffix('.html')}")
    return 0


def _report(out: Path, html: bool = False) -> Path:
    from analysis import report

    return report.main(out, html=html)


def cmd_report(args) -> int:
    out = Path(args.out)
    if not (out / "results").is_dir():
        raise UsageError(f"--out {str(out)!r}: no results/ folder to build the report from")
    _studies()
    path = _report(out, html=args.html)
    print(f"wrote {path}" + (f" and {path.with_suffix('.html')}" if args.html else ""))
    return 0


def cmd_analyze(args) -> int:
    _plugins(args)
    out = Path(args.out)
    _check_out(out)
    registry = _studies()
    if args.study not in registry.STUDIES:
        raise UsageError(f"unknown study {args.study!r} (known: {', '.join(registry.STUDIES)})")
    from analysis.common import run_and_check

    try:
        run_and_check(registry.get(args.study), out, quick=args.quick, workers=args.workers)
    except AssertionError as err:  # the results are written; a headline claim does not hold
        print(f"error: {args.study}: a check of its headline claims failed: {err}",
              file=sys.stderr)  # fmt: skip
        return 1
    print(f"wrote the {args.study} results into {out}")
    return 0


def cmd_bench(args) -> int:
    out = Path(args.out)
    _check_out(out)
    perf = _studies().get("performance")
    res = perf.run(out, quick=args.quick, workers=args.workers, against=args.against)
    print(f"wrote {out}/results/performance.json, {out}/tables/performance.md")
    missed = [k for k, ok in res["targets_met"].items() if ok is False]
    print("targets met: " + ", ".join(k for k, ok in res["targets_met"].items() if ok))
    if missed:  # a missed target is a measurement, not a failure of the command
        print("targets not met: " + ", ".join(missed))
    return 0


def cmd_sweep(args) -> int:
    from wmr.engine import sweep

    _plugins(args)
    try:
        spec = sweep.load_spec(args.spec)
        sweep.check_out(Path(args.out), spec)
        print(f"sweep {spec.name}: {spec.n_jobs} runs ({len(spec.points)} design points x "
              f"{len(spec.scenarios)} scenarios x {len(spec.controllers)} controllers x "
              f"{len(spec.seeds)} seeds) into {args.out}", flush=True)  # fmt: skip
        manifest = sweep.run_sweep(spec, args.out, workers=args.workers,
                                   scheduler=args.scheduler, batch_seconds=args.batch_seconds,
                                   flush_seconds=args.flush_seconds,
                                   retry_errors=args.retry_errors)  # fmt: skip
    except sweep.SweepError as err:
        raise UsageError(str(err)) from None
    rate = manifest["runs_per_s"]
    print(f"done: {manifest['done']}/{manifest['jobs']} runs in the store "
          f"({manifest['runs_this_time']} this time{f', {rate:.1f} runs/s' if rate else ''}; "
          f"{manifest['engine']}); wrote {args.out}/summary.md")  # fmt: skip
    return 0


def cmd_settings(args) -> int:
    from wmr.io import atomic_write_text
    from wmr.settings_reference import markdown

    text = markdown()
    if args.out is None:
        print(text, end="")
    else:
        atomic_write_text(args.out, text)
        print(f"wrote {args.out}")
    return 0


def cmd_identify(args) -> int:
    from wmr.estimation import identify
    from wmr.io import atomic_write_text

    if args.out is not None and Path(args.out).is_dir():
        raise UsageError(f"--out {args.out!r}: is a directory")
    options = {k: v for k, v in (("max_delay", args.max_delay), ("segment", args.segment))
               if v is not None}  # fmt: skip
    try:
        found = identify.identify(identify.read_log(args.log), **options)
    except identify.LogError as err:
        raise UsageError(str(err)) from None
    print(identify.report(found))
    text = identify.to_toml(found)
    if args.out is None:
        print(text, end="")
    else:
        atomic_write_text(args.out, text)
        print(f"wrote {args.out}")
    return 0


def _plugin_option(parser) -> None:
    parser.add_argument("--plugin", action="append", metavar="PATH_OR_MODULE", default=[],
                        help="load the controllers of a plugin (a .py file or a module with "
                             "CONTROLLERS; repeatable; DESIGN §3.8)")  # fmt: skip


def cmd_cache(args) -> int:
    from wmr import _jit

    print(f"wmr's compiled kernels: {_jit.CACHE_DIR}")
    if args.prune:
        removed = _jit.prune_old_caches()
        print(f"removed {len(removed)} folder(s) of earlier versions of the source")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="wmr",
                     description="Adaptive trajectory tracking of wheeled mobile robots.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    run = sub.add_parser("run", help="run a scenario file and write summary, trajectories, figure")
    run.add_argument("scenario", help="scenario TOML file")
    run.add_argument("--controller", nargs="+", action="extend", metavar="NAME",
                     help="controller name(s), or 'all' (default: all)")  # fmt: skip
    run.add_argument("--seed", type=_nonnegative_int, help="seed (default: the scenario's)")
    run.add_argument("--out", help="output folder (default: wmr-runs/<scenario name>)")
    _plugin_option(run)
    run.set_defaults(func=cmd_run)

    rep = sub.add_parser("reproduce", help="the paper's scenarios x controllers x seeds, the "
                         "analyses, the benchmark and the report, into --out")  # fmt: skip
    rep.add_argument("--seeds", type=_positive_int, default=20, help="seeds per run (default 20)")
    rep.add_argument("--out", default="paper", help="output folder (default: paper)")
    rep.add_argument("--workers", type=_positive_int, default=None,
                     help="worker processes (default: all cores)")  # fmt: skip
    rep.add_argument("--skip-analyses", action="store_true", help="only the reproduction runs")
    rep.add_argument("--skip-bench", action="store_true", help="do not run the benchmark")
    _plugin_option(rep)
    rep.set_defaults(func=cmd_reproduce)

    report = sub.add_parser("report", help="rebuild report.md from the stored results")
    report.add_argument("--out", default="paper", help="folder with results/ (default: paper)")
    report.add_argument("--html", action="store_true",
                        help="also write report.html: one self-contained page, figures "
                             "embedded")  # fmt: skip
    report.set_defaults(func=cmd_report)

    ana = sub.add_parser("analyze", help="run one study of analysis/ (and check it)")
    ana.add_argument("study", help="study name (analysis.STUDIES)")
    ana.add_argument("--out", default="paper", help="output folder (default: paper)")
    ana.add_argument("--quick", action="store_true", help="a short version of the study")
    ana.add_argument("--workers", type=_positive_int, default=None,
                     help="worker processes (default: all cores)")  # fmt: skip
    _plugin_option(ana)
    ana.set_defaults(func=cmd_analyze)

    sw = sub.add_parser("sweep", help="run (or resume) a sweep spec into a Parquet store")
    sw.add_argument("spec", help="sweep spec TOML file (DESIGN §3.5)")
    sw.add_argument("--out", required=True, help="the store's folder (resumed if it holds one)")
    sw.add_argument("--workers", type=_positive_int, default=None,
                    help="local worker processes (default: all cores; 1: serial here)")
    sw.add_argument("--scheduler", default=None,
                    help="address of an existing Dask scheduler, e.g. tcp://host:8786")
    sw.add_argument("--batch-seconds", type=_positive_float, default=2.0,
                    help="work per task, in seconds (default 2)")
    sw.add_argument("--flush-seconds", type=_positive_float, default=30.0,
                    help="write completed rows at least this often (default 30)")
    sw.add_argument("--retry-errors", action="store_true",
                    help="run again the jobs whose stored row is an error (the new rows "
                         "supersede them)")  # fmt: skip
    _plugin_option(sw)
    sw.set_defaults(func=cmd_sweep)

    ref = sub.add_parser("settings", help="print the settings reference (every scenario key)")
    ref.add_argument("--out", default=None, help="write it to this file (docs/settings.md)")
    ref.set_defaults(func=cmd_settings)

    bench = sub.add_parser("bench", help="the side-by-side performance benchmark")
    bench.add_argument("--quick", action="store_true", help="a short benchmark (< 2 minutes)")
    bench.add_argument("--out", default="paper", help="output folder (default: paper)")
    bench.add_argument("--workers", type=_positive_int, default=None)
    bench.add_argument("--against", default=None, metavar="REF",
                       help="also time a git worktree of commit REF against this tree, pair by "
                            "pair (per-run and set-up cost of each controller)")  # fmt: skip
    bench.set_defaults(func=cmd_bench)

    idf = sub.add_parser("identify", help="fit the [plant] of DESIGN §3.3 to a robot's log "
                         "(commands and measured poses; wmr run's trajectory CSV)")  # fmt: skip
    idf.add_argument("log", help="CSV with t, v, w, x_meas, y_meas, theta_meas (dv, dw optional)")
    idf.add_argument("--out", default=None, help="write the [plant] table here (default: print)")
    idf.add_argument("--max-delay", type=_nonnegative_int, default=None,
                     help="largest delay searched, in steps (default 10)")  # fmt: skip
    idf.add_argument("--segment", type=_positive_float, default=None,
                     help="multiple-shooting segment length [s] (default 10)")  # fmt: skip
    idf.set_defaults(func=cmd_identify)

    cache = sub.add_parser("cache", help="where wmr's compiled kernels are cached (--prune: "
                           "remove those of earlier versions of the source)")  # fmt: skip
    cache.add_argument("--prune", action="store_true",
                       help="keep only the newest caches of earlier versions")  # fmt: skip
    cache.set_defaults(func=cmd_cache)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``wmr`` command; returns the exit code."""
    import matplotlib

    from wmr.engine.faults import RetriesExhausted

    matplotlib.use("Agg")  # the command line writes figures to files; no display is needed
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except UsageError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except RetriesExhausted as err:  # a transient failure that persisted: what finished is kept
        print(f"error: {err}", file=sys.stderr)
        return 1
    except Exception as err:  # noqa: BLE001 - the contract: one line, exit 1
        print(f"error: unexpected failure: {type(err).__name__}: {err}", file=sys.stderr)
        if os.environ.get("WMR_DEBUG"):
            traceback.print_exc()
        return 1


if __name__ == "__main__":
    sys.exit(main())
