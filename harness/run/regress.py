"""Regression references in the FMI cross-check layout: writing them, comparing fresh runs with them,
and the ``python -m harness regress`` command.

For each library scenario ``<Name>`` the folder ``tests/regression/`` holds
``<Name>_in.csv`` (the inputs the driver applied, zero-order hold written as duplicate time
rows), ``<Name>_ref.csv`` (every output of the RailCar FMU, every REFERENCE_INTERVAL) and
``<Name>_ref.opt`` (StartTime, StopTime, StepSize, RelTol). As the cross-check rules require,
the CSV headers are the quoted variable names, time first; their units are the FMU variables'
(docs/variables.md). The outputs are those of the model description's table
(fmu_src/variables.py), so an output added there is in the next regenerated reference.
``tests/regression/variants/`` holds the same for VARIANTS: a library scenario with estimator
options the FMU's defaults do not use, run on the models chain (the Python code the pythonfmu FMU
runs), which the library's references (C core) do not pin.

A fresh run passes when every output is within its tolerance of the reference (``tolerance``:
integers exact, Reals by FLOAT_TOLERANCES) and fmpy's band test (``fmpy.util.validate_result``)
finds no outlier among the Reals. A reference without a column for an output fails, naming the
columns and the command that regenerates it.

Checking and regenerating are separate commands; pytest only checks:

    python -m harness regress [NAME ...]                       check the library scenarios
    python -m harness regress --update [NAME ...]              rewrite their references
    python -m harness regress --variants [NAME ...]            check the variants (models chain)
    python -m harness regress --variants --update [NAME ...]   rewrite the variants' references

A NAME may be a pattern ('ato_*': the span scenarios, whose inputs are the ATO's demands, so a
change to models/ato/ changes them). To regenerate everything after a deliberate model change:

    python -m harness regress --update && python -m harness regress --variants --update

``--update`` writes a file only if its content changes and says, per file, what changed: added
or removed columns, how many rows and which columns, and the largest change (with the time and
whether it is beyond the tolerance). "unchanged" means the three files are byte for byte the same.
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field, replace
from fnmatch import fnmatchcase
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np
from fmpy.util import read_csv, read_ref_opt_file, validate_result

from fmu_src.variables import RAILCAR, VARIABLES
from harness.run.driver import run_on_chain
from harness.run.phases import INPUTS
from harness.run.result import RunResult
from harness.run.scenario import load_scenario
from harness.textio import InputError, check_text_file

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = ROOT / "scenarios" / "library"
REFERENCES = ROOT / "tests" / "regression"
VARIANT_REFERENCES = REFERENCES / "variants"
REFERENCE_INTERVAL = 0.5     # [s] between stored reference rows (keeps the files small)
# fmpy's band test is a heuristic: at a jump (the distance restarting at a station) it flags a
# few samples even of identical data (0.29 % in station_day); the explicit tolerances are the
# strict check, the band test the coarse one.
BAND_OUTLIERS_ALLOWED = 0.01

# Tolerances of the Real outputs: (atol in the output's unit, rtol). One machine reproduces runs
# bit for bit; these only absorb last-bit differences between BLAS/LAPACK builds (relative 1e-16),
# ~10 orders above them and far below any deliberate model change (1 % of A0 moves the speed by
# centimetres per second). By kind:
#   truth and measurements (car.*, sensor.*): rtol 1e-6; atol 1e-6 m/s for speeds and
#     accelerations, 1e-5 m for distances (integrated from the speed over ~10^3 steps), 1e-6 N for
#     forces (the demands' own tolerance: closed-loop demands follow the truth; the forces'
#     means over a sample interval, car.*_force_mean, as the forces they average), 1e-6 t for the
#     mass (car.mass + boarded payload), 1e-4 permille for the grade (averaged over the car's
#     length, so it moves with the position: <= 25 permille over ~20 m times 1e-5 m is 1.3e-5),
#     1e-5 s for a track-sensor time stamp (a distance tolerance over a speed of >= 1 m/s);
#   filtered speed and distance: as the measurements they filter;
#   estimates and their standard deviations (est.*, filter.*_std): rtol 1e-5 (a covariance
#     propagated over thousands of steps accumulates more rounding than the plant), atol about
#     1e-6 of the quantity's typical size (A1 ~ 0.03, A2 ~ 0.01, a filter std ~ 0.01-0.1 m/s);
#     est.sigma2 (1e-7 to 1e-4 m2/s2): atol 1e-12 m2/s2, the speed tolerance squared;
#     the A's covariances (est.cov_*): rtol 1e-5, atol about 1e-6 of their typical size
#     (A0 std ~ 1, A1 std ~ 0.1, A2 std ~ 0.01: cov_A0_A1 ~ 0.1, cov_A0_A2 ~ 0.01, cov_A1_A2 ~ 1e-3).
# Integer outputs (car.mode, est.samples, est.station_stops, est.status, filter.rejected) are
# modes, counters and a status: compared exactly (EXACT), as a changed count is a changed decision.
FLOAT_TOLERANCES: dict[str, tuple[float, float]] = {
    "car.speed": (1e-6, 1e-6), "car.position": (1e-5, 1e-6), "car.acceleration": (1e-6, 1e-6),
    "car.traction_force": (1e-6, 1e-6), "car.brake_force": (1e-6, 1e-6), "car.grade": (1e-4, 1e-6),
    "car.total_mass": (1e-6, 1e-6),
    "car.traction_force_mean": (1e-6, 1e-6), "car.brake_force_mean": (1e-6, 1e-6),
    "sensor.speed": (1e-6, 1e-6), "sensor.position": (1e-5, 1e-6),
    "sensor.track_speed": (1e-6, 1e-6), "sensor.track_time": (1e-5, 1e-6),
    "est.mass": (1e-5, 1e-6), "est.mass_std": (1e-5, 1e-5),
    "est.A0": (1e-6, 1e-5), "est.A1": (1e-8, 1e-5), "est.A2": (1e-9, 1e-5),
    "est.A0_std": (1e-6, 1e-5), "est.A1_std": (1e-8, 1e-5), "est.A2_std": (1e-9, 1e-5),
    "est.sigma2": (1e-12, 1e-5),
    "est.cov_A0_A1": (1e-7, 1e-5), "est.cov_A0_A2": (1e-8, 1e-5), "est.cov_A1_A2": (1e-9, 1e-5),
    "filter.speed": (1e-6, 1e-6), "filter.position": (1e-5, 1e-6),
    "filter.speed_std": (1e-8, 1e-5), "filter.position_std": (1e-7, 1e-5),
}
EXACT = (0.0, 0.0)

# Estimator options beyond the FMU's defaults, pinned by tests/regression/variants/: (library
# scenario, parameters by FMU name), run on the models chain (the C core covers only the defaults).
VARIANTS: dict[str, tuple[str, dict]] = {
    # LS on Sidorenko's (1997) slopes, A0 and A2 kept physical, sigma^2 by likelihood, slow forgetting
    "station_day_all_options": ("station_day", {"est.method": 2, "est.physical": 1,
                                                "est.sigma2_method": 1, "est.run_forgetting": 0.1}),
    # the coasting EKF for the A's with the same options
    "station_day_coast_ekf": ("station_day", {"est.method": 3, "est.physical": 1,
                                              "est.sigma2_method": 1, "est.run_forgetting": 0.1}),
}


class ReferenceFileError(InputError):
    """A reference file that cannot be read (not UTF-8 text, not the cross-check layout); names it."""


@dataclass(frozen=True)
class Output:
    """One output of the RailCar FMU as the references store it."""
    name: str
    integer: bool       # Integer (or Boolean): written as an integer, compared exactly


def reference_outputs() -> list[Output]:
    """Every output of the RailCar FMU, in the model description's order (fmu_src/variables.py)."""
    return [Output(v.name, v.type != "Real") for v in VARIABLES
            if v.causality == "output" and RAILCAR in v.fmus]


