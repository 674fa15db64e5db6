"""Regression references in the FMI cross-check layout, and comparing fresh runs with them.

For each library scenario ``<Name>`` the folder ``tests/regression/`` holds
``<Name>_in.csv`` (the inputs the driver applied, zero-order hold written as duplicate time
rows), ``<Name>_ref.csv`` (key outputs) and ``<Name>_ref.opt`` (StartTime, StopTime,
StepSize, RelTol). As the cross-check rules require, the CSV headers are the quoted variable
names, time first; their units are the FMU variables' (README tables).

A fresh run passes when every key signal is within its explicit tolerance of the reference
and fmpy's band test (``fmpy.util.validate_result``) finds no outlier.

The references are written by ``python -m harness regress --update [NAME ...]``; the span
scenarios' (the ATO in closed loop: scenarios/library/ato_*.toml) alone by
``python -m harness regress --update 'ato_*'``. Their inputs are the ATO's demands, so a change
to models/ato*.py changes them: regenerate with that command after one, deliberately.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from fmpy.util import read_csv, read_ref_opt_file, validate_result

from harness.run.driver import INPUTS
from harness.textio import InputError, check_text_file

ROOT = Path(__file__).resolve().parents[2]
LIBRARY = ROOT / "scenarios" / "library"
REFERENCES = ROOT / "tests" / "regression"
REFERENCE_INTERVAL = 0.5     # [s] between stored reference rows (keeps the files small)
# fmpy's band test is a heuristic: at a jump (the distance restarting at a station) it flags a
# few samples even of identical data (0.29 % in station_day); the explicit tolerances are the
# strict check, the band test the coarse one.
BAND_OUTLIERS_ALLOWED = 0.01

# Tolerances (atol in the signal's unit, rtol): one machine reproduces runs bit for bit; these
# only absorb last-bit differences between BLAS/LAPACK builds, ~10 orders above them and far
# below any deliberate model change (1 % of A0 moves the speed by centimetres per second).
KEY_SIGNALS: dict[str, tuple[float, float]] = {
    "car.speed": (1e-6, 1e-6), "car.position": (1e-5, 1e-6), "sensor.speed": (1e-6, 1e-6),
    "sensor.position": (1e-5, 1e-6), "est.mass": (1e-5, 1e-6), "est.mass_std": (1e-5, 1e-5),
    "est.A0": (1e-6, 1e-5), "est.A1": (1e-8, 1e-5), "est.A2": (1e-9, 1e-5),
    "filter.speed": (1e-6, 1e-6), "filter.position": (1e-5, 1e-6),
    "filter.speed_std": (1e-8, 1e-5), "filter.position_std": (1e-7, 1e-5),
}


class ReferenceFileError(InputError):
    """A reference file that cannot be read (not UTF-8 text, not the cross-check layout); names it."""


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


def _structured(time: np.ndarray, columns: dict[str, np.ndarray]) -> np.ndarray:
    names = ["time"] + list(columns)
    arr = np.zeros(len(time), dtype=[(n, np.float64) for n in names])
    arr["time"] = time
    for n, c in columns.items():
        arr[n] = c
    return arr


def _write(path: Path, arr: np.ndarray) -> None:
    with open(path, "w") as f:
        f.write(",".join(f'"{n}"' for n in arr.dtype.names) + "\n")
        for row in arr:
            f.write(",".join(repr(float(x)) for x in row) + "\n")


def reference_rows(result) -> np.ndarray:
    """Indices of the rows stored in a reference (every REFERENCE_INTERVAL, and the last)."""
    stride = max(1, int(round(REFERENCE_INTERVAL / result.scenario.step_s)))
    idx = np.arange(0, len(result.time), stride)
    return idx if idx[-1] == len(result.time) - 1 else np.append(idx, len(result.time) - 1)


def write_reference(result, folder: Path = REFERENCES) -> list[Path]:
    """Write <Name>_in.csv, <Name>_ref.csv and <Name>_ref.opt for a run."""
    folder.mkdir(parents=True, exist_ok=True)
    name = result.scenario.name
    t = result.time
    # inputs, zero-order hold: a change at t_k is written as (t_k, old) then (t_k, new)
    u = np.column_stack([result.inputs[n] for n in INPUTS])
    rows_t, rows_u = [t[0]], [u[0]]
    for k in range(1, len(t)):
        if not np.array_equal(u[k], u[k - 1]):
            rows_t += [t[k], t[k]]
            rows_u += [u[k - 1], u[k]]
    rows_t.append(t[-1])
    rows_u.append(u[-1])
    inp = _structured(np.array(rows_t), {n: np.array(rows_u)[:, j] for j, n in enumerate(INPUTS)})
    idx = reference_rows(result)
    ref = _structured(t[idx], {n: result[n][idx] for n in KEY_SIGNALS})
    paths = [folder / f"{name}_in.csv", folder / f"{name}_ref.csv", folder / f"{name}_ref.opt"]
    _write(paths[0], inp)
    _write(paths[1], ref)
    paths[2].write_text(f"StartTime, 0.0\nStopTime, {float(t[-1])!r}\nStepSize, {result.scenario.step_s!r}\n"
                        f"RelTol, 1e-06\n")
    return paths


def compare(result, folder: Path = REFERENCES) -> Comparison:
    """Compare a fresh run with its stored reference; problems name the scenario and signal."""
    name = result.scenario.name
    ref_path = folder / f"{name}_ref.csv"
    if not ref_path.is_file():
        return Comparison(name, [f"{name}: no reference {ref_path.name} (python -m harness regress --update)"], {})
    ref, opts = read_reference(name, folder)
    problems, max_abs = [], {}
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
    for signal, (atol, rtol) in KEY_SIGNALS.items():
        if signal not in ref.dtype.names:
            problems.append(f"{name}: {signal}: not in the reference")
            continue
        fresh, old = result[signal][idx], ref[signal][shared]
        diff = np.abs(fresh - old)
        max_abs[signal] = float(diff.max())
        bad = diff > atol + rtol * np.abs(old)
        if bad.any():
            j = int(np.argmax(diff))
            problems.append(f"{name}: {signal}: {int(bad.sum())} of {len(diff)} samples off; largest "
                            f"|{fresh[j]:.9g} - {old[j]:.9g}| = {diff[j]:.3g} at t = {t_cmp[j]:.2f} s "
                            f"(atol {atol:g}, rtol {rtol:g})")
    fresh_arr = _structured(result.time[idx], {n: result[n][idx] for n in KEY_SIGNALS})
    rel_out = validate_result(fresh_arr, ref[shared], stop_time=float(t_cmp[-1]))
    if rel_out > BAND_OUTLIERS_ALLOWED:
        problems.append(f"{name}: fmpy band test: {100 * rel_out:.2f} % of the samples of the worst signal "
                        f"lie outside the reference band")
    return Comparison(name, problems, max_abs)


def read_reference(name: str, folder: Path = REFERENCES) -> tuple[np.ndarray, dict]:
    """(<Name>_ref.csv as a structured array, <Name>_ref.opt as a dict); ReferenceFileError names a
    file that is not UTF-8 text or not in the cross-check layout."""
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
    return read_csv(folder / f"{name}_in.csv")
