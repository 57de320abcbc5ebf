"""Command line: ``wmr run | reproduce | report | analyze | bench`` (DESIGN §3.2).

Exit codes: 0 success; 2 bad input (one line ``error: ...`` on stderr naming the file, key and
value; nothing written); 1 an unexpected failure.  A diverged run is a result, not an error.
"""

from __future__ import annotations

import argparse
import os
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


def _controllers(requested: list[str] | None) -> list[str]:
    from wmr import controllers

    if not requested or "all" in requested:
        return list(controllers.NAMES)
    for name in requested:
        if name not in controllers.REGISTRY:
            raise UsageError(
                f"--controller {name!r}: unknown controller (known: all, {', '.join(controllers.NAMES)})"
            )
    return list(dict.fromkeys(requested))


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


def cmd_run(args) -> int:
    from wmr import scenario as scn
    from wmr import sim
    from wmr.io import save_figure, write_csv, write_json
    from wmr.plots import tracking_figure

    try:
        sc = scn.load(args.scenario)
    except scn.ScenarioError as err:
        raise UsageError(str(err)) from None
    names = _controllers(args.controller)
    seed = sc.seed if args.seed is None else args.seed
    out = Path(args.out) if args.out else Path("wmr-runs") / sc.name
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {str(out)!r}: exists and is not a directory")

    runs = [sim.simulate(sc, name, seed) for name in names]
    summary = {"scenario": sc.name, "seed": seed, "runs": [r.summary() for r in runs]}
    print(f"scenario {sc.name} (seed {seed}, {sc.n_steps} steps of {sc.dt} s)")
    print(_format_table(summary["runs"]))
    for r in runs:
        if r.diverged:
            print(f"note: {r.controller} diverged at t = {r.diverged_at:.2f} s: {r.cause}")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as err:  # e.g. a parent of --out is a file, or no permission: bad option
        raise UsageError(f"--out {str(out)!r}: cannot create the folder: {err.strerror}") from None
    write_json(out / "summary.json", summary)
    for r in runs:
        header = ["t", "x", "y", "theta", "x_r", "y_r", "theta_r", "v_r", "w_r",
                  "x_hat", "y_hat", "theta_hat", "v", "w", *r.state_names]  # fmt: skip
        n = len(r.u)
        rows = []
        for k in range(len(r.t)):
            per_step = (
                [*r.q_hat[k], *r.u[k], *r.state[k]]
                if k < n
                else [""] * (5 + len(r.state_names))
            )
            rows.append([float(r.t[k]), *map(float, r.q[k]), *map(float, r.ref[k]),
                         *[float(x) if x != "" else x for x in per_step]])  # fmt: skip
        write_csv(out / f"trajectory-{r.controller}.csv", header, rows)
    import matplotlib.pyplot as plt

    # a literal "$" in the name would start matplotlib mathtext (and "$\\frac$" fails to parse)
    title = f"{sc.name} (seed {seed})".replace("$", r"\$")
    fig = tracking_figure(runs, title=title)
    save_figure(fig, out / "tracking.png")
    plt.close(fig)
    print(f"wrote {out}/summary.json, trajectory-*.csv, tracking.png")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="wmr", description="Adaptive trajectory tracking of wheeled mobile robots.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    run = sub.add_parser("run", help="run a scenario file and write summary, trajectories, figure")
    run.add_argument("scenario", help="scenario TOML file")
    run.add_argument("--controller", nargs="+", action="extend", metavar="NAME",
                     help="controller name(s), or 'all' (default: all)")  # fmt: skip
    run.add_argument("--seed", type=_nonnegative_int, help="seed (default: the scenario's)")
    run.add_argument("--out", help="output folder (default: wmr-runs/<scenario name>)")
    run.set_defaults(func=cmd_run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``wmr`` command; returns the exit code."""
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except UsageError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # noqa: BLE001 - the contract: one line, exit 1
        print(f"error: unexpected failure: {type(err).__name__}: {err}", file=sys.stderr)
        if os.environ.get("WMR_DEBUG"):
            traceback.print_exc()
        return 1


if __name__ == "__main__":
    sys.exit(main())
