"""AtoControllerNative3.fmu (fmu_src/build/native_fmi3.py build_native_ato3): the backend of the FMI 2
AtoControllerNative (fmu_src/c/native_ato.c) and the C core behind the FMI 3 glue
(fmu_src/c/fmi3_glue.c), run through fmpy's FMU3Slave.

- its description is the one table's in FMI 3 (Booleans as Boolean with "true"/"false" starts,
  FMU states (test_native_ato_state.py), outputs without direct feedthrough), fmpy validates it, it is the writer's;
- on ato_nominal's span, fed the closed loop's recorded inputs (test_native_ato_fmu.py's
  drivers, their ``Slave`` swapped for Slave3 here), every output at every step is the FMI 2
  native FMU's bit for bit (which test_native_ato_fmu.py holds to the pythonfmu AtoController),
  and so are the warnings;
- test_ato_supervision.py's catalogue (bad inputs, steps, parameters) and
  test_native_ato_fmu.py's list of refusals pass on it unchanged: the same runner and the same
  assertions, through an FMU3Slave that answers under FMU2Slave's names;
- no call sequence crashes the host; no AtoControllerNative* binary (FMI 2 and 3, every
  platform) needs a Python symbol or library.
"""
from __future__ import annotations

import ctypes
import json
import math
import os
import random
import re
import subprocess
import sys
import zipfile
from pathlib import Path
from types import SimpleNamespace

import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave, fmi3Boolean, fmi3Float64
from fmpy.validation import validate_fmu

import conftest
import test_ato_supervision as catalogue
import test_native_ato_fmu as ato2
from conftest import FmuFile, Slave
from fmu_src.build import native_fmi3
from fmu_src.build.toolchain import available_targets
from fmu_src.variables import ATO, variables_for
from test_native_ato_fmu import (closed_loop, monkeypatch_module, native_ato,  # noqa: F401
                                 profiles)
from test_native_fmi3 import Fmi3AsFmi2, _Md3
from test_native_fmi3 import Slave3 as Fmi3Slave

STEP = ato2.STEP             # [s]
HERE = Path(__file__).resolve().parent


# ------------------------------------------------------------- FMI 3 under FMI 2's names

class _RawDoStep:
    """fmi3DoStep answering as test_ato_supervision's raw fmi2DoStep call does: the status,
    Warning included (fmpy's doStep raises above Warning and hides Warning itself)."""

    def __init__(self, fmu: FMU3Slave):
        self.fmu = fmu
        self.argtypes = self.restype = None       # what the caller sets for fmi2DoStep

    def __call__(self, component, t: float, h: float, no_set_prior: int) -> int:
        event, terminate, early, last = fmi3Boolean(), fmi3Boolean(), fmi3Boolean(), fmi3Float64()
        return self.fmu.dll.fmi3DoStep(component, t, h, fmi3Boolean(bool(no_set_prior)),
                                       ctypes.byref(event), ctypes.byref(terminate),
                                       ctypes.byref(early), ctypes.byref(last))


class AtoFmi3AsFmi2(Fmi3AsFmi2):
    """test_native_fmi3's Fmi3AsFmi2 with what the AtoController's drivers also call: Booleans,
    the raw doStep (``dll.fmi2DoStep``, ``component``) and fmi2LastSuccessfulTime, which is
    FMI 3's independent variable "time" (value reference ``time_vr``): the end of the last
    step that was not discarded."""

    def __init__(self, fmu: FMU3Slave, time_vr: int):
        super().__init__(fmu)
        self.component = fmu.component
        self.dll = SimpleNamespace(fmi2DoStep=_RawDoStep(fmu))
        self.time_vr = time_vr

    def getBoolean(self, vr):
        return self.fmu.getBoolean(vr)

    def setBoolean(self, vr, values):
        self.fmu.setBoolean(vr, values)

    def getRealStatus(self, kind: int) -> float:
        assert kind == 2, "only fmi2LastSuccessfulTime (2) has an FMI 3 counterpart"
        return self.fmu.getFloat64([self.time_vr])[0]


