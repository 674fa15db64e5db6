"""Command line of the validation harness.

    python -m harness run SCENARIO.toml [--out DIR] [--dist DIR] [--rebuild]
    python -m harness plan SCENARIO.toml --out PROFILE.csv

Exit codes: 0 success; 1 a run failed; 2 bad usage or an invalid scenario.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .scenario import ScenarioError, load_scenario

EXIT_OK, EXIT_RUN_FAILED, EXIT_USAGE = 0, 1, 2


def cmd_run(args) -> int:
    from .fmus import DIST, ensure_built
    from .metrics import format_summary, summarise
    from .report import write_report
    from .runner import FmuRunner, RunError

    scenario = load_scenario(args.scenario)
    dist = Path(args.dist) if args.dist else DIST
    fmus = ensure_built(dist, force=args.rebuild)
    print(f"running '{scenario.name}': {scenario.purpose}", flush=True)
    with FmuRunner(fmus["RailCar"]) as runner:
        try:
            result = runner.run(scenario)
        except RunError as e:
            print(f"error: {e}", file=sys.stderr)
            return EXIT_RUN_FAILED
    true_A = tuple(scenario.parameter(n) for n in ("car.A0", "car.A1", "car.A2"))
    summary = summarise(result, true_A)
    print(format_summary(summary))
    out = Path(args.out) if args.out else Path("out") / scenario.name
    files = write_report(result, summary, true_A, out)
    print(f"report: {files[1]} (with {', '.join(p.name for p in files[2:])}; data {files[0].name})")
    return EXIT_OK


def cmd_plan(args) -> int:
    from .plan import plan_speed_profile, profile_csv_text
    scenario = load_scenario(args.scenario)
    xs, vs = plan_speed_profile(scenario)
    Path(args.out).write_text(profile_csv_text(xs, vs), encoding="utf-8")
    print(f"wrote {args.out}: {len(xs)} points up to {xs[-1]:.1f} m")
    return EXIT_OK


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness", description="RailCar FMU validation harness")
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="build the FMUs if needed, run a scenario, print a summary, write a report")
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", help="report folder (default: out/<scenario name>)")
    p.add_argument("--dist", help="folder of the FMUs (default: dist/)")
    p.add_argument("--rebuild", action="store_true", help="rebuild the FMUs even if current")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("plan", help="write the nominal reference speed profile V_zad(X) of a scenario")
    p.add_argument("scenario")
    p.add_argument("--out", required=True, help="CSV file to write (distance_m,speed_mps)")
    p.set_defaults(func=cmd_plan)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except ScenarioError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
