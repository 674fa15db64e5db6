"""FMU states of the native AtoController (AtoControllerNative.fmu, FMI 2.0, and
AtoControllerNative3.fmu, FMI 3.0): get / set / free and serialize / deserialize, through fmpy.

The state is the whole controller (fmu_src/c/native_ato.c's NAT_STATE_OPS and
models/core/ato_line.c's ato_line_state_*): the variables, the line's configuration, and each
span's controller with its course, planner buffers, plans, supervision and events. Checked here,
for both FMUs, on ato_nominal's closed loop (test_ato_fmu.py's span, its recorded inputs) and on
scenarios/library/ato_line.toml (three spans; a state taken mid-span and one taken in a
station's dwell), each replay with one bad input (filter.speed = NaN) after the state so that the
safe brake, its latch and its warning are part of what must repeat:
- restoring a state and repeating the same inputs gives bit-identical outputs (the doubles' bits)
  and the same logged warnings;
- the serialized bytes continue in a FRESH instance (only instantiated) once the instance that
  made them is gone, bit for bit and with the same warnings; it serializes to the same bytes;
- rolling back to an earlier state after a later one, twice, and a state overwritten in place;
- truncated, foreign (the other FMI version's) and corrupt bytes (a model part cut anywhere,
  forged counts with a correct checksum) are refused naming the function and what is wrong,
  and the instance goes on as it was;
- random call sequences with the state calls mixed in (seeded) never crash the host or go fatal;
- all but the last once more with both binaries built with -fsanitize=address,undefined, in a
  Python process preloading the sanitizer runtimes (as test_fmu_state.py does).
Over 600 lines: one fmpy-level harness of state calls serves both standards, both scenarios and the
sanitized build, which kept apart would repeat it.
"""
from __future__ import annotations

import json
import math
import os
import random
import struct
import subprocess
import sys
from ctypes import c_void_p
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException

from conftest import ERROR, OK, ROOT, FmuFile
from fmu_src.build import native, native_fmi3
from test_fmu_state import Unit as StateUnit, bits, refused, resealed, sanitized_copy, sanitizer_env
from test_native_ato_fmu import closed_loop, line_run, profiles  # noqa: F401  (fixtures)

WARNING = 1
VERSIONS = {"AtoControllerNative": 2, "AtoControllerNative3": 3}
HOLD, SAFE = 8, 9                        # ato.mode: the holding brake, the safe brake


# ------------------------------------------------------------------------------- the runs

@dataclass
class Case:
    """A run to replay: parameters, rows (t [s], step [s], inputs by name), the step the state is
    taken after (`at`), the steps replayed after it (`n`)."""
    name: str
    parameters: dict
    rows: list
    at: int
    n: int


class AtoFmu:
    """One native ATO FMU, extracted."""

    def __init__(self, name: str, path: Path, unzipdir: str):
        self.name, self.path, self.unzipdir = name, Path(path), unzipdir
        self.version = VERSIONS[name]
        self.md = read_model_description(str(path))
        self.variables = {v.name: v for v in self.md.modelVariables}
        self.outputs = [v for v in self.md.modelVariables if v.causality == "output"]

    def as_fmu_file(self) -> FmuFile:
        return FmuFile("AtoController", self.path, self.md, self.unzipdir)


class Unit(StateUnit):
    """test_fmu_state's instance of a native FMU, with the ATO's runs: rows of (t, step, inputs)
    and the warnings logged."""

    def ordered(self) -> list:
        """The outputs in read_outputs' order."""
        order = ("Real", "Float64", "Integer", "Int32", "Boolean")
        return sorted(self.outputs, key=lambda v: order.index(v.type))

    def run(self, rows: list, first: int, n: int) -> tuple[np.ndarray, list[str]]:
        """Steps first .. first + n - 1: every output after each, and the warnings logged."""
        before = len(self.messages)
        out = []
        for t, h, inputs in rows[first:first + n]:
            self.set(inputs)
            self.fmu.doStep(t, h)
            out.append(self.read_outputs())
        return np.array(out), self.warnings(before)

    def warnings(self, since: int = 0) -> list[str]:
        return [m.message for m in self.messages[since:] if m.status == WARNING]


