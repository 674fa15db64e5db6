"""AtoControllerNative.fmu (fmu_src/c/native_ato.c, FMI 2.0): the pythonfmu AtoController.fmu without
Python, the C core's controller (models/core/ato_line.h) behind our glue.

- fed the recorded inputs of a closed loop of the models chain driven by the Python controller on
  ato_nominal's span (tests/fmu_tests/test_ato_fmu.py closed_loop_on_chain), the native and the
  pythonfmu FMU give the same value of every output at every step, bit for bit, and the same
  event warnings;
- the catalogue of test_ato_supervision.py (bad inputs, steps, parameters) passes on it with the
  same words, and every refusal there and in test_ato_fmu.py's list is word for word the one
  fmu_src/ato_controller.py raises (check_span_parameters, open_line) for the same values;
- a line (line.profile, line.speed_limit_profile): fed the recorded inputs of the models chain
  driven over scenarios/library/ato_line.toml's three spans by models.ato.line.LineController,
  the native and the pythonfmu FMU give the same value of every output at every step, bit for
  bit, and the same warnings, and the commands are the Python line's own; every bad line file
  of a catalogue (the CSV rules, each row's checks, a span the ATO cannot run, files that cannot
  be read, the order of refusals) is refused by both FMUs with the words
  fmu_src/ato_controller.py's open_line raises, and files both accept run alike;
  ``--fmu auto`` picks the native FMU for a line;
- fmpy validates it, its binary needs no Python symbol, the table header is current.
Built once per module from the session's pythonfmu AtoController.fmu (a few seconds of gcc).
"""
from __future__ import annotations

import json
import math
import os
import random
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


# ------------------------------------------------------------------ a line of several spans

LINE_SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "library" / "ato_line.toml"


@pytest.fixture(scope="module")
def line_run(tmp_path_factory):
    """ato_line.toml run on the models chain by the harness's AtoDriver (models.ato.line), and the
    AtoController parameters of that line: span 1 as span.*, spans 2 and 3 in line.profile and
    line.speed_limit_profile as `python -m harness system build` writes them, the scenario's car
    and tuning."""
    from dataclasses import fields
    from harness.run.driver import run_on_chain
    from harness.run.scenario import load_scenario
    from harness.systems.scenario_system import limits_csv, line_csv, line_limits_csv
    scenario = load_scenario(LINE_SCENARIO)
    result = run_on_chain(scenario)
    setup = scenario.ato_setup()
    first = setup.spans[0].span
    folder = tmp_path_factory.mktemp("ato_line")
    for name, data in (("limits.csv", limits_csv(first.limit_distances, first.limit_speeds)),
                       ("line.csv", line_csv(setup.spans)),
                       ("line_limits.csv", line_limits_csv(setup.spans))):
        (folder / name).write_bytes(data)
    parameters = {"span.stop": first.stop, "span.length": first.length,
                  "span.schedule": first.schedule,
                  "span.grade_profile": scenario.parameters["track.grade_profile"],
                  "span.speed_limit_profile": str(folder / "limits.csv"),
                  "line.profile": str(folder / "line.csv"),
                  "line.speed_limit_profile": str(folder / "line_limits.csv")}
    for prefix, obj in (("car", setup.car), ("ato", setup.tuning)):
        for f in fields(obj):
            name = f"{prefix}.{f.name}"
            if name in PARAMETER_STARTS:
                parameters[name] = getattr(obj, f.name)
            else:                       # a field the FMU has no parameter for keeps its default
                assert getattr(obj, f.name) == getattr(type(obj)(), f.name), name
    return result, parameters


LINE_INPUTS = tuple(v.name for v in variables_for(ATO) if v.causality == "input")


