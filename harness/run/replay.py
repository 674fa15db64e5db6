"""Replay of recorded data: logs in, RailCarEstimator's estimates out.

A log is a CSV whose header cells are ``name [unit]``, time first:

    time [s],traction_force [N],brake_force [N],sensor.speed [m/s],sensor.position [m]

``sensor.speed`` may be given in [km/h] (converted here, at the edge). Optional truth columns
``car.speed [m/s]``, ``car.position [m]``, ``car.total_mass [t]`` enable error metrics. Rows
are the measurement instants; forces on a row are applied until the next row (finite, >= 0, as
RailCarEstimator requires). The file is UTF-8 text; a BOM is skipped (harness.textio).

``estimator_parameters`` checks ``--param NAME=VALUE`` against RailCarEstimator's variable table
and the FMU's own rules (profiles parsed, the estimator configured as the FMU configures it), so
that a bad parameter is invalid input before any FMU runs.

**Replaying a RailCar run's own log** (``run --log``). ``write_log`` writes every value in full
precision (repr), the run's est.* (to compare with), and beside the log ``<log>.params``: the
run's values of RailCarEstimator's parameters (all shared with RailCar), NAME=VALUE a line, which
``replay`` reads (``--param`` overrides them). On a uniform time grid the replay steps with the
grid's step exactly, as RailCar's estimator does (not t[k+1] - t[k], which differs in the last
bits). The log's forces are the ones RailCar's estimator was fed, which RailCar outputs
(``INTERVAL_FORCES``: the means over each sample interval, the plant's impulse / sample period),
so with the communication step equal to ``sensor.sample_period`` (one sample a row) the replay
gives the run's every est.* bit for bit, one row later: RailCarEstimator outputs, at row k + 1,
what it identified from the samples up to row k (tests/harness_tests/run/test_replay.py shows it
on the native and the pythonfmu FMUs). A run result without those outputs (an FMU built before
them) is logged with the force applied at the next row instead, the instantaneous force at the
interval's end, and the est.* differ slightly (est.mass 34.184 t against the run's 34.212 t on the
default scenario). filter.* never compare bit for bit, whatever the forces: RailCarEstimator
outputs the filter's one-step prediction for the next row (its estimate for t + h, from the
measurements up to t), RailCar its posterior at the row (updated with that row's measurement).
``compare_with_run`` (and the replay's report, harness/reports/replay_report.py) says which case
a log is.
"""
from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmu_src.variables import ESTIMATOR, variables_for
from models.units import kmh_to_mps

from harness.run.scenario import PATH_PARAMETERS, check_integer, named_parameter, profile_file, read_profile
from harness.textio import InputError, read_text

REQUIRED = {"time": ("s",), "traction_force": ("N",), "brake_force": ("N",),
            "sensor.speed": ("m/s", "km/h"), "sensor.position": ("m",)}
OPTIONAL = {"car.speed": ("m/s",), "car.position": ("m",), "car.total_mass": ("t",)}
RUN_ESTIMATES = {"est.mass": "t", "est.mass_std": "t", "est.A0": "N/kN", "est.A1": "N/kN/(m/s)",
                 "est.A2": "N/kN/(m/s)2", "est.A0_std": "N/kN", "est.A1_std": "N/kN/(m/s)",
                 "est.A2_std": "N/kN/(m/s)2", "est.sigma2": "m2/s2"}
"""A RailCar run's own estimates, which its log carries to compare the replay with (ASCII units:
a log is read by programs)."""
OPTIONAL.update({n: (u,) for n, u in RUN_ESTIMATES.items()})

INTERVAL_FORCES = ("car.traction_force_mean", "car.brake_force_mean")
"""[N] RailCar's outputs: the traction and brake force applied over the last sample interval,
averaged (the impulse over it / sensor.sample_period), what RailCar's estimator was fed. A log of
a run that recorded them replays to the run's est.* bit for bit."""
EXACT, NEXT_ROW = "interval_mean", "next_row"     # what a log's forces are (its .params says)
_HEADER = re.compile(r"^\s*\"?([A-Za-z0-9_.]+)\s*\[([^\]]*)\]\"?\s*$")


NONNEGATIVE = ("traction_force", "brake_force")     # [N] the estimator refuses negative forces


class LogError(InputError):
    """A log that cannot be replayed; names the file, line and column."""


class ParamError(InputError):
    """A ``--param NAME=VALUE`` that RailCarEstimator cannot start with; names the parameter."""


@dataclass
class Log:
    path: str
    time: np.ndarray                       # [s]
    columns: dict[str, np.ndarray]         # SI units


