"""Batch parameter sweeps of RailCar on dask.distributed worker processes.

A sweep file (TOML) names a base scenario and the values to run it with:

    name = "mass_noise"                      # optional (default: the file's stem)
    purpose = "one line"                     # optional
    scenario = "../library/level_run.toml"   # the base scenario, relative to this file

    [fixed]                                  # applied to every run (not a column of the results)
    duration_s = 60.0

    [grid]                                   # full factorial: every combination of these axes
    "car.mass" = [30.0, 34.0, 40.0]                               # explicit values
    "sensor.speed_std" = { start = 0.02, stop = 0.10, num = 5 }   # evenly spaced, both ends

    [zip]                                    # explicit lists varied together (equal lengths):
    "car.mass" = [30.0, 40.0]                # the k-th point takes the k-th value of each
    "est.mass_initial" = [28.0, 38.0]

    [lhs]                                    # Latin hypercube (scipy.stats.qmc.LatinHypercube)
    samples = 200
    seed = 1                                 # default 0: same file, same sample
    [lhs.bounds]
    "car.mass" = [25.0, 45.0]                # [low, high], uniform within

    seeds = 100                              # Monte Carlo: FMU parameter `seed` = 1..100, or a list

The runs are the product grid x zip x lhs x seeds (each block optional; seeds vary fastest),
numbered 0, 1, ... in that order: the run id. A name may appear in one block only. Names are
RailCar parameters (contract names, SI units, checked and typed by
``harness.scenario.parse_parameters``; profile paths relative to the sweep file) or scenario
fields: ``step_s``, ``duration_s``, ``stop_after_last_phase``, ``driver[i].KEY`` (a key of
the base scenario's i-th ``[[driver]]`` phase) and ``wind[i].time_s`` / ``wind[i].speed_mps``.
A malformed sweep file raises ``SweepError`` (a ``ScenarioError``) naming the file, key and
reason; a run whose values make an invalid scenario (say step_s = 0) or whose FMU fails
becomes a row with status "failed" and the message, and the sweep goes on.

Execution: every run is one dask task on a worker *process* (one thread each: FMU calls hold
the GIL). Each worker process extracts the FMU once and keeps one live instance, reset between
runs (``fmi2Reset``; gives the same results bit for bit as a fresh instance, see the tests);
after an initialisation failure (pythonfmu: fmi2Fatal) that instance is leaked, never called
again, and the next run gets a fresh one. The FMU is shipped by *path*: a remote cluster must
see the same path (and the project on its PYTHONPATH).

Which FMU: ``--fmu`` (harness.fmus.choose). One FMU runs the whole sweep: by default (``auto``)
the native RailCar (the C core, no Python, bit-identical rows) when the C core covers every
valid run's parameters, else the pythonfmu RailCar. The choice is printed, and the ``fmu``
column (last) of every row that ran says which kind ran it. A worker that finds a rebuilt
native FMU at the same path loads the new one (no Python modules are cached for it); a
rebuilt pythonfmu FMU still needs fresh worker processes.

Results: one row per run, appended to ``DIR/results.csv`` as runs finish (completion order,
units in the header cells ``name [unit]``), and to ``DIR/results.parquet`` when pyarrow is
importable (rewritten from the CSV every few seconds and at the end, so it is always a valid
file). ``read_results(DIR)`` returns the table sorted by run id. ``--resume`` skips the run ids
already in results.csv (ok or failed) if the sweep, its base scenario and the FMU build are
unchanged (``DIR/sweep.json``); without ``--resume``, a folder that holds results is refused
(SweepError) unless ``--overwrite`` says to start again. Seeds must be in the FMU's range,
0..2**31 - 1 (``seed`` is a 32-bit fmi2Integer). The embedded cluster's scratch space and its
workers' FMU extractions live in one temporary folder, removed when the sweep ends, also on an
error, Ctrl-C or SIGTERM (harness/sweep_folder.py).

List-valued metrics of ``RunSummary`` become two columns:
``NAME.max_abs`` (largest absolute value; nan when the list is empty or holds a nan) and
``NAME.list`` (the values, ';'-joined reprs). Tuples of A coefficients become ``A0_true`` ...
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (import before any FMU is loaded in this process)

import contextlib
import copy
import csv
import hashlib
import io
import itertools
import json
import math
import os
import re
import sys
import time
import tomllib
import uuid
from collections import Counter
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np
from fmpy import calloc, free
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)

from fmu_src.variables import RAILCAR, variables_for

from .runner import FmuRunner, RunError
from .scenario import (PATH_PARAMETERS, SEED_MAX, Scenario, ScenarioError, check_integer, parse_parameters,
                       read_toml, scenario_from_dict)
from .sweep_folder import check_rerun, clear_outputs, read_meta, scratch_folder, workers_ignore_ctrl_c
from .textio import check_out_dir, decode_text, read_text

PARAMETERS = {v.name: v for v in variables_for(RAILCAR) if v.causality == "parameter"}
SCENARIO_FIELDS = {"step_s": "s", "duration_s": "s", "stop_after_last_phase": ""}
WIND_KEYS = {"time_s": "s", "speed_mps": "m/s"}
_FIELD_RE = re.compile(r"^(driver|wind)\[(\d+)\]\.([A-Za-z_][A-Za-z0-9_]*)$")
_SUFFIX_UNITS = (("_mps2", "m/s2"), ("_mps", "m/s"), ("_kmh", "km/h"), ("_pct", "%"), ("_s", "s"),
                 ("_m", "m"), ("_N", "N"), ("_t", "t"))
TEXT_STATUS_OK, TEXT_STATUS_FAILED = "ok", "failed"
PARQUET_EVERY_S = 10.0


class SweepError(ScenarioError):
    """A sweep file that cannot run; the message names the file, the key and the reason."""


# ======================================================================== sweep file -> runs

@dataclass(frozen=True)
class RunSpec:
    """One run: its id, the swept values (name -> value), and its scenario or why it is invalid."""
    run_id: int
    values: tuple            # ((name, value), ...) in the sweep's column order
    scenario: Scenario | None
    error: str | None = None

    def label(self) -> str:
        return f"run {self.run_id} (" + ", ".join(f"{k}={v}" for k, v in self.values) + ")"


@dataclass(frozen=True)
class Sweep:
    name: str
    purpose: str
    path: Path
    base_path: Path
    axes: tuple              # swept names, in column order
    blocks: dict             # block name -> tuple of names ("grid", "zip", "lhs", "seeds")
    runs: tuple              # RunSpec, by run id
    fingerprint: str         # changes when the runs, the fixed values or the base scenario change

    @property
    def grid_axes(self) -> tuple:
        return self.blocks.get("grid", ())


def _where(path: Path, block: str, name: str | None = None) -> str:
    return f"{path}: {block}" + (f".\"{name}\"" if name is not None else "")


def _unit_from_suffix(name: str) -> str:
    for suffix, unit in _SUFFIX_UNITS:
        if name.endswith(suffix):
            return unit
    return ""


def name_unit(name: str) -> str:
    """Unit of a swept name (FMU parameter or scenario field), '' if none."""
    if name in PARAMETERS:
        u = PARAMETERS[name].unit
        return "" if u in ("", "–", "-") else u
    if name in SCENARIO_FIELDS:
        return SCENARIO_FIELDS[name]
    m = _FIELD_RE.match(name)
    return _unit_from_suffix(m.group(3)) if m else ""


def name_kind(name: str) -> str:
    """'float', 'int' or 'str': how a swept name's values are stored."""
    if name in PARAMETERS:
        return {"Real": "float", "Integer": "int"}.get(PARAMETERS[name].type, "str")
    if name in ("step_s", "duration_s"):
        return "float"
    if name == "stop_after_last_phase":
        return "str"
    m = _FIELD_RE.match(name)
    if m and (m.group(1) == "wind" or m.group(3) not in ("action", "until_brake_curve")):
        return "float"
    return "str"