def with_bad_speed(rows: list, k: int) -> list:
    """rows with filter.speed = NaN at step k (the safe brake, its warning, its latch)."""
    out = list(rows)
    t, h, inputs = out[k]
    out[k] = (t, h, {**inputs, "filter.speed": math.nan})
    return out


def nominal_case(closed_loop, profiles) -> Case:  # noqa: F811
    seen, _commands, _ctrl = closed_loop
    rows = [(k * 0.1, 0.1, inputs) for k, inputs in enumerate(seen)]
    return Case("nominal", profiles, with_bad_speed(rows, 410), 400, 150)


def line_rows(line_run) -> tuple[list, dict]:  # noqa: F811
    from test_native_ato_fmu import LINE_INPUTS
    result, parameters = line_run
    h = float(result.time[1] - result.time[0])
    columns = {n: [float(x) for x in result.signals[n]] for n in LINE_INPUTS}
    rows = [(float(t), h, {n: c[j] for n, c in columns.items()})
            for j, t in enumerate(result.time)]
    return rows, parameters


def line_cases(fmu: AtoFmu, line_run) -> list[Case]:  # noqa: F811
    """Mid-span (span 2 running) and in the dwell at station 2, found on a reference run."""
    rows, parameters = line_rows(line_run)
    unit = Unit(fmu, "reference")
    unit.initialize(parameters)
    out, _ = unit.run(rows, 0, len(rows))
    unit.close()
    names = [v.name for v in unit.ordered()]
    span, mode, finished = (out[:, names.index(n)]
                            for n in ("ato.span", "ato.mode", "ato.finished"))
    dwell = next(j for j in range(len(out)) if span[j] == 1 and finished[j] == 1) + 50
    assert mode[dwell] == HOLD and span[dwell] == 1, "not in station 2's dwell"
    departs = next(j for j in range(dwell, len(out)) if span[j] == 2)
    running = departs + 300
    assert span[running] == 2 and mode[running] not in (HOLD, SAFE), "span 2 is not running"
    assert departs - dwell < 400, "the dwell replay would not reach the departure"
    return [Case("line mid-span", parameters, with_bad_speed(rows, running + 10), running, 200),
            Case("line in a dwell", parameters, with_bad_speed(rows, departs + 20), dwell, 400)]


def state_cases(fmu: AtoFmu, closed_loop, profiles, line_run) -> list[Case]:  # noqa: F811
    return [nominal_case(closed_loop, profiles), *line_cases(fmu, line_run)]


def started(fmu: AtoFmu, case: Case, name: str = "unit") -> Unit:
    """An instance initialised with the case's parameters and stepped up to its state."""
    unit = Unit(fmu, name)
    unit.initialize(case.parameters)
    unit.run(case.rows, 0, case.at)
    return unit


# ------------------------------------------------------------------------------- the checks

def check_restore(fmu: AtoFmu, case: Case) -> None:
    unit = started(fmu, case)
    state = unit.get_state()
    at_state = unit.read_outputs()
    first, first_warnings = unit.run(case.rows, case.at, case.n)
    unit.fmu.setFMUState(state)
    assert np.array_equal(bits(unit.read_outputs()), bits(at_state)), "outputs not restored"
    again, again_warnings = unit.run(case.rows, case.at, case.n)
    assert np.array_equal(bits(again), bits(first)), f"{case.name}: the repeated steps differ"
    assert again_warnings == first_warnings, case.name
    assert any("safe brake" in w for w in first_warnings), first_warnings   # the bad input's
    assert len({tuple(r) for r in first}) > case.n // 4, "the outputs hardly move: a weak check"
    unit.fmu.freeFMUState(state)
    unit.close()
    assert unit.errors() == ""


def check_fresh_instance(fmu: AtoFmu, case: Case) -> None:
    unit = started(fmu, case)
    state = unit.get_state()
    data = unit.fmu.serializeFMUState(state)
    expected, expected_warnings = unit.run(case.rows, case.at, case.n)
    unit.fmu.freeFMUState(state)
    unit.close()                               # gone: nothing of it may be used below
    assert unit.errors() == ""

    fresh = Unit(fmu, "fresh")                 # only instantiated
    restored = fresh.deserialize(data)
    fresh.fmu.setFMUState(restored)
    again_state = fresh.get_state()
    assert fresh.fmu.serializeFMUState(again_state) == data, "the restored instance's state differs"
    got, warnings = fresh.run(case.rows, case.at, case.n)
    assert np.array_equal(bits(got), bits(expected)), case.name
    assert warnings == expected_warnings, case.name
    for s in (restored, again_state):
        fresh.fmu.freeFMUState(s)
    fresh.close()
    assert fresh.errors() == ""