def read_log(path: str | Path) -> Log:
    """Read and check a log; speeds in km/h are converted to m/s."""
    path = Path(path)
    reader = csv.reader(read_text(path, LogError).splitlines())
    try:
        rows = list(reader)
    except csv.Error as e:
        raise LogError(f"{path}: line {reader.line_num + 1}: not valid CSV: {e}") from None
    if len(rows) < 3:
        raise LogError(f"{path}: needs a header and at least two rows")
    names, units = [], []
    for j, cell in enumerate(rows[0]):
        m = _HEADER.match(cell)
        if not m:
            raise LogError(f"{path}: line 1, column {j + 1}: header cell '{cell}' is not 'name [unit]'")
        names.append(m.group(1))
        units.append(m.group(2).strip())
    if names[0] != "time":
        raise LogError(f"{path}: line 1: the first column must be 'time [s]'")
    for j, name in enumerate(names):
        if name in names[:j]:
            raise LogError(f"{path}: line 1, column {j + 1}: column '{name}' appears twice")
    for name, allowed in REQUIRED.items():
        if name not in names:
            raise LogError(f"{path}: line 1: missing column '{name} [{allowed[0]}]'")
    for name, unit in zip(names, units):
        allowed = REQUIRED.get(name) or OPTIONAL.get(name)
        if allowed and unit not in allowed:
            raise LogError(f"{path}: line 1: column '{name}' must be in [{' or '.join(allowed)}], got [{unit}]")
    data = np.empty((len(rows) - 1, len(names)))
    for i, row in enumerate(rows[1:], start=2):
        if len(row) != len(names):
            raise LogError(f"{path}: line {i}: expected {len(names)} values, got {len(row)}")
        for j, cell in enumerate(row):
            try:
                x = float(cell)
            except ValueError:
                raise LogError(f"{path}: line {i}, column '{names[j]}': not a number: '{cell}'") from None
            if not math.isfinite(x):
                raise LogError(f"{path}: line {i}, column '{names[j]}': not finite: '{cell}'")
            if x < 0 and names[j] in NONNEGATIVE:
                raise LogError(f"{path}: line {i}, column '{names[j]}': must be >= 0 [N], got {cell}")
            data[i - 2, j] = x
    t = data[:, 0]
    bad = np.nonzero(np.diff(t) <= 0)[0]
    if bad.size:
        raise LogError(f"{path}: line {bad[0] + 3}: time must increase")
    cols = {n: data[:, j] for j, n in enumerate(names)}
    if units[names.index("sensor.speed")] == "km/h":
        cols["sensor.speed"] = kmh_to_mps(cols["sensor.speed"])
    return Log(str(path), t, cols)


_ESTIMATOR_PARAMETERS = {v.name: v for v in variables_for(ESTIMATOR) if v.causality == "parameter"}


def estimator_parameters(items: list[str] | None, dt: float = 1.0) -> dict:
    """``--param NAME=VALUE`` strings -> RailCarEstimator parameter values, checked as the FMU
    checks them at initialisation; ``dt`` [s] is the log's first step (the estimator's sampling
    period). A profile path that names a file here is made absolute (the FMU would look in its
    resources first); one that does not is checked where the FMU looks. ParamError names the
    parameter (and the file and line of a bad profile)."""
    from fmu_src.adapter import estimator_settings, track_settings
    from models.chain import build_estimator
    from models.plant.track import GradeProfile
    out, profiles = {}, {}
    for item in items or []:
        if "=" not in item:
            raise ParamError(f"--param {item!r}: expected NAME=VALUE")
        name, text = item.split("=", 1)
        key = f"--param {name}"
        var = _ESTIMATOR_PARAMETERS.get(name)
        if var is None:
            raise ParamError(f"{key}: not a RailCarEstimator parameter (see the README's variable table)")
        if var.type == "Real":
            try:
                value = float(text)
            except ValueError:
                raise ParamError(f"{key}: '{text}' is not a number") from None
        elif var.type == "Integer":
            try:
                value = int(text)
            except ValueError:
                raise ParamError(f"{key}: '{text}' is not an integer") from None
            check_integer(name, value, key, ParamError)
        else:
            value = text
            if name in PATH_PARAMETERS and text:
                local = Path(text)
                found = local if local.is_file() else profile_file(text, None)
                profiles[name] = read_profile(name, found, key, ParamError)
                if local.is_file():
                    value = str(local.resolve())
        out[name] = value
    v = {n: out.get(n, var.start) for n, var in _ESTIMATOR_PARAMETERS.items()}
    try:
        ident, filt, station = estimator_settings(v)
        track_settings(v).validate()
        build_estimator(ident, filt, station, profiles.get("track.grade_profile") or GradeProfile.level(),
                        profiles.get("track.speed_profile"), dt)
    except (ValueError, ArithmeticError) as e:
        name = named_parameter(str(e), _ESTIMATOR_PARAMETERS)
        where = f"--param {name}" if name else "--param"
        if name and name not in out:
            where += f" (not set: the FMU's default {_ESTIMATOR_PARAMETERS[name].start!r})"
        raise ParamError(f"{where}: {e}") from None
    return out