def _check_value(name: str, value, path: Path, block: str, base: dict, sweep_dir: Path):
    """A swept or fixed value: check the name and the type; returns the typed value.

    FMU parameters go through harness.scenario.parse_parameters (types, profile paths resolved
    against the sweep file's folder); scenario fields are checked here, their values' ranges
    later, per run, by harness.scenario.scenario_from_dict."""
    where = _where(path, block, name)
    if name in PARAMETERS:
        return parse_parameters({name: value}, f"{path}: {block}", sweep_dir)[name]
    if name in ("step_s", "duration_s"):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SweepError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if name == "stop_after_last_phase":
        if not isinstance(value, bool):
            raise SweepError(f"{where}: expected true or false, got {value!r}")
        return value
    m = _FIELD_RE.match(name)
    if m is None:
        raise SweepError(f"{where}: not a RailCar parameter (see fmu_src/variables.py) nor a sweepable "
                         f"scenario field (step_s, duration_s, stop_after_last_phase, driver[i].KEY, "
                         f"wind[i].time_s, wind[i].speed_mps)")
    table, index, key = m.group(1), int(m.group(2)), m.group(3)
    entries = base.get(table, [])
    if index >= len(entries):
        raise SweepError(f"{where}: the base scenario has {len(entries)} [[{table}]] entries, no index {index}")
    if table == "driver":
        from .driver import _PHASE_KEYS
        if key not in _PHASE_KEYS:
            raise SweepError(f"{where}: '{key}' is not a driver phase key (known: {', '.join(sorted(_PHASE_KEYS))})")
    elif key not in WIND_KEYS:
        raise SweepError(f"{where}: '{key}' is not a wind key (known: {', '.join(WIND_KEYS)})")
    if name_kind(name) == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SweepError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if not isinstance(value, (str, bool)):
        raise SweepError(f"{where}: expected a string or true/false, got {value!r}")
    return value


def _axis_values(raw, where: str) -> list:
    """An axis: an explicit non-empty list, or {start, stop, num} (evenly spaced, ends included)."""
    if isinstance(raw, list):
        if not raw:
            raise SweepError(f"{where}: empty list of values")
        return raw
    if isinstance(raw, dict):
        unknown = set(raw) - {"start", "stop", "num"}
        if unknown or not {"start", "stop", "num"} <= set(raw):
            raise SweepError(f"{where}: a range needs exactly start, stop and num, got {sorted(raw)}")
        for k in ("start", "stop"):
            v = raw[k]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise SweepError(f"{where}.{k}: expected a finite number, got {v!r}")
        n = raw["num"]
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise SweepError(f"{where}.num: expected an integer >= 1, got {n!r}")
        return [float(x) for x in np.linspace(float(raw["start"]), float(raw["stop"]), n)]
    raise SweepError(f"{where}: expected a list of values or {{start, stop, num}}, got {raw!r}")


def latin_hypercube(bounds: dict[str, tuple[float, float]], samples: int, seed: int) -> list[dict]:
    """``samples`` points, uniform within ``bounds`` (name -> (low, high)), one per stratum per axis.

    scipy.stats.qmc.LatinHypercube (scrambled), seeded: the same arguments give the same points.
    """
    from scipy.stats import qmc
    names = list(bounds)
    try:
        engine = qmc.LatinHypercube(d=len(names), rng=np.random.default_rng(seed))
    except TypeError:                 # scipy < 1.15 calls it seed
        engine = qmc.LatinHypercube(d=len(names), seed=np.random.default_rng(seed))
    unit = engine.random(samples)
    lo = np.array([bounds[n][0] for n in names])
    hi = np.array([bounds[n][1] for n in names])
    pts = qmc.scale(unit, lo, hi)
    return [{n: float(p[j]) for j, n in enumerate(names)} for p in pts]


def _apply(data: dict, overrides: dict) -> dict:
    """A copy of the base scenario's TOML data with values set (FMU parameters already typed)."""
    data = copy.deepcopy(data)
    for name, value in overrides.items():
        if name in PARAMETERS:
            data.setdefault("parameters", {})[name] = value
        elif name in SCENARIO_FIELDS:
            data[name] = value
        else:
            m = _FIELD_RE.match(name)
            data[m.group(1)][int(m.group(2))][m.group(3)] = value
    return data


def load_sweep(path: str | Path) -> Sweep:
    """Read and validate a sweep file and build every run's scenario (or the reason it is invalid)."""
    path = Path(path)
    raw = read_toml(path, SweepError)
    try:
        return sweep_from_dict(raw, path)
    except SweepError:
        raise
    except ScenarioError as e:        # from harness.scenario.parse_parameters: same message
        raise SweepError(str(e)) from None


def _file_digest(path: str) -> str:
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return "unreadable"