def check_rolling_back(fmu: AtoFmu, case: Case) -> None:
    """case: the line in a dwell (early), its departure and span 2 after (late)."""
    unit = started(fmu, case)
    half = case.n // 2
    early = unit.get_state()
    first_pass, _ = unit.run(case.rows, case.at, half)
    late = unit.get_state()
    after_late, late_warnings = unit.run(case.rows, case.at + half, half)

    unit.fmu.setFMUState(early)
    assert np.array_equal(bits(unit.run(case.rows, case.at, half)[0]), bits(first_pass))
    unit.fmu.setFMUState(late)
    got, warnings = unit.run(case.rows, case.at + half, half)
    assert np.array_equal(bits(got), bits(after_late)) and warnings == late_warnings
    unit.fmu.setFMUState(early)
    assert np.array_equal(bits(unit.run(case.rows, case.at, half)[0]), bits(first_pass))
    same = unit.get_state(early)               # overwritten in place: now at case.at + half
    assert same.value == early.value
    unit.fmu.setFMUState(late)
    unit.run(case.rows, case.at + half, 10)
    unit.fmu.setFMUState(early)
    assert np.array_equal(bits(unit.run(case.rows, case.at + half, half)[0]), bits(after_late))
    unit.deserialize(unit.fmu.serializeFMUState(late), early)   # deserialized over a state
    unit.fmu.setFMUState(early)
    assert np.array_equal(bits(unit.run(case.rows, case.at + half, half)[0]), bits(after_late))
    for s in (early, late):
        unit.fmu.freeFMUState(s)
    unit.close()
    assert unit.errors() == ""


def model_fields(model_part: bytes) -> dict[str, int]:
    """Offsets of the counts in a model part of a built line (native_ato.c's layout)."""
    u32 = lambda at: int.from_bytes(model_part[at:at + 4], sys.byteorder)      # noqa: E731
    u64 = lambda at: int.from_bytes(model_part[at:at + 8], sys.byteorder)      # noqa: E731
    nvars = u32(0)
    at = 4 + nvars * 8 + nvars * 4 + 16
    for _ in range(nvars):
        length = u64(at)
        at += 8 + (0 if length == 2**64 - 1 else length)
    fields = {"built": at}
    fields["spans"] = at + 4
    n = u32(at + 4)
    fields["grade rows"] = at + 8
    at += 8 + 8 + 3 * 8 * u64(at + 8)
    fields["car"] = at + 8                    # rc_ato_car: mass, A0, A1, A2, gamma, length
    at += 8 + u64(at)
    fields["limit rows"] = at
    at += 8
    for k in range(n):
        if k == 0:
            fields["span limit rows"] = at + 24
        at += 24 + 8 + 16 * u64(at + 24)
    at += 16 * n
    fields["events logged"] = at
    at += 8 * n
    fields["line size"] = at
    fields["line image"] = at + 16                       # after the line size and its struct size
    return fields


def forged(model_part: bytes, at: int, value: int, width: int = 8) -> bytes:
    signed = value < 0
    return (model_part[:at] + value.to_bytes(width, sys.byteorder, signed=signed)
            + model_part[at + width:])