def _applied_until_next_row(x: np.ndarray) -> np.ndarray:
    """RailCar reports the force applied up to each row; a log wants the force from it on."""
    return np.append(x[1:], x[-1:])


def params_path(log_path: Path) -> Path:
    """The parameters beside a log: default_log.csv -> default_log.params."""
    return Path(log_path).with_suffix(".params")


def write_log(path: Path, result) -> Path:
    """A RailCar run as a replayable log: the measurements, the forces (the interval means where
    the run recorded them, ``INTERVAL_FORCES``, else the force applied at the next row), the
    truth and the run's own est.*, every value in full precision; and ``params_path(path)``: the
    run's values of RailCarEstimator's parameters (module docstring)."""
    exact = all(n in result.signals for n in INTERVAL_FORCES)
    forces = INTERVAL_FORCES if exact else ("car.traction_force", "car.brake_force")
    cols = [("time", "s", result.time),
            ("traction_force", "N", _applied_until_next_row(result[forces[0]])),
            ("brake_force", "N", _applied_until_next_row(result[forces[1]])),
            ("sensor.speed", "m/s", result["sensor.speed"]),
            ("sensor.position", "m", result["sensor.position"]), ("car.speed", "m/s", result["car.speed"]),
            ("car.position", "m", result["car.position"]), ("car.total_mass", "t", result["car.total_mass"])]
    cols += [(n, u, result[n]) for n, u in RUN_ESTIMATES.items() if n in result.signals]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([f"{n} [{u}]" for n, u, _ in cols])
        for k in range(len(result.time)):
            w.writerow([repr(float(c[k])) for _, _, c in cols])
    values = result.setup.values
    lines = [f"# RailCarEstimator parameters of the run '{result.scenario.name}' that wrote {Path(path).name}: "
             f"python -m harness replay reads them (--param overrides)",
             f"# forces: {EXACT if exact else NEXT_ROW}"]
    lines += [f"{n}={_param_text(values[n])}" for n in _ESTIMATOR_PARAMETERS]
    params_path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _param_text(value) -> str:
    return repr(float(value)) if isinstance(value, float) else str(value)


def read_log_parameters(log_path: Path) -> tuple[list[str], str]:
    """(NAME=VALUE items, what the forces are: EXACT, NEXT_ROW, or "" for a log without
    parameters beside it) from ``params_path(log_path)``."""
    p = params_path(log_path)
    if not p.is_file():
        return [], ""
    items, forces = [], NEXT_ROW
    for line in read_text(p, ParamError).splitlines():
        line = line.strip()
        if line.startswith("# forces:"):
            forces = line.split(":", 1)[1].strip()
        elif line and not line.startswith("#"):
            items.append(line)
    return items, forces


def uniform_step(time: np.ndarray) -> float | None:
    """The step [s] of a uniform time grid, t[k] = t[0] + k * (t[1] - t[0]) to the bit (a harness
    run's rows), else None: then the replay steps t[k+1] - t[k]."""
    h = float(time[1] - time[0])
    k = np.arange(len(time))
    return h if np.array_equal(time, time[0] + k * h) else None


def compare_with_run(log: Log, signals: dict[str, np.ndarray], forces: str) -> list[str]:
    """Lines comparing the replay's est.* with the run's own that the log carries: the replay's
    row k + 1 with the run's row k (module docstring), bit for bit or the largest difference,
    and why they differ when they may."""
    names = [n for n in RUN_ESTIMATES if n in log.columns and n in signals]
    if not names:
        return []
    diff = {n: float(np.max(np.abs(signals[n][1:] - log.columns[n][:-1]))) for n in names}
    same = all(np.array_equal(signals[n][1:], log.columns[n][:-1]) for n in names)
    if same:
        return [f"  est.* vs the run's own  bit for bit ({', '.join(names)}; the replay's row k+1 is the run's row k)"]
    worst = max(diff, key=diff.get)
    lines = [f"  est.* vs the run's own  not bit for bit: max |diff| {diff[worst]:.3g} ({worst}; the replay's "
             f"row k+1 against the run's row k)"]
    if forces != EXACT:
        lines.append("    why: the log's forces are those applied at the next row, not the means over each "
                     "sample interval that RailCar's estimator saw (the run recorded no "
                     f"{' / '.join(INTERVAL_FORCES)}); see harness/run/replay.py")
    return lines
