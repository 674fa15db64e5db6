"""AtoControllerNative.fmu (fmu_src/c/native_ato.c, FMI 2.0): the pythonfmu AtoController.fmu without
Python, the C core's controller (models/core/ato_line.h) behind our glue.

- fed the recorded inputs of a closed loop of the models chain driven by the Python controller on
  ato_nominal's span (tests/fmu_tests/test_ato_fmu.py closed_loop_on_chain), the native and the
  pythonfmu FMU give the same value of every output at every step, bit for bit, and the same
  event warnings;
- the catalogue of test_ato_supervision.py (bad inputs, steps, parameters) passes on it with the
  same words, and every refusal there and in test_ato_fmu.py's list is word for word the one
  fmu_src/ato_controller.py raises (check_span_parameters, open_line) for the same values;
- a line (line.profile) is refused by name: the pythonfmu FMU runs it;
- fmpy validates it, its binary needs no Python symbol, the table header is current.
Built once per module from the session's pythonfmu AtoController.fmu (a few seconds of gcc).
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from fmpy import extract, read_model_description

from conftest import OK, FmuFile, Slave
from fmu_src.build.native import (ATO_NATIVE_NAME, ATO_TABLE_HEADER,
                                  generate_ato_header)
from fmu_src.variables import ATO, variables_for

import test_ato_fmu as ato_cases
import test_ato_supervision as catalogue

STEP = 0.1                   # [s]
OUTPUTS = tuple(v.name for v in variables_for(ATO) if v.causality == "output")
PARAMETER_STARTS = {v.name: v.start for v in variables_for(ATO) if v.causality == "parameter"}


@pytest.fixture(scope="module")
def native_ato(native_fmus, tmp_path_factory) -> FmuFile:
    """build.py's AtoControllerNative.fmu (the session's build: build_native_ato's recipe)."""
    folder = tmp_path_factory.mktemp("native_ato")
    path = native_fmus["AtoControllerNative"]
    unzipdir = extract(str(path), unzipdir=str(folder / "unzip"))
    return FmuFile("AtoController", path, read_model_description(str(path)), unzipdir)


def _run(fmu: FmuFile, parameters: dict, seen: list[dict]) -> tuple[list[list], list[str]]:
    """Every output after each step fed ``seen``, and the warnings logged."""
    s = Slave(fmu, "closed_loop")
    try:
        s.initialize(parameters)
        rows = []
        for k, inputs in enumerate(seen):
            s.set(inputs)
            assert s.do_step(k * STEP, STEP) in (OK, 1), s.log_text()
            rows.append([s.get(n) for n in OUTPUTS])
        warnings = [m.message for m in s.messages if m.status == 1]
        return rows, warnings
    finally:
        s.close()


@pytest.fixture(scope="module")
def closed_loop():
    """The Python controller driving the models chain over test_ato_fmu.py's span (ato_nominal's):
    what it saw at each step, its commands, the controller."""
    return ato_cases.closed_loop_on_chain()


NOMINAL_IN_RESOURCES = {"span.grade_profile": "profiles/ato_span_grade.csv",
                        "span.speed_limit_profile": "profiles/ato_span_limits.csv",
                        "span.stop": 2150.0, "span.length": 2200.0, "span.schedule": 135.0}
"""ato_nominal's span as its files in the FMUs' resources/ (relative paths resolve there)."""