class Slave3(Fmi3Slave):
    """test_native_fmi3.Slave3 on AtoControllerNative3, its FMI 2 face AtoFmi3AsFmi2."""

    @staticmethod
    def adapter(fmu3: FMU3Slave, fmu: FmuFile) -> AtoFmi3AsFmi2:
        time_vr = next(v.valueReference for v in fmu.md._md.modelVariables
                       if v.causality == "independent")
        return AtoFmi3AsFmi2(fmu3, time_vr)


def fmi2_view(fmu: FmuFile) -> FmuFile:
    """``fmu`` as the FMI 2 drivers read it (an FMI 3 description behind _Md3)."""
    if fmu.md.fmiVersion != "3.0" or isinstance(fmu.md, _Md3):
        return fmu
    return FmuFile(fmu.name, fmu.path, _Md3(fmu.md), fmu.unzipdir)


def any_slave(fmu: FmuFile, *args, **kwargs) -> Slave:
    """conftest.Slave for an FMI 2 FMU, Slave3 for an FMI 3 one (by its description)."""
    fmu = fmi2_view(fmu)
    return (Slave3 if fmu.md.fmiVersion == "3.0" else Slave)(fmu, *args, **kwargs)


@pytest.fixture(scope="module")
def native_ato3(native_fmus, tmp_path_factory) -> FmuFile:
    """build.py's AtoControllerNative3.fmu (the session's build), as the FMI 2 drivers read it."""
    path = native_fmus["AtoControllerNative3"]
    unzipdir = extract(str(path), unzipdir=str(tmp_path_factory.mktemp("native_ato3") / "unzip"))
    return fmi2_view(FmuFile(ATO, path, read_model_description(str(path)), unzipdir))


@pytest.fixture
def fmi3_aware_drivers(monkeypatch):
    """test_native_ato_fmu's drivers open FMI 3 FMUs with Slave3 (these tests only)."""
    monkeypatch.setattr(ato2, "Slave", any_slave)


# ------------------------------------------------------------------------------ the package

def test_fmpy_validates_it_and_it_describes_the_table_in_fmi3(native_ato3, native_ato):
    assert validate_fmu(str(native_ato3.path)) == []
    md = native_ato3.md
    assert md.fmiVersion == "3.0" and native_ato3.path.name == f"{native_fmi3.ATO_NATIVE3_NAME}.fmu"
    assert md.coSimulation.modelIdentifier == ATO and not md.coSimulation.needsExecutionTool
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
    table = variables_for(ATO)
    raw = read_model_description(str(native_ato3.path)).modelVariables
    assert [v.name for v in raw] == [v.name for v in table] + ["time"]
    assert [v.valueReference for v in raw] == list(range(len(table) + 1))
    fmi3_type = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean", "String": "String"}
    assert [v.type for v in raw[:-1]] == [fmi3_type[v.type] for v in table]
    # the same variables, causalities and FMI 2 types as the FMI 2 native FMU
    assert [(v.name, v.causality, v.type) for v in md.modelVariables] == [
        (v.name, v.causality, v.type) for v in native_ato.md.modelVariables]
    with zipfile.ZipFile(native_ato3.path) as z:
        xml = z.read("modelDescription.xml")
    assert xml == native_fmi3.ato_model_description_xml(native_fmi3.ato_instantiation_token())


def test_its_booleans_are_fmi3_booleans_with_the_tables_starts(native_ato3):
    """ato.replan and ato.use_estimates (parameters, start true) and ato.finished,
    ato.using_estimates (calculated outputs: no start) are <Boolean> in FMI 3, and reading and
    setting them goes through fmi3GetBoolean / fmi3SetBoolean (fmi3Boolean is a bool, the
    backend's fmi2Boolean an int: fmi3_glue.c converts)."""
    with zipfile.ZipFile(native_ato3.path) as z:
        xml = z.read("modelDescription.xml").decode()
    booleans = {v.name: v for v in variables_for(ATO) if v.type == "Boolean"}
    assert set(booleans) == {"ato.replan", "ato.use_estimates", "ato.finished",
                             "ato.using_estimates"}
    for name, v in booleans.items():
        element = re.search(rf'<Boolean name="{re.escape(name)}"[^>]*/>', xml)
        assert element, f"{name} is not a <Boolean>"
        start = re.search(r'start="(\w+)"', element.group(0))
        if v.causality == "output":
            assert start is None and 'initial="calculated"' in element.group(0)
        else:
            assert start.group(1) == ("true" if v.start else "false")
    # no direct feedthrough: every output depends on no input of the same step, as in FMI 2
    outputs = re.findall(r"<Output [^>]*/>", xml)
    assert len(outputs) == 11 and all('dependencies=""' in o for o in outputs)
    s = Slave3(native_ato3, "booleans")
    try:
        s.setup({"ato.replan": False})
        assert s.get("ato.replan") is False and s.get("ato.use_estimates") is True
        assert s.exit_init() == 0, s.log_text()
        assert s.get("ato.finished") is False and s.get("ato.using_estimates") is False
    finally:
        s.close()