def sweep_from_dict(raw: dict, path: Path) -> Sweep:
    known = {"name", "purpose", "scenario", "fixed", "grid", "zip", "lhs", "seeds"}
    for key in raw:
        if key not in known:
            raise SweepError(f"{path}: unknown key '{key}' (known: {', '.join(sorted(known))})")
    name = raw.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise SweepError(f"{path}: name: expected a non-empty string")
    purpose = raw.get("purpose", "")
    if not isinstance(purpose, str):
        raise SweepError(f"{path}: purpose: expected a string")
    sweep_dir = path.parent
    if not isinstance(raw.get("scenario"), str) or not raw["scenario"]:
        raise SweepError(f"{path}: scenario: give the base scenario file (relative to this file)")
    base_path = Path(raw["scenario"])
    if not base_path.is_absolute():
        base_path = sweep_dir / base_path
    try:
        base_text = decode_text(base_path.read_bytes(), f"{path}: scenario: {base_path}", SweepError)
        base = tomllib.loads(base_text)
    except OSError as e:
        raise SweepError(f"{path}: scenario: cannot read {base_path}: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise SweepError(f"{path}: scenario: {base_path} is not valid TOML: {e}") from None
    try:
        scenario_from_dict(base, str(base_path), base_path.parent)
    except ScenarioError as e:
        raise SweepError(f"{path}: scenario: the base scenario is invalid: {e}") from None

    def table(key):
        t = raw.get(key, {})
        if not isinstance(t, dict):
            raise SweepError(f"{path}: {key}: expected a table [{key}]")
        return t

    seen: dict[str, str] = {}

    def claim(name, block):
        if name in seen:
            raise SweepError(f"{_where(path, block, name)}: already set in [{seen[name]}]; a name may "
                             f"appear in one block only")
        seen[name] = block

    fixed = {}
    for n, v in table("fixed").items():
        claim(n, "fixed")
        fixed[n] = _check_value(n, v, path, "fixed", base, sweep_dir)

    blocks: dict[str, tuple] = {}
    point_sets: list[list[dict]] = []

    grid = table("grid")
    if grid:
        axes = []
        for n, v in grid.items():
            claim(n, "grid")
            where = _where(path, "grid", n)
            axes.append([(n, _check_value(n, x, path, "grid", base, sweep_dir)) for x in _axis_values(v, where)])
        blocks["grid"] = tuple(grid)
        point_sets.append([dict(p) for p in itertools.product(*axes)])

    zipped = table("zip")
    if zipped:
        cols, length = {}, None
        for n, v in zipped.items():
            claim(n, "zip")
            where = _where(path, "zip", n)
            if not isinstance(v, list) or not v:
                raise SweepError(f"{where}: expected a non-empty list of values")
            if length is not None and len(v) != length:
                raise SweepError(f"{where}: {len(v)} values, but the first [zip] list has {length}; "
                                 f"zipped lists must have equal lengths")
            length = len(v)
            cols[n] = [_check_value(n, x, path, "zip", base, sweep_dir) for x in v]
        blocks["zip"] = tuple(zipped)
        point_sets.append([{n: cols[n][k] for n in cols} for k in range(length)])

    lhs = table("lhs")
    if lhs:
        for key in lhs:
            if key not in ("samples", "seed", "bounds"):
                raise SweepError(f"{path}: lhs: unknown key '{key}' (known: bounds, samples, seed)")
        samples, seed = lhs.get("samples"), lhs.get("seed", 0)
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
            raise SweepError(f"{path}: lhs.samples: expected an integer >= 1, got {samples!r}")
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise SweepError(f"{path}: lhs.seed: expected an integer >= 0, got {seed!r}")
        bounds_raw = lhs.get("bounds")
        if not isinstance(bounds_raw, dict) or not bounds_raw:
            raise SweepError(f"{path}: lhs.bounds: give at least one \"name\" = [low, high]")
        bounds = {}
        for n, b in bounds_raw.items():
            claim(n, "lhs")
            where = _where(path, "lhs.bounds", n)
            if not isinstance(b, list) or len(b) != 2:
                raise SweepError(f"{where}: expected [low, high], got {b!r}")
            lo, hi = (_check_value(n, x, path, "lhs.bounds", base, sweep_dir) for x in b)
            if name_kind(n) != "float":
                raise SweepError(f"{where}: a Latin hypercube samples real values; {n} is not a real "
                                 f"number (sweep it in [grid] or [zip])")
            if not lo < hi:
                raise SweepError(f"{where}: low must be < high, got [{lo}, {hi}]")
            bounds[n] = (lo, hi)
        blocks["lhs"] = tuple(bounds)
        point_sets.append(latin_hypercube(bounds, samples, seed))

    if "seeds" in raw:
        s = raw["seeds"]
        where = f"{path}: seeds"
        if "seed" in seen:
            raise SweepError(f"{where}: seed is already set in [{seen['seed']}]; give seeds or a seed, not both")
        if isinstance(s, bool):
            raise SweepError(f"{where}: expected a count >= 1 or a list of integers, got {s!r}")
        if isinstance(s, int):
            if s < 1:
                raise SweepError(f"{where}: expected a count >= 1, got {s}")
            if s > SEED_MAX:
                raise SweepError(f"{where}: a count must be <= {SEED_MAX}: the seeds 1..count must be in "
                                 f"0..{SEED_MAX} (the FMU's seed is a 32-bit fmi2Integer), got {s}")
            seeds = list(range(1, s + 1))
        elif isinstance(s, list) and s:
            if any(isinstance(x, bool) or not isinstance(x, int) for x in s):
                raise SweepError(f"{where}: expected a list of integers, got {s!r}")
            for i, x in enumerate(s):
                check_integer("seed", x, f"{where}[{i}]", SweepError)
            if len(set(s)) != len(s):
                raise SweepError(f"{where}: repeated seeds in {s!r}")
            seeds = list(s)
        else:
            raise SweepError(f"{where}: expected a count >= 1 or a non-empty list of integers, got {s!r}")
        seen["seed"] = "seeds"
        blocks["seeds"] = ("seed",)
        point_sets.append([{"seed": x} for x in seeds])

    if not point_sets:
        raise SweepError(f"{path}: nothing to sweep: add [grid], [zip], [lhs] or seeds")
    axes = tuple(n for b in ("grid", "zip", "lhs", "seeds") for n in blocks.get(b, ()))
    runs = []
    for run_id, combo in enumerate(itertools.product(*point_sets)):
        values = {}
        for part in combo:
            values.update(part)
        ordered = tuple((n, values[n]) for n in axes)
        data = _apply(base, {**fixed, **values})
        try:
            sc = scenario_from_dict(data, str(base_path), base_path.parent)
            runs.append(RunSpec(run_id, ordered, sc))
        except ScenarioError as e:
            runs.append(RunSpec(run_id, ordered, None, f"invalid scenario: {e}"))
    files = {str(base_path.parent / base["driver_table"]["file"])} if isinstance(base.get("driver_table"), dict) \
        and isinstance(base["driver_table"].get("file"), str) else set()
    for r in runs:                      # profiles the runs read: their contents count too
        if r.scenario is not None:
            files |= {r.scenario.parameter(n) for n in PATH_PARAMETERS if r.scenario.parameter(n)}
    fp = hashlib.sha256(json.dumps({"base": base_text, "fixed": fixed,
                                    "files": {f: _file_digest(f) for f in sorted(files)},
                                    "runs": [[r.run_id, [list(v) for v in r.values]] for r in runs]},
                                   sort_keys=True, default=repr).encode()).hexdigest()
    return Sweep(name=name, purpose=purpose, path=path, base_path=base_path, axes=axes, blocks=blocks,
                 runs=tuple(runs), fingerprint=fp)


# ======================================================================== result columns

@dataclass(frozen=True)
class Column:
    key: str
    unit: str          # '' for text and ids; '-' for dimensionless numbers
    kind: str          # 'int', 'float' or 'str'

    @property
    def header(self) -> str:
        return f"{self.key} [{self.unit}]" if self.unit else self.key


_METRIC_UNITS = {"duration_s": "s", "stops": "-", "mass_true_t": "t", "mass_est_t": "t", "mass_std_t": "t",
                 "mass_error_pct": "%", "mass_errors_at_stops_pct": "%", "mass_time_within_1pct_s": "s",
                 "w0_rel_rms_error": "-", "coast_time_errors_s": "s", "speed_nees": "-",
                 "position_nees": "-"}
_A_UNITS = ("N/kN", "N/kN/(m/s)", "N/kN/(m/s)2")
CALIBRATION_COLUMNS = (
    Column("mass_stops_covered", "-", "int"),          # arrivals with |est.mass - truth| <= 2 est.mass_std
    Column("mass_z_at_stops.max_abs", "-", "float"),   # (est.mass - truth) / est.mass_std at each arrival
    Column("mass_z_at_stops.list", "-", "str"),
    Column("moving_samples", "-", "int"),              # rows with car.speed > 0
    Column("speed_within_2sigma", "-", "int"),         # ... of them with |filter.speed - car.speed| <= 2 std
    Column("position_within_2sigma", "-", "int"),
    Column("speed_within_2sigma_pct", "%", "float"),
    Column("position_within_2sigma_pct", "%", "float"),
)


def _metric_unit(name: str) -> str:
    if name in _METRIC_UNITS:
        return _METRIC_UNITS[name]
    if name.startswith("speed_"):
        return "m/s"
    if name.startswith("position_"):
        return "m"
    return _unit_from_suffix(name) or "-"


def metric_columns() -> list[Column]:
    """Columns of a flattened RunSummary (derived from its fields and their annotations)."""
    from .metrics import RunSummary
    cols = []
    for f in fields(RunSummary):
        ann = str(f.type)
        if f.name == "scenario":
            continue
        if f.name in ("A_true", "A_est"):
            suffix = f.name[2:]
            cols += [Column(f"A{i}_{suffix}", _A_UNITS[i], "float") for i in range(3)]
        elif ann.startswith(("list", "tuple")):
            unit = _metric_unit(f.name)
            cols += [Column(f"{f.name}.max_abs", unit, "float"), Column(f"{f.name}.list", unit, "str")]
        elif ann == "int" or f.name == "stops":
            cols.append(Column(f.name, _metric_unit(f.name), "int"))
        elif ann == "str":
            cols.append(Column(f.name, "", "str"))
        else:
            cols.append(Column(f.name, _metric_unit(f.name), "float"))
    return cols


FMU_COLUMN = Column("fmu", "", "str")          # which FMU ran the row: native, python ('' none ran)


def sweep_columns(sweep: Sweep) -> list[Column]:
    cols = [Column("run_id", "", "int"), Column("status", "", "str"), Column("error", "", "str"),
            Column("wall_time", "s", "float")]
    cols += [Column(n, name_unit(n) or ("-" if name_kind(n) != "str" else ""), name_kind(n)) for n in sweep.axes]
    if "seed" not in sweep.axes:
        cols.append(Column("seed", "-", "int"))
    return cols + metric_columns() + list(CALIBRATION_COLUMNS) + [FMU_COLUMN]


def _max_abs(xs) -> float:
    if not xs:
        return float("nan")
    a = [abs(float(x)) for x in xs]
    return float("nan") if any(math.isnan(x) for x in a) else max(a)


def _joined(xs) -> str:
    return ";".join(repr(float(x)) for x in xs)


def flatten_summary(summary) -> dict:
    """RunSummary -> scalars (see the module docstring: lists -> .max_abs and .list)."""
    out = {}
    for f in fields(summary):
        v = getattr(summary, f.name)
        if f.name == "scenario":
            continue
        if f.name in ("A_true", "A_est"):
            for i, x in enumerate(v):
                out[f"A{i}_{f.name[2:]}"] = float(x)
        elif isinstance(v, (list, tuple)):
            out[f"{f.name}.max_abs"] = _max_abs(v)
            out[f"{f.name}.list"] = _joined(v)
        elif isinstance(v, (bool, str)):
            out[f.name] = v
        elif isinstance(v, (int, np.integer)):
            out[f.name] = int(v)
        else:
            out[f.name] = float(v)
    return out


def calibration(result) -> dict:
    """Is the truth inside the estimator's and the filter's +-2 sigma? Counts for one run.

    Mass: at the arrival at each stop (harness.metrics.stop_indices, before passengers board),
    |est.mass - car.total_mass| <= 2 est.mass_std. Filter: over the moving rows (car.speed > 0),
    |filter.speed - car.speed| <= 2 filter.speed_std, and the same for the distance.
    """
    from .metrics import stop_indices
    v = result["car.speed"]
    stops = stop_indices(v)
    err = result["est.mass"] - result["car.total_mass"]
    std = result["est.mass_std"]
    z = [float(err[k] / std[k]) if std[k] > 0 else (0.0 if err[k] == 0 else math.copysign(math.inf, err[k]))
         for k in stops]
    moving = v > 0.0
    n = int(moving.sum())
    sv = np.abs(result["filter.speed"] - v) <= 2.0 * result["filter.speed_std"]
    sx = np.abs(result["filter.position"] - result["car.position"]) <= 2.0 * result["filter.position_std"]
    nv, nx = int((sv & moving).sum()), int((sx & moving).sum())
    return {"mass_stops_covered": int(sum(abs(err[k]) <= 2.0 * std[k] for k in stops)),
            "mass_z_at_stops.max_abs": _max_abs(z), "mass_z_at_stops.list": _joined(z),
            "moving_samples": n, "speed_within_2sigma": nv, "position_within_2sigma": nx,
            "speed_within_2sigma_pct": 100.0 * nv / n if n else float("nan"),
            "position_within_2sigma_pct": 100.0 * nx / n if n else float("nan")}


# ======================================================================== the worker side

_LEAKED: list = []            # instances after fmi2Fatal: FMI allows no further call (pythonfmu segfaults)
_WORKER_FMUS: dict = {}       # per process: FMU path -> ReusableRunner (one extraction, one live instance)
FATAL = 4


class _Lease:
    """The live instance lent to one FmuRunner.run: freeInstance() hands it back instead of freeing."""

    def __init__(self, fmu, owner: "ReusableRunner"):
        self._fmu, self._owner, self.fatal = fmu, owner, False

    def __getattr__(self, name):
        attr = getattr(self._fmu, name)
        if name in ("doStep", "terminate", "exitInitializationMode"):
            def call(*a, **k):
                try:
                    return attr(*a, **k)
                except Exception as e:
                    if getattr(e, "status", FATAL) >= FATAL:
                        self.fatal = True
                    raise
            return call
        setattr(self, name, attr)          # cache plain forwards (getReal, setReal, ...)
        return attr

    def freeInstance(self):
        self._owner._give_back(self._fmu, self.fatal)


class ReusableRunner(FmuRunner):
    """An FmuRunner whose runs share one live FMU instance, reset between runs.

    ``run(scenario)`` is FmuRunner.run (same stepping, same results); only the instance's life
    cycle differs: instantiate once, then fmi2Reset before each later run. An instance whose
    initialisation failed (pythonfmu reports fmi2Fatal) is leaked and replaced by a fresh one.
    """

    def __init__(self, fmu_path, unzip_root=None):
        super().__init__(fmu_path, unzip_root)
        self.live = None                  # the instance kept between runs
        self.sink: list[str] = []         # the current run's log
        self.counts = Counter()           # instantiate / reset / leaked

    def _instantiate(self, log):
        self.counts["instantiate"] += 1      # messages go into the current run's log
        return self._new_instance(lambda: self.sink,
                                  f"{self.md.modelName}_{os.getpid()}_{self.counts['instantiate']}")

    def start(self, parameters, stop_time, log, what):
        """The live instance reset (or a new one), initialised with ``parameters``; RunError if that fails."""
        self.sink = log
        fmu, self.live = self.live, None
        if fmu is not None:
            try:
                fmu.reset()
                self.counts["reset"] += 1
            except Exception:
                _LEAKED.append(fmu)
                self.counts["leaked"] += 1
                fmu = None
        if fmu is None:
            fmu = self._instantiate(log)
        try:
            self.initialise(fmu, parameters, stop_time, log, what)
        except RunError:
            _LEAKED.append(fmu)               # fmi2Fatal: never call this instance again
            self.counts["leaked"] += 1
            raise
        return _Lease(fmu, self)

    def _give_back(self, fmu, fatal: bool) -> None:
        if fatal:
            _LEAKED.append(fmu)
            self.counts["leaked"] += 1
        else:
            self.live = fmu

    def close(self) -> None:
        fmu, self.live = self.live, None
        if fmu is not None:
            for call in (fmu.terminate, fmu.freeInstance):
                try:
                    call()
                except Exception:
                    pass
        super().close()


def worker_runner(fmu_path: str, guid: str | None = None, extract_root: str | None = None):
    """This process's runner of ``fmu_path`` (extracted once, below ``extract_root`` if given);
    checks it is the build expected. A native FMU rebuilt at the same path replaces the old one
    (a fresh extraction, its own shared library); a pythonfmu one cannot (its Python modules are
    cached in the process)."""
    runner = _WORKER_FMUS.get(fmu_path)
    if runner is not None and guid is not None and runner.md.guid != guid and runner.kind == "native":
        _WORKER_FMUS.pop(fmu_path).close()
        runner = None
    if runner is None:
        runner = _WORKER_FMUS[fmu_path] = ReusableRunner(fmu_path, extract_root)
    if guid is not None and runner.md.guid != guid:
        raise RuntimeError(f"this worker process (pid {os.getpid()}) already loaded another build of "
                           f"{fmu_path} (GUID {runner.md.guid}, wanted {guid}); a process caches the FMU's "
                           f"Python modules: restart the workers")
    return runner


def _one_line(text: str, limit: int = 600) -> str:
    s = " | ".join(line.strip() for line in str(text).splitlines() if line.strip())
    return s if len(s) <= limit else s[:limit - 3] + "..."


def base_row(spec: RunSpec) -> dict:
    row = {"run_id": spec.run_id, **dict(spec.values)}
    if spec.scenario is not None:
        row["seed"] = spec.scenario.parameter("seed")
    elif "seed" not in row:
        row["seed"] = None
    return row


def execute_run(fmu_path: str, guid: str | None, spec: RunSpec, extract_root: str | None = None) -> dict:
    """Run one sweep point in this (worker) process; never raises: a failure is a row. The FMU is
    extracted below ``extract_root`` (the embedded cluster's scratch folder, removed at its end)
    or, by default, in the system's temporary folder for the worker process's life."""
    from .metrics import summarise
    row = base_row(spec)
    t0 = time.perf_counter()
    if spec.error is not None:
        row.update(status=TEXT_STATUS_FAILED, error=_one_line(spec.error), wall_time=0.0)
        return row
    try:
        runner = worker_runner(fmu_path, guid, extract_root)
        row["fmu"] = runner.kind
        result = runner.run(spec.scenario)
    except RunError as e:
        row.update(status=TEXT_STATUS_FAILED, error=_one_line(e))
    except Exception as e:
        row.update(status=TEXT_STATUS_FAILED, error=_one_line(f"{type(e).__name__}: {e}"))
    else:
        try:
            row.update(flatten_summary(summarise(result)))
            row.update(calibration(result))
            row.update(status=TEXT_STATUS_OK, error="")
        except Exception as e:
            row.update(status=TEXT_STATUS_FAILED, error=_one_line(f"metrics: {type(e).__name__}: {e}"))
    row["wall_time"] = time.perf_counter() - t0
    return row


def worker_check(fmu_path: str) -> dict:
    """Run on every worker before a sweep: can it import the harness and read the FMU path?"""
    import threading
    return {"pid": os.getpid(), "fmu_readable": os.access(fmu_path, os.R_OK),
            "harness": str(Path(__file__).resolve().parent), "threads": threading.active_count()}


# ======================================================================== the results table

def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return repr(float(value))
    return str(value)


def _parse(text: str, kind: str):
    if text == "":
        return None if kind != "str" else ""
    if kind == "int":
        return int(text)
    if kind == "float":
        return float(text)
    return text


@dataclass
class Table:
    """Rows of a sweep's results (dicts keyed by column key), typed by the columns."""
    columns: list[Column]
    rows: list[dict] = field(default_factory=list)

    def column(self, key: str) -> list:
        return [r.get(key) for r in self.rows]

    def comparable(self, exclude=("wall_time",)) -> list[tuple]:
        """Rows as tuples of exact cell texts (floats by repr), for bit-for-bit comparisons."""
        keys = [c.key for c in self.columns if c.key not in exclude]
        return [tuple(_cell(r.get(k)) for k in keys) for r in self.rows]


def _columns_from_json(meta: dict) -> list[Column]:
    return [Column(*c) for c in meta["columns"]]


def read_results(out_dir: str | Path, sort: bool = True) -> Table:
    """The results of a sweep folder (results.csv + sweep.json), sorted by run id (or as written)."""
    out_dir = Path(out_dir)
    meta = read_meta(out_dir / "sweep.json", SweepError)
    cols = _columns_from_json(meta)
    rows = _read_csv_rows(out_dir / "results.csv", cols)
    if sort:
        rows.sort(key=lambda r: r["run_id"])
    return Table(cols, rows)


def _read_csv_rows(path: Path, cols: list[Column]) -> list[dict]:
    """Well-formed rows of results.csv (a line cut short by an interruption is dropped)."""
    if not path.is_file():
        return []
    text = read_text(path, SweepError)
    rows = []
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header != [c.header for c in cols]:
        raise SweepError(f"{path}: header does not match the sweep's columns")
    complete = text.endswith("\n")
    lines = list(reader)
    for i, cells in enumerate(lines):
        if len(cells) != len(cols) or (i == len(lines) - 1 and not complete):
            continue
        try:
            rows.append({c.key: _parse(x, c.kind) for c, x in zip(cols, cells)})
        except ValueError:
            continue
    return rows


class ResultsWriter:
    """Appends rows to DIR/results.csv as they come (deduplicated by run id), Parquet alongside."""

    def __init__(self, out_dir: Path, sweep: Sweep, fmu_guid: str | None, resume: bool, overwrite: bool = False,
                 fmu_kind: str | None = None):
        self.out_dir = out_dir
        self.fmu_kind = fmu_kind
        self.cols = sweep_columns(sweep)
        self.csv_path = out_dir / "results.csv"
        self.parquet_path = out_dir / "results.parquet"
        meta_path = out_dir / "sweep.json"
        meta = {"sweep": str(sweep.path.resolve()), "name": sweep.name, "fingerprint": sweep.fingerprint,
                "fmu_guid": fmu_guid, "fmu_kind": fmu_kind, "runs": len(sweep.runs),
                "columns": [[c.key, c.unit, c.kind] for c in self.cols]}
        out_dir.mkdir(parents=True, exist_ok=True)
        self._lock = _lock_folder(out_dir)
        try:
            rows = self._previous_rows(sweep, fmu_guid, resume, overwrite)
        except BaseException:
            self._unlock()
            raise
        meta_path.write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
        self.rows = rows
        self.done = {r["run_id"] for r in rows}
        tmp = self.csv_path.with_suffix(".csv.tmp")       # a clean file: header + the complete rows kept
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow([c.header for c in self.cols])
            for r in rows:
                w.writerow([_cell(r.get(c.key)) for c in self.cols])
        os.replace(tmp, self.csv_path)
        self._f = open(self.csv_path, "a", newline="", encoding="utf-8")
        self._w = csv.writer(self._f)
        self._last_parquet = time.monotonic()
        self.resumed = len(rows)

    def _previous_rows(self, sweep: Sweep, fmu_guid, resume: bool, overwrite: bool) -> list[dict]:
        """The rows kept from an earlier call (--resume); a folder that holds results is refused
        without --resume or --overwrite (its rows would be discarded silently)."""
        old = check_rerun(self.out_dir, sweep.fingerprint, resume, overwrite, SweepError)
        if overwrite:
            clear_outputs(self.out_dir)
            return []
        if not resume or not old:
            return []
        if old.get("fingerprint") != sweep.fingerprint:
            raise SweepError(f"{self.out_dir}: --resume: the results there are of another sweep (its runs, "
                             f"fixed values or base scenario differ); use another --out or drop --resume")
        if old.get("fmu_kind") and self.fmu_kind and old["fmu_kind"] != self.fmu_kind:
            raise SweepError(f"{self.out_dir}: --resume: the results there ran on the {old['fmu_kind']} FMU, this "
                             f"call would run the {self.fmu_kind} one; give --fmu {old['fmu_kind']} to continue, "
                             f"or use another --out")
        if old.get("fmu_guid") != fmu_guid:
            raise SweepError(f"{self.out_dir}: --resume: the FMU was rebuilt since (GUID {old.get('fmu_guid')} "
                             f"-> {fmu_guid}); rows of two builds would mix: use another --out or drop --resume")
        seen, kept = set(), []
        for r in _read_csv_rows(self.csv_path, self.cols):      # the first row of a run id wins
            if r["run_id"] not in seen:
                seen.add(r["run_id"])
                kept.append(r)
        return kept

    def _unlock(self) -> None:
        if self._lock is not None:
            self._lock.close()            # releases the lock
            self._lock = None

    def write(self, row: dict) -> bool:
        """Append a row unless its run id is already there; False for a duplicate."""
        if row["run_id"] in self.done:
            return False
        self.done.add(row["run_id"])
        cells = [_cell(row.get(c.key)) for c in self.cols]
        self._w.writerow(cells)
        self._f.flush()
        self.rows.append({c.key: _parse(x, c.kind) for c, x in zip(self.cols, cells)})
        if time.monotonic() - self._last_parquet > PARQUET_EVERY_S:
            self.write_parquet()
        return True

    def write_parquet(self) -> Path | None:
        self._last_parquet = time.monotonic()
        return write_parquet(Table(self.cols, self.rows), self.parquet_path)

    def close(self) -> None:
        if not self._f.closed:
            self._f.close()
        self.write_parquet()
        self._unlock()


def _lock_folder(out_dir: Path):
    """An exclusive lock on DIR/sweep.lock for the sweep's life: two sweeps writing one folder
    would lose rows (a --resume rewrites results.csv). None where fcntl is missing (Windows)."""
    try:
        import fcntl
    except ImportError:
        return None
    f = open(out_dir / "sweep.lock", "a+", encoding="utf-8")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.seek(0)
        holder = f.read().strip()
        f.close()
        raise SweepError(f"{out_dir}: another sweep is writing there ({holder or 'unknown process'}); "
                         f"wait for it or use another --out") from None
    f.seek(0)
    f.truncate()
    f.write(f"pid {os.getpid()}\n")
    f.flush()
    return f


def write_parquet(table: Table, path: Path) -> Path | None:
    """The table as Parquet (units in each field's metadata); None when pyarrow is missing."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    types = {"int": pa.int64(), "float": pa.float64(), "str": pa.string()}
    arrays, schema = [], []
    for c in table.columns:
        arrays.append(pa.array([r.get(c.key) for r in table.rows], type=types[c.kind]))
        schema.append(pa.field(c.key, types[c.kind], metadata={"unit": c.unit}))
    tmp = path.with_suffix(".parquet.tmp")
    pq.write_table(pa.Table.from_arrays(arrays, schema=pa.schema(schema)), tmp)
    os.replace(tmp, path)
    return path


# ======================================================================== running a sweep

@dataclass
class SweepOutcome:
    table: Table                 # every row in DIR, sorted by run id
    ran: int                     # runs executed by this call
    resumed: int                 # rows kept from an earlier call (--resume)
    missing: list                # run ids with no row (interrupted, --limit)
    wall_s: float
    workers: int
    files: list = field(default_factory=list)
    fmu: str = ""                # which FMU ran and why (harness.fmus.FmuChoice.describe)


class _Progress:
    """harness.progress.Progress (runs done/failed, ETA) on a terminal; else a line every 10 %
    of the runs (at most one per 5 s, and the last)."""

    def __init__(self, total: int, label: str, enabled: bool | None):
        from .progress import Progress
        self.bar = Progress(total, label, enabled)
        self.lines = enabled is None and not self.bar.enabled
        self.next_share, self.last_line = 0.1, 0.0

    def advance(self, what: str, failed: bool) -> None:
        self.bar.advance(what, failed)
        b = self.bar
        if not self.lines or not b.total:
            return
        now = time.monotonic()
        if b.done == b.total or (b.done / b.total >= self.next_share and now - self.last_line >= 5.0):
            self.next_share = b.done / b.total + 0.1
            self.last_line = now
            elapsed = now - b.t0
            eta = elapsed / b.done * (b.total - b.done)
            print(f"  {b.done}/{b.total} runs, {b.failed} failed, {elapsed:.0f} s, ETA {eta:.0f} s", flush=True)


def run_sweep(sweep: Sweep, out_dir: str | Path, fmu_path: str | Path, scheduler: str | None = None,
              workers: int | None = None, resume: bool = False, limit: int | None = None,
              progress: bool | None = None, plots: bool = True, client=None, log=print,
              overwrite: bool = False, fmu_note: str = "") -> SweepOutcome:
    """Run the sweep's runs (those not in DIR yet with ``resume``; the first ``limit`` of them).
    A DIR that holds results is refused (SweepError) unless ``resume`` or ``overwrite``.

    Runs on ``client`` if given, else on the dask scheduler at ``scheduler``, else on a
    LocalCluster of ``workers`` (default: one per core) single-threaded worker processes whose
    scratch space and FMU extractions are in one temporary folder, removed when the sweep ends.
    ``fmu_path`` is either kind of RailCar FMU (harness.fmus); ``fmu_note`` says which and why,
    for the summary (default: its kind and path).
    """
    from fmpy import read_model_description
    from .fmus import fmu_guid, is_native
    out_dir = Path(out_dir)
    fmu_path = Path(fmu_path).resolve()
    if not fmu_path.is_file():
        raise FileNotFoundError(f"FMU not found: {fmu_path}")
    guid = fmu_guid(fmu_path)
    kind = "native" if is_native(read_model_description(str(fmu_path))) else "python"
    writer = ResultsWriter(out_dir, sweep, guid, resume, overwrite, fmu_kind=kind)
    todo = [s for s in sweep.runs if s.run_id not in writer.done]
    if limit is not None:
        todo = todo[:limit]
    t0 = time.monotonic()
    bar = _Progress(len(todo), f"sweep {sweep.name}", progress)
    ran = 0
    own_cluster = own_client = extract_root = None
    n_workers = 0
    scratch = contextlib.ExitStack()         # closed last: after the cluster's worker processes ended
    try:
        for spec in [s for s in todo if s.error is not None]:        # invalid scenarios: rows now
            writer.write(execute_run(str(fmu_path), guid, spec))
            bar.advance(f"run {spec.run_id}", failed=True)
            ran += 1
        valid = [s for s in todo if s.error is None]
        if valid:
            from distributed import Client, LocalCluster
            if client is None:
                if scheduler:
                    client = own_client = Client(scheduler, timeout="30s")
                else:
                    import logging
                    extract_root = scratch.enter_context(scratch_folder())
                    with workers_ignore_ctrl_c():
                        own_cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                                   processes=True, dashboard_address=None, host="127.0.0.1",
                                                   silence_logs=logging.ERROR, local_directory=extract_root,
                                                   scheduler_kwargs={"local_directory": extract_root})
                    client = own_client = Client(own_cluster)
            n_workers = _check_workers(client, fmu_path, log)
            ran += _execute(client, sweep, valid, str(fmu_path), guid, writer, bar, extract_root)
    finally:
        with scratch:
            writer.close()
            if own_client is not None:
                own_client.close()
            if own_cluster is not None:
                own_cluster.close()
    table = read_results(out_dir)
    done = {r["run_id"] for r in table.rows}
    outcome = SweepOutcome(table=table, ran=ran, resumed=writer.resumed,
                           missing=[s.run_id for s in sweep.runs if s.run_id not in done],
                           wall_s=time.monotonic() - t0, workers=n_workers, fmu=fmu_note or f"{kind} {fmu_path}")
    outcome.files = [out_dir / "results.csv"] + ([writer.parquet_path] if writer.parquet_path.is_file() else [])
    text = format_sweep_summary(sweep, outcome)
    (out_dir / "summary.md").write_text(f"# Sweep: {sweep.name}\n\n{sweep.purpose}\n\n```\n{text}\n```\n",
                                        encoding="utf-8")
    outcome.files.append(out_dir / "summary.md")
    if plots:
        outcome.files += plot_sweep(sweep, table, out_dir / "plots")
    return outcome


def _check_workers(client, fmu_path: Path, log) -> int:
    info = client.scheduler_info()
    if not info.get("workers"):
        client.wait_for_workers(1, timeout=60)
    checks = client.run(worker_check, str(fmu_path), on_error="return")
    bad = {w: r for w, r in checks.items() if isinstance(r, BaseException)}
    if bad:
        w, e = next(iter(bad.items()))
        raise RuntimeError(f"{len(bad)} dask worker(s) cannot run the harness (e.g. {w}: {type(e).__name__}: {e}); "
                           f"start them from the project folder or with the project on PYTHONPATH")
    unreadable = [w for w, r in checks.items() if not r["fmu_readable"]]
    if unreadable:
        raise RuntimeError(f"{len(unreadable)} dask worker(s) cannot read {fmu_path} (e.g. {unreadable[0]}); "
                           f"the FMU is shipped by path: it must be reachable at that path on every worker")
    threads = {w: n for w, n in client.nthreads().items() if n > 1}
    if threads:
        log(f"warning: {len(threads)} worker(s) run {max(threads.values())} threads: every FMU call takes "
            f"the GIL, so only one thread per worker is useful (dask worker --nthreads 1)")
    return len(checks)


def _execute(client, sweep: Sweep, specs: list[RunSpec], fmu_path: str, guid, writer: ResultsWriter, bar,
             extract_root: str | None = None) -> int:
    from distributed import as_completed
    nonce = uuid.uuid4().hex[:8]
    futures = {}
    for spec in specs:
        f = client.submit(execute_run, fmu_path, guid, spec, extract_root, pure=False, retries=2,
                          key=f"railcar-sweep-{sweep.fingerprint[:8]}-{nonce}-{spec.run_id}")
        futures[f.key] = (f, spec)
    ran = 0
    try:
        # with_results: results come in batches with the completions (no round trip per run)
        for f, result in as_completed([f for f, _ in futures.values()], with_results=True, raise_errors=False):
            _, spec = futures.pop(f.key)
            if isinstance(result, dict):
                row = result
            else:                    # an exception: KilledWorker (the run killed its worker every time), ...
                row = base_row(spec)
                row.update(status=TEXT_STATUS_FAILED, wall_time=None,
                           error=_one_line(f"dask: {type(result).__name__}: {result}"))
            f.release()
            if writer.write(row):
                ran += 1
                bar.advance(f"run {spec.run_id}", failed=row["status"] != TEXT_STATUS_OK)
    finally:
        for f, _ in futures.values():
            f.cancel()
    return ran


# ======================================================================== summary and plots

def _finite(xs) -> list[float]:
    return [float(x) for x in xs if x is not None and not isinstance(x, str) and math.isfinite(x)]


def coverage(table: Table) -> dict:
    """Pooled calibration over the ok rows: percentage of stops / moving samples inside +-2 sigma."""
    ok = [r for r in table.rows if r.get("status") == TEXT_STATUS_OK]
    stops = sum(r.get("stops") or 0 for r in ok)
    covered = sum(r.get("mass_stops_covered") or 0 for r in ok)
    n = sum(r.get("moving_samples") or 0 for r in ok)
    nv = sum(r.get("speed_within_2sigma") or 0 for r in ok)
    nx = sum(r.get("position_within_2sigma") or 0 for r in ok)
    nan = float("nan")
    return {"runs": len(ok), "stops": stops, "moving_samples": n,
            "mass_pct": 100.0 * covered / stops if stops else nan,
            "speed_pct": 100.0 * nv / n if n else nan,
            "position_pct": 100.0 * nx / n if n else nan}


SUMMARY_METRICS = ("mass_error_pct", "mass_errors_at_stops_pct.max_abs", "mass_time_within_1pct_s.max_abs",
                   "mass_std_t", "w0_rel_rms_error", "coast_time_errors_s.max_abs", "speed_rmse_sensor",
                   "speed_rmse_filter", "position_rmse_sensor", "position_rmse_filter", "speed_nees",
                   "position_nees")


def format_sweep_summary(sweep: Sweep, o: SweepOutcome) -> str:
    t = o.table
    ok = [r for r in t.rows if r["status"] == TEXT_STATUS_OK]
    failed = [r for r in t.rows if r["status"] != TEXT_STATUS_OK]
    units = {c.key: c.unit for c in t.columns}
    lines = [f"sweep '{sweep.name}' on {sweep.base_path.name}: {len(sweep.runs)} runs over "
             f"{', '.join(sweep.axes)}",
             f"  rows {len(t.rows)}: {len(ok)} ok, {len(failed)} failed; this call ran {o.ran} in {o.wall_s:.1f} s"
             + (f" ({o.ran / o.wall_s:.2f} runs/s on {o.workers} workers)" if o.ran and o.wall_s > 0 and o.workers else "")
             + (f"; {o.resumed} rows kept from before (--resume)" if o.resumed else "")]
    if o.fmu:
        lines.append(f"  fmu: {o.fmu}")
    if o.missing:
        lines.append(f"  not run yet: {len(o.missing)} runs (first ids {', '.join(map(str, o.missing[:5]))}); "
                     f"--resume continues")
    if ok:
        lines.append("")
        w = max(len(m) for m in SUMMARY_METRICS) + 6
        lines.append(f"  {'metric (over the ok runs)':<{w}} {'min':>10} {'median':>10} {'max':>10}")
        for m in SUMMARY_METRICS:
            xs = _finite(r.get(m) for r in ok)
            label = f"{m} [{units.get(m, '-')}]"
            if xs:
                lines.append(f"  {label:<{w}} {min(xs):>10.4g} {float(np.median(xs)):>10.4g} {max(xs):>10.4g}")
            else:
                lines.append(f"  {label:<{w}} {'n/a':>10}")
        c = coverage(t)
        lines += ["", "  calibration: truth inside the estimate +- 2 sigma (95.4 % for honest Gaussian errors)",
                  f"    mass at the arrival at each stop    {_pct(c['mass_pct'])} of {c['stops']} stops",
                  f"    filter speed (moving samples)       {_pct(c['speed_pct'])} of {c['moving_samples']} samples",
                  f"    filter distance (moving samples)    {_pct(c['position_pct'])} of {c['moving_samples']} samples"]
    if failed:
        lines += ["", "  failures (by message):"]
        for msg, n in Counter(r.get("error") or "?" for r in failed).most_common(5):
            ids = [str(r["run_id"]) for r in failed if (r.get("error") or "?") == msg][:5]
            lines.append(f"    {n} x (runs {', '.join(ids)}{', ...' if n > 5 else ''}): {msg[:300]}")
    return "\n".join(lines)


def _pct(x: float) -> str:
    return "  n/a " if math.isnan(x) else f"{x:5.1f} %"


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def _plot_metrics(table: Table) -> list[Column]:
    """Numeric metric columns that vary over the ok runs."""
    ok = [r for r in table.rows if r["status"] == TEXT_STATUS_OK]
    keys = {c.key for c in metric_columns()} | {c.key for c in CALIBRATION_COLUMNS}
    skip = {"moving_samples", "speed_within_2sigma", "position_within_2sigma", "duration_s"}
    out = []
    for c in table.columns:
        if c.kind == "str" or c.key not in keys or c.key in skip:
            continue
        xs = _finite(r.get(c.key) for r in ok)
        if xs and max(xs) > min(xs):
            out.append(c)
    return out


def plot_sweep(sweep: Sweep, table: Table, plot_dir: Path) -> list[Path]:
    """Each metric against each swept value (and heat maps of a two-axis grid) as PNGs."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plot_dir.mkdir(parents=True, exist_ok=True)
    ok = [r for r in table.rows if r["status"] == TEXT_STATUS_OK]
    metrics = _plot_metrics(table)
    if not ok or not metrics:
        return []
    units = {c.key: c.unit for c in table.columns}
    kinds = {c.key: c.kind for c in table.columns}
    files = []
    ncol = min(5, len(metrics))
    nrow = math.ceil(len(metrics) / ncol)

    def grid_fig():
        fig, axs = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 2.6 * nrow), squeeze=False)
        for ax in axs.flat[len(metrics):]:
            ax.set_visible(False)
        return fig, axs.flat

    def save(fig, name):
        fig.tight_layout()
        p = plot_dir / name
        fig.savefig(p, dpi=90)
        plt.close(fig)
        files.append(p)

    xs_names = [n for n in sweep.axes if n != "seed" and kinds.get(n) != "str"
                and len({r.get(n) for r in ok}) > 1]
    for xn in xs_names:
        fig, axs = grid_fig()
        for ax, m in zip(axs, metrics):
            pts = [(r[xn], r[m.key]) for r in ok if r.get(m.key) is not None and math.isfinite(r[m.key])]
            if pts:
                ax.plot(*zip(*pts), ".", ms=4, alpha=0.7)
            ax.set_xlabel(f"{xn} [{units.get(xn) or '-'}]", fontsize=8)
            ax.set_title(f"{m.key} [{m.unit}]", fontsize=8)
            ax.tick_params(labelsize=7)
        fig.suptitle(f"{sweep.name}: metrics vs {xn} ({len(ok)} ok runs)", fontsize=10)
        save(fig, f"vs_{_safe(xn)}.png")

    if "seed" in sweep.axes and len(ok) > 1:
        fig, axs = grid_fig()
        for ax, m in zip(axs, metrics):
            ax.hist(_finite(r.get(m.key) for r in ok), bins=min(30, max(5, len(ok) // 5)))
            ax.set_title(f"{m.key} [{m.unit}]", fontsize=8)
            ax.tick_params(labelsize=7)
        fig.suptitle(f"{sweep.name}: distribution over {len(ok)} ok runs", fontsize=10)
        save(fig, "histograms.png")

    grid = [n for n in sweep.grid_axes if kinds.get(n) != "str"]
    if len(sweep.grid_axes) == 2 and len(grid) == 2:
        a, b = grid
        av = sorted({r[a] for r in table.rows})
        bv = sorted({r[b] for r in table.rows})
        fig, axs = grid_fig()
        for ax, m in zip(axs, metrics):
            z = np.full((len(bv), len(av)), np.nan)
            for i, y in enumerate(bv):
                for j, x in enumerate(av):
                    vals = _finite(r.get(m.key) for r in ok if r[a] == x and r[b] == y)
                    if vals:
                        z[i, j] = float(np.mean(vals))   # the mean over the other axes (seeds)
            im = ax.imshow(z, origin="lower", aspect="auto", cmap="viridis")
            ax.set_xticks(range(len(av)), [f"{x:.4g}" for x in av], fontsize=6, rotation=45)
            ax.set_yticks(range(len(bv)), [f"{y:.4g}" for y in bv], fontsize=6)
            ax.set_xlabel(f"{a} [{units.get(a) or '-'}]", fontsize=7)
            ax.set_ylabel(f"{b} [{units.get(b) or '-'}]", fontsize=7)
            ax.set_title(f"{m.key} [{m.unit}]", fontsize=8)
            cb = fig.colorbar(im, ax=ax)
            cb.ax.tick_params(labelsize=6)
        fig.suptitle(f"{sweep.name}: heat maps over {a} x {b} (mean over other axes; blank: failed)", fontsize=10)
        save(fig, f"heatmap_{_safe(a)}__{_safe(b)}.png")
    return files


# ======================================================================== command line

def cli_sweep(args) -> int:
    """``python -m harness sweep``: see harness/__main__.py for the arguments."""
    from .fmus import select
    if args.scheduler and args.workers:
        print("error: --workers sets the size of the embedded local cluster; not with --scheduler", file=sys.stderr)
        return 2
    if args.workers is not None and args.workers < 1:
        print("error: --workers must be >= 1", file=sys.stderr)
        return 2
    if args.limit is not None and args.limit < 0:
        print("error: --limit must be >= 0", file=sys.stderr)
        return 2
    if args.resume and args.overwrite:
        print("error: --resume continues the results in --out, --overwrite discards them: give one", file=sys.stderr)
        return 2
    sweep = load_sweep(args.sweep)
    out = Path(args.out) if args.out else Path("out") / "sweeps" / sweep.name
    check_out_dir(out)
    check_rerun(out, sweep.fingerprint, args.resume, args.overwrite, SweepError)   # before any build
    choice = select(getattr(args, "fmu", "auto"), "RailCar", args.dist, args.rebuild,
                    [(f"run {r.run_id}", r.scenario.parameters) for r in sweep.runs if r.scenario is not None])
    where = args.scheduler or f"a local cluster of {args.workers or os.cpu_count()} worker processes"
    print(f"sweep '{sweep.name}': {len(sweep.runs)} runs of {sweep.base_path} on {where} -> {out}", flush=True)
    print(choice.line(), flush=True)
    try:
        o = run_sweep(sweep, out, choice.path, scheduler=args.scheduler, workers=args.workers,
                      resume=args.resume, limit=args.limit, plots=not args.no_plots, overwrite=args.overwrite,
                      fmu_note=choice.describe())
    except KeyboardInterrupt:
        print(f"\ninterrupted: the finished runs are in {out / 'results.csv'}; --resume continues", file=sys.stderr)
        return 1
    except (OSError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(format_sweep_summary(sweep, o))
    print(f"results: {', '.join(str(p) for p in o.files if p.suffix != '.png')}"
          + (f"; plots: {out / 'plots'} ({sum(p.suffix == '.png' for p in o.files)} files)" if not args.no_plots else ""))
    failed = sum(r["status"] != TEXT_STATUS_OK for r in o.table.rows)
    if failed:
        print(f"{failed} run(s) failed (status and message in results.csv)", file=sys.stderr)
    return 1 if failed else 0
