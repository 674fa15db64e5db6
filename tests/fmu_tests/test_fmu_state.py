"""FMU states of the native FMUs (issue 28): get / set / free and serialize / deserialize in every
native FMU (RailCarNative, RailCarEstimatorNative; FMI 2.0 and FMI 3.0), through fmpy.

The state is the whole instance (fmu_src/c/native_state.c behind glue_common.c's gc_*_state):
variables, the glue's mode and time, and a deep copy of the C core's chain (its profile buffer,
the identifier's batch, est.method 2's slope window, the plant's noise streams). Checked here:
- restoring a state and repeating the same steps gives bit-identical outputs (exact equality of
  the doubles' bits), with the process and sensor noise on (seeded: the RNG state is restored
  too), a grade and a speed profile, est.method 0 and 2 (the slope window's buffers);
- the serialized bytes, deserialized into a FRESH instance that was only instantiated, set and
  stepped, give the same bits; that instance serializes to the very same bytes;
- rolling back to an earlier state after a later one, twice, and overwriting a state in place;
- truncated, foreign (other magic, other FMU's state, an FMI 2 state in the FMI 3 FMU) and
  corrupt bytes -> fmi2Error / fmi3Error with a message naming what is wrong; the instance
  goes on stepping;
- the pointer rules: freeing NULL is ignored, a freed state is refused, states die with the
  instance that made them; the pythonfmu FMUs declare and answer "no FMU states";
- all of the above once more with the binary built with -fsanitize=address,undefined (both
  glues, both backends: RailCarNative and RailCarEstimatorNative3), in a Python process that
  preloads the sanitizer runtimes (as tests/fmu_tests/test_fmu_sanitized.py does; leak checking
  off, the interpreter keeps memory to the end): any report aborts it.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import zipfile
from ctypes import byref, c_void_p, create_string_buffer
from pathlib import Path
from xml.etree import ElementTree as ET

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave

from conftest import ERROR, OK, ROOT, LogMessage, Slave
from fmu_src.build import native, native_fmi3, toolchain

NATIVE = {  # native FMU -> (the pythonfmu twin it is built beside, FMI version)
    "RailCarNative": ("RailCar", 2),
    "RailCarEstimatorNative": ("RailCarEstimator", 2),
    "RailCarNative3": ("RailCar", 3),
    "RailCarEstimatorNative3": ("RailCarEstimator", 3),
}
PROFILES = ROOT / "scenarios" / "profiles"
STEP = 0.1                           # [s] communication step
BEFORE, AFTER = 150, 100             # steps before the state is taken, steps repeated after it


def bits(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64).view(np.int64)


def railcar_inputs(k: int) -> dict:
    """Hand inputs: traction, coast, brake, a gusting wind [N], [N], [m/s], [t]."""
    t = k * STEP
    return {"traction_force_demand": 30000.0 if t < 12.0 else 0.0,
            "brake_force_demand": 20000.0 if 20.0 <= t < 24.0 else 0.0,
            "wind_speed": 2.0 * math.sin(0.1 * t), "car.payload": 0.0}


def estimator_inputs(n_steps: int, seed: int = 7) -> list[dict]:
    """A car accelerating at 0.5 m/s^2 to 15 m/s, measured with seeded noise (0.05 m/s, 1 m),
    a track-sensor speed every 5 s."""
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(n_steps):
        t = k * STEP
        v = min(0.5 * t, 15.0)
        x = 0.25 * t * t if t <= 30.0 else 225.0 + 15.0 * (t - 30.0)
        t_track = 5.0 * math.floor(t / 5.0)
        rows.append({"traction_force": 20000.0 if t < 30.0 else 3000.0, "brake_force": 0.0,
                     "sensor.speed": v + 0.05 * rng.standard_normal(),
                     "sensor.position": x + rng.standard_normal(),
                     "sensor.track_speed": min(0.5 * t_track, 15.0),
                     "sensor.track_time": t_track})
    return rows



def get_state(fmu, version: int, state: c_void_p | None = None) -> c_void_p:
    """A new FMU state of fmpy's ``fmu`` (FMI ``version`` 2 or 3), or ``state`` overwritten (the
    standard's *FMUstate != NULL, which fmpy's getFMUState does not offer)."""
    if state is None:
        return fmu.getFMUState()
    fn = fmu.fmi2GetFMUstate if version == 2 else fmu.fmi3GetFMUState
    fn(fmu.component, byref(state))
    return state


def deserialize(fmu, version: int, data: bytes, state: c_void_p | None = None) -> c_void_p:
    """``data`` deserialized into a new state or into ``state`` (fmpy's FMU3Slave.deserializeFMUState
    returns nothing: the standard's function is called directly)."""
    state = c_void_p() if state is None else state
    buffer = create_string_buffer(data, len(data))
    if version == 2:
        fmu.fmi2DeSerializeFMUstate(fmu.component, buffer, len(data), byref(state))
    else:
        from ctypes import POINTER, cast
        from fmpy.fmi3 import fmi3Byte
        fmu.fmi3DeserializeFMUState(fmu.component, cast(buffer, POINTER(fmi3Byte)), len(data), byref(state))
    return state

class Unit:
    """One instance of a native FMU through fmpy (FMU2Slave or FMU3Slave), variables by name;
    ``call`` returns the status instead of raising, ``messages`` collects the log. ``native_fmu``:
    an extracted FMU with ``version``, ``md``, ``unzipdir``, ``variables`` and ``as_fmu_file()``
    (NativeFmu here, test_native_ato_state's AtoFmu)."""

    def __init__(self, native_fmu: "NativeFmu", instance_name: str = "unit"):
        self.nf = native_fmu
        self.messages: list[LogMessage] = []
        md = native_fmu.md
        if native_fmu.version == 2:
            self.slave = Slave(native_fmu.as_fmu_file(), instance_name)
            self.messages = self.slave.messages
            self.fmu = self.slave.fmu
        else:
            def logger(_env, status, category, message):
                text = message.decode(errors="replace") if message else ""
                self.messages.append(LogMessage(int(status),
                                                category.decode() if category else None, text))
            self.fmu = FMU3Slave(guid=md.guid, unzipDirectory=native_fmu.unzipdir,
                                 modelIdentifier=md.coSimulation.modelIdentifier,
                                 instanceName=instance_name)
            self.fmu.instantiate(loggingOn=True, logMessage=logger)
        self.outputs = [v for v in md.modelVariables if v.causality == "output"]

    def call(self, function: str, *args) -> int:
        try:
            getattr(self.fmu, function)(*args)
            return OK
        except FMICallException as e:
            return int(e.status)

    def set(self, values: dict) -> None:
        two = self.nf.version == 2
        for name, value in values.items():
            v = self.nf.variables[name]
            vr = [v.valueReference]
            if v.type in ("Real", "Float64"):
                (self.fmu.setReal if two else self.fmu.setFloat64)(vr, [float(value)])
            elif v.type in ("Integer", "Int32"):
                (self.fmu.setInteger if two else self.fmu.setInt32)(vr, [int(value)])
            elif v.type == "Boolean":
                self.fmu.setBoolean(vr, [bool(value)])
            else:
                self.fmu.setString([v.valueReference], [str(value)])

    def initialize(self, parameters: dict) -> None:
        if self.nf.version == 2:
            self.fmu.setupExperiment(startTime=0.0)
            self.fmu.enterInitializationMode()
        else:
            self.fmu.enterInitializationMode(startTime=0.0)
        self.set(parameters)
        self.fmu.exitInitializationMode()

    def step(self, k: int, inputs: dict) -> np.ndarray:
        """Inputs, then the step from k * STEP; all outputs after it (integers as doubles)."""
        self.set(inputs)
        self.fmu.doStep(k * STEP, STEP)
        return self.read_outputs()

    def read_outputs(self) -> np.ndarray:
        """Every output: the Reals, then the Integers, then the Booleans, all as doubles."""
        reals = [v.valueReference for v in self.outputs if v.type in ("Real", "Float64")]
        ints = [v.valueReference for v in self.outputs if v.type in ("Integer", "Int32")]
        bools = [v.valueReference for v in self.outputs if v.type == "Boolean"]
        two = self.nf.version == 2
        values = [*(self.fmu.getReal if two else self.fmu.getFloat64)(reals),
                  *(self.fmu.getInteger if two else self.fmu.getInt32)(ints),
                  *(self.fmu.getBoolean(bools) if bools else [])]
        return np.array(values, dtype=float)

    # -- FMU states (fmpy's FMU3Slave.deserializeFMUState returns nothing: called directly)
    def get_state(self, state: c_void_p | None = None) -> c_void_p:
        return get_state(self.fmu, self.nf.version, state)

    def deserialize(self, data: bytes, state: c_void_p | None = None) -> c_void_p:
        return deserialize(self.fmu, self.nf.version, data, state)

    def errors(self) -> str:
        return "\n".join(m.message for m in self.messages if m.status == ERROR)

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


class NativeFmu:
    """A native FMU of the session's build, extracted once."""

    def __init__(self, name: str, path: Path, unzipdir: str):
        self.name, self.path, self.unzipdir = name, path, unzipdir
        self.twin, self.version = NATIVE[name]
        self.md = read_model_description(str(path))
        self.variables = {v.name: v for v in self.md.modelVariables}

    def as_fmu_file(self):
        from conftest import FmuFile
        return FmuFile(self.name, self.path, self.md, self.unzipdir)

    def is_railcar(self) -> bool:
        return self.twin == "RailCar"


@pytest.fixture(scope="module")
def natives(built_fmus, tmp_path_factory) -> dict[str, NativeFmu]:
    out = {}
    for name in NATIVE:
        path = built_fmus["RailCar"].parent / "native" / f"{name}.fmu"
        out[name] = NativeFmu(name, path, extract(str(path),
                                                  unzipdir=str(tmp_path_factory.mktemp(name))))
    return out


def parameters(nf: NativeFmu, method: int) -> dict:
    """Profiles from scenarios/profiles (absolute paths), est.method 0, or 2 (slope window) with
    est.sigma2_method 1 (the likelihood bank's members and posterior)."""
    values = {"track.grade_profile": str(PROFILES / "steep_grades.csv"),
              "track.speed_profile": str(PROFILES / "default_speed.csv"),
              "est.method": method, "est.slope_window": 10, "est.sigma2_method": int(method == 2)}
    if nf.is_railcar():
        values["seed"] = 12345          # sensor and process noise on (the defaults' std > 0)
    return values


def input_rows(nf: NativeFmu, n_steps: int) -> list[dict]:
    return ([railcar_inputs(k) for k in range(n_steps)] if nf.is_railcar()
            else estimator_inputs(n_steps))


def started(nf: NativeFmu, method: int, name: str = "unit") -> tuple[Unit, list[dict]]:
    """An initialised instance stepped BEFORE steps, and the inputs of BEFORE + 3 * AFTER steps."""
    unit = Unit(nf, name)
    unit.initialize(parameters(nf, method))
    rows = input_rows(nf, BEFORE + 3 * AFTER)
    for k in range(BEFORE):
        unit.step(k, rows[k])
    return unit, rows


def run(unit: Unit, rows: list[dict], first: int, n: int) -> np.ndarray:
    return np.array([unit.step(k, rows[k]) for k in range(first, first + n)])


CASES = [pytest.param(name, method, id=f"{name}-method{method}")
         for name in NATIVE for method in (0, 2)]


@pytest.mark.parametrize("name, method", CASES)
def test_restoring_a_state_repeats_the_steps_bit_for_bit(natives, name, method):
    nf = natives[name]
    unit, rows = started(nf, method)
    state = unit.get_state()
    at_state = unit.read_outputs()
    first = run(unit, rows, BEFORE, AFTER)
    unit.fmu.setFMUState(state)
    assert np.array_equal(bits(unit.read_outputs()), bits(at_state)), "outputs not restored"
    again = run(unit, rows, BEFORE, AFTER)
    assert np.array_equal(bits(again), bits(first)), "the repeated steps differ"
    assert len({tuple(r) for r in first}) > AFTER // 2, "the outputs hardly move: a weak check"
    unit.fmu.freeFMUState(state)
    unit.close()
    assert unit.errors() == ""


@pytest.mark.parametrize("name, method", CASES)
def test_two_instances_given_the_same_calls_save_the_same_bytes(natives, name, method):
    """A state holds only what the calls made: no byte of uninitialised memory (the slope
    window's buffers were saved before they had filled, from malloc)."""
    units = [started(natives[name], method)[0] for _ in range(2)]
    states = [u.get_state() for u in units]
    data = [u.fmu.serializeFMUState(s) for u, s in zip(units, states)]
    assert data[0] == data[1], f"{sum(x != y for x, y in zip(*data))} bytes differ"
    for u, s in zip(units, states):
        u.fmu.freeFMUState(s)
        u.close()
        assert u.errors() == ""


EARLY_STEPS = (0, 5, 30)
"""Steps after initialisation at which state_digests serializes: before est.batch_size's 50 rows
have filled, where the batch buffers hold only what the calls wrote if they were zeroed."""


def state_digests(natives: dict[str, NativeFmu]) -> list[str]:
    """'name method steps sha256' of the serialized state of each native FMU and est.method at
    each of EARLY_STEPS (the child process of the test below prints these)."""
    out = []
    for name in NATIVE:
        for method in (0, 2):
            nf = natives[name]
            unit = Unit(nf, "digest")
            unit.initialize(parameters(nf, method))
            rows = input_rows(nf, EARLY_STEPS[-1])
            for k in range(EARLY_STEPS[-1] + 1):
                if k in EARLY_STEPS:
                    state = unit.get_state()
                    digest = hashlib.sha256(unit.fmu.serializeFMUState(state)).hexdigest()
                    out.append(f"{name} {method} {k} {digest}")
                    unit.fmu.freeFMUState(state)
                if k < EARLY_STEPS[-1]:
                    unit.step(k, rows[k])
            unit.close()
    return out


def test_a_state_holds_no_uninitialised_heap_or_padding(natives):
    """Two processes whose malloc fills new memory with different bytes (glibc's MALLOC_PERTURB_)
    serialize the same bytes for the same calls, right after initialisation and before the
    identification batch has filled (the batch buffers came from malloc and the configurations'
    padding from the stack: 1,926 bytes differed)."""
    unzipdirs = json.dumps({n: str(nf.unzipdir) for n, nf in natives.items()})
    runs = []
    for perturb in ("165", "90"):
        env = dict(os.environ, MALLOC_PERTURB_=perturb,
                   PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "tests")]))
        proc = subprocess.run([sys.executable, __file__, unzipdirs, "--digests"], capture_output=True,
                              text=True, env=env, timeout=300, cwd=ROOT)
        assert proc.returncode == 0, proc.stderr[-4000:]
        runs.append(proc.stdout.split("\n")[:-1])
    assert len(runs[0]) == len(NATIVE) * 2 * len(EARLY_STEPS)
    differ = [a for a, b in zip(*runs) if a != b]
    assert not differ, f"{len(differ)} states differ, e.g. {differ[0]}"