def check_bad_bytes(fmu: AtoFmu, other: AtoFmu, case: Case) -> None:
    foreign_unit = started(other, case, "foreign")          # first: fmpy's FMI 2 logger proxy
    s = foreign_unit.get_state()
    foreign = foreign_unit.fmu.serializeFMUState(s)
    foreign_unit.fmu.freeFMUState(s)
    foreign_unit.close()
    unit = started(fmu, case)
    state = unit.get_state()
    data = unit.fmu.serializeFMUState(state)
    prefix = "fmi2DeSerializeFMUstate: " if fmu.version == 2 else "fmi3DeserializeFMUState: "
    refused(unit, b"", prefix + "0 bytes are too few for an FMU state")
    refused(unit, data[:-1], "(truncated)")
    refused(unit, data + b"\0", "(trailing bytes)")
    refused(unit, foreign, "belongs to another FMU")
    token_len = int.from_bytes(data[28:32], sys.byteorder)
    model_part = data[64 + token_len:-8]
    assert resealed(data, model_part) == data
    corrupt = prefix + "the FMU state is corrupt or of another build"
    for cut in [*range(0, 1300, 97), *range(1300, len(model_part), 4999), len(model_part) - 1]:
        refused(unit, resealed(data, model_part[:cut]), corrupt)
    refused(unit, resealed(data, model_part + b"\0" * 8), corrupt)
    f = model_fields(model_part)
    assert int.from_bytes(model_part[f["spans"]:f["spans"] + 4], sys.byteorder) == 3
    for what, at, value, width in [
            ("built flag", f["built"], 2, 4), ("span count", f["spans"], 0, 4),
            ("span count", f["spans"], 1 << 30, 4), ("grade rows", f["grade rows"], 0, 8),
            ("grade", f["grade rows"], 1 << 40, 8), ("limit rows", f["limit rows"], 1 << 40, 8),
            ("span limit rows", f["span limit rows"], 0, 8),
            ("span limit rows", f["span limit rows"], 1 << 40, 8),
            ("events logged", f["events logged"], -1, 8),
            ("events logged", f["events logged"], 1 << 40, 8),
            ("line size", f["line size"], 12, 8), ("line counts", f["line image"], -1, 4)]:
        refused(unit, resealed(data, forged(model_part, at, value, width)), f"({what})")
    # a longer car (the state's configuration): span 1's grid, made again, is not the saved one
    length_at = f["car"] + 5 * 8
    longer = struct.pack("=d", struct.unpack("=d", model_part[length_at:length_at + 8])[0] + 7.0)
    refused(unit, resealed(data, model_part[:length_at] + longer + model_part[length_at + 8:]),
            "(course: not the one of this span and car)")
    # the last controller's planner block size: the u64 just before its block, which ends the
    # bytes (the block's own numbers may look like a length of what follows them: the largest)
    tail = min(j for j in range(len(model_part) - 8, 0, -8)
               if int.from_bytes(model_part[j:j + 8], sys.byteorder) == len(model_part) - j - 8)
    refused(unit, resealed(data, forged(model_part, tail, len(model_part) - tail - 16)),
            "(planner block size)")

    expected, warnings = unit.run(case.rows, case.at, case.n)     # unchanged: it steps on
    unit.fmu.setFMUState(state)
    got, again = unit.run(case.rows, case.at, case.n)
    assert np.array_equal(bits(got), bits(expected)) and again == warnings
    unit.fmu.freeFMUState(state)
    unit.close()


# ------------------------------------------------------------------------------- the tests

@pytest.fixture(scope="module")
def atos(native_fmus, tmp_path_factory) -> dict[str, AtoFmu]:
    return {name: AtoFmu(name, native_fmus[name],
                         extract(str(native_fmus[name]),
                                 unzipdir=str(tmp_path_factory.mktemp(name))))
            for name in VERSIONS}


@pytest.fixture(scope="module")
def cases(atos, closed_loop, profiles, line_run) -> list[Case]:  # noqa: F811
    return state_cases(atos["AtoControllerNative"], closed_loop, profiles, line_run)


CASE_NAMES = ("nominal", "line mid-span", "line in a dwell")


def case_named(cases: list[Case], name: str) -> Case:
    return next(c for c in cases if c.name == name)


def test_both_fmus_declare_fmu_states(atos):
    for af in atos.values():
        cs = af.md.coSimulation
        assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate, af.name


@pytest.mark.parametrize("case_name", CASE_NAMES)
@pytest.mark.parametrize("name", VERSIONS)
def test_restoring_a_state_repeats_outputs_and_warnings_bit_for_bit(atos, cases, name, case_name):
    check_restore(atos[name], case_named(cases, case_name))