def tolerance(output: Output) -> tuple[float, float]:
    """(atol [the output's unit], rtol) of an output: EXACT for integers, FLOAT_TOLERANCES for Reals.
    A Real output without a tolerance raises KeyError saying where to add one."""
    if output.integer:
        return EXACT
    try:
        return FLOAT_TOLERANCES[output.name]
    except KeyError:
        raise KeyError(f"{output.name}: a Real output without a regression tolerance: add one, with its "
                       f"reason, to FLOAT_TOLERANCES in harness/run/regress.py") from None


def regenerate_command(name: str, folder: Path = REFERENCES) -> str:
    """The command that rewrites the reference ``name`` in ``folder``."""
    variants = Path(folder).resolve() == VARIANT_REFERENCES.resolve()
    return f"python -m harness regress{' --variants' if variants else ''} --update {name}"


@dataclass
class Comparison:
    scenario: str
    problems: list[str]
    max_abs: dict[str, float]

    @property
    def ok(self) -> bool:
        return not self.problems


def library_scenarios() -> list[Path]:
    return sorted(LIBRARY.glob("*.toml"))


def run_variant(name: str) -> RunResult:
    """The variant ``name`` (VARIANTS) on the models chain; the result carries the variant's name."""
    base, parameters = VARIANTS[name]
    scenario = load_scenario(LIBRARY / f"{base}.toml")
    return run_on_chain(replace(scenario, name=name), parameters)