@pytest.mark.parametrize("name, method", CASES)
def test_serialized_state_continues_in_a_fresh_instance(natives, name, method):
    nf = natives[name]
    unit, rows = started(nf, method)
    state = unit.get_state()
    data = unit.fmu.serializeFMUState(state)
    expected = run(unit, rows, BEFORE, AFTER)

    fresh = Unit(nf, "fresh")                  # only instantiated: no setup, no initialisation
    restored = fresh.deserialize(data)
    fresh.fmu.setFMUState(restored)
    again_state = fresh.get_state()
    assert fresh.fmu.serializeFMUState(again_state) == data, "the restored instance's state differs"
    got = run(fresh, rows, BEFORE, AFTER)
    assert np.array_equal(bits(got), bits(expected))
    for s in (restored, again_state):
        fresh.fmu.freeFMUState(s)
    fresh.close()
    unit.fmu.freeFMUState(state)
    unit.close()
    assert unit.errors() == "" and fresh.errors() == ""


@pytest.mark.parametrize("name", NATIVE)
def test_rolling_back_twice_and_overwriting_a_state(natives, name):
    nf = natives[name]
    unit, rows = started(nf, 2)
    early = unit.get_state()
    first_pass = run(unit, rows, BEFORE, AFTER)
    late = unit.get_state()
    after_late = run(unit, rows, BEFORE + AFTER, AFTER)

    unit.fmu.setFMUState(early)                # back to the early state
    assert np.array_equal(bits(run(unit, rows, BEFORE, AFTER)), bits(first_pass))
    unit.fmu.setFMUState(late)                 # forward to the later one
    assert np.array_equal(bits(run(unit, rows, BEFORE + AFTER, AFTER)), bits(after_late))
    unit.fmu.setFMUState(early)                # and back again
    assert np.array_equal(bits(run(unit, rows, BEFORE, AFTER)), bits(first_pass))

    # *FMUstate non-NULL: the same state object now holds the instance at BEFORE + AFTER
    same = unit.get_state(early)
    assert same.value == early.value
    unit.fmu.setFMUState(late)
    run(unit, rows, BEFORE + AFTER, 10)
    unit.fmu.setFMUState(early)
    assert np.array_equal(bits(run(unit, rows, BEFORE + AFTER, AFTER)), bits(after_late))
    # deserializing into an existing state overwrites it too
    unit.deserialize(unit.fmu.serializeFMUState(late), early)
    unit.fmu.setFMUState(early)
    assert np.array_equal(bits(run(unit, rows, BEFORE + AFTER, AFTER)), bits(after_late))
    for s in (early, late):
        unit.fmu.freeFMUState(s)
    unit.close()
    assert unit.errors() == ""