def _run_line(fmu: FmuFile, parameters: dict, result, steps: int) -> tuple[list[list], list[str]]:
    """Every output after each of the first ``steps`` steps, fed the run's recorded outputs (as
    the harness's loop fed its AtoDriver), and the warnings logged."""
    s = Slave(fmu, "line")
    columns = [[float(x) for x in result.signals[n]] for n in LINE_INPUTS]
    h = float(result.time[1] - result.time[0])
    try:
        s.initialize(parameters)
        rows = []
        for j in range(steps):
            s.set({n: c[j] for n, c in zip(LINE_INPUTS, columns)})
            assert s.do_step(float(result.time[j]), h) in (OK, 1), s.log_text()
            rows.append([s.get(n) for n in OUTPUTS])
        return rows, [m.message for m in s.messages if m.status == 1]
    finally:
        s.close()


def test_a_line_runs_on_the_native_fmu_bit_for_bit_as_on_the_pythonfmu_fmu(native_ato, ato_fmu,
                                                                           line_run):
    result, parameters = line_run
    steps = len(result.driver_steps)
    assert result.driver_steps[-1].span == 2 and steps > 3500       # the whole line, 3 spans
    native, native_warnings = _run_line(native_ato, parameters, result, steps)
    python, python_warnings = _run_line(ato_fmu, parameters, result, steps)
    for k, (a, b) in enumerate(zip(native, python)):
        bits = [x.hex() if isinstance(x, float) else x for x in a]     # -0.0 is not 0.0 here
        assert bits == [x.hex() if isinstance(x, float) else x for x in b], \
            f"step {k} (t = {result.time[k]:.1f} s): native {dict(zip(OUTPUTS, a))}\n" \
            f"pythonfmu {dict(zip(OUTPUTS, b))}"
    assert len(native) == len(python) == steps
    column = {n: [row[OUTPUTS.index(n)] for row in native] for n in OUTPUTS}
    # the Python line's own commands, span and boarding
    assert [[column[n][k] for n in ("traction_force_demand", "brake_force_demand", "ato.mode",
                                    "ato.planned_speed", "ato.ep_stage", "ato.span")]
            for k in range(steps)] == [
        [st.command.traction, st.command.brake, st.command.mode, st.command.planned_speed,
         st.command.ep_stage, st.span + 1] for st in result.driver_steps]
    payload = 0.0
    for k, st in enumerate(result.driver_steps):
        payload += st.payload_change
        assert column["ato.payload"][k] == payload, k
    assert sorted(set(column["ato.span"])) == [1, 2, 3] and column["ato.payload"][-1] == 2.0
    assert column["ato.finished"][-1] in (True, 1)
    assert native_warnings == python_warnings
    # a line's events name their span: "t = 12.300 s: span 2: ..."
    assert all(w.split(": ", 1)[1].startswith("span ") for w in native_warnings), native_warnings


GOOD_LINE = "stop_m,length_m,schedule_s,dwell_s,boarding_t\n700,0,70,30,4\n"
SPAN1 = {"span.stop": 900.0, "span.length": 950.0, "span.schedule": 80.0}
"""A short level span 1 and a good line file of one more span (test_ssp_line.py's)."""