@pytest.mark.parametrize("where", ["absolute files", "relative, in resources/"])
def test_the_native_and_the_pythonfmu_fmu_give_the_same_outputs_bit_for_bit(
        native_ato, ato_fmu, profiles, closed_loop, where):
    seen, commands, ctrl = closed_loop
    assert ctrl.finished and len(seen) > 1000                 # a whole run, to the stop
    parameters = profiles if where == "absolute files" else NOMINAL_IN_RESOURCES
    native, native_warnings = _run(native_ato, parameters, seen)
    python, python_warnings = _run(ato_fmu, parameters, seen)
    for k, (a, b) in enumerate(zip(native, python)):
        # == on floats is bit-identity here but for -0.0 / 0.0: compare the bits
        bits = [x.hex() if isinstance(x, float) else x for x in a]
        assert bits == [x.hex() if isinstance(x, float) else x for x in b], \
            f"step {k} (t = {k * STEP:.1f} s): native {dict(zip(OUTPUTS, a))}\n" \
            f"pythonfmu {dict(zip(OUTPUTS, b))}"
    assert len(native) == len(python) == len(seen)
    assert native[-1][OUTPUTS.index("ato.finished")] in (True, 1)
    assert native[-1][OUTPUTS.index("ato.replans")] > 10
    if where == "absolute files":       # the Python controller's own run: its commands too
        assert native[-1][OUTPUTS.index("ato.replans")] == ctrl.replans
        named = [OUTPUTS.index(n) for n in ato_cases.OUTPUTS]
        assert [[row[i] for i in named] for row in native] == [
            [c.traction, c.brake, c.mode, c.planned_speed, c.ep_stage] for c in commands]
    assert native_warnings == python_warnings
    assert all(math.isfinite(x) for row in native for x in row)


@pytest.fixture(scope="module")
def profiles(tmp_path_factory) -> dict:
    """ato_nominal's span (test_ato_fmu.py's profiles: grade and limits files)."""
    folder = tmp_path_factory.mktemp("ato_profiles")
    (folder / "grade.csv").write_text(ato_cases.GRADE_CSV)
    (folder / "limits.csv").write_text(ato_cases.LIMIT_CSV)
    return {"span.grade_profile": str(folder / "grade.csv"),
            "span.speed_limit_profile": str(folder / "limits.csv"),
            "span.stop": 2150.0, "span.length": 2200.0, "span.schedule": 135.0}


# ------------------------------------------------------------------ the catalogue of issue 29

@pytest.fixture(scope="module")
def records(native_ato, tmp_path_factory, monkeypatch_module) -> dict:
    """test_ato_supervision.py's cases run on the native FMU (in this process: no Python in it)."""
    work = tmp_path_factory.mktemp("native_supervision")
    monkeypatch_module.chdir(work)
    out = catalogue._catalogue(str(native_ato.path), native_ato.unzipdir, str(work))
    return {(r["kind"], r["case"]): r for r in out}


@pytest.fixture(scope="module")
def monkeypatch_module():
    mp = pytest.MonkeyPatch()
    yield mp
    mp.undo()


@pytest.mark.parametrize("case, words", [(c, w) for c, _, w in catalogue.BAD_INPUTS])
def test_a_bad_input_gives_the_safe_brake_and_a_warning_naming_it(records, case, words):
    catalogue.test_a_bad_input_gives_the_safe_brake_and_a_warning_naming_it(records, case, words)


def test_a_speed_stuck_at_zero_and_unconnected_inputs_are_found(records):
    catalogue.test_a_speed_stuck_at_zero_while_the_car_moves_is_found_within_3_s(records)
    catalogue.test_inputs_left_unconnected_are_found_after_3_s_of_traction(records)


@pytest.mark.parametrize("case, words", [(c, w) for c, _, _, w in catalogue.BAD_STEPS])
def test_a_bad_step_is_discarded_with_a_message_and_changes_nothing(records, case, words):
    catalogue.test_a_bad_step_is_discarded_with_a_message_and_changes_nothing(records, case, words)


@pytest.mark.parametrize("parameters, words", catalogue.BAD_PARAMETERS,
                         ids=[json.dumps(p)[:40] for p, _ in catalogue.BAD_PARAMETERS])
def test_a_bad_parameter_is_refused_naming_it_and_quickly(records, parameters, words):
    catalogue.test_a_bad_parameter_is_refused_naming_it_and_quickly(records, parameters, words)


def _python_refusal(values: dict, resources: str) -> str:
    """What fmu_src/ato_controller.py's _build raises for these parameter values."""
    from fmu_src.adapter import ParameterError
    from fmu_src.ato_controller import check_span_parameters, open_line
    v = dict(PARAMETER_STARTS, **values)
    try:
        check_span_parameters(v, resources)
        open_line(v, resources)
    except ParameterError as e:
        return f"initialisation failed: {e}"
    raise AssertionError(f"the pythonfmu FMU accepts {values}")