def refused(unit: Unit, data: bytes, phrase: str) -> None:
    """deserialize(data) -> Error with `phrase` logged; nothing written to the state pointer."""
    state = c_void_p()
    before = len(unit.messages)
    try:
        unit.deserialize(data, state)
        status = OK
    except FMICallException as e:
        status = e.status
    new = [m for m in unit.messages[before:] if m.status == ERROR]
    assert status == ERROR, f"{phrase}: status {status}"
    assert state.value is None
    assert any(phrase in m.message for m in new), \
        f"expected '{phrase}' in {[m.message for m in new]}"


def fnv1a64(data: bytes) -> int:
    h = 0xcbf29ce484222325
    for b in data:
        h = ((h ^ b) * 0x100000001b3) & 0xFFFFFFFFFFFFFFFF
    return h


def resealed(data: bytes, model_part: bytes) -> bytes:
    """`data` (a serialized state) with another model part, its lengths and checksum made
    consistent: only the backend's own checks can refuse it (glue_common.c's layout)."""
    token_len = int.from_bytes(data[28:32], sys.byteorder)
    head = bytearray(data[:64 + token_len])
    head[56 + token_len:64 + token_len] = len(model_part).to_bytes(8, sys.byteorder)
    head[32:40] = (len(head) + len(model_part) + 8).to_bytes(8, sys.byteorder)
    body = bytes(head) + model_part
    return body + fnv1a64(body).to_bytes(8, sys.byteorder)