@pytest.mark.parametrize("case_name", CASE_NAMES)
@pytest.mark.parametrize("name", VERSIONS)
def test_a_serialized_state_continues_in_a_fresh_instance(atos, cases, name, case_name):
    check_fresh_instance(atos[name], case_named(cases, case_name))


@pytest.mark.parametrize("name", VERSIONS)
def test_rolling_back_twice_and_overwriting_a_state(atos, cases, name):
    check_rolling_back(atos[name], case_named(cases, "line in a dwell"))


@pytest.mark.parametrize("name", VERSIONS)
def test_bad_states_are_refused_and_the_instance_goes_on(atos, cases, name):
    other = next(n for n in VERSIONS if n != name)
    check_bad_bytes(atos[name], atos[other], case_named(cases, "line mid-span"))


def test_states_taken_before_initialisation_and_before_the_first_step(atos, cases):
    """Set into a running instance, a state taken before initialisation refuses steps until
    the instance is initialised again, and then it runs as a new instance does; so does one
    taken between initialisation and the first step."""
    case = case_named(cases, "nominal")
    for af in atos.values():
        unit = Unit(af, "early")
        blank = unit.get_state()
        unit.initialize(case.parameters)
        first, _ = unit.run(case.rows, 0, 50)
        unit.fmu.setFMUState(blank)
        assert unit.call("doStep", 5.0, 0.1) == ERROR
        assert "DoStep: not allowed in state 'instantiated'" in unit.errors(), af.name
        unit.initialize(case.parameters)
        initialised = unit.get_state()         # and one taken before the first step
        again, _ = unit.run(case.rows, 0, 50)
        assert np.array_equal(bits(again), bits(first)), af.name
        unit.fmu.setFMUState(initialised)
        assert np.array_equal(bits(unit.run(case.rows, 0, 50)[0]), bits(first)), af.name
        for s in (blank, initialised):
            unit.fmu.freeFMUState(s)
        unit.close()


# ---------------------------------------------------------------- random calls with states

STATE_CALLS = ("init", "doStep", "doStepNaN", "setNaN", "reset", "getState", "setState",
               "freeState", "serialize", "deserialize", "deserializeCut", "getAll")


def random_state_calls(name: str, path: str, unzipdir: str, parameters: dict, rows: list,
                       seed: int, n: int) -> list[list]:
    """``n`` calls drawn at random (seeded) on one instance, whatever its state, the state calls
    among them; [call, status] of each. Run in a child process: a crash is its exit code."""
    rng = random.Random(seed)
    unit = Unit(AtoFmu(name, Path(path), unzipdir), "calls")
    states: list[c_void_p] = []
    blobs: list[bytes] = []
    statuses, k = [], 0
    for _ in range(n):
        call = rng.choice(STATE_CALLS)
        if call == "init":
            status = unit.call("enterInitializationMode") if unit.nf.version == 2 else \
                unit.call("enterInitializationMode", None, 0.0)
            if status == OK:
                unit.set(parameters)
                status = unit.call("exitInitializationMode")
            k = 0
        elif call in ("doStep", "doStepNaN"):
            t, h, inputs = rows[k % len(rows)]
            try:
                unit.set(inputs)
            except FMICallException:
                pass                            # not settable in this state: the step says so
            status = unit.call("doStep", t, h if call == "doStep" else math.nan)
            k = k + 1 if status <= WARNING and call == "doStep" else k
        elif call == "setNaN":
            status = unit.call("setReal" if unit.nf.version == 2 else "setFloat64",
                               [unit.nf.variables["filter.speed"].valueReference], [math.nan])
        elif call == "reset":
            status, k = unit.call("reset"), 0
        elif call == "getState":
            try:
                states.append(unit.get_state(rng.choice(states) if states and rng.random() < 0.3
                                             else None))
                status = OK
            except FMICallException as e:
                status = int(e.status)
        elif call == "setState":
            status = unit.call("setFMUState", rng.choice(states)) if states else OK
        elif call == "freeState":
            status = unit.call("freeFMUState", states.pop(rng.randrange(len(states)))) \
                if states else OK
        elif call == "serialize":
            try:
                blobs.append(unit.fmu.serializeFMUState(rng.choice(states)) if states else b"")
                status = OK
            except FMICallException as e:
                status = int(e.status)
        elif call in ("deserialize", "deserializeCut"):
            data = rng.choice(blobs) if blobs else b""
            if call == "deserializeCut" and data:
                data = data[:rng.randrange(len(data))]
            try:
                states.append(unit.deserialize(data))
                status = OK
            except FMICallException as e:
                status = int(e.status)
        else:
            status = max(unit.call("getReal" if unit.nf.version == 2 else "getFloat64",
                                   [v.valueReference for v in unit.nf.outputs
                                    if v.type in ("Real", "Float64")]),
                         unit.call("getString", [unit.nf.variables["span.grade_profile"]
                                                 .valueReference]))
        statuses.append([call, status])
        if status == 4:
            break
    statuses += [["terminate", unit.call("terminate")], ["freeInstance", unit.call("freeInstance")]]
    return statuses


