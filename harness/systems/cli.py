"""System descriptions (scenarios/systems/*.toml) -> SSP packages, and a small command line.

A description names the components' FMUs (relative to the FMU folder, default dist/), their
start values, and the connections by "Component.variable":

    name = "plant_estimator"
    step_s = 0.1
    stop_s = 30.0
    connections = [["car.sensor.speed", "est.sensor.speed"], ...]

    [components.car]
    fmu = "native/RailCarNative.fmu"
    parameters = {"car.mass" = 36.0, seed = 11}

Command line (docs/systems.md):

    python -m harness.systems.cli build scenarios/systems/ato_span.toml out/ato_span.ssp
    python -m harness.systems.cli run out/ato_span.ssp [--master ours|libcosim] [--stop S] [--csv F]
        [--output Component.variable ...]

Exit codes: 0 done, 1 a failed run (MasterError), 2 invalid input (SspError and other InputError).
"""
from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

from harness.systems.ssp import Component, Connection, SspError, SystemSpec, write_ssp
from harness.textio import read_text

__all__ = ["load_system", "build_system", "main"]

ROOT = Path(__file__).resolve().parents[2]
DIST = ROOT / "dist"
KEYS = {"name", "description", "step_s", "start_s", "stop_s", "components", "connections"}


def load_system(path: str | Path, dist: str | Path = DIST) -> SystemSpec:
    """A SystemSpec from a TOML description; FMU paths relative to ``dist``. Errors name the file
    and the key (SspError)."""
    path = Path(path)
    try:
        data = tomllib.loads(read_text(path, SspError))
    except tomllib.TOMLDecodeError as e:
        raise SspError(f"{path}: not valid TOML: {e}") from None
    unknown = sorted(set(data) - KEYS)
    if unknown:
        raise SspError(f"{path}: unknown key(s) {', '.join(unknown)} (expected {', '.join(sorted(KEYS))})")
    for key in ("name", "step_s", "components"):
        if key not in data:
            raise SspError(f"{path}: '{key}' is missing")
    comps = data["components"]
    if not isinstance(comps, dict) or not comps:
        raise SspError(f"{path}: [components.NAME] tables expected")
    components = []
    for name, table in comps.items():
        where = f"{path}: [components.{name}]"
        if not isinstance(table, dict) or "fmu" not in table:
            raise SspError(f"{where}: 'fmu' is missing")
        extra = sorted(set(table) - {"fmu", "parameters"})
        if extra:
            raise SspError(f"{where}: unknown key(s) {', '.join(extra)} (expected fmu, parameters)")
        params = table.get("parameters", {})
        if not isinstance(params, dict):
            raise SspError(f"{where}: 'parameters' must be a table")
        fmu = Path(table["fmu"])
        components.append(Component(name, fmu if fmu.is_absolute() else Path(dist) / fmu, dict(params)))
    connections = []
    for k, pair in enumerate(data.get("connections", []), 1):
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(x, str) for x in pair)):
            raise SspError(f"{path}: connections[{k}]: expected [\"Component.output\", \"Component.input\"]")
        connections.append(Connection(*pair))
    numbers = {}
    for key in ("step_s", "start_s", "stop_s"):
        value = data.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise SspError(f"{path}: '{key}' must be a number of seconds")
        numbers[key] = value
    return SystemSpec(str(data["name"]), components, connections, numbers["step_s"],
                      numbers["start_s"] or 0.0, numbers["stop_s"], str(data.get("description", "")))


def build_system(description: str | Path, out: str | Path, dist: str | Path = DIST) -> Path:
    """Write the .ssp of a TOML description (checked against its FMUs)."""
    spec = load_system(description, dist)
    for c in spec.components:
        if not Path(c.fmu).is_file():
            raise SspError(f"{description}: [components.{c.name}]: FMU file not found: {c.fmu} (build the "
                           f"FMUs with: python build.py; --dist names another folder)")
    return write_ssp(spec, out)


def main(argv=None, prog: str = "python -m harness.systems.cli") -> int:
    from harness.systems.master import MasterError, report_failure, run_system
    p = argparse.ArgumentParser(prog=prog,
                                description="Build an SSP system from a description, or run one.")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="description (.toml) -> .ssp")
    b.add_argument("description")
    b.add_argument("out")
    b.add_argument("--dist", default=str(DIST), help="folder the FMU paths are relative to (default dist/)")
    r = sub.add_parser("run", help="run an .ssp and print the last values (or write them all: --csv)")
    r.add_argument("ssp")
    r.add_argument("--master", choices=("ours", "libcosim"), default="ours")
    r.add_argument("--stop", type=float, default=None, help="stop time [s] (default: the file's)")
    r.add_argument("--output", action="append", default=None, help="Component.variable (repeatable)")
    r.add_argument("--csv", default=None, help="write every time point here, units in the header")
    args = p.parse_args(argv)
    try:
        if args.command == "build":
            print(build_system(args.description, args.out, args.dist))
            return 0
        if args.master == "libcosim":                # in a child process: libcosim aborts its
            from harness.systems.libcosim import run_libcosim       # process when an FMU fails initialisation
            result = run_libcosim(args.ssp, stop_time=args.stop, outputs=args.output, isolated=True)
        else:
            result = run_system(args.ssp, stop_time=args.stop, outputs=args.output)
    except (SspError, MasterError) as e:
        return report_failure(e)
    except ImportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.csv:
        try:
            print(f"wrote {result.write_csv(args.csv)}")
        except OSError as e:
            print(f"error: --csv {args.csv}: cannot write: {e.strerror or e}", file=sys.stderr)
            return 2
    width = max(len(n) for n in result.signals) if result.signals else 0
    print(f"{result.master}: {len(result.time) - 1} steps to t = {float(result.time[-1])!r} s")
    for name, values in result.signals.items():
        print(f"  {name:<{width}}  {values[-1].item()!r} {result.units.get(name, '')}".rstrip())
    return 0


if __name__ == "__main__":
    sys.exit(main())