REFUSALS = [p for p, _ in catalogue.BAD_PARAMETERS] + [
    {"profiles": True, **p} for p in (       # on ato_nominal's span; test_ato_fmu.py's and more
        {"span.schedule": 60.0}, {"span.stop": 2500.0},
        {"ato.a_ep": 0.0}, {"car.eta_f": 1.5}, {"car.mass": -1.0}, {"car.regen_off_speed": 5.0},
        {"span.speed_limit_profile": "", "span.speed_limit": math.nan}, {"ato.grid_step": 0.2},
        {"span.grade_profile": "no_such_grade.csv"},
        {"limits": "distance_m,speed_mps\n0,20\n"}, {"limits": "distance_m,speed_limit_mps\n0,20\n900,0\n"},
        {"limits": "distance_m,speed_limit_mps\n10,20\n"}, {"limits": "distance_m,speed_limit_mps\n0,abc\n"},
        {"limits": "distance_m,speed_limit_mps\n0,20\n2300,15\n"})]
"""Parameter sets both FMUs refuse ("profiles": over test_ato_fmu.py's grade and limit files;
"limits": a limits file of that text, in the working directory)."""


@pytest.mark.parametrize("parameters", REFUSALS, ids=[json.dumps(p)[:48] for p in REFUSALS])
def test_every_refusal_is_the_pythonfmu_ones_word_for_word(native_ato, profiles, parameters,
                                                           tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    values = dict(parameters)
    if values.pop("profiles", False):
        values = {**profiles, **values}
    if values.get("span.grade_profile") == "<a directory>":
        values["span.grade_profile"] = str(tmp_path)
    if "limits" in values:                 # a limits file of this text
        (tmp_path / "limits.csv").write_text(values.pop("limits"))
        values["span.speed_limit_profile"] = "limits.csv"
    expected = _python_refusal(values, str(Path(native_ato.unzipdir) / "resources"))
    s = Slave(native_ato, "refusal")
    try:
        s.setup(values)
        assert s.exit_init() == 3
        errors = [m.message for m in s.messages if m.status == 3]
    finally:
        s.close()
    assert any(line.endswith(expected) for line in errors), f"{expected!r} not in {errors}"


def test_a_line_is_refused_by_name_and_runs_on_the_pythonfmu_fmu(native_ato, tmp_path):
    line = tmp_path / "line.csv"
    line.write_text("stop_m,length_m,schedule_s,dwell_s,boarding_t\n1500,0,110,20,2\n")
    s = Slave(native_ato, "line")
    try:
        s.setup({"line.profile": str(line)})
        assert s.exit_init() == 3
        assert "line.profile: not covered by the native AtoController" in s.log_text()
        assert "use AtoController.fmu" in s.log_text()
    finally:
        s.close()
    from harness.run.fmus import uncovered
    assert "line.profile" in uncovered(ATO, {"line.profile": str(line)})
    assert uncovered(ATO, {"span.stop": 1500.0}) is None


def test_fmu_auto_picks_the_native_fmu_unless_a_line_is_set(tmp_path):
    from harness.run.fmus import choose
    (tmp_path / "native").mkdir()
    (tmp_path / "AtoController.fmu").write_bytes(b"")
    assert choose("auto", ATO, tmp_path, [("one span", {})]).kind == "python"   # no native FMU
    (tmp_path / "native" / f"{ATO_NATIVE_NAME}.fmu").write_bytes(b"")
    one = choose("auto", ATO, tmp_path, [("one span", {"span.stop": 1500.0})])
    assert one.kind == "native" and one.path.name == f"{ATO_NATIVE_NAME}.fmu"
    line = choose("auto", ATO, tmp_path, [("a line", {"line.profile": "line.csv"})])
    assert line.kind == "python" and "line.profile = 'line.csv'" in line.why


# ------------------------------------------------------------------ the binary and its header

def test_fmpy_validates_the_fmu_and_it_states_what_it_is(native_ato):
    from fmpy.validation import validate_fmu
    assert validate_fmu(str(native_ato.path)) == []
    md = native_ato.md
    assert md.coSimulation.modelIdentifier == ATO and not md.coSimulation.needsExecutionTool
    assert not md.coSimulation.canGetAndSetFMUstate         # this backend saves no FMU state
    assert [v.name for v in md.modelVariables] == [v.name for v in variables_for(ATO)]
    assert native_ato.path.name == f"{ATO_NATIVE_NAME}.fmu"


def test_the_binary_needs_no_python_symbol(native_ato):
    with zipfile.ZipFile(native_ato.path) as z:
        binary = next(n for n in z.namelist() if n.startswith("binaries/linux64/"))
    out = subprocess.run(["nm", "-D", "--undefined-only", str(Path(native_ato.unzipdir) / binary)],
                         capture_output=True, text=True, check=True).stdout
    symbols = [line.split()[-1] for line in out.splitlines() if line.strip()]
    assert symbols and not [s for s in symbols if s.startswith(("Py", "_Py"))], symbols


def test_the_table_header_is_current():
    assert ATO_TABLE_HEADER.read_text(encoding="utf-8") == generate_ato_header()


# ------------------------------------------------------------------ no call sequence crashes

CALLS = ("setupExperiment", "enterInitializationMode", "exitInitializationMode", "doStep",
         "doStepNaN", "setNaN", "setParameter", "getAll", "reset", "terminate", "getFMUstate")


def _random_calls(fmu_path: str, unzipdir: str, seed: int, n: int) -> list[int]:
    """``n`` calls drawn at random (seeded) on one instance, whatever its state; their statuses.
    Run in a child process (test below): a crash is its exit code, not pytest's."""
    import random
    fmu = FmuFile("AtoController", Path(fmu_path), read_model_description(fmu_path), unzipdir)
    rng = random.Random(seed)
    s = Slave(fmu, "calls")
    statuses, t = [], 0.0
    for _ in range(n):
        call = rng.choice(CALLS)
        if call == "setupExperiment":
            status = s.call("setupExperiment", None, 0.0)
        elif call == "doStep":
            status = s.do_step(t, STEP)
            t = t + STEP if status <= 1 else t
        elif call == "doStepNaN":
            status = s.do_step(t, math.nan)
        elif call == "setNaN":
            status = s.call("setReal", [fmu.vr["filter.speed"], fmu.vr["span.stop"]],
                            [math.nan, math.nan])
        elif call == "setParameter":
            status = s.call("setReal", [fmu.vr["span.stop"]], [rng.choice([1500.0, -1.0, 2000.0])])
        elif call == "getAll":
            status = max(s.call("getReal", [v.valueReference for v in fmu.md.modelVariables
                                            if v.type == "Real"]),
                         s.call("getString", [fmu.vr["span.grade_profile"]]))
        elif call == "reset":
            status = s.call("reset")
            t = 0.0
        elif call == "getFMUstate":
            status = s.call("getFMUstate")
        else:
            status = s.call(call)
        statuses.append(status)
        if status == 4:         # fmi2Fatal: FMI 2 allows no further call
            break
    statuses += [s.call("terminate"), s.call("freeInstance")]    # whatever the state
    s.freed = True
    return statuses


def test_no_call_sequence_crashes_the_host(native_ato):
    code = ("import json, sys; sys.path.insert(0, sys.argv[1]); import test_native_ato_fmu as t; "
            "print(json.dumps([t._random_calls(sys.argv[2], sys.argv[3], seed, 150) "
            "for seed in range(20)]))")
    here = Path(__file__).resolve().parent
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(here.parents[1]), str(here.parent)]))
    proc = subprocess.run([sys.executable, "-c", code, str(here), str(native_ato.path),
                           native_ato.unzipdir], capture_output=True, text=True, timeout=600,
                          cwd=here, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    statuses = [s for run in runs for s in run]
    assert len(runs) == 20 and 4 not in statuses            # never fatal
    assert statuses.count(0) > 200 and statuses.count(3) > 50   # both successes and refusals met