def test_random_call_sequences_with_states_never_crash(atos, cases, tmp_path):
    case = case_named(cases, "nominal")
    spec = tmp_path / "calls.json"
    spec.write_text(json.dumps({"parameters": case.parameters, "rows": case.rows[:300]}))
    here = Path(__file__).resolve().parent
    code = ("import json, sys; sys.path.insert(0, sys.argv[1]); import test_native_ato_state as t; "
            "d = json.load(open(sys.argv[5])); rows = [tuple(r) for r in d['rows']]; "
            "print(json.dumps([t.random_state_calls(sys.argv[2], sys.argv[3], sys.argv[4], "
            "d['parameters'], rows, seed, 120) for seed in range(12)]))")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(here.parents[1]), str(here.parent)]))
    for af in atos.values():
        proc = subprocess.run([sys.executable, "-c", code, str(here), af.name, str(af.path),
                               af.unzipdir, str(spec)], capture_output=True, text=True,
                              timeout=600, cwd=here, env=env)
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs = json.loads(proc.stdout.strip().splitlines()[-1])
        calls = [tuple(c) for run in runs for c in run]
        statuses = [status for _, status in calls]
        assert len(runs) == 12 and 4 not in statuses, af.name          # never fatal
        assert statuses.count(OK) > 300 and statuses.count(ERROR) > 30, af.name
        for name in ("getState", "setState", "deserialize", "doStep"):   # states were used
            assert (name, OK) in calls, (af.name, name)
        assert ("deserializeCut", ERROR) in calls, af.name


# ---------------------------------------------------------------------------- under sanitizers

def sanitized_session(atos: dict[str, AtoFmu], cases: list[Case]) -> None:
    """The checks above on both FMUs (the sanitized process runs this)."""
    for name, af in atos.items():
        for case in cases:
            check_restore(af, case)
            check_fresh_instance(af, case)
        check_rolling_back(af, case_named(cases, "line in a dwell"))
        other = next(n for n in atos if n != name)
        check_bad_bytes(af, atos[other], case_named(cases, "line mid-span"))


def test_the_state_path_is_clean_under_sanitizers(atos, cases, tmp_path):
    folders = {}
    for name, af in atos.items():
        sources = native.ato_c_sources() if af.version == 2 else native_fmi3.ato_c_sources()
        folders[name] = str(sanitized_copy(af, sources, tmp_path / name))
    spec = tmp_path / "cases.json"
    spec.write_text(json.dumps({"folders": folders, "cases": [
        {"name": c.name, "parameters": c.parameters, "rows": c.rows[:c.at + c.n],
         "at": c.at, "n": c.n} for c in cases]}))
    env = sanitizer_env()
    proc = subprocess.run([sys.executable, __file__, str(spec)], capture_output=True, text=True,
                          env=env, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    assert proc.stdout.strip().endswith("ATO-STATE-SANITIZED-DONE"), proc.stdout[-500:]


if __name__ == "__main__":        # the sanitized process: the unzipped FMUs and the cases
    given = json.loads(Path(sys.argv[1]).read_text())
    sanitized_session({n: AtoFmu(n, Path(p), p)
                       for n, p in given["folders"].items()},
                      [Case(c["name"], c["parameters"], [tuple(r) for r in c["rows"]], c["at"],
                            c["n"]) for c in given["cases"]])
    print("ATO-STATE-SANITIZED-DONE")