def test_sources_are_the_fmi3_glue_and_the_fmi2_fmus_backend(native_ato3):
    """buildDescription.xml lists fmi3_glue.c, glue_common.c, native_ato.c and the core, not
    fmi2_glue.c; sources/ ships them with every header they include (that sources/ compiles
    alone for every platform: test_cross_platform.py's test_sources_alone_compile_...)."""
    listed = read_model_description(
        str(native_ato3.path)).buildConfigurations[0].sourceFileSets[0].sourceFiles
    assert listed == [p.name for p in native_fmi3.ato_c_sources()]
    assert {"fmi3_glue.c", "glue_common.c", "native_ato.c"} <= set(listed)
    assert "fmi2_glue.c" not in listed and "native_common.c" not in listed
    with zipfile.ZipFile(native_ato3.path) as z:
        shipped = {n.removeprefix("sources/") for n in z.namelist() if n.startswith("sources/")}
    assert shipped == {p.name for p in [*native_fmi3.ato_c_sources(), *native_fmi3.ato_c_headers()]
                       } | {"buildDescription.xml"}


# ------------------------------------------------- the FMI 2 native FMU's outputs, bit for bit

@pytest.mark.parametrize("where", ["absolute files", "relative, in resources/"])
def test_fmi3_outputs_are_the_fmi2_native_ones_bit_for_bit(native_ato3, native_ato, profiles,
                                                           closed_loop, where, fmi3_aware_drivers):
    seen, commands, ctrl = closed_loop
    parameters = profiles if where == "absolute files" else ato2.NOMINAL_IN_RESOURCES
    fmi3, fmi3_warnings = ato2._run(native_ato3, parameters, seen)
    fmi2, fmi2_warnings = ato2._run(native_ato, parameters, seen)
    assert len(fmi3) == len(fmi2) == len(seen) > 1000
    for k, (a, b) in enumerate(zip(fmi3, fmi2)):
        # == on floats is bit-identity but for -0.0 / 0.0: compare the bits
        assert [x.hex() if isinstance(x, float) else x for x in a] == [
            x.hex() if isinstance(x, float) else x for x in b], \
            f"step {k}: FMI 3 {dict(zip(ato2.OUTPUTS, a))}\nFMI 2 {dict(zip(ato2.OUTPUTS, b))}"
    assert fmi3_warnings == fmi2_warnings
    assert fmi3[-1][ato2.OUTPUTS.index("ato.finished")] is True      # an fmi3Boolean, a bool
    if where == "absolute files":       # and the Python controller's own commands
        named = [ato2.OUTPUTS.index(n) for n in ato2.ato_cases.OUTPUTS]
        assert [[row[i] for i in named] for row in fmi3] == [
            [c.traction, c.brake, c.mode, c.planned_speed, c.ep_stage] for c in commands]
        assert fmi3[-1][ato2.OUTPUTS.index("ato.replans")] == ctrl.replans


def test_the_comparison_sees_one_ulp(native_ato3, profiles, closed_loop, fmi3_aware_drivers):
    """A car.mass one ulp off changes some output bits: the comparison above can fail."""
    seen, _, _ = closed_loop
    base, _ = ato2._run(native_ato3, profiles, seen[:400])
    nudged, _ = ato2._run(native_ato3, {**profiles, "car.mass": math.nextafter(30.0, 31.0)},
                          seen[:400])
    assert [[x.hex() if isinstance(x, float) else x for x in row] for row in base] != [
        [x.hex() if isinstance(x, float) else x for x in row] for row in nudged]


# ------------------------------------------- the catalogue of issue 29, unchanged, on FMI 3

