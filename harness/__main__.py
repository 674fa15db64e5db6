"""Command line of the validation harness.

    python -m harness run SCENARIO.toml [--out DIR] [--log LOG.csv] [--plots all|none] [--dist DIR] [--rebuild] [--fmu KIND]
    python -m harness span-info SCENARIO.toml    (per span: the fastest feasible run, the schedule's margin, its energy)
    python -m harness replay LOG.csv [--param NAME=VALUE ...] [--out DIR]    (LOG.params beside it: the run's parameters)
    python -m harness regress [--update] [--variants] [NAME ...]    (a NAME may be a pattern: 'ato_*')
    python -m harness report [--out DIR] [--engine fmu|batch|auto] [NAME ...]
    python -m harness filters [NAME ...]
    python -m harness sweep SWEEP.toml [--out DIR] [--scheduler tcp://HOST:PORT] [--workers N] [--resume | --overwrite] [--engine auto|batch|fmu] [--chunk N]
    python -m harness plan SCENARIO.toml --out PROFILE.csv
    python -m harness list

Every command that runs an FMU (run, replay, regress, report, filters, sweep) takes
``--fmu auto|native|python`` (harness.run.fmus): the native FMU (the C core, no Python, bit-identical
outputs), the pythonfmu FMU, or by default ``auto``: the native FMU when the C core covers the
parameters of everything the command runs, else the pythonfmu FMU. The choice is printed
("fmu: ...") and recorded (summary.md, library.md, the sweep's ``fmu`` column).

Exit codes: 0 success; 1 a run failed or a regression/target check failed; 2 bad usage or
invalid input (scenario, log, parameter, sweep file, output folder): one line on stderr naming
the file and the key or line (harness.textio.InputError and its subclasses), no traceback. The
scenario's FMU parameters are checked with the FMU's own rules before any FMU runs; should the
FMU still refuse to initialise with them, that is invalid input too (2); a run that fails after
initialisation is 1.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from harness.run.scenario import ScenarioError, load_scenario
from harness.textio import InputError, check_out_dir

EXIT_OK, EXIT_RUN_FAILED, EXIT_USAGE = 0, 1, 2


def _init_failed(where, e, hint: str = "") -> int:
    """The FMU refused to initialise with the parameters of ``where``: invalid input."""
    print(f"error: {where}: the FMU refused to initialise: {e.reason}{hint}", file=sys.stderr)
    return EXIT_USAGE


def _native_hint(choice, model: str, parameters: dict) -> str:
    """For a native FMU refusing an option the C core does not cover: how to run it anyway."""
    from harness.run.fmus import uncovered
    if choice.kind == "native" and uncovered(model, parameters):
        return " (--fmu auto or --fmu python runs it on the pythonfmu FMU)"
    return ""


def _check_log_path(path: str) -> None:
    """--log names a file to write; its folder is created (it may be the report's --out)."""
    p = Path(path)
    if p.is_dir():
        raise InputError(f"--log {p}: is a folder; give a CSV file name")
    existing = next(a for a in p.absolute().parents if a.exists())
    if not existing.is_dir():
        raise InputError(f"--log {p}: {existing} is not a folder")


def cmd_run(args) -> int:
    """One run, walked once: the scenario loaded and resolved (parameters checked by the FMU's
    rules, profiles read, the ATO built: harness.run.scenario), the FMU run once through the loop
    (the RunResult holds the outputs, the held inputs, the ATO's calls and log), every metric
    computed once (harness.metrics.run: the oracle filter is the one other model run), then
    printed and drawn (harness.reports.run_report)."""
    from harness.run.fmus import select
    from harness.metrics.run import run_metrics
    from harness.reports.run_report import format_run_summary, short_path, write_report
    from harness.run.runner import FmuRunner, InitError, RunError

    scenario = load_scenario(args.scenario)
    out = Path(args.out) if args.out else Path("out") / scenario.name
    check_out_dir(out)
    if args.log:
        _check_log_path(args.log)
    choice = select(args.fmu, "RailCar", args.dist, args.rebuild, [(str(args.scenario), scenario.parameters)])
    print(f"running '{scenario.name}': {scenario.purpose}", flush=True)
    print(choice.line(), flush=True)
    with FmuRunner(choice.path) as runner:
        try:
            result = runner.run(scenario)
        except InitError as e:
            return _init_failed(f"{args.scenario}: parameters", e,
                                _native_hint(choice, "RailCar", scenario.parameters))
        except RunError as e:
            print(f"error: {e}", file=sys.stderr)
            return EXIT_RUN_FAILED
    metrics = run_metrics(result)
    print(format_run_summary(metrics.summary, result))
    if metrics.ato is not None:
        from harness.metrics.ato import format_ato
        print("ATO, per span:")
        print(format_ato(metrics.ato))
        for line in metrics.driver_log:
            print(f"  log: {line}")
    if not metrics.A_covariance_full:
        print("  (resistance band from the A's stds alone: this FMU outputs no est.cov_*)")
    fmu = f"{choice.kind} {short_path(choice.path)} (--fmu {choice.asked}: {choice.why})"
    files = write_report(result, metrics, out, fmu=fmu, plots=args.plots)
    if args.log:
        from harness.run.replay import write_log
        Path(args.log).parent.mkdir(parents=True, exist_ok=True)
        print(f"log for replay: {write_log(Path(args.log), result)}")
    figures = f"with {', '.join(p.name for p in files[2:])}" if files[2:] else "no plots: --plots none"
    print(f"report: {files[1]} ({figures}; data {files[0].name})")
    return EXIT_OK


def _library(names: list[str]) -> list:
    from harness.run.regress import library_scenarios
    from fnmatch import fnmatchcase
    paths = library_scenarios()
    if names:
        known = {p.stem: p for p in paths}
        # a name may be a pattern ('ato_*': the span scenarios), matching one or more
        matched = {n: [k for k in known if fnmatchcase(k, n)] for n in names}
        unknown = [n for n, found in matched.items() if not found]
        if unknown:
            raise ScenarioError(f"unknown library scenario(s): {', '.join(unknown)} "
                                f"(known: {', '.join(sorted(known))})")
        paths = [known[k] for k in dict.fromkeys(k for n in names for k in matched[n])]
    return [load_scenario(p) for p in paths]


def _choose_each(scenarios, kind: str, dist, rebuild: bool) -> dict:
    """The FMU for each scenario (--fmu, harness.run.fmus.choose: auto decides per scenario), printed
    as one line per FMU used."""
    from harness.run.fmus import DIST, choose, ensure_built
    dist = Path(dist) if dist else DIST
    ensure_built(dist, force=rebuild, native=kind != "python")
    choices = {s.name: choose(kind, "RailCar", dist, [(str(s.path or s.name), s.parameters)]) for s in scenarios}
    groups: dict = {}
    for name, c in choices.items():
        groups.setdefault((c.kind, c.path), []).append((name, c))
    for (k, path), members in groups.items():
        whys = list(dict.fromkeys(c.why for _, c in members))
        which = (f"all {len(members)} scenarios" if len(members) == len(choices) and len(members) > 1
                 else ", ".join(n for n, _ in members))
        print(f"fmu: {k} {path} for {which} (--fmu {kind}: {'; '.join(whys)})", flush=True)
    return choices


def _run_all(scenarios, dist, rebuild=False, kind: str = "auto"):
    """Run scenarios, each on the FMU --fmu picks for it (each FMU extracted once); yields
    (scenario, result or RunError). A RunError carries ``fmu``, the kind that ran."""
    from harness.progress import Progress
    from harness.run.runner import FmuRunner, RunError
    choices = _choose_each(scenarios, kind, dist, rebuild)
    bar = Progress(len(scenarios), "scenarios")
    runners: dict = {}
    try:
        for s in scenarios:
            path = choices[s.name].path
            runner = runners.get(path) or runners.setdefault(path, FmuRunner(path))
            try:
                result = runner.run(s)
                bar.advance(s.name)
                yield s, result
            except RunError as e:
                e.fmu = runner.kind
                bar.advance(s.name, failed=True)
                yield s, e
    finally:
        for runner in runners.values():
            runner.close()


def _init_failures(results) -> int | None:
    """EXIT_USAGE (with a line per scenario) if the FMU refused a library scenario's parameters."""
    from harness.run.runner import InitError
    bad = [(s, r) for s, r in results if isinstance(r, InitError)]
    for s, r in bad:
        _init_failed(f"{s.path or s.name}: parameters", r)
    return EXIT_USAGE if bad else None


def cmd_regress(args) -> int:
    from harness.run.regress import VARIANT_REFERENCES, check_or_update, variant_runs
    if args.variants:                   # the models chain: no FMU to choose
        ok = check_or_update(variant_runs(args.names), args.update, VARIANT_REFERENCES)
        return EXIT_OK if ok else EXIT_RUN_FAILED
    results = []

    def runs():
        for s, result in _run_all(_library(args.names), args.dist, args.rebuild, args.fmu):
            results.append((s, result))
            yield s.name, result
    ok = check_or_update(runs(), args.update)
    return _init_failures(results) or (EXIT_OK if ok else EXIT_RUN_FAILED)


def _run_batch_each(scenarios):
    """Run scenarios one by one on the C batch engine (harness.run.batch.run_batch): yields
    (scenario, result or exception, engine). The engine is ENGINE_BATCH, or ENGINE_REFERENCE when
    run_batch ran it on run_on_chain, the Python reference. A step the chain rejects
    (StepRejected) is a failed run; another ValueError is a parameter the C core refuses."""
    from harness.progress import Progress
    from harness.reports.library_report import ENGINE_BATCH, ENGINE_REFERENCE
    from harness.run.batch import ENGINES, run_batch
    bar = Progress(len(scenarios), "scenarios")
    for s in scenarios:
        on_python = ENGINES["python"]
        try:
            result = run_batch([s])[0]
        except ValueError as e:
            bar.advance(s.name, failed=True)
            yield s, e, ENGINE_BATCH
            continue
        bar.advance(s.name)
        yield s, result, (ENGINE_REFERENCE if ENGINES["python"] > on_python else ENGINE_BATCH)


def cmd_report(args) -> int:
    """``--engine`` (harness.reports.library_report.choose_engines) picks what runs each scenario:
    the FMU (``--fmu`` picks which, _run_all) or the C batch engine (_run_batch_each); the rows
    are printed and written in the library's order, whichever ran them."""
    from harness.reports.library_report import (ENGINE_FMU, choose_engines, engine_choice_lines,
                                                engine_usage_error, format_table, library_rows, write_table)
    from models.chain import StepRejected
    problem = engine_usage_error(args.engine, args.fmu)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return EXIT_USAGE
    scenarios = _library(args.names)
    out = Path(args.out) if args.out else Path("out") / "library"
    check_out_dir(out)
    choices = choose_engines(scenarios, args.engine, args.fmu)
    for line in engine_choice_lines(choices):
        print(line, flush=True)
    on_fmu = [s for s in scenarios if choices[s.name].engine == ENGINE_FMU]
    done, engines, refused = {}, {}, []
    for s, result, engine in _run_batch_each([s for s in scenarios if choices[s.name].engine != ENGINE_FMU]):
        if isinstance(result, ValueError) and not isinstance(result, StepRejected):
            refused.append((s, result))
        done[s.name], engines[s.name] = result, engine
    if on_fmu:
        for s, result in _run_all(on_fmu, args.dist, args.rebuild, args.fmu or "auto"):
            done[s.name], engines[s.name] = result, ENGINE_FMU
    results = [(s, done[s.name]) for s in scenarios]
    rows = library_rows(results, engines)
    print(format_table(rows))
    path = write_table(rows, out)
    print(f"table: {path}")
    for s, e in refused:
        print(f"error: {s.path or s.name}: parameters: the C batch engine refused them: {e}", file=sys.stderr)
    return ((EXIT_USAGE if refused else None) or _init_failures(results)
            or (EXIT_OK if all(r.ok for r in rows) else EXIT_RUN_FAILED))


def cmd_replay(args) -> int:
    from harness.run.fmus import select
    from harness.reports.replay_report import replay_report
    from harness.run.replay import estimator_parameters, params_path, read_log, read_log_parameters, uniform_step
    from harness.run.runner import FmuRunner, InitError, RunError
    log = read_log(args.log)                     # LogError, ParamError: invalid input (exit 2)
    # a harness run's log has its estimator's parameters beside it; --param overrides them
    logged, forces = read_log_parameters(Path(args.log))
    params = estimator_parameters(logged + (args.param or []), dt=float(log.time[1] - log.time[0]))
    out = Path(args.out) if args.out else Path("out") / f"replay_{Path(args.log).stem}"
    check_out_dir(out)
    choice = select(args.fmu, "RailCarEstimator", args.dist, args.rebuild, [("--param", params)])
    print(choice.line(), flush=True)
    if logged:
        print(f"parameters: {params_path(Path(args.log)).name} ({len(logged)}), then --param", flush=True)
    with FmuRunner(choice.path) as runner:
        try:
            signals, _ = runner.replay(log, params, what=Path(args.log).name, step=uniform_step(log.time))
        except InitError as e:
            return _init_failed("--param", e, _native_hint(choice, "RailCarEstimator", params))
        except RunError as e:
            print(f"error: {e}", file=sys.stderr)
            return EXIT_RUN_FAILED
    print(replay_report(log, signals, out, fmu=f"{choice.kind} ({choice.path.name})", forces=forces))
    return EXIT_OK


def cmd_filters(args) -> int:
    from harness.run.fmus import select
    from harness.metrics.filter_compare import KINDS, compare_filters, format_rows
    from harness.progress import Progress
    from harness.run.runner import FmuRunner
    scenarios = _library(args.names)
    choice = select(args.fmu, "RailCar", args.dist, args.rebuild,
                    [(f"{s.name} with filter.kind = {k}", {**s.parameters, "filter.kind": k})
                     for s in scenarios for k in KINDS])
    print(choice.line(), flush=True)
    with FmuRunner(choice.path) as runner:
        rows = compare_filters(scenarios, runner, Progress(len(scenarios) * len(KINDS), "filters"))
    print(format_rows(rows))
    return EXIT_OK


def cmd_plan(args) -> int:
    from harness.run.plan import plan_speed_profile, profile_csv_text
    scenario = load_scenario(args.scenario)
    if Path(args.out).is_dir():
        raise InputError(f"--out {args.out}: is a folder; give a CSV file name")
    xs, vs = plan_speed_profile(scenario)
    Path(args.out).write_text(profile_csv_text(xs, vs), encoding="utf-8")
    print(f"wrote {args.out}: {len(xs)} points up to {xs[-1]:.1f} m")
    return EXIT_OK


def cmd_span_info(args) -> int:
    """Per span of a span scenario, before any run: the fastest run the ATO's planner makes for the
    configured car, the schedule's margin over it and the energies (harness.metrics.ato.span_info).
    A schedule the ATO refuses is shown with the reason, and the exit code is 1."""
    from harness.metrics.ato import format_span_info, span_info
    scenario = load_scenario(args.scenario, check_ato=False)
    setup = scenario.ato_setup()
    if setup is None:
        raise InputError(f"{args.scenario}: not a span scenario (no [span] or [[span]]): nothing for the ATO to plan")
    car = setup.car
    given = f"; [ato.car] gives {', '.join(setup.car_given)}" if setup.car_given else ""
    print(f"'{scenario.name}': the ATO configured for a car of {car.mass:g} t, A0 {car.A0:g} N/kN, "
          f"{car.traction_force_max / 1e3:g} kN / {car.traction_power_max / 1e3:g} kW{given}; "
          f"planning limits V_lim - {setup.tuning.limit_margin:g} m/s")
    infos = span_info(setup)
    print(format_span_info(infos))
    return EXIT_RUN_FAILED if any(i.problem for i in infos) else EXIT_OK


def cmd_list(args) -> int:
    """The scenarios (default and library), the sweep and the system files, one line each: name and purpose."""
    import tomllib
    from harness.run.regress import library_scenarios
    root = Path(__file__).resolve().parent.parent / "scenarios"
    print("scenarios (python -m harness run scenarios/...; library: regress, report)")
    for path in [root / "default.toml", *library_scenarios()]:
        s = load_scenario(path)
        print(f"  {path.relative_to(root).as_posix():40s} {s.purpose}")
    print("sweeps (python -m harness sweep scenarios/sweeps/NAME.toml [--out DIR])")
    for path in sorted((root / "sweeps").glob("*.toml")):
        with path.open("rb") as f:
            purpose = tomllib.load(f).get("purpose", "")
        print(f"  {path.relative_to(root).as_posix():40s} {purpose}")
    print("systems (python -m harness system build scenarios/systems/NAME.toml OUT.ssp; then run OUT.ssp)")
    for path in sorted((root / "systems").glob("*.toml")):
        with path.open("rb") as f:
            purpose = tomllib.load(f).get("description", "")
        print(f"  {path.relative_to(root).as_posix():40s} {purpose}")
    return EXIT_OK


def cmd_sweep(args) -> int:
    from harness.sweep.main import cli_sweep
    return cli_sweep(args)


def _fmu_options(p) -> None:
    from harness.run.fmus import DEFAULT_KIND, KINDS
    p.add_argument("--dist", metavar="DIR", help="folder of RailCar.fmu and RailCarEstimator.fmu and their native "
                   "twins in DIR/native (default: dist/); they are built there when missing or built from other "
                   "sources")
    p.add_argument("--fmu", choices=KINDS, default=DEFAULT_KIND,
                   help="which FMU runs: native (the C core, no Python), python (pythonfmu, every option), or "
                        "auto (default): native when the C core covers the parameters (est.method 0 or 2, "
                        "any est.physical and est.sigma2_method), else python; the choice is printed and recorded")
    p.add_argument("--rebuild", action="store_true", help="rebuild the FMUs into --dist even if they are current")


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["system"]:          # harness.systems.cli parses its own arguments (and -h)
        from harness.systems.cli import main as system_main
        return system_main(argv[1:], prog="python -m harness system")
    ap = argparse.ArgumentParser(prog="python -m harness", description="RailCar FMU validation harness")
    sub = ap.add_subparsers(dest="command", required=True)
    p = sub.add_parser("run", help="build the FMUs if needed, run a scenario, print a summary, write a report")
    p.add_argument("scenario", help="scenario TOML file")
    p.add_argument("--out", help="report folder (default: out/<scenario name>)")
    _fmu_options(p)
    p.add_argument("--log", help="also write the run's measurements as a replayable log CSV")
    p.add_argument("--plots", choices=("all", "none"), default="all",
                   help="all (default): draw the report's PNGs; none: the result CSV and summary.md alone "
                        "(the figures take most of a span run's time)")
    p.set_defaults(func=cmd_run)
    p = sub.add_parser("replay", help="run RailCarEstimator on a logged CSV (time, forces, measured speed and distance)")
    p.add_argument("log", help="log CSV, header 'time [s],traction_force [N],brake_force [N],sensor.speed [m/s],sensor.position [m]'")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="RailCarEstimator parameter, e.g. track.grade_profile=grade.csv (repeatable)")
    p.add_argument("--out", help="folder for the estimates (default: out/replay_<log>)")
    _fmu_options(p)
    p.set_defaults(func=cmd_replay)
    p = sub.add_parser("regress", help="run the library scenarios and compare with tests/regression references")
    from harness.run.regress import add_arguments as regress_arguments
    regress_arguments(p)                # names, --update, --variants (harness.run.regress)
    _fmu_options(p)
    p.set_defaults(func=cmd_regress)
    p = sub.add_parser("report", help="run the library scenarios and print and write one table of metrics")
    p.add_argument("names", nargs="*", help="library scenario names or patterns such as 'ato_*' (default: all)")
    p.add_argument("--out", help="folder of the table (default: out/library)")
    from harness.reports.library_report import DEFAULT_ENGINE, ENGINES as REPORT_ENGINES
    p.add_argument("--engine", choices=REPORT_ENGINES, default=DEFAULT_ENGINE,
                   help="fmu (default): every scenario through the FMU (--fmu picks which), since the report "
                        "validates the FMUs users load; batch: whole runs in the C core, no FMU (the same table, "
                        "bit-identical runs, in seconds), an error for a scenario the C core does not cover; "
                        "auto: batch where the C core covers the scenario, else the FMU (any --fmu: the FMU "
                        "for all). --engine batch with --fmu is refused: the batch engine runs no FMU")
    _fmu_options(p)
    p.set_defaults(func=cmd_report, fmu=None)     # None: no --fmu given (--engine auto may take the batch engine)
    p = sub.add_parser("filters", help="each filter.kind on the library scenarios: speed/distance RMSE and NEES")
    p.add_argument("names", nargs="*", help="library scenario names or patterns such as 'ato_*' (default: all)")
    _fmu_options(p)
    p.set_defaults(func=cmd_filters)
    sub.add_parser("system", help="build an SSP system (RailCar + AtoController, ...) from scenarios/systems/NAME.toml or a span scenario, "
                   "or run an .ssp in our master, libcosim or ecos and compare them (python -m harness system -h)")
    p = sub.add_parser("list", help="the scenarios, sweeps and systems that come with the harness, one line each")
    p.set_defaults(func=cmd_list)
    p = sub.add_parser("plan", help="write the nominal reference speed profile V_zad(X) of a scenario")
    p.add_argument("scenario", help="scenario TOML file (its phases and RailCar parameters)")
    p.add_argument("--out", required=True, help="CSV file to write (distance_m,speed_mps)")
    p.set_defaults(func=cmd_plan)
    p = sub.add_parser("span-info", help="per span of a span scenario: the fastest run the ATO plans, the "
                       "schedule's margin over it, the energy of the minimum-time run (no FMU runs)")
    p.add_argument("scenario", help="span scenario TOML file ([span] or [[span]])")
    p.set_defaults(func=cmd_span_info)
    p = sub.add_parser("sweep", help="run a parameter sweep (TOML) on dask worker processes: results.csv, summary, plots")
    p.add_argument("sweep", help="sweep TOML file (base scenario + grid / zip / lhs / seeds)")
    p.add_argument("--out", help="results folder (default: out/sweeps/<sweep name>)")
    p.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run on this dask scheduler's workers "
                   "(default: an embedded local cluster, one single-threaded worker process per core)")
    p.add_argument("--workers", type=int, help="worker processes of the embedded cluster (default: cores)")
    p.add_argument("--resume", action="store_true", help="skip the runs already in OUT/results.csv")
    p.add_argument("--overwrite", action="store_true", help="discard the results already in OUT and start again "
                   "(without --resume or --overwrite, a folder that holds results is refused)")
    p.add_argument("--limit", type=int, metavar="K", help="run only the first K runs not done yet")
    p.add_argument("--no-plots", action="store_true", help="write no plots")
    p.add_argument("--engine", choices=("auto", "batch", "fmu"), default="auto",
                   help="batch: whole runs in the C core, many per dask task (rows bit-identical to the FMU's); "
                        "fmu: a run a task through the RailCar FMU (--fmu), to validate the FMU itself; auto "
                        "(default): batch when the C core covers every run and no --fmu is given, else fmu")
    p.add_argument("--chunk", type=int, metavar="N", help="runs per dask task of the batch engine (default: about "
                   "four tasks per worker, at most 100)")
    _fmu_options(p)
    p.set_defaults(func=cmd_sweep, fmu=None)     # None: no --fmu given (--engine auto may take the batch engine)
    args = ap.parse_args(argv)
    from harness.run.fmus import BuildError
    try:
        return args.func(args)
    except InputError as e:                  # ScenarioError, SweepError, LogError, ParamError, ...
        print(f"error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except BuildError as e:
        print(f"error: {e}", file=sys.stderr)
        return EXIT_RUN_FAILED


if __name__ == "__main__":
    code = main()
    # Every result is written and every file closed by now. Skip the interpreter's teardown:
    # with pythonfmu FMUs loaded in-process it sometimes aborts in native finalisers
    # ("corrupted double-linked list", exit 134, seen in 2 of 3 `regress --update` runs here
    # with pythonfmu 0.7.0 / fmpy 0.3.32), which would turn a finished run into a failure.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code or 0)