LINE_HEADER = "stop_m,length_m,schedule_s,dwell_s,boarding_t\n"
LIMIT_HEADER = "span,distance_m,speed_limit_mps\n"
BAD_LINES = [         # (what, line.profile text, line.speed_limit_profile text or None, extra values)
    ("wrong header", "stop,length_m,schedule_s,dwell_s,boarding_t\n700,0,70,30,4\n", None, {}),
    ("header of 6 columns", LINE_HEADER.strip() + ",x\n", None, {}),
    ("empty file", "", None, {}),
    ("comments only", "# nothing\n\n", None, {}),
    ("no span", LINE_HEADER, None, {}),
    ("not a number", GOOD_LINE + "# next\n800,0,fast,30,0\n", None, {}),
    ("four values", GOOD_LINE + "800,0,80,30\n", None, {}),
    ("six values", GOOD_LINE + "800,0,80,30,0,1\n", None, {}),
    ("nan", GOOD_LINE + "800,0,nan,30,0\n", None, {}),
    ("inf boarding", GOOD_LINE + "800,0,80,30,-inf\n", None, {}),
    ("a hex number", GOOD_LINE + "0x10,0,80,30,0\n", None, {}),
    ("stop 0", GOOD_LINE + "0,0,80,30,0\n", None, {}),
    ("stop < 0", GOOD_LINE + "-5.5,0,80,30,0\n", None, {}),
    ("length < stop", GOOD_LINE + "800,700,80,30,0\n", None, {}),
    ("schedule -0", GOOD_LINE + "800,0,-0.0,30,0\n", None, {}),
    ("dwell 0", GOOD_LINE + "800,0,80,0,0\n", None, {}),
    ("the ATO cannot run span 3", GOOD_LINE + "1800,0,20,30,0\n", None, {}),
    ("span 2 under a limit too low", GOOD_LINE, LIMIT_HEADER + "2,0,0.5\n", {}),
    ("a limit above 200 m/s", GOOD_LINE, LIMIT_HEADER + "2,0,20\n2,100,250\n", {}),
    ("a limit beyond the span", GOOD_LINE, LIMIT_HEADER + "2,0,20\n2,700,15\n", {}),
    ("span.speed_limit nan for a span without rows", GOOD_LINE + "800,0,80,30,0\n",
     LIMIT_HEADER + "2,0,20\n", {"span.speed_limit_profile": "<span 1's limits>",
                                  "span.speed_limit": math.nan}),
    ("limits: span 3 of 2", GOOD_LINE, LIMIT_HEADER + "3,0,20\n", {}),
    ("limits: span 2.5", GOOD_LINE + "800,0,80,30,0\n", LIMIT_HEADER + "2.5,0,20\n", {}),
    ("limits: span 1e300", GOOD_LINE, LIMIT_HEADER + "1e300,0,20\n", {}),
    ("limits: span 3 then 2", GOOD_LINE + "800,0,80,30,0\n", LIMIT_HEADER + "3,0,20\n2,0,20\n", {}),
    ("limits: first not at 0", GOOD_LINE, LIMIT_HEADER + "2,10,20\n", {}),
    ("limits: not increasing", GOOD_LINE, LIMIT_HEADER + "2,0,20\n2,0,15\n", {}),
    ("limits: limit <= 0", GOOD_LINE, LIMIT_HEADER + "2,0,-1\n", {}),
    ("limits: wrong header", GOOD_LINE, "span,distance_m,speed_mps\n2,0,20\n", {}),
    ("limits: empty", GOOD_LINE, "", {}),
    ("a bad row in both: the line's first", GOOD_LINE + "800,0,80,0,0\n", LIMIT_HEADER + "2,10,20\n", {}),
    ("span 1 infeasible and a bad line: span 1's first", GOOD_LINE + "800,0,80,0,0\n", None,
     {"span.schedule": 20.0}),
    ("span 1's limit nan and a bad line file", "garbage", None, {"span.speed_limit": math.nan}),
    ("limits without a line", None, LIMIT_HEADER + "2,0,20\n", {}),
    ("missing line file", "<missing>", None, {}),
    ("line file is a folder", "<folder>", None, {}),
    ("missing limits file", GOOD_LINE, "<missing>", {}),
    ("line file not UTF-8", b"stop_m,length_m,schedule_s,dwell_s,boarding_t\n7\xff0,0,70,30,4\n", None, {}),
]
"""Line files both FMUs refuse, with the message fmu_src/ato_controller.py raises."""

GOOD_LINES = [        # (what, line.profile text, line.speed_limit_profile text or None)
    ("a BOM, CRLF, quotes, spaces, comments", "\ufeff# spans\r\n" + LINE_HEADER.replace(",", " , ")
     + '"700" ,0,70.0,30,4\r\n\r\n  # more\r\n800,0,8e1,30,-2\r\n', None),
    ("Unicode digits and underscores", LINE_HEADER + "\u0667\u0660\u0660,0,7_0,3\u0660,4\n",
     LIMIT_HEADER + "2,0,2_0.5\n2,100.5,15\n"),
    ("a span with limits, another without", GOOD_LINE + "800,850,80,30,0\n",
     LIMIT_HEADER + "3,0,19\n3,400,15\n"),
]
"""Line files both FMUs accept (csv_number_rows's rules)."""


