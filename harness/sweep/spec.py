"""The sweep file: what it may say, its checks, and the runs it makes (grid, zip, Latin hypercube,
seeds). Pure reading and computing: no FMU, no dask, no output folder.

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
RailCar parameters (docs/variables.md lists them: contract names, SI units; checked and typed by
``harness.run.scenario.parse_parameters``; profile paths relative to the sweep file) or scenario
fields: ``step_s``, ``duration_s``, ``stop_after_last_phase``, ``driver[i].KEY`` (a key of
the base scenario's i-th ``[[driver]]`` phase) and ``wind[i].time_s`` / ``wind[i].speed_mps``.
A malformed sweep file raises ``SweepError`` (a ``ScenarioError``) naming the file, key and
reason; a run whose values make an invalid scenario (say step_s = 0) is kept as a ``RunSpec``
with the reason, and becomes a "failed" row when the sweep runs. Seeds must be in the FMU's
range, 0..2**31 - 1 (``seed`` is a 32-bit fmi2Integer).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from collections.abc import Iterator, Sequence

import numpy as np

from harness.run.scenario import RAILCAR_PARAMETERS as PARAMETERS
from harness.run.scenario import (PATH_PARAMETERS, SEED_MAX, Scenario, ScenarioError, check_integer, parse_parameters,
                       read_toml, scenario_from_dict)
from harness.textio import InputError, decode_text, did_you_mean, read_bytes

SCENARIO_FIELDS = {"step_s": "s", "duration_s": "s", "stop_after_last_phase": ""}
WIND_KEYS = {"time_s": "s", "speed_mps": "m/s"}
BLOCKS = ("grid", "zip", "lhs", "seeds")          # in the order of the product (seeds vary fastest)
_FIELD_RE = re.compile(r"^(driver|wind)\[(\d+)\]\.([A-Za-z_][A-Za-z0-9_]*)$")
_SUFFIX_UNITS = (("_mps2", "m/s2"), ("_mps", "m/s"), ("_kmh", "km/h"), ("_pct", "%"), ("_s", "s"),
                 ("_m", "m"), ("_N", "N"), ("_t", "t"))


class SweepError(ScenarioError):
    """A sweep file that cannot run; the message names the file, the key and the reason."""


@dataclass(frozen=True)
class RunSpec:
    """One run: its id, the swept values (name -> value), and its scenario or why it is invalid."""
    run_id: int
    values: tuple            # ((name, value), ...) in the sweep's column order
    scenario: Scenario | None
    error: str | None = None

    def label(self) -> str:
        return f"run {self.run_id} (" + ", ".join(f"{k}={v}" for k, v in self.values) + ")"


class _Seeds(Sequence):
    """The seeds block's points, {"seed": x}, made when asked: a count of seeds is a range, so that
    100,000 seeds take no memory until their runs are built."""

    def __init__(self, seeds: Sequence[int]):
        self.seeds = seeds

    def __len__(self) -> int:
        return len(self.seeds)

    def __getitem__(self, k: int) -> dict:
        return {"seed": self.seeds[k]}


@dataclass(frozen=True)
class RunPlan:
    """How to build any run of a sweep from its id: the base scenario's TOML data, the fixed
    values, and the factors of the product (each a sequence of points, name -> value: one per
    [grid] axis, then [zip], [lhs] and the seeds; the last varies fastest). Small whatever the
    number of runs (a count of seeds is a range)."""
    base: dict
    base_path: Path
    fixed: dict
    axes: tuple
    factors: tuple

    @property
    def total(self) -> int:
        return math.prod(len(f) for f in self.factors)

    def point(self, run_id: int) -> dict:
        """Run ``run_id``'s swept values, name -> value (itertools.product's order of the factors)."""
        if not 0 <= run_id < self.total:
            raise IndexError(f"run id {run_id} out of range 0..{self.total - 1}")
        values, rest = {}, run_id
        picks = []
        for f in reversed(self.factors):
            rest, k = divmod(rest, len(f))
            picks.append(f[k])
        for part in reversed(picks):
            values.update(part)
        return values

    def values(self, run_id: int) -> tuple:
        """((name, value), ...) of run ``run_id`` in the sweep's column order."""
        values = self.point(run_id)
        return tuple((n, values[n]) for n in self.axes)

    def build(self, run_id: int) -> RunSpec:
        """Run ``run_id``: its scenario (the base with the fixed and the run's values), or why it
        is invalid (a RunSpec with the reason: a "failed" row when the sweep runs)."""
        return self.make(run_id, self.point(run_id))

    def recipe(self) -> "RunPlan":
        """This plan without its factors: what ``make`` needs, a few kB whatever the runs (a
        chunk of runs ships it with the runs' ids and points, and its worker builds them)."""
        return RunPlan(base=self.base, base_path=self.base_path, fixed=self.fixed, axes=self.axes, factors=())

    def make(self, run_id: int, values: dict) -> RunSpec:
        """``build`` of run ``run_id`` whose swept values (``point``) are ``values``."""
        ordered = tuple((n, values[n]) for n in self.axes)
        data = _apply(self.base, {**self.fixed, **values})
        try:
            return RunSpec(run_id, ordered, scenario_from_dict(data, str(self.base_path), self.base_path.parent))
        except ScenarioError as e:
            return RunSpec(run_id, ordered, None, f"invalid scenario: {e}")

    def seeds_per_point(self) -> int:
        """Runs that differ only in their seed, consecutive (1 without a seeds block)."""
        return len(self.factors[-1]) if self.factors and isinstance(self.factors[-1], _Seeds) else 1