# ------------------------------------------------------------------------------ writing

def _csv_text(columns: dict[str, np.ndarray], integers: Iterable[str] = ()) -> str:
    """A cross-check CSV: quoted names, then one row per sample; floats as repr (round-trips
    exactly), integer columns as integers."""
    integers = set(integers)
    formats = [(lambda x: str(int(x))) if n in integers else (lambda x: repr(float(x))) for n in columns]
    lines = [",".join(f'"{n}"' for n in columns)]
    lines += [",".join(f(x) for f, x in zip(formats, row)) for row in zip(*columns.values())]
    return "\n".join(lines) + "\n"


def reference_rows(result) -> np.ndarray:
    """Indices of the rows stored in a reference (every REFERENCE_INTERVAL, and the last)."""
    stride = max(1, int(round(REFERENCE_INTERVAL / result.scenario.step_s)))
    idx = np.arange(0, len(result.time), stride)
    return idx if idx[-1] == len(result.time) - 1 else np.append(idx, len(result.time) - 1)


def reference_texts(result) -> dict[str, str]:
    """The contents of <Name>_in.csv, <Name>_ref.csv and <Name>_ref.opt for a run, by file name.
    Raises KeyError naming an output the run did not record."""
    name, t = result.scenario.name, result.time
    # inputs, zero-order hold: a change at t_k is written as (t_k, old) then (t_k, new)
    u = np.column_stack([result.inputs[n] for n in INPUTS])
    rows_t, rows_u = [t[0]], [u[0]]
    for k in range(1, len(t)):
        if not np.array_equal(u[k], u[k - 1]):
            rows_t += [t[k], t[k]]
            rows_u += [u[k - 1], u[k]]
    rows_t.append(t[-1])
    rows_u.append(u[-1])
    rows_u = np.array(rows_u)
    inputs = {"time": np.array(rows_t), **{n: rows_u[:, j] for j, n in enumerate(INPUTS)}}
    idx = reference_rows(result)
    outputs = reference_outputs()
    missing = [o.name for o in outputs if o.name not in result.signals]
    if missing:
        raise KeyError(f"{name}: the run did not record the outputs {', '.join(missing)}")
    ref = {"time": t[idx], **{o.name: result[o.name][idx] for o in outputs}}
    opt = (f"StartTime, 0.0\nStopTime, {float(t[-1])!r}\nStepSize, {result.scenario.step_s!r}\n"
           f"RelTol, 1e-06\n")
    return {f"{name}_in.csv": _csv_text(inputs), f"{name}_ref.csv": _csv_text(ref, (o.name for o in outputs if o.integer)),
            f"{name}_ref.opt": opt}


@dataclass
class FileUpdate:
    """What writing one reference file did: ``status`` "unchanged" (byte-identical, not written),
    "new" or "changed" (written); ``changes``: what changed, one line each."""
    path: Path
    status: str
    changes: list[str] = field(default_factory=list)