@pytest.fixture(scope="module")
def records3(native_ato3, tmp_path_factory, monkeypatch_module) -> dict:  # noqa: F811
    """test_ato_supervision.py's cases through its own runner (_catalogue), which opens the FMU
    with conftest.Slave: Slave3 for these cases (in this process: no Python in the FMU)."""
    work = tmp_path_factory.mktemp("native3_supervision")
    monkeypatch_module.chdir(work)
    monkeypatch_module.setattr(conftest, "Slave", any_slave)
    try:
        out = catalogue._catalogue(str(native_ato3.path), native_ato3.unzipdir, str(work))
    finally:
        monkeypatch_module.setattr(conftest, "Slave", Slave)
    return {(r["kind"], r["case"]): r for r in out}


@pytest.mark.parametrize("case, words", [(c, w) for c, _, w in catalogue.BAD_INPUTS])
def test_a_bad_input_gives_the_safe_brake_and_a_warning_naming_it(records3, case, words):
    catalogue.test_a_bad_input_gives_the_safe_brake_and_a_warning_naming_it(records3, case, words)


def test_a_speed_stuck_at_zero_and_unconnected_inputs_are_found(records3):
    catalogue.test_a_speed_stuck_at_zero_while_the_car_moves_is_found_within_3_s(records3)
    catalogue.test_inputs_left_unconnected_are_found_after_3_s_of_traction(records3)


@pytest.mark.parametrize("case, words", [(c, w) for c, _, _, w in catalogue.BAD_STEPS])
def test_a_bad_step_is_discarded_with_a_message_and_changes_nothing(records3, case, words):
    catalogue.test_a_bad_step_is_discarded_with_a_message_and_changes_nothing(records3, case,
                                                                              words)


@pytest.mark.parametrize("parameters, words", catalogue.BAD_PARAMETERS,
                         ids=[json.dumps(p)[:40] for p, _ in catalogue.BAD_PARAMETERS])
def test_a_bad_parameter_is_refused_naming_it_and_quickly(records3, parameters, words):
    catalogue.test_a_bad_parameter_is_refused_naming_it_and_quickly(records3, parameters, words)


@pytest.mark.parametrize("parameters", ato2.REFUSALS, ids=[json.dumps(p)[:48] for p in ato2.REFUSALS])
def test_every_refusal_is_the_pythonfmu_ones_word_for_word(native_ato3, profiles, parameters,
                                                           tmp_path, monkeypatch,
                                                           fmi3_aware_drivers):
    ato2.test_every_refusal_is_the_pythonfmu_ones_word_for_word(native_ato3, profiles, parameters,
                                                                tmp_path, monkeypatch)


# ------------------------------------------------------------------ no call sequence crashes

CALLS = ("enterInitializationMode", "exitInitializationMode", "doStep", "doStepNaN", "setNaN",
         "setParameter", "setBoolean", "getAll", "reset", "terminate", "getFMUState",
         "enterEventMode", "enterStepMode", "updateDiscreteStates")


def _random_calls(fmu_path: str, unzipdir: str, seed: int, n: int) -> list[int]:
    """``n`` FMI 3 calls drawn at random (seeded) on one instance, whatever its state; their
    statuses. Run in a child process (test below): a crash is its exit code, not pytest's."""
    md = read_model_description(fmu_path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    reals = [v.valueReference for v in md.modelVariables if v.type == "Float64"]
    booleans = [v.valueReference for v in md.modelVariables if v.type == "Boolean"]
    rng = random.Random(seed)
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=unzipdir,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="calls")
    fmu.instantiate(loggingOn=True, logMessage=lambda *args: None)

    def call(function, *args) -> int:
        try:
            getattr(fmu, function)(*args)
            return 0
        except FMICallException as e:
            return int(e.status)

    statuses, t = [], 0.0
    for _ in range(n):
        name = rng.choice(CALLS)
        if name == "doStep":
            status = call("doStep", t, STEP)
            t = t + STEP if status <= 1 else t
        elif name == "doStepNaN":
            status = call("doStep", t, math.nan)
        elif name == "setNaN":
            status = call("setFloat64", [vr["filter.speed"], vr["span.stop"]], [math.nan] * 2)
        elif name == "setParameter":
            status = call("setFloat64", [vr["span.stop"]], [rng.choice([1500.0, -1.0, 2000.0])])
        elif name == "setBoolean":
            status = call("setBoolean", [vr["ato.replan"], vr["ato.finished"]], [False, True])
        elif name == "getAll":
            status = max(call("getFloat64", reals), call("getBoolean", booleans),
                         call("getString", [vr["span.grade_profile"]]))
        elif name == "reset":
            status = call("reset")
            t = 0.0
        else:
            status = call(name)
        statuses.append(status)
        if status == 4:         # fmi3Fatal: FMI 3 allows no further call
            break
    statuses += [call("terminate"), call("freeInstance")]         # whatever the state
    return statuses