class SweepRuns(Sequence):
    """A sweep's runs by run id, each built (RunPlan.build) only when asked for: indexing builds
    one RunSpec, iterating builds them one at a time, slicing gives the runs of a sub-range (built
    when asked for too). Its memory is the plan's, whatever the number of runs; a run asked for
    twice is built twice (a RunSpec holds its scenario: ~1.7 kB, and ~1 ms to build a station_day
    run)."""

    def __init__(self, plan: RunPlan, ids: range | None = None):
        self.plan = plan
        self.ids = range(plan.total) if ids is None else ids

    def __len__(self) -> int:
        return len(self.ids)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return SweepRuns(self.plan, self.ids[k])
        return self.plan.build(self.ids[k])

    def __iter__(self) -> Iterator[RunSpec]:
        return (self.plan.build(i) for i in self.ids)

    def build(self, run_id: int) -> RunSpec:
        """The run whose id is ``run_id`` (not its position among these runs)."""
        return self.plan.build(run_id)

    def representatives(self) -> Iterator[RunSpec]:
        """One run of each point of these runs but the seed (the first of its seeds here): what
        decides a run's validity, the engine that covers it and the FMU that can run it (a seed
        changes none of them, and every seed was checked in range at load)."""
        per, last = self.plan.seeds_per_point(), None
        for i in self.ids:
            if i // per != last:
                last = i // per
                yield self.plan.build(i)


@dataclass(frozen=True)
class Sweep:
    name: str
    purpose: str
    path: Path
    base_path: Path
    axes: tuple              # swept names, in column order
    blocks: dict             # block name -> tuple of names ("grid", "zip", "lhs", "seeds")
    runs: SweepRuns          # by run id, each built when asked for (RunPlan.build)
    fingerprint: str         # changes when the runs, the fixed values or the base scenario change
    span: bool = False       # the base is a span scenario (the ATO drives): rows carry the ATO's metrics

    @property
    def grid_axes(self) -> tuple:
        return self.blocks.get("grid", ())


def _where(path: Path, block: str, name: str | None = None) -> str:
    return f"{path}: {block}" + (f".\"{name}\"" if name is not None else "")


def unit_from_suffix(name: str) -> str:
    """The unit a name's suffix says (``_kmh`` -> km/h, ``_s`` -> s, ...), '' if none."""
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
    return unit_from_suffix(m.group(3)) if m else ""


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