def write_reference(result, folder: Path = REFERENCES) -> list[FileUpdate]:
    """Write <Name>_in.csv, <Name>_ref.csv and <Name>_ref.opt for a run, each only if its content
    changes; return what happened to each file."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    updates = []
    for file_name, text in reference_texts(result).items():
        path = folder / file_name
        new = text.encode("utf-8")
        old = path.read_bytes() if path.is_file() else None
        if old == new:
            updates.append(FileUpdate(path, "unchanged"))
            continue
        if old is None:
            changes = []
        elif file_name.endswith(".csv"):
            changes = describe_csv_change(old.decode("utf-8", errors="replace"), text)
        else:
            changes = _describe_opt_change(old.decode("utf-8", errors="replace"), text)
        path.write_bytes(new)
        updates.append(FileUpdate(path, "new" if old is None else "changed", changes))
    return updates


def _parse_csv(text: str) -> tuple[list[str], np.ndarray]:
    """(column names, rows x columns of float) of a cross-check CSV; ValueError if it is not one."""
    lines = text.splitlines()
    if not lines:
        raise ValueError("empty")
    names = [n.strip().strip('"') for n in lines[0].split(",")]
    rows = [[float(x) for x in line.split(",")] for line in lines[1:] if line.strip()]
    if any(len(r) != len(names) for r in rows):
        raise ValueError("rows and header differ in length")
    return names, np.array(rows, dtype=float).reshape(len(rows), len(names))


def describe_csv_change(old_text: str, new_text: str) -> list[str]:
    """What changed between two versions of a reference CSV, one line each: added and removed
    columns; then, on the same time grid, how many rows changed, the largest change (column, time,
    beyond its tolerance or not) and each changed column (rows, largest change)."""
    try:
        old_names, old = _parse_csv(old_text)
    except ValueError as e:
        return [f"the old file was not a reference CSV ({e}): rewritten"]
    new_names, new = _parse_csv(new_text)
    lines = []
    added = [n for n in new_names if n not in old_names]
    removed = [n for n in old_names if n not in new_names]
    if added:
        lines.append(f"added {len(added)} columns: {', '.join(added)}")
    if removed:
        lines.append(f"removed {len(removed)} columns: {', '.join(removed)}")
    if "time" not in old_names or "time" not in new_names:
        return lines + ["no time column: values not compared"]
    t_old, t_new = old[:, old_names.index("time")], new[:, new_names.index("time")]
    if len(t_old) != len(t_new) or not np.array_equal(t_old, t_new):
        return lines + [f"time grid changed: {len(t_old)} rows -> {len(t_new)} rows "
                        f"(last time {t_old[-1] if len(t_old) else 'none'} -> {t_new[-1]} s); "
                        f"values not compared row by row"]
    outputs = {o.name: o for o in reference_outputs()}
    changed_rows = np.zeros(len(t_new), dtype=bool)
    per_column = []          # (largest |change|, name, rows, time of the largest, beyond tolerance)
    for name in new_names:
        if name not in old_names:
            continue
        a, b = old[:, old_names.index(name)], new[:, new_names.index(name)]
        differ = ~((a == b) | (np.isnan(a) & np.isnan(b)))
        if not differ.any():
            continue
        changed_rows |= differ
        diff = np.where(differ, np.abs(b - a), 0.0)
        diff = np.where(np.isnan(diff), np.inf, diff)
        j = int(np.argmax(diff))
        beyond = None
        if name in outputs:
            try:
                atol, rtol = tolerance(outputs[name])
                beyond = int(np.sum(np.abs(b - a) > atol + rtol * np.abs(a)))
            except KeyError:
                pass
        per_column.append((float(diff[j]), name, int(differ.sum()), float(t_new[j]), beyond))
    if not per_column:
        return lines or ["same values, different text (number formatting)"]
    per_column.sort(reverse=True)
    d, name, _, t, beyond = per_column[0]
    within = ("" if beyond is None else
              f", {'within' if not beyond else 'BEYOND'} its tolerance" +
              (f" in {beyond} rows" if beyond else ""))
    lines.append(f"{int(changed_rows.sum())} of {len(t_new)} rows changed in {len(per_column)} columns; "
                 f"largest change {d:.3g} in {name} at t = {t:g} s{within}")
    lines.append("changed: " + ", ".join(f"{n} ({rows} rows, max {d:.3g}"
                                         f"{'' if not b else f', {b} beyond tolerance'})"
                                         for d, n, rows, _, b in per_column))
    return lines


def _describe_opt_change(old_text: str, new_text: str) -> list[str]:
    old = dict(line.split(",", 1) for line in old_text.splitlines() if "," in line)
    new = dict(line.split(",", 1) for line in new_text.splitlines() if "," in line)
    return [f"{k}: {old.get(k, '(none)').strip()} -> {new.get(k, '(none)').strip()}"
            for k in dict.fromkeys([*old, *new]) if old.get(k, "").strip() != new.get(k, "").strip()] \
        or ["same entries, different text"]


# ------------------------------------------------------------------------------ comparing

def compare(result, folder: Path = REFERENCES) -> Comparison:
    """Compare a fresh run with its stored reference; problems name the scenario and output."""
    name = result.scenario.name
    regenerate = regenerate_command(name, folder)
    ref_path = Path(folder) / f"{name}_ref.csv"
    if not ref_path.is_file():
        return Comparison(name, [f"{name}: no reference {ref_path.name}; write it with {regenerate}"], {})
    ref, opts = read_reference(name, folder)
    problems, max_abs = [], {}
    outputs = reference_outputs()
    known = {o.name for o in outputs}
    lacking = [o.name for o in outputs if o.name not in ref.dtype.names]
    if lacking:
        problems.append(f"{name}: reference lacks columns {', '.join(lacking)}; regenerate with {regenerate}")
    unknown = [n for n in ref.dtype.names[1:] if n not in known]
    if unknown:
        problems.append(f"{name}: reference has columns that are no RailCar output: {', '.join(unknown)}; "
                        f"regenerate with {regenerate}")
    t_ref = ref["time"]
    if abs(result.time[-1] - opts["StopTime"]) > 1e-9 * max(1.0, opts["StopTime"]):
        problems.append(f"{name}: run ends at {result.time[-1]:.3f} s, reference at {opts['StopTime']:.3f} s")
    # rows of the fresh run at the reference's instants (as far as both go)
    k = np.searchsorted(result.time, t_ref - 1e-9)
    shared = (k < len(result.time))
    shared[shared] &= np.abs(result.time[k[shared]] - t_ref[shared]) <= 1e-9
    if not shared.any():
        problems.append(f"{name}: no instant in common with the reference")
        return Comparison(name, problems, max_abs)
    idx, t_cmp = k[shared], t_ref[shared]
    compared = []
    for output in outputs:
        if output.name not in ref.dtype.names:
            continue
        if output.name not in result.signals:
            problems.append(f"{name}: {output.name}: not among the run's outputs")
            continue
        atol, rtol = tolerance(output)
        fresh, old = result[output.name][idx].astype(float), ref[output.name][shared]
        diff = np.abs(fresh - old)
        max_abs[output.name] = float(diff.max())
        bad = ~(diff <= atol + rtol * np.abs(old))        # NaN on either side is off
        if bad.any():
            j = int(np.argmax(np.where(bad, np.nan_to_num(diff, nan=np.inf), -1.0)))
            rule = "exact" if (atol, rtol) == EXACT else f"atol {atol:g}, rtol {rtol:g}"
            problems.append(f"{name}: {output.name}: {int(bad.sum())} of {len(diff)} samples off; largest "
                            f"|{fresh[j]:.9g} - {old[j]:.9g}| = {diff[j]:.3g} at t = {t_cmp[j]:.2f} s ({rule})")
        if not output.integer:
            compared.append(output.name)
    # the band test on the Reals (the integers are compared exactly; their steps are no signal shape)
    fresh_arr = _structured(result.time[idx], {n: result[n][idx] for n in compared})
    rel_out = validate_result(fresh_arr, ref[shared][["time", *compared]], stop_time=float(t_cmp[-1]))
    if rel_out > BAND_OUTLIERS_ALLOWED:
        problems.append(f"{name}: fmpy band test: {100 * rel_out:.2f} % of the samples of the worst signal "
                        f"lie outside the reference band")
    return Comparison(name, problems, max_abs)


def _structured(time: np.ndarray, columns: dict[str, np.ndarray]) -> np.ndarray:
    arr = np.zeros(len(time), dtype=[(n, np.float64) for n in ["time", *columns]])
    arr["time"] = time
    for n, c in columns.items():
        arr[n] = c
    return arr


def read_reference(name: str, folder: Path = REFERENCES) -> tuple[np.ndarray, dict]:
    """(<Name>_ref.csv as a structured array, <Name>_ref.opt as a dict); ReferenceFileError names a
    file that is not UTF-8 text or not in the cross-check layout."""
    folder = Path(folder)
    ref_path, opt_path = folder / f"{name}_ref.csv", folder / f"{name}_ref.opt"
    for p in (ref_path, opt_path):
        check_text_file(p, ReferenceFileError, reader="fmpy.util.read_csv")
    try:
        ref = read_csv(ref_path)
    except Exception as e:              # fmpy / numpy parse errors: no common type
        raise ReferenceFileError(f"{ref_path}: not a reference CSV: {type(e).__name__}: {e}") from None
    if not ref.dtype.names or ref.dtype.names[0] != "time":
        raise ReferenceFileError(f"{ref_path}: line 1: the first column must be \"time\"")
    try:
        opts = read_ref_opt_file(opt_path)
        stop = float(opts["StopTime"])
    except Exception as e:
        raise ReferenceFileError(f"{opt_path}: not a reference options file (StopTime, ...): "
                             f"{type(e).__name__}: {e}") from None
    return ref, dict(opts, StopTime=stop)


def read_inputs(name: str, folder: Path = REFERENCES) -> np.ndarray:
    """The stored inputs of a scenario (structured array, duplicate time rows at changes)."""
    return read_csv(Path(folder) / f"{name}_in.csv")


# ------------------------------------------------------------------------------ the command

def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of ``python -m harness regress`` (the FMU options are the harness's own)."""
    parser.description = __doc__.split("\n\n", 1)[1]
    parser.formatter_class = argparse.RawDescriptionHelpFormatter
    parser.add_argument("names", nargs="*", help="library scenario (or, with --variants, variant) names or "
                        "patterns such as 'ato_*' (default: all)")
    parser.add_argument("--update", action="store_true",
                        help="rewrite the references instead of checking them: each file only if its content "
                             "changes, saying per file what changed (columns, rows, largest change)")
    parser.add_argument("--variants", action="store_true",
                        help=f"the estimator-option variants ({', '.join(VARIANTS)}) on the models chain "
                             f"instead of the library on the FMU (--fmu, --dist, --rebuild do not apply), "
                             f"references in tests/regression/variants/")


