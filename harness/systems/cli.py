"""System descriptions (scenarios/systems/*.toml) and span scenarios -> SSP packages, and the
command ``python -m harness system`` (harness/__main__.py hands its arguments to ``main`` here).

A description names the components' FMUs (relative to the FMU folder, default dist/), their
start values, and the connections by "Component.variable":

    name = "plant_estimator"
    step_s = 0.1
    stop_s = 30.0
    connections = [["car.sensor.speed", "est.sensor.speed"], ...]

    [components.car]
    fmu = "native/RailCarNative.fmu"
    parameters = {"car.mass" = 36.0, seed = 11, "track.grade_profile" = "../profiles/demo_grade.csv"}

A profile parameter (every String parameter of our FMUs names a profile file) is a path relative
to the description, checked when the package is built (a missing file or one that is not a regular
file is refused naming the parameter and the path) and packed into it
(harness.systems.ssp.PackedFile). A span scenario (scenarios/library/ato_nominal.toml) builds
its RailCar <-> AtoController system with nothing repeated (harness.systems.scenario_system).

Command line (docs/systems.md):

    python -m harness system build scenarios/systems/ato_span.toml out/ato_span.ssp
    python -m harness system build scenarios/library/ato_nominal.toml out/ato_nominal.ssp [--fmu auto|native|python]
        [--fmi 2|3] [--jacobi]
    python -m harness system run out/ato_span.ssp [--master ours|libcosim|ecos] [--stop S] [--csv F]
        [--output Component.variable ...]
    python -m harness system compare out/plant_estimator.ssp [--masters ours,libcosim,ecos] [--stop S]
        [--output Component.variable ...]

``run`` prints the last values and, for a system with an AtoController driving the car, the ATO
metrics (harness.systems.ato_run). ``compare`` runs the package in each master and prints, per
master, how its table differs from our master's (``compare_masters``): the outputs compared, how
many have the same bits at every time point, the largest differences, and the last values of
``--output`` (default: the car's position and speed, the estimated mass); a master that refuses the
package (a limit of that master: libcosim and FMI 3) or fails says why in its row; exit code 1 if
one failed or is not installed.

Every error in a description, also one found against the FMUs while building (an unknown
variable, a unit mismatch), names the TOML file, the line where it can and the key
(``ato_span.toml: line 12: [connections] 3 (ato.x -> car.y): ...``), not the .ssp being written.
Exit codes: 0 done, 1 a failed run (MasterError), 2 invalid input (SspError and other InputError).
"""
from __future__ import annotations

import argparse
import re
import sys
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from harness.systems.ssp import Component, Connection, PackedFile, SspError, SystemSpec, Where, write_ssp
from harness.textio import InputError, read_text

__all__ = ["load_system", "build", "build_system", "file_parameters", "compare_masters", "MasterComparison",
           "format_comparison", "main"]

ROOT = Path(__file__).resolve().parents[2]
DIST = ROOT / "dist"
KEYS = {"name", "description", "step_s", "start_s", "stop_s", "components", "connections", "step_order"}
PROG = "python -m harness system"
_TABLE_HEADER = re.compile(r"""\s*\[{1,2}[\w\s."'-]+\]{1,2}\s*(#.*)?$""")     # [a.b] or [[a]], not ["x", "y"],