def _finite_number(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SweepError(f"{where}: expected a finite number, got {value!r}")
    return float(value)


def _check_value(name: str, value, path: Path, block: str, base: dict, sweep_dir: Path):
    """A swept or fixed value: check the name and the type; returns the typed value.

    FMU parameters go through harness.run.scenario.parse_parameters (types, profile paths resolved
    against the sweep file's folder); scenario fields are checked here, their values' ranges
    later, per run, by harness.run.scenario.scenario_from_dict."""
    where = _where(path, block, name)
    if name in PARAMETERS:
        return parse_parameters({name: value}, f"{path}: {block}", sweep_dir)[name]
    if name in ("step_s", "duration_s"):
        return _finite_number(value, where)
    if name == "stop_after_last_phase":
        if not isinstance(value, bool):
            raise SweepError(f"{where}: expected true or false, got {value!r}")
        return value
    m = _FIELD_RE.match(name)
    if m is None:
        raise SweepError(f"{where}: not a RailCar parameter (docs/variables.md lists them) nor a sweepable "
                         f"scenario field (step_s, duration_s, stop_after_last_phase, driver[i].KEY, "
                         f"wind[i].time_s, wind[i].speed_mps){did_you_mean(name, [*PARAMETERS, *SCENARIO_FIELDS])}")
    table, index, key = m.group(1), int(m.group(2)), m.group(3)
    entries = base.get(table, [])
    if index >= len(entries):
        raise SweepError(f"{where}: the base scenario has {len(entries)} [[{table}]] entries, no index {index}")
    if table == "driver":
        from harness.run.phases import _PHASE_KEYS
        if key not in _PHASE_KEYS:
            raise SweepError(f"{where}: '{key}' is not a driver phase key (known: {', '.join(sorted(_PHASE_KEYS))})"
                             f"{did_you_mean(key, _PHASE_KEYS)}")
    elif key not in WIND_KEYS:
        raise SweepError(f"{where}: '{key}' is not a wind key (known: {', '.join(WIND_KEYS)}){did_you_mean(key, WIND_KEYS)}")
    if name_kind(name) == "float":
        return _finite_number(value, where)
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
            _finite_number(raw[k], f"{where}.{k}")
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
    """The base scenario's TOML data with values set (FMU parameters already typed), as a new
    dict: what it changes is copied (the top level, the parameters table, the driver or wind
    list and entry changed), the rest shared with ``data``, which stays as it was (nothing reads
    it to change it: scenario_from_dict builds new objects); a deep copy of station_day's data
    took a quarter of the time to build its run."""
    data = dict(data)
    copied = set()
    for name, value in overrides.items():
        if name in PARAMETERS:
            if "parameters" not in copied:
                data["parameters"] = dict(data.get("parameters", {}))
                copied.add("parameters")
            data["parameters"][name] = value
        elif name in SCENARIO_FIELDS:
            data[name] = value
        else:
            m = _FIELD_RE.match(name)
            table, index = m.group(1), int(m.group(2))
            if table not in copied:
                data[table] = list(data[table])
                copied.add(table)
            if (table, index) not in copied:
                data[table][index] = dict(data[table][index])
                copied.add((table, index))
            data[table][index][m.group(3)] = value
    return data


def load_sweep(path: str | Path) -> Sweep:
    """Read and validate a sweep file; its runs (``Sweep.runs``) are built when asked for, a chunk
    at a time when the sweep runs, so that loading takes the same memory for 10 or 10 million
    runs. A run's values that make an invalid scenario show when it is built (a RunSpec with the
    reason)."""
    path = Path(path)
    raw = read_toml(path, SweepError)
    try:
        return sweep_from_dict(raw, path)
    except SweepError:
        raise
    except ScenarioError as e:        # from harness.run.scenario.parse_parameters: same message
        raise SweepError(str(e)) from None


def _file_digest(path: str) -> str:
    try:
        return hashlib.sha256(read_bytes(path)).hexdigest()
    except InputError:          # not a regular file, too large, unreadable
        return "unreadable"


def _read_base(raw: dict, path: Path) -> tuple[Path, str, dict, Scenario]:
    """The base scenario: its path, its text, its TOML data and the scenario; SweepError unless it
    is valid."""
    if not isinstance(raw.get("scenario"), str) or not raw["scenario"]:
        raise SweepError(f"{path}: scenario: give the base scenario file (relative to this file)")
    base_path = Path(raw["scenario"])
    if not base_path.is_absolute():
        base_path = path.parent / base_path
    where = f"{path}: scenario: {base_path}"
    try:
        os.stat(base_path)
        # a regular file of bounded size, checked before it is opened (a FIFO would block)
        base_text = decode_text(read_bytes(base_path, SweepError, where=where), where, SweepError)
        base = tomllib.loads(base_text)
    except OSError as e:
        raise SweepError(f"{path}: scenario: cannot read {base_path}: {e.strerror}") from None
    except tomllib.TOMLDecodeError as e:
        raise SweepError(f"{path}: scenario: {base_path} is not valid TOML: {e}") from None
    try:
        scenario = scenario_from_dict(base, str(base_path), base_path.parent)
    except ScenarioError as e:
        raise SweepError(f"{path}: scenario: the base scenario is invalid: {e}") from None
    return base_path, base_text, base, scenario


class _Blocks:
    """Reads the blocks of one sweep file in turn; remembers which block set each name."""

    def __init__(self, raw: dict, path: Path, base: dict):
        self.raw, self.path, self.base = raw, path, base
        self.seen: dict[str, str] = {}

    def table(self, key: str) -> dict:
        t = self.raw.get(key, {})
        if not isinstance(t, dict):
            raise SweepError(f"{self.path}: {key}: expected a table [{key}]")
        return t

    def claim(self, name: str, block: str) -> None:
        if name in self.seen:
            raise SweepError(f"{_where(self.path, block, name)}: already set in [{self.seen[name]}]; a name may "
                             f"appear in one block only")
        self.seen[name] = block

    def value(self, name: str, x, block: str):
        return _check_value(name, x, self.path, block, self.base, self.path.parent)

    def fixed(self) -> dict:
        fixed = {}
        for n, v in self.table("fixed").items():
            self.claim(n, "fixed")
            fixed[n] = self.value(n, v, "fixed")
        return fixed

    def grid_axes(self) -> list[list[dict]]:
        """Each [grid] axis as its points ({name: value}); their product is the grid."""
        axes = []
        for n, v in self.table("grid").items():
            self.claim(n, "grid")
            axes.append([{n: self.value(n, x, "grid")} for x in _axis_values(v, _where(self.path, "grid", n))])
        return axes

    def zip_points(self) -> list[dict]:
        cols, length = {}, None
        for n, v in self.table("zip").items():
            self.claim(n, "zip")
            where = _where(self.path, "zip", n)
            if not isinstance(v, list) or not v:
                raise SweepError(f"{where}: expected a non-empty list of values")
            if length is not None and len(v) != length:
                raise SweepError(f"{where}: {len(v)} values, but the first [zip] list has {length}; "
                                 f"zipped lists must have equal lengths")
            length = len(v)
            cols[n] = [self.value(n, x, "zip") for x in v]
        return [{n: cols[n][k] for n in cols} for k in range(length)]

    def lhs_points(self) -> tuple[tuple, list[dict]]:
        lhs, path = self.table("lhs"), self.path
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
            self.claim(n, "lhs")
            where = _where(path, "lhs.bounds", n)
            if not isinstance(b, list) or len(b) != 2:
                raise SweepError(f"{where}: expected [low, high], got {b!r}")
            lo, hi = (self.value(n, x, "lhs.bounds") for x in b)
            if name_kind(n) != "float":
                raise SweepError(f"{where}: a Latin hypercube samples real values; {n} is not a real "
                                 f"number (sweep it in [grid] or [zip])")
            if not lo < hi:
                raise SweepError(f"{where}: low must be < high, got [{lo}, {hi}]")
            bounds[n] = (lo, hi)
        return tuple(bounds), latin_hypercube(bounds, samples, seed)

    def seed_points(self) -> _Seeds:
        s, where = self.raw["seeds"], f"{self.path}: seeds"
        if "seed" in self.seen:
            raise SweepError(f"{where}: seed is already set in [{self.seen['seed']}]; give seeds or a seed, not both")
        if isinstance(s, bool):
            raise SweepError(f"{where}: expected a count >= 1 or a list of integers, got {s!r}")
        if isinstance(s, int):
            if s < 1:
                raise SweepError(f"{where}: expected a count >= 1, got {s}")
            if s > SEED_MAX:
                raise SweepError(f"{where}: a count must be <= {SEED_MAX}: the seeds 1..count must be in "
                                 f"0..{SEED_MAX} (the FMU's seed is a 32-bit fmi2Integer), got {s}")
            seeds = range(1, s + 1)
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
        self.seen["seed"] = "seeds"
        return _Seeds(seeds)


def sweep_from_dict(raw: dict, path: Path) -> Sweep:
    known = {"name", "purpose", "scenario", "fixed", *BLOCKS}
    for key in raw:
        if key not in known:
            raise SweepError(f"{path}: unknown key '{key}' (known: {', '.join(sorted(known))})")
    name = raw.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise SweepError(f"{path}: name: expected a non-empty string")
    purpose = raw.get("purpose", "")
    if not isinstance(purpose, str):
        raise SweepError(f"{path}: purpose: expected a string")
    base_path, base_text, base, base_scenario = _read_base(raw, path)
    reader = _Blocks(raw, path, base)
    fixed = reader.fixed()
    blocks: dict[str, tuple] = {}
    factors: list = []                    # the product's factors, the last varies fastest
    if reader.table("grid"):
        blocks["grid"] = tuple(raw["grid"])
        factors += reader.grid_axes()
    if reader.table("zip"):
        blocks["zip"] = tuple(raw["zip"])
        factors.append(reader.zip_points())
    if reader.table("lhs"):
        blocks["lhs"], points = reader.lhs_points()
        factors.append(points)
    if "seeds" in raw:
        factors.append(reader.seed_points())
        blocks["seeds"] = ("seed",)
    if not factors:
        raise SweepError(f"{path}: nothing to sweep: add [grid], [zip], [lhs] or seeds")

    axes = tuple(n for b in BLOCKS for n in blocks.get(b, ()))
    plan = RunPlan(base=base, base_path=base_path, fixed=fixed, axes=axes, factors=tuple(factors))
    return Sweep(name=name, purpose=purpose, path=path, base_path=base_path, axes=axes, blocks=blocks,
                 runs=SweepRuns(plan),
                 fingerprint=_fingerprint(base, base_text, base_path, fixed, plan, base_scenario),
                 span="span" in base)


def _profile_files(base: dict, base_path: Path, fixed: dict, plan: RunPlan, base_scenario: Scenario) -> set:
    """The profile files the runs may read: the base's driver table, and each PATH_PARAMETERS'
    value: a swept one's values, else the fixed one, else the base scenario's (every value as a
    run's scenario holds it: resolved to an absolute path). Found from the factors, without
    building a run."""
    files = {str(base_path.parent / base["driver_table"]["file"])} if isinstance(base.get("driver_table"), dict) \
        and isinstance(base["driver_table"].get("file"), str) else set()
    for n in PATH_PARAMETERS:
        swept = [p[n] for f in plan.factors if not isinstance(f, _Seeds) for p in f if n in p]
        if swept:
            files |= {v for v in swept if v}
        elif fixed.get(n):
            files.add(fixed[n])
        elif base_scenario.parameter(n):
            files.add(base_scenario.parameter(n))
    return files


FINGERPRINT_RUNS_PER_UPDATE = 4096
"""Runs' values encoded per update of the fingerprint's hash: its text is never whole in memory."""


def _fingerprint(base: dict, base_text: str, base_path: Path, fixed: dict, plan: RunPlan,
                 base_scenario: Scenario) -> str:
    """A digest of the base scenario, the fixed values, the runs and the profile files they read:
    the SHA-256 of json.dumps({"base", "files", "fixed", "runs": [[run_id, [[name, value], ...]],
    ...]}, sort_keys=True, default=repr), as sweeps have always had it (--resume compares it with
    the one in sweep.json), hashed a part at a time: the runs' values are made from their ids
    (RunPlan.values), none is built."""
    files = _profile_files(base, base_path, fixed, plan, base_scenario)
    head = json.dumps({"base": base_text, "files": {f: _file_digest(f) for f in sorted(files)}, "fixed": fixed,
                       "runs": []}, sort_keys=True, default=repr)
    assert head.endswith('"runs": []}')               # "runs" sorts last: its list is written in parts
    h = hashlib.sha256(head[:-2].encode())
    total = plan.total
    for first in range(0, total, FINGERPRINT_RUNS_PER_UPDATE):
        part = [json.dumps([i, [list(v) for v in plan.values(i)]], sort_keys=True, default=repr)
                for i in range(first, min(total, first + FINGERPRINT_RUNS_PER_UPDATE))]
        h.update(((", " if first else "") + ", ".join(part)).encode())
    h.update(b"]}")
    return h.hexdigest()