@pytest.mark.parametrize("name", NATIVE)
def test_bad_bytes_are_refused_and_the_instance_goes_on(natives, name):
    nf = natives[name]
    # another FMU's state: the other model, and the same model under the other FMI version
    # (made first: fmpy's FMI 2 logger proxy logs every instance to the latest one's logger)
    foreign = {}
    other_model = next(n for n, (twin, v) in NATIVE.items()
                       if v == nf.version and twin != nf.twin)
    other_version = next(n for n, (twin, v) in NATIVE.items()
                         if twin == nf.twin and v != nf.version)
    for other in (other_model, other_version):
        unit, _ = started(natives[other], 0, "foreign")
        s = unit.get_state()
        foreign[other] = unit.fmu.serializeFMUState(s)
        unit.fmu.freeFMUState(s)
        unit.close()
    unit, rows = started(nf, 2)
    state = unit.get_state()
    data = unit.fmu.serializeFMUState(state)
    prefix = "fmi2DeSerializeFMUstate: " if nf.version == 2 else "fmi3DeserializeFMUState: "
    refused(unit, b"", prefix + "0 bytes are too few for an FMU state")
    refused(unit, data[:20], "20 bytes are too few")
    refused(unit, data[:-1], f"says it is {len(data)} bytes long, but {len(data) - 1} bytes "
                             "were given (truncated)")
    refused(unit, data[:len(data) // 2], "(truncated)")
    refused(unit, data + b"\0", "(trailing bytes)")
    refused(unit, b"X" + data[1:], "not an FMU state of this FMU")
    refused(unit, bytes(len(data)), "not an FMU state of this FMU")
    middle = bytearray(data)
    middle[len(data) // 2] ^= 0x40
    refused(unit, bytes(middle), "checksum mismatch")
    version = bytearray(data)
    version[8] = 9
    refused(unit, bytes(version), "format version 9")
    swapped = bytearray(data)
    swapped[12:16] = data[15:11:-1]
    refused(unit, bytes(swapped), "written on a machine of another byte order")
    windows = bytearray(data)
    windows[17] = 4                             # sizeof(long) on win64
    refused(unit, bytes(windows), "(another platform)")
    layout = bytearray(data[:-8])
    layout[24] ^= 1
    layout += fnv1a64(bytes(layout)).to_bytes(8, sys.byteorder)
    refused(unit, bytes(layout), "written by a build of this FMU with another memory layout")

    for other, foreign_bytes in foreign.items():
        refused(unit, foreign_bytes, "belongs to another FMU")
    # a model part cut short (every length consistent, the checksum right): the reader's own
    # bounds refuse it wherever the cut falls
    token_len = int.from_bytes(data[28:32], sys.byteorder)
    model_part = data[64 + token_len:-8]
    assert resealed(data, model_part) == data
    for cut in [*range(0, 64, 4), *range(64, len(model_part), 997), len(model_part) - 1]:
        refused(unit, resealed(data, model_part[:cut]),
                "the FMU state is corrupt or of another build")
    refused(unit, resealed(data, model_part + b"\0" * 8), "(bytes left over)")

    # still the same instance: the state it had, and it steps on
    expected = run(unit, rows, BEFORE, AFTER)
    unit.fmu.setFMUState(state)
    assert np.array_equal(bits(run(unit, rows, BEFORE, AFTER)), bits(expected))
    unit.fmu.freeFMUState(state)
    unit.close()


@pytest.mark.parametrize("name", NATIVE)
def test_state_pointer_rules(natives, name):
    nf = natives[name]
    other, _ = started(nf, 0, "other")       # first: fmpy's FMI 2 proxy logs to the latest
    unit, _ = started(nf, 0)
    assert unit.call("freeFMUState", c_void_p()) == OK          # NULL: ignored
    state = unit.get_state()
    stale = c_void_p(state.value)
    assert unit.call("freeFMUState", state) == OK and state.value is None
    assert unit.call("setFMUState", stale) == ERROR
    assert unit.call("freeFMUState", stale) == ERROR                # a double free is refused
    assert "is not a live FMU state of this FMU" in unit.errors()
    # a state belongs to the instance that made it: usable by another, freed with its maker
    mine = other.get_state()
    assert unit.call("setFMUState", mine) == OK
    kept = c_void_p(mine.value)
    other.close()
    assert unit.call("setFMUState", kept) == ERROR
    assert unit.call("serializeFMUState", kept) == ERROR
    unit.close()


def test_only_the_native_fmus_declare_fmu_states(built_fmus, natives, railcar):
    """modelDescription.xml: true in the four native FMUs, false in the pythonfmu ones, whose
    binary (pyslave.c) answers "not supported"."""
    def flags(path: Path) -> dict:
        with zipfile.ZipFile(path) as z:
            root = ET.fromstring(z.read("modelDescription.xml"))
        cosim = root.find("CoSimulation")
        return {k: v for k, v in cosim.attrib.items() if "FMUstate" in k or "FMUState" in k}

    for name, nf in natives.items():
        assert set(flags(nf.path).values()) == {"true"}, name
        assert len(flags(nf.path)) == 2
    for name in ("RailCar", "RailCarEstimator", "AtoController"):
        assert set(flags(built_fmus[name]).values()) == {"false"}, name
    with Slave(railcar, "python") as slave:
        slave.initialize()
        assert slave.call("getFMUstate") == ERROR
        assert ("fmi2GetFMUstate: not supported by RailCar (it keeps no FMU states)"
                in slave.log_text())


# ---------------------------------------------------------------------------- under sanitizers

def state_session(natives: dict[str, NativeFmu], name: str) -> None:
    """Every check above on one FMU (the sanitized process runs this)."""
    for method in (0, 2):
        test_restoring_a_state_repeats_the_steps_bit_for_bit(natives, name, method)
        test_serialized_state_continues_in_a_fresh_instance(natives, name, method)
    test_rolling_back_twice_and_overwriting_a_state(natives, name)
    test_bad_bytes_are_refused_and_the_instance_goes_on(natives, name)
    test_state_pointer_rules(natives, name)


def sanitized_copy(extracted, sources: list, folder: Path) -> Path:
    """A copy of the extracted FMU ``extracted`` (``unzipdir``, ``md``, ``version``) in
    ``folder`` whose linux x86-64 binary is rebuilt from ``sources`` under ASan/UBSan."""
    gcc = shutil.which("gcc")
    assert gcc, "no gcc"
    shutil.copytree(extracted.unzipdir, folder)
    target = toolchain.LINUX_X86_64
    platform = target.fmi2_folder if extracted.version == 2 else target.tuple
    binary = folder / "binaries" / platform / f"{extracted.md.coSimulation.modelIdentifier}.so"
    assert binary.is_file()
    flags = [f for f in native.C_FLAGS if f not in ("-O2", "-Wl,--no-undefined")]
    proc = subprocess.run([gcc, *flags, "-O1", "-g", "-fsanitize=address,undefined",
                           "-fno-sanitize-recover=all", "-I", str(native.C_DIR), "-I",
                           str(native.CORE_DIR), "-I", str(toolchain.fmi_headers()),
                           *[str(s) for s in sources], "-o", str(binary), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert b"__asan_" in binary.read_bytes()
    return folder


def sanitizer_env() -> dict:
    """The environment of a Python child process that loads sanitized FMU binaries."""
    gcc = shutil.which("gcc")
    runtimes = [subprocess.run([gcc, f"-print-file-name={lib}"], capture_output=True, text=True,
                               check=True).stdout.strip() for lib in ("libasan.so", "libubsan.so")]
    return dict(os.environ, LD_PRELOAD=" ".join(runtimes),
                ASAN_OPTIONS="detect_leaks=0:abort_on_error=1",
                PYTHONPATH=os.pathsep.join([str(ROOT), str(ROOT / "tests")]))


@pytest.mark.parametrize("name", ["RailCarNative", "RailCarEstimatorNative3"])
def test_state_calls_clean_under_sanitizers(natives, name, tmp_path):
    nf = natives[name]
    spec = native.RAILCAR_SPEC if nf.is_railcar() else native.ESTIMATOR_SPEC
    sources = native.c_sources(spec) if nf.version == 2 else native_fmi3.c_sources(spec)
    unzipdir = sanitized_copy(nf, sources, tmp_path / name)
    unzipdirs = {n: str(unzipdir if n == name else other.unzipdir) for n, other in natives.items()}
    env = sanitizer_env()
    proc = subprocess.run([sys.executable, __file__, json.dumps(unzipdirs), name],
                          capture_output=True, text=True, env=env, timeout=600, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    assert proc.stdout.strip().endswith("STATE-SANITIZED-DONE"), proc.stdout[-500:]


if __name__ == "__main__":        # a child process: unzipped FMUs by name, then the FMU to check
    folders = json.loads(sys.argv[1])      # under the sanitizers, or --digests
    children = {n: NativeFmu(n, Path(p), p) for n, p in folders.items()}
    if sys.argv[2] == "--digests":
        print("\n".join(state_digests(children)))
    else:
        state_session(children, sys.argv[2])
        print("STATE-SANITIZED-DONE")
