"""The system descriptions in scenarios/systems/ (harness.systems.cli): they describe the systems
tests/harness_tests/systems/test_ssp_master.py compares in both masters, build into .ssp packages with the session's
FMUs, and the command line builds and runs them (exit codes 0, 1 failed run, 2 invalid input);
a bad description is refused naming the file and the key."""
from __future__ import annotations

import pytest

from conftest import ROOT
from harness.systems.ssp import SspError, read_ssp
from harness.systems.cli import load_system, main
from test_ssp_master import ato_system, plant_estimator

SYSTEMS = ROOT / "scenarios" / "systems"


@pytest.fixture(scope="module")
def dist(built_fmus):
    return built_fmus["RailCar"].parent


def test_descriptions_are_the_tested_systems(dist):
    pe = load_system(SYSTEMS / "plant_estimator.toml", dist)
    want = plant_estimator(dist / "native" / "RailCarNative.fmu",
                           dist / "native" / "RailCarEstimatorNative.fmu")
    assert (pe.name, pe.step, pe.stop, pe.components, pe.connections) == \
        (want.name, want.step, want.stop, want.components, want.connections)
    ato = load_system(SYSTEMS / "ato_span.toml", dist)
    want = ato_system(dist / "native" / "RailCarNative.fmu", dist / "AtoController.fmu")
    assert (ato.name, ato.step, ato.stop, ato.components, ato.connections) == \
        (want.name, want.step, want.stop, want.components, want.connections)


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
    assert "ato_span.toml: [components.car]: FMU file not found" in err and "python build.py" in err


def test_command_line_failed_run_exits_1(dist, tmp_path, capsys):
    text = (SYSTEMS / "plant_estimator.toml").read_text().replace("traction_force_demand = 30e3",
                                                                  "traction_force_demand = -1.0")
    (tmp_path / "bad.toml").write_text(text)
    ssp = tmp_path / "bad.ssp"
    assert main(["build", str(tmp_path / "bad.toml"), str(ssp), "--dist", str(dist)]) == 0
    assert main(["run", str(ssp), "--stop", "1"]) == 1
    assert "component 'car': doStep at t = 0.0 s returned discard" in capsys.readouterr().err


BAD = {
    "unknown key": ('stop = 3\n', "unknown key(s) stop"),
    "no fmu": ('[components.x]\nparameters = {}\n', "[components.x]: 'fmu' is missing"),
    "bad connection": ('connections = [["car.sensor.speed"]]\n[components.car]\nfmu = "a.fmu"\n',
                       "connections[1]: expected"),
    "bad toml": ('name = \n', "not valid TOML"),
    "step text": ('step_s = "0.1"\n[components.car]\nfmu = "a.fmu"\n', "'step_s' must be a number"),
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