class TomlWhere(Where):
    """Where each part of a system is in its TOML description: the file, the line (found in the
    text: tomllib gives lines for syntax errors only) and the key or table. Without a line (a key
    written in a way the search does not know) the message names the key alone."""

    def __init__(self, path: Path, text: str):
        super().__init__(path)
        self.lines = text.splitlines()
        self.connections: list[Connection] = []        # set once read: to tell a pair written twice

    def _at(self, line: int | None, what: str) -> str:
        return f"{self.file}: line {line}: {what}" if line else f"{self.file}: {what}"

    def _find(self, pattern: str, start: int = 0, stop: int | None = None) -> int | None:
        """The line number (from 1) of the first line in [start, stop) that matches ``pattern``."""
        rx = re.compile(pattern)
        for i, line in enumerate(self.lines[start:stop], start):
            if not line.lstrip().startswith("#") and rx.search(line):
                return i + 1
        return None

    def key_line(self, key: str) -> int | None:
        """The line of a top-level ``key = ...``."""
        return self._find(rf"^\s*{re.escape(key)}\s*=")

    def key(self, key: str) -> str:
        return self._at(self.key_line(key), key)

    def system(self, key: str) -> str:
        name = {"name": "name", "step": "step_s"}.get(key, key)
        return self.key(name)

    def _component_lines(self, name: str) -> tuple[int | None, int]:
        """(line of the [components.NAME] header, end of its table as a line index)."""
        header = self._find(rf'^\s*\[\s*components\s*\.\s*"?{re.escape(name)}"?\s*\]')
        if header is None:
            return None, 0
        end = next((i for i in range(header, len(self.lines)) if _TABLE_HEADER.match(self.lines[i])), len(self.lines))
        return header, end

    def component(self, name: str) -> str:
        return self._at(self._component_lines(name)[0], f"[components.{name}]")

    def parameters(self, component: str) -> str:
        header, end = self._component_lines(component)
        line = self._find(r"^\s*parameters\s*=", header, end) if header else None
        return self._at(line or header, f"[components.{component}] parameters")

    def parameter(self, component: str, name: str) -> str:
        header, end = self._component_lines(component)
        key = rf'(^|[\s{{,])("{re.escape(name)}"|{re.escape(name)})\s*='
        line = self._find(key, header, end) if header else None
        return self._at(line or header, f'[components.{component}] parameters."{name}"')

    def connection(self, number: int, conn: Connection | None = None) -> str:
        """The ``number``-th pair (from 1) of ``connections``: the line that holds it."""
        line = self.key_line("connections")
        if line and conn is not None:
            pair = rf'\[\s*"{re.escape(conn.start)}"\s*,\s*"{re.escape(conn.end)}"\s*\]'
            rx, seen = re.compile(pair), 0
            occurrence = self._occurrence(number, conn)
            for i in range(line - 1, len(self.lines)):
                seen += len(rx.findall(self.lines[i]))
                if seen >= occurrence:
                    line = i + 1
                    break
        what = f"[connections] {number}" + (f" ({conn})" if conn is not None else "")
        return self._at(line, what)

    def _occurrence(self, number: int, conn: Connection) -> int:
        """How many times the pair ``conn`` appears among the first ``number`` pairs (a pair
        written twice: the second is the one meant)."""
        return sum(c == conn for c in self.connections[:number])


def load_system(path: str | Path, dist: str | Path = DIST) -> SystemSpec:
    """A SystemSpec from a TOML description; FMU paths relative to ``dist``. Errors name the file,
    the line and the key (SspError)."""
    return _load(Path(path), Path(dist))[0]


def _load(path: Path, dist: Path) -> tuple[SystemSpec, TomlWhere]:
    """The system of a description and where its parts are written in it."""
    text = read_text(path, SspError)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:          # its message ends "(at line L, column C)"
        raise SspError(f"{path}: not valid TOML: {e}") from None
    where = TomlWhere(path, text)
    unknown = sorted(set(data) - KEYS)
    if unknown:
        raise SspError(f"{where.key(unknown[0])}: unknown key{'s ' + ', '.join(unknown) if len(unknown) > 1 else ''} "
                       f"(expected {', '.join(sorted(KEYS))})")
    for key in ("name", "step_s", "components"):
        if key not in data:
            raise SspError(f"{path}: '{key}' is missing")
    comps = data["components"]
    if not isinstance(comps, dict) or not comps:
        raise SspError(f"{where.key('components')}: [components.NAME] tables expected")
    components = []
    for name, table in comps.items():
        if not isinstance(table, dict) or "fmu" not in table:
            raise SspError(f"{where.component(name)}: 'fmu' is missing")
        extra = sorted(set(table) - {"fmu", "parameters"})
        if extra:
            raise SspError(f"{where.component(name)}: unknown key(s) {', '.join(extra)} (expected fmu, parameters)")
        params = table.get("parameters", {})
        if not isinstance(params, dict):
            raise SspError(f"{where.parameters(name)}: must be a table ({{\"name\" = value, ...}})")
        if not isinstance(table["fmu"], str):
            raise SspError(f"{where.component(name)}: 'fmu' must be a file name (relative to --dist)")
        fmu = Path(table["fmu"])
        components.append(Component(name, fmu if fmu.is_absolute() else dist / fmu,
                                    _pack_profiles(params, path.parent)))
    pairs = data.get("connections", [])
    if not isinstance(pairs, list):
        raise SspError(f"{where.key('connections')}: expected a list of [\"Component.output\", \"Component.input\"]")
    connections = []
    for k, pair in enumerate(pairs, 1):
        if not (isinstance(pair, list) and len(pair) == 2 and all(isinstance(x, str) for x in pair)):
            raise SspError(f"{where.connection(k)}: expected [\"Component.output\", \"Component.input\"], "
                           f"got {pair!r}")
        connections.append(Connection(*pair))
    where.connections = connections
    numbers = {}
    for key in ("step_s", "start_s", "stop_s"):
        value = data.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise SspError(f"{where.key(key)}: must be a number of seconds, got {value!r}")
        numbers[key] = value
    order = data.get("step_order", [])
    if not (isinstance(order, list) and all(isinstance(x, str) for x in order)):
        raise SspError(f"{where.key('step_order')}: expected a list of component names (Gauss-Seidel, "
                       f"our master only), got {order!r}")
    spec = SystemSpec(str(data["name"]), components, connections, numbers["step_s"],
                      numbers["start_s"] or 0.0, numbers["stop_s"], str(data.get("description", "")),
                      tuple(order))
    return spec, where