def _line_values(tmp_path: Path, line, limits, extra: dict) -> dict:
    """SPAN1 with line.profile / line.speed_limit_profile files of these texts (None: empty;
    "<missing>", "<folder>": a name of no file, a folder)."""
    values = dict(SPAN1, **extra)
    for name, text, file in (("line.profile", line, "line.csv"),
                             ("line.speed_limit_profile", limits, "line_limits.csv")):
        if text is None:
            continue
        path = tmp_path / file
        if text == "<folder>":
            path.mkdir()
        elif text != "<missing>":
            path.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8"))
        values[name] = str(path)
    if values.get("span.speed_limit_profile") == "<span 1's limits>":
        (tmp_path / "limits.csv").write_text("distance_m,speed_limit_mps\n0,20\n")
        values["span.speed_limit_profile"] = str(tmp_path / "limits.csv")
    return values


def _initialisation(fmu: FmuFile, values: dict) -> tuple[int, list[str]]:
    s = Slave(fmu, "line_file")
    try:
        s.setup(values)
        status = s.exit_init()
        return status, [m.message for m in s.messages if m.status == 3]
    finally:
        s.close()


@pytest.mark.parametrize("kind", ["native", "pythonfmu"])
@pytest.mark.parametrize("what, line, limits, extra", BAD_LINES, ids=[c[0] for c in BAD_LINES])
def test_a_bad_line_file_is_refused_by_both_fmus_with_the_same_words(
        native_ato, ato_fmu, tmp_path, kind, what, line, limits, extra):
    values = _line_values(tmp_path, line, limits, extra)
    fmu = native_ato if kind == "native" else ato_fmu
    expected = _python_refusal(values, str(Path(fmu.unzipdir) / "resources"))
    status, errors = _initialisation(fmu, values)
    assert status == 3
    assert any(e.rstrip().endswith(expected) for e in errors), f"{expected!r} not in {errors}"
    if what.startswith("span 1"):               # span 1's refusal comes before the line's
        assert "line." not in expected, expected
    elif line is not None:
        assert expected.startswith("initialisation failed: line."), expected


@pytest.mark.parametrize("what, line, limits", GOOD_LINES, ids=[c[0] for c in GOOD_LINES])
def test_a_line_file_both_fmus_accept_gives_the_same_first_steps(native_ato, ato_fmu, tmp_path,
                                                                 what, line, limits):
    """Initialised, the two FMUs hold span 1's brake and then run it alike (20 steps of a car
    at rest: the same commands bit for bit)."""
    values = _line_values(tmp_path, line, limits, {})
    outputs = []
    for fmu in (native_ato, ato_fmu):
        s = Slave(fmu, "good_line")
        try:
            s.initialize(values)
            rows = [[s.get(n) for n in OUTPUTS]]
            for k in range(20):
                s.set({"est.station_stops": 0, "filter.speed": 0.0, "filter.position": 0.0})
                assert s.do_step(k * STEP, STEP) in (OK, 1), s.log_text()
                rows.append([s.get(n) for n in OUTPUTS])
            outputs.append(rows)
        finally:
            s.close()
    assert outputs[0] == outputs[1]
    assert outputs[0][0][OUTPUTS.index("ato.mode")] == 8
    assert outputs[0][-1][OUTPUTS.index("ato.span")] == 1


TOKENS = ("0", "-0", "700", "800", "1e3", "30", "2", "3", "0.5", "250", "-2", "nan", "inf", "",
          " ", '"5"', "abc", "1_0", "1__0", "\u0663\u0660", "0x1", "+4", "4.", ".5", "1e", "\u00a07")
"""Cells a random line file is made of: good numbers and every kind float() refuses or reads
its own way (test_core_profile.py's grammar)."""


