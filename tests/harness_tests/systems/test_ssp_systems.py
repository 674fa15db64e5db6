"""The system descriptions in scenarios/systems/ (harness.systems.cli, the command
``python -m harness system``): they describe the systems tests/harness_tests/systems/test_ssp_master.py
compares in both masters, build into .ssp packages with the session's FMUs, and the command line
builds and runs them (exit codes 0, 1 failed run, 2 invalid input). A bad description is refused
naming the TOML file, the line and the key, also when the error is found against the FMUs while
building (never the .ssp being written)."""
from __future__ import annotations

from pathlib import Path

import pytest

from conftest import ROOT
from harness.systems.ssp import PackedFile, SspError
from harness.systems.ssp_read import read_ssp
from harness.systems.cli import build_system, load_system, main
from test_ssp_master import ato_system, plant_estimator

SYSTEMS = ROOT / "scenarios" / "systems"


@pytest.fixture(scope="module")
def dist(built_fmus):
    return built_fmus["RailCar"].parent


def files_as_sources(components) -> list:
    """The components with each profile as the file it is: a description's PackedFile (relative
    to the description) and a test system's "profiles/x.csv" (the FMU's bundled copy of
    scenarios/profiles/x.csv) both as the resolved path of the source file."""
    out = []
    for c in components:
        params = {}
        for name, value in c.parameters.items():
            if isinstance(value, PackedFile):
                value = ("file", Path(value.source).resolve())
            elif isinstance(value, str) and value.startswith("profiles/"):
                value = ("file", (ROOT / "scenarios" / value).resolve())
            params[name] = value
        out.append((c.name, c.fmu, params))
    return out


def test_descriptions_are_the_tested_systems(dist):
    pe = load_system(SYSTEMS / "plant_estimator.toml", dist)
    want = plant_estimator(dist / "native" / "RailCarNative.fmu",
                           dist / "native" / "RailCarEstimatorNative.fmu")
    assert (pe.name, pe.step, pe.stop, files_as_sources(pe.components), pe.connections) == \
        (want.name, want.step, want.stop, files_as_sources(want.components), want.connections)
    assert isinstance(pe.components[0].parameters["track.grade_profile"], PackedFile)
    ato = load_system(SYSTEMS / "ato_span.toml", dist)
    want = ato_system(dist / "native" / "RailCarNative.fmu", dist / "AtoController.fmu")
    assert (ato.name, ato.step, ato.stop, files_as_sources(ato.components), ato.connections) == \
        (want.name, want.step, want.stop, files_as_sources(want.components), want.connections)


def test_command_line_builds_and_runs(dist, tmp_path, capsys):
    ssp = tmp_path / "pe.ssp"
    assert main(["build", str(SYSTEMS / "plant_estimator.toml"), str(ssp), "--dist", str(dist)]) == 0
    assert read_ssp(ssp).spec.name == "plant_estimator"
    capsys.readouterr()
    assert main(["run", str(ssp), "--stop", "2", "--output", "est.est.samples",
                 "--csv", str(tmp_path / "r.csv")]) == 0
    out = capsys.readouterr().out
    assert "harness.systems.master: 20 steps to t = 2.0 s" in out and "est.est.samples  " in out
    assert (tmp_path / "r.csv").read_text().splitlines()[0] == "time [s],est.est.samples [-]"
    assert main(["run", str(ssp), "--stop", "2", "--output", "est.est.mas"]) == 2
    assert "has no variable 'est.mas'" in capsys.readouterr().err