def file_parameters() -> frozenset[str]:
    """The parameters that name a file: every String parameter of our FMUs (fmu_src.variables)."""
    from fmu_src.variables import VARIABLES
    return frozenset(v.name for v in VARIABLES if v.type == "String" and v.causality == "parameter")


def _pack_profiles(params: dict, base: Path) -> dict:
    """The parameters with each non-empty profile path (relative to ``base``, the description's
    folder) a PackedFile, checked and packed when the package is written."""
    names = file_parameters()
    out = {}
    for name, value in params.items():
        if name in names and isinstance(value, str) and value:
            p = Path(value)
            value = PackedFile(p if p.is_absolute() else base / p)
        out[name] = value
    return out


def build(source: str | Path, out: str | Path, dist: str | Path = DIST, fmu: str = "auto",
          jacobi: bool = False, fmi: int = 2, say=None) -> Path:
    """Write the .ssp of a system description or of a span scenario (told apart by [components]:
    harness.systems.scenario_system.is_scenario); ``fmu`` chooses a scenario's RailCar and
    AtoController FMUs, ``fmi`` 3 their FMI 3.0 natives, ``jacobi`` builds it without a step order
    (libcosim and ecos run it; the demand one step late). ``say`` (print) gets the lines naming
    each chosen FMU and why; a description names its FMUs itself."""
    from harness.systems.scenario_system import is_scenario, scenario_system
    source = Path(source)
    try:
        data = tomllib.loads(read_text(source, SspError))
    except tomllib.TOMLDecodeError as e:
        raise SspError(f"{source}: not valid TOML: {e}") from None
    if not is_scenario(data):
        if fmi != 2 or fmu != "auto":
            raise SspError(f"{source}: a system description names its FMUs ([components.NAME] fmu); "
                           f"--fmu and --fmi choose a span scenario's")
        return build_system(source, out, dist)
    system = scenario_system(source, dist, fmu, jacobi, fmi)
    if say is not None:
        for line in system.choice_lines():
            say(line)
    return write_ssp(system.spec, out, Where(source))


def build_system(description: str | Path, out: str | Path, dist: str | Path = DIST) -> Path:
    """Write the .ssp of a TOML description, checked against its FMUs; an error names the
    description's file, line and key."""
    spec, where = _load(Path(description), Path(dist))
    for c in spec.components:
        if not Path(c.fmu).is_file():
            raise SspError(f"{where.component(c.name)}: FMU file not found: {c.fmu} (build the "
                           f"FMUs with: python build.py; --dist names another folder)")
    return write_ssp(spec, out, where)


MASTERS = ("ours", "libcosim", "ecos")
SHOWN_BY_DEFAULT = ("car.car.position", "car.car.speed", "est.est.mass", "car.est.mass")


def run_in(master: str, system, stop_time: float | None = None, outputs=None):
    """Run ``system`` in ``master`` (ours, libcosim in a child process, ecos in a child process):
    harness.systems.master.Result."""
    if master == "libcosim":                     # libcosim aborts its process when an FMU fails initialisation
        from harness.systems.libcosim import run_libcosim
        return run_libcosim(system, stop_time=stop_time, outputs=outputs, isolated=True)
    if master == "ecos":
        from harness.systems.ecos import run_ecos
        return run_ecos(system, stop_time=stop_time, outputs=outputs)
    from harness.systems.master import run_system
    return run_system(system, stop_time=stop_time, outputs=outputs)