def _random_line_files(seed: int) -> tuple[str, str | None]:
    """A line.profile and maybe a line.speed_limit_profile text: the good files with a few
    cells, rows, separators or line breaks changed at random (seeded; the header rarely)."""
    rng = random.Random(seed)
    line = [LINE_HEADER.strip(), "700,0,70,30,4", "800,850,80,30,-2"]
    limits = [LIMIT_HEADER.strip(), "2,0,20", "2,300,15", "3,0,19"]
    for text in (line, limits):
        for _ in range(rng.randint(0, 3)):
            k = rng.randrange(1, len(text)) if len(text) > 1 and rng.random() < 0.9 else 0
            cells = text[k].split(",")
            what = rng.random()
            if what < 0.6:
                cells[rng.randrange(len(cells))] = rng.choice(TOKENS)
            elif what < 0.7:
                cells.append(rng.choice(TOKENS))
            elif what < 0.8 and len(cells) > 1:
                cells.pop()
            elif what < 0.9:
                text.insert(k, rng.choice(["", "# note", text[k]]))
                continue
            else:
                del text[k]
                continue
            text[k] = ",".join(cells)
    ending = rng.choice(["\n", "\r\n", "\r", "\n\n"])
    return (ending.join(line) + ending,
            ending.join(limits) + ending if rng.random() < 0.7 else None)


def test_random_line_files_are_accepted_or_refused_as_the_python_reader_does(native_ato, tmp_path):
    """200 seeded random variations of a good line: the native FMU initialises exactly when
    open_line accepts the files, and refuses with its words otherwise."""
    resources = str(Path(native_ato.unzipdir) / "resources")
    outcomes = {"accepted": 0, "refused": 0}
    for seed in range(200):
        folder = tmp_path / str(seed)
        folder.mkdir()
        line, limits = _random_line_files(seed)
        values = _line_values(folder, line, limits, {})
        try:
            expected = _python_refusal(values, resources)
        except AssertionError:                      # the Python FMU accepts these files
            expected = None
        status, errors = _initialisation(native_ato, values)
        if expected is None:
            assert status == 0, f"seed {seed}: {line!r} {limits!r}: {errors}"
            outcomes["accepted"] += 1
        else:
            assert status == 3 and any(e.rstrip().endswith(expected) for e in errors), \
                f"seed {seed}: {expected!r} not in {errors}"
            outcomes["refused"] += 1
    assert outcomes["accepted"] >= 20 and outcomes["refused"] >= 100, outcomes   # both met


def test_fmu_auto_picks_the_native_fmu_for_one_span_and_a_line(tmp_path):
    from harness.run.fmus import choose, uncovered
    (tmp_path / "native").mkdir()
    (tmp_path / "AtoController.fmu").write_bytes(b"")
    assert choose("auto", ATO, tmp_path, [("one span", {})]).kind == "python"   # no native FMU
    (tmp_path / "native" / f"{ATO_NATIVE_NAME}.fmu").write_bytes(b"")
    one = choose("auto", ATO, tmp_path, [("one span", {"span.stop": 1500.0})])
    assert one.kind == "native" and one.path.name == f"{ATO_NATIVE_NAME}.fmu"
    line = choose("auto", ATO, tmp_path, [("a line", {"line.profile": "line.csv",
                                                      "line.speed_limit_profile": "limits.csv"})])
    assert line.kind == "native" and line.path.name == f"{ATO_NATIVE_NAME}.fmu", line
    assert uncovered(ATO, {"line.profile": "line.csv"}) is None


# ------------------------------------------------------------------ the binary and its header

def test_fmpy_validates_the_fmu_and_it_states_what_it_is(native_ato):
    from fmpy.validation import validate_fmu
    assert validate_fmu(str(native_ato.path)) == []
    md = native_ato.md
    assert md.coSimulation.modelIdentifier == ATO and not md.coSimulation.needsExecutionTool
    # FMU states: saved and restored (test_native_ato_state.py)
    assert md.coSimulation.canGetAndSetFMUstate and md.coSimulation.canSerializeFMUstate
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