def test_building_without_the_fmus_says_how_to_build_them(tmp_path, capsys):
    assert main(["build", str(SYSTEMS / "ato_span.toml"), str(tmp_path / "a.ssp"), "--dist", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    line = line_of((SYSTEMS / "ato_span.toml").read_text(), "[components.car]")
    assert f"ato_span.toml: line {line}: [components.car]: FMU file not found" in err and "python build.py" in err


def test_command_line_failed_run_exits_1(dist, tmp_path, capsys):
    text = (SYSTEMS / "plant_estimator.toml").read_text().replace("traction_force_demand = 30e3",
                                                                  "traction_force_demand = -1.0")
    text = text.replace('"../profiles/', f'"{ROOT / "scenarios" / "profiles"}/')     # the copy is elsewhere
    (tmp_path / "bad.toml").write_text(text)
    ssp = tmp_path / "bad.ssp"
    assert main(["build", str(tmp_path / "bad.toml"), str(ssp), "--dist", str(dist)]) == 0
    assert main(["run", str(ssp), "--stop", "1"]) == 1
    assert "component 'car': doStep at t = 0.0 s returned discard" in capsys.readouterr().err


def line_of(text: str, needle: str) -> int:
    """The number (from 1) of the one line of ``text`` that holds ``needle``."""
    [number] = [i for i, line in enumerate(text.splitlines(), 1) if needle in line]
    return number


def test_usage_names_the_one_spelling(capsys):
    with pytest.raises(SystemExit):
        main(["-h"])
    assert capsys.readouterr().out.startswith("usage: python -m harness system ")


PE = (SYSTEMS / "plant_estimator.toml").read_text()
PAIR_2 = '["car.sensor.position", "est.sensor.position"]'
# case: (old text, new text, start of the message after "FILE: line L: ", the rest of it)
BUILD_ERRORS = {
    "unknown input": (PAIR_2, '["car.sensor.position", "est.sensor.positon"]',
                      "[connections] 2 (car.sensor.position -> est.sensor.positon): ",
                      "has no variable 'sensor.positon'; did you mean 'sensor.position'?"),
    "unit mismatch": (PAIR_2, '["car.sensor.position", "est.sensor.speed"]',
                      "[connections] 2 (car.sensor.position -> est.sensor.speed): ",
                      "unit mismatch: car.sensor.position [m], est.sensor.speed [m/s] (no unit conversion)"),
    "no component": (PAIR_2, '["car.sensor.position", "estsensorposition"]',
                     "[connections] 2 (car.sensor.position -> estsensorposition): ",
                     "'estsensorposition': expected Component.variable"),
    "output to output": (PAIR_2, '["car.sensor.position", "est.filter.position"]',
                         "[connections] 2 (car.sensor.position -> est.filter.position): ",
                         "est.filter.position is an output; a connection goes from an output to an input"),
    "unknown parameter": ('"car.mass" = 36.0', '"car.mas" = 36.0', "[components.car] parameters: ",
                          "has no variable 'car.mas'; did you mean 'car.mass'?"),
    "bad value": ('"est.batch_size" = 40', '"est.batch_size" = 40.5',
                  '[components.est] parameters."est.batch_size" (Integer): ', "40.5 is not a valid Integer"),
    "output bound": ('"est.batch_size" = 40', '"est.mass" = 1.0', '[components.est] parameters."est.mass": ',
                     "'est.mass' is an output, not a parameter or input"),
    "step": ("step_s = 0.1", "step_s = 0.0", "step_s 0.0: ", "expected a step > 0 [s]"),
    "name": ('name = "plant_estimator"', 'name = "plant estimator"', "name 'plant estimator': ",
             "letters, digits and _ only"),
}


@pytest.mark.parametrize("case", list(BUILD_ERRORS))
def test_build_errors_name_the_description_its_line_and_key(dist, tmp_path, case):
    old, new, where, words = BUILD_ERRORS[case]
    assert PE.count(old) == 1
    path = tmp_path / "pe.toml"
    path.write_text(PE.replace(old, new))
    out = tmp_path / "pe.ssp"
    with pytest.raises(SspError) as e:
        build_system(path, out, dist)
    message = str(e.value)
    assert message.startswith(f"{path}: line {line_of(path.read_text(), new)}: {where}"), message
    assert message.endswith(words) and "pe.ssp" not in message, message
    assert not out.exists()


def test_a_pair_written_twice_is_found_on_its_second_line(dist, tmp_path):
    """The second of two equal pairs drives an input twice: the message names its line, not the first's."""
    first = '    ["car.sensor.speed", "est.sensor.speed"],\n'
    text = PE.replace("\n]\n", "\n" + first + "]\n", 1)
    assert text.count(first) == 2
    path = tmp_path / "pe.toml"
    path.write_text(text)
    with pytest.raises(SspError) as e:
        build_system(path, tmp_path / "pe.ssp", dist)
    second = [i for i, line in enumerate(text.splitlines(), 1) if line == first.rstrip("\n")][1]
    assert str(e.value) == (f"{path}: line {second}: [connections] 5 (car.sensor.speed -> est.sensor.speed): "
                            f"est.sensor.speed is already driven by car.sensor.speed")


BAD = {
    "unknown key": ('stop = 3\n', "line 3: stop: unknown key (expected"),
    "no fmu": ('[components.x]\nparameters = {}\n', "line 3: [components.x]: 'fmu' is missing"),
    "bad connection": ('connections = [["car.sensor.speed"]]\n[components.car]\nfmu = "a.fmu"\n',
                       "line 3: [connections] 1: expected"),
    "bad toml": ('name = \n', "not valid TOML: Invalid value (at line 1, column 8)"),
    "step text": ('step_s = "0.1"\n[components.car]\nfmu = "a.fmu"\n', "line 2: step_s: must be a number"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_description_names_file_and_key(tmp_path, case):
    body, words = BAD[case]
    head = 'name = "x"\n' if "name" not in body else ""
    if "step_s" not in body and case != "bad toml":
        head += "step_s = 0.1\n"
    path = tmp_path / "s.toml"
    path.write_text(head + body)
    with pytest.raises(SspError) as e:
        load_system(path, tmp_path)
    assert str(path) in str(e.value) and words in str(e.value), str(e.value)