@dataclass
class MasterComparison:
    """One master's table against the reference (our master's): ``result`` None and ``error`` the
    reason when it did not run; ``compared`` the outputs in both tables; ``identical`` those with
    the same bits (the same integers, booleans) at every time point; ``max_abs`` / ``max_rel`` the
    largest |difference| of a Real output [its unit] and relative to max(1, |ours|), with
    ``worst`` the output of max_rel; ``integer_diffs`` the non-Real outputs that differ."""
    master: str
    result: object = None
    error: str = ""
    compared: list = field(default_factory=list)
    identical: list = field(default_factory=list)
    max_abs: float = 0.0
    max_rel: float = 0.0
    worst: str = ""
    integer_diffs: list = field(default_factory=list)
    limits: list = field(default_factory=list)
    refused: bool = False             # the master refused the package (SspError), did not fail


def compare_results(reference, other, master: str) -> MasterComparison:
    """How ``other`` (a Result) differs from ``reference`` on their common outputs; the times must
    be the same grid (else AssertionError naming both)."""
    import numpy as np
    if len(reference.time) != len(other.time) or not np.array_equal(reference.time, other.time):
        raise AssertionError(f"{master}: {len(other.time)} time points, the reference {len(reference.time)}")
    c = MasterComparison(master, other, limits=list(getattr(other, "limits", [])))
    for name, y in other.signals.items():
        if name not in reference.signals:
            continue
        x = reference.signals[name]
        c.compared.append(name)
        if x.dtype.kind == "f":
            same = np.array_equal(x.view(np.int64), np.ascontiguousarray(y, dtype=np.float64).view(np.int64))
            d = np.abs(x - y)
            rel = float(np.max(d / np.maximum(1.0, np.abs(x))))
            c.max_abs = max(c.max_abs, float(np.max(d)))
            if rel > c.max_rel:
                c.max_rel, c.worst = rel, name
        else:
            same = np.array_equal(x, y)
            if not same:
                c.integer_diffs.append(name)
        if same:
            c.identical.append(name)
    return c


def compare_masters(system, masters=MASTERS, stop_time: float | None = None, outputs=None) -> list[MasterComparison]:
    """Run ``system`` in every master of ``masters`` and compare each table with our master's
    (which runs first, whether asked or not); a master that refuses or fails has its error."""
    from harness.systems.master import MasterError
    reference = run_in("ours", system, stop_time, outputs)
    rows = []
    for master in masters:
        if master == "ours":
            rows.append(compare_results(reference, reference, "ours"))
            continue
        try:
            rows.append(compare_results(reference, run_in(master, system, stop_time, outputs), master))
        except SspError as e:                    # this master cannot run such a package: a limit
            rows.append(MasterComparison(master, error=str(e).splitlines()[0], refused=True))
        except (MasterError, ImportError) as e:
            rows.append(MasterComparison(master, error=str(e).splitlines()[0]))
    return rows


def format_comparison(system, rows: list[MasterComparison], shown=None) -> str:
    """The table ``compare`` prints: one row per master, then the last values of ``shown``."""
    ref = rows[0].result if rows and rows[0].result is not None else next((r.result for r in rows if r.result), None)
    n = len(ref.time) - 1 if ref is not None else 0
    lines = [f"{system.path.name}: {n} steps of {system.spec.step!r} s, compared with our master "
             f"(harness.systems.master)",
             f"{'master':<9} {'ran':<4} {'outputs':>7} {'same bits':>9} {'max |diff|':>10} "
             f"{'max rel':>8}  worst output"]
    for r in rows:
        if r.result is None:
            lines.append(f"{r.master:<9} {'no:' if r.refused else 'FAILED:'} {r.error}")
            continue
        lines.append(f"{r.master:<9} {'yes':<4} {len(r.compared):>7} {len(r.identical):>9} {r.max_abs:>10.1e} "
                     f"{r.max_rel:>8.1e}  {r.worst or '-'}"
                     + (f"; integers/booleans differ: {', '.join(r.integer_diffs)}" if r.integer_diffs else ""))
    for r in rows:
        for limit in r.limits:
            lines.append(f"  {r.master}: {limit}")
    ran = [r for r in rows if r.result is not None]
    if shown is None:
        shown = [o for o in SHOWN_BY_DEFAULT if ran and o in ran[0].result.signals]
    if shown and ran:
        width = max(len(o) for o in shown)
        lines.append(f"last values (t = {float(ran[0].result.time[-1])!r} s):")
        lines.append(f"  {'':<{width}}  " + "  ".join(f"{r.master:>22}" for r in ran))
        for o in shown:
            cells = [f"{r.result.signals[o][-1].item()!r:>22}" if o in r.result.signals else f"{'-':>22}" for r in ran]
            lines.append(f"  {o:<{width}}  " + "  ".join(cells) + f"  {ran[0].result.units.get(o, '')}".rstrip())
    return "\n".join(lines)