def test_no_call_sequence_crashes_the_host(native_ato3):
    code = ("import json, sys; sys.path.insert(0, sys.argv[1]); import test_native_ato3_fmu as t; "
            "print(json.dumps([t._random_calls(sys.argv[2], sys.argv[3], seed, 150) "
            "for seed in range(20)]))")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(HERE.parents[1]), str(HERE.parent)]))
    proc = subprocess.run([sys.executable, "-c", code, str(HERE), str(native_ato3.path),
                           native_ato3.unzipdir], capture_output=True, text=True, timeout=600,
                          cwd=HERE, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    statuses = [s for run in runs for s in run]
    assert len(runs) == 20 and 4 not in statuses                  # never fatal
    assert statuses.count(0) > 200 and statuses.count(3) > 50     # successes and refusals met


# ------------------------------------------------- every AtoControllerNative binary: no Python

PYTHON_SYMBOL = re.compile(r"^_?Py|^python", re.I)


def _undefined_symbols(binary: Path) -> list[str]:
    """What an ELF library needs from elsewhere (nm -D --undefined-only; the aarch64 binutils'
    nm for an aarch64 library when it is here), or the DLLs and functions a PE DLL imports."""
    head = binary.read_bytes()[:20]
    if head[:2] == b"MZ":
        dump = subprocess.run(["x86_64-w64-mingw32-objdump", "-p", str(binary)],
                              capture_output=True, text=True, check=True).stdout
        imports = dump.split("The Import Tables", 1)[1].split("The Export Tables", 1)[0]
        return (re.findall(r"DLL Name: (\S+)", imports)
                + re.findall(r"^\s+[0-9a-f]+\s+\d+\s+(\S+)$", imports, re.M))
    nm = "nm"
    if int.from_bytes(head[18:20], "little") == 183:          # e_machine EM_AARCH64
        nm = "aarch64-linux-gnu-nm" if subprocess.run(
            ["which", "aarch64-linux-gnu-nm"], capture_output=True).returncode == 0 else "nm"
    out = subprocess.run([nm, "-D", "--undefined-only", str(binary)], capture_output=True,
                         text=True, check=True).stdout
    return [line.split()[-1] for line in out.splitlines() if line.strip()]


@pytest.mark.parametrize("name", ["AtoControllerNative", "AtoControllerNative3"])
def test_no_atocontrollernative_binary_needs_python(native_fmus, name, tmp_path):
    """nm -D --undefined-only of every binary the FMU carries (linux64/x86_64-linux,
    aarch64-linux; the Windows DLL: its import table) names no Python symbol or library, and
    needs only the C library (and on Windows only what Windows ships)."""
    with zipfile.ZipFile(native_fmus[name]) as z:
        members = [n for n in z.namelist() if n.startswith("binaries/") and not n.endswith("/")]
        z.extractall(tmp_path, members)
    folders = {m.split("/")[1] for m in members}
    assert folders == {t.fmi2_folder if name == "AtoControllerNative" else t.tuple
                       for t in available_targets(report=False)}
    for member in members:
        symbols = _undefined_symbols(tmp_path / member)
        assert symbols, f"{member}: no undefined symbol at all? (nm or objdump read nothing)"
        python = [s for s in symbols if PYTHON_SYMBOL.search(s)]
        assert not python, f"{member} needs Python: {python}"
        if member.endswith(".dll"):
            dlls = {s.lower() for s in symbols if s.lower().endswith(".dll")}
            assert dlls == {"kernel32.dll", "msvcrt.dll"}, dlls