def select_variants(patterns: list[str]) -> list[str]:
    """The VARIANTS matching ``patterns`` (all if none); InputError names a pattern matching none."""
    if not patterns:
        return list(VARIANTS)
    unknown = [p for p in patterns if not any(fnmatchcase(v, p) for v in VARIANTS)]
    if unknown:
        raise InputError(f"unknown variant(s): {', '.join(unknown)} (known: {', '.join(VARIANTS)})")
    return [v for v in VARIANTS if any(fnmatchcase(v, p) for p in patterns)]


def variant_runs(patterns: list[str]) -> Iterator[tuple[str, RunResult]]:
    """(name, result) of each selected variant, run on the models chain as it is asked for."""
    for name in select_variants(patterns):
        yield name, run_variant(name)


def check_or_update(runs: Iterable[tuple[str, object]], update: bool, folder: Path = REFERENCES,
                    out=print) -> bool:
    """For each (name, RunResult or the exception its run raised): compare with the reference
    (``ok``/``FAIL`` and the problems) or, with ``update``, write it and say per file what changed
    (``unchanged``: all three files byte-identical). True when every run ran and, checking, matched."""
    all_ok = True
    for name, result in runs:
        if isinstance(result, Exception):
            out(f"FAIL {name}: {result}")
            all_ok = False
            continue
        if update:
            updates = write_reference(result, folder)
            written = [u for u in updates if u.status != "unchanged"]
            if not written:
                out(f"unchanged {name} ({len(updates)} files byte-identical)")
                continue
            out(f"{'new' if all(u.status == 'new' for u in written) else 'updated'} {name}")
            for u in updates:
                out(f"    {u.path.name}: {u.status}" + ("" if not u.changes else ":"))
                for line in u.changes:
                    out(f"        {line}")
            continue
        c = compare(result, folder)
        out(f"{'ok  ' if c.ok else 'FAIL'} {name}")
        for p in c.problems:
            out(f"     {p}")
        all_ok &= c.ok
    return all_ok