def main(argv=None, prog: str = PROG) -> int:
    """``python -m harness system build|run ...``; the exit code."""
    from harness.systems.master import MasterError, report_failure
    p = argparse.ArgumentParser(prog=prog,
                                description="Build an SSP system from a description, or run one.")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="system description or span scenario (.toml) -> .ssp")
    b.add_argument("description", help="a system description (scenarios/systems/) or a span scenario")
    b.add_argument("out")
    b.add_argument("--dist", default=str(DIST), help="folder the FMU paths are relative to (default dist/)")
    b.add_argument("--fmu", choices=("auto", "native", "python"), default="auto",
                   help="a span scenario's RailCar and AtoController FMUs (as python -m harness run --fmu; "
                        "default auto: each native FMU when it runs the parameters)")
    b.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                   help="a span scenario's FMI version: 3 builds it on the FMI 3.0 natives (default 2)")
    b.add_argument("--jacobi", action="store_true",
                   help="a span scenario's system stepped Jacobi, as libcosim steps: the ATO's demand "
                        "reaches the car one step late (default: the ATO steps first, as in python -m harness run)")
    r = sub.add_parser("run", help="run an .ssp and print the last values (or write them all: --csv)")
    r.add_argument("ssp")
    r.add_argument("--master", choices=MASTERS, default="ours")
    r.add_argument("--stop", type=float, default=None, help="stop time [s] (default: the file's)")
    r.add_argument("--output", action="append", default=None, help="Component.variable (repeatable)")
    r.add_argument("--csv", default=None, help="write every time point here, units in the header")
    c = sub.add_parser("compare", help="run an .ssp in several masters and print how they differ from ours")
    c.add_argument("ssp")
    c.add_argument("--masters", default=",".join(MASTERS),
                   help=f"comma-separated, of {', '.join(MASTERS)} (default all)")
    c.add_argument("--stop", type=float, default=None, help="stop time [s] (default: the file's)")
    c.add_argument("--output", action="append", default=None,
                   help="Component.variable whose last value is shown (repeatable)")
    args = p.parse_args(argv)
    try:
        if args.command == "build":
            print(build(args.description, args.out, args.dist, args.fmu, args.jacobi, args.fmi, say=print))
            return 0
        if args.command == "compare":
            from harness.systems.ssp_read import read_ssp
            masters = [m.strip() for m in args.masters.split(",") if m.strip()]
            bad = [m for m in masters if m not in MASTERS]
            if bad or not masters:
                print(f"error: --masters {args.masters!r}: expected some of {', '.join(MASTERS)}", file=sys.stderr)
                return 2
            system = read_ssp(args.ssp)
            if args.output:
                for o in args.output:
                    system.variable(o, f"--output {o}")
            rows = compare_masters(system, masters, args.stop)
            print(format_comparison(system, rows, args.output))
            return 0 if all(r.result is not None or r.refused for r in rows) else 1
        from harness.systems.ato_run import metric_outputs, system_ato_metrics
        from harness.systems.ssp_read import read_ssp
        system = read_ssp(args.ssp)
        extra = metric_outputs(system)
        outputs = None if args.output is None else list(dict.fromkeys(args.output + extra))
        result = run_in(args.master, system, args.stop, outputs)
        metrics = system_ato_metrics(system, result) if extra else None
    except (SspError, MasterError) as e:
        return report_failure(e)
    except InputError as e:                          # a scenario's ScenarioError, a build's choice
        print(f"error: {e}", file=sys.stderr)
        return 2
    except ImportError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.csv:
        try:
            print(f"wrote {result.write_csv(args.csv)}")
        except OSError as e:
            print(f"error: --csv {args.csv}: cannot write: {e.strerror or e}", file=sys.stderr)
            return 2
    shown = result.signals if args.output is None else {n: result.signals[n] for n in args.output}
    width = max(len(n) for n in shown) if shown else 0
    print(f"{result.master}: {len(result.time) - 1} steps to t = {float(result.time[-1])!r} s")
    for name, values in shown.items():
        print(f"  {name:<{width}}  {values[-1].item()!r} {result.units.get(name, '')}".rstrip())
    if metrics is not None:
        from harness.metrics.ato import format_ato
        print("ATO (harness.metrics.ato; truth from the car, demands as applied):")
        print(format_ato(metrics))
    return 0



if __name__ == "__main__":           # the one spelling of the command is python -m harness system
    sys.exit(f"the systems command is: {PROG} build|run ... ({PROG} -h)")
