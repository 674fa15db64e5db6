"""``python -m harness system build`` from a span scenario (harness.systems.scenario_system) and the
ATO metrics of ``system run`` (harness.systems.ato_run), against ``python -m harness run``.

- scenarios/library/ato_nominal.toml built into a system (RailCarNative <-> AtoControllerNative,
  the ATO stepping first) and run in our master gives the harness's own run of the scenario: the
  same ATO metrics as printed, and the same trajectory to 1e-9 (the two differ only in the time
  grid: the master counts integer nanoseconds as libcosim does, the harness k * h, so a step
  size differs in its last bit now and then);
- every profile is packed into the .ssp (the car's and the ATO's grade: one file, the bytes of
  the scenario's; the limits made at build in m/s, the exact doubles of limit_kmh), and the run
  does not depend on the working directory, in our master and in libcosim;
- a profile that is missing or not a regular file is refused at build, naming the parameter
  and the path; a wind that changes and a scenario without a span are
  refused at build saying why; libcosim refuses a system with a step order.
"""
from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np
import pytest

from conftest import ROOT
from harness.metrics.ato import ato_metrics, format_ato
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario
from harness.systems.ato_run import metric_outputs, system_ato_metrics
from harness.systems.cli import build, main
from harness.systems.master import run_system
from harness.systems.ssp import PACKED_DIR, SspError
from harness.systems.ssp_read import read_ssp
from harness.textio import InputError
from models.units import kmh_to_mps

NOMINAL = ROOT / "scenarios" / "library" / "ato_nominal.toml"
GRADE = ROOT / "scenarios" / "profiles" / "ato_span_grade.csv"
TRAJECTORY = {"car.position": "car.car.position", "car.speed": "car.car.speed",
              "filter.position": "car.filter.position", "est.mass": "car.est.mass"}


@pytest.fixture(scope="module")
def dist(built_fmus) -> Path:
    return built_fmus["RailCar"].parent


def system_and_harness_runs(path: Path, ssp: Path, dist: Path, outputs) -> tuple:
    """(the .ssp built from the scenario at ``path``, its run in our master recording the ATO
    metrics' outputs and ``outputs``, the harness's run of the scenario on the same FMU, the
    scenario): the pair every system-vs-harness comparison starts from. Built with --fmu auto: the
    native car, and the ATO's FMU whichever harness.run.fmus.uncovered allows (the native one for
    a span; test_ssp_native_ato.py checks the choice)."""
    ssp = build(path, ssp, dist, "auto")
    assert ssp.is_file()
    system = read_ssp(ssp)
    assert Path(system.spec.components[0].fmu).name == "RailCarNative.fmu"
    ours = run_system(system, outputs=list(dict.fromkeys(metric_outputs(system) + list(outputs))))
    scenario = load_scenario(path)
    with FmuRunner(dist / "native" / "RailCarNative.fmu") as runner:
        harness = runner.run(scenario)
    return ssp, ours, harness, scenario


@pytest.fixture(scope="module")
def nominal(dist, tmp_path_factory):
    return system_and_harness_runs(NOMINAL, tmp_path_factory.mktemp("span_build") / "ato_nominal.ssp",
                                   dist, TRAJECTORY.values())


def test_the_system_is_the_harness_run(nominal):
    ssp, ours, harness, scenario = nominal
    system = read_ssp(ssp)
    assert system.spec.step_order == ("ato", "car") and system.spec.stop == scenario.duration_s
    n = len(harness.time)                     # the harness stops once the car stands at the mark
    assert 1200 < n < len(ours.time) == 1951
    assert np.max(np.abs(ours.time[:n] - harness.time)) < 1e-9
    for name, full in TRAJECTORY.items():
        x, y = np.asarray(harness[name]), np.asarray(ours[full])[:n]
        assert np.max(np.abs(x - y)) <= 1e-9, f"{name}: {np.max(np.abs(x - y))}"
    # the ATO's demand at row r + 1 (it steps first) is what the harness applied from row r
    for name in ("traction_force_demand", "brake_force_demand"):
        applied, ato = harness.inputs[name][:n - 1], np.asarray(ours[f"ato.{name}"])[1:n]
        assert np.max(np.abs(applied - ato)) <= 1e-6, name
    want = ato_metrics(scenario, harness, harness.driver_steps)
    got = system_ato_metrics(system, ours)
    assert format_ato(got) == format_ato(want)
    (g,), (w,) = got, want
    assert g.arrived and w.arrived and g.interventions == w.interventions == 0
    for field in ("arrival_error_s", "stop_error_m", "energy_kwh", "margin_mps"):
        assert abs(getattr(g, field) - getattr(w, field)) <= 1e-9, field


def test_every_profile_is_packed_and_the_limits_are_in_mps(nominal):
    ssp, *_ = nominal
    system = read_ssp(ssp)
    car, ato = (c.parameters for c in system.spec.components)
    grade = PACKED_DIR + "ato_span_grade.csv"
    assert car["track.grade_profile"] == ato["span.grade_profile"] == grade
    assert car["seed"] == 31 and ato["span.stop"] == 2150.0 and ato["span.schedule"] == 135.0
    with zipfile.ZipFile(ssp) as z:
        assert sorted(n for n in z.namelist() if n.startswith(PACKED_DIR)) == \
            sorted([grade, ato["span.speed_limit_profile"]])
        assert z.read(grade) == GRADE.read_bytes()
        rows = z.read(ato["span.speed_limit_profile"]).decode().splitlines()
    assert rows[1] == "distance_m,speed_limit_mps"
    assert [tuple(float(x) for x in r.split(",")) for r in rows[2:]] == \
        [(0.0, kmh_to_mps(80)), (900.0, kmh_to_mps(60)), (1300.0, kmh_to_mps(80))]


def test_system_run_prints_the_ato_metrics(nominal, capsys):
    ssp, _, harness, scenario = nominal
    capsys.readouterr()
    assert main(["run", str(ssp), "--output", "car.car.position"]) == 0
    out = capsys.readouterr().out
    assert format_ato(ato_metrics(scenario, harness, harness.driver_steps)) in out
    assert "  car.car.speed" not in out                # the metrics' extra outputs are not listed


def own_scenario(folder: Path, grade: str = "own/my_grade.csv", extra: str = "") -> Path:
    """ato_nominal with its grade a file of the user's, relative to the scenario, named as no
    FMU's bundled profile is."""
    (folder / "own").mkdir(exist_ok=True)
    (folder / "own" / "my_grade.csv").write_bytes(GRADE.read_bytes())
    text = NOMINAL.read_text().replace('"../profiles/ato_span_grade.csv"', f'"{grade}"')
    path = folder / "mine.toml"
    path.write_text(text + extra)
    return path


def test_a_system_runs_from_any_working_directory(nominal, dist, tmp_path, monkeypatch):
    _, ours, *_ = nominal
    ssp = build(own_scenario(tmp_path), tmp_path / "mine.ssp", dist, "native")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    r = run_system(Path("..") / "mine.ssp", stop_time=60.0, outputs=["car.car.position"])
    assert np.array_equal(r["car.car.position"], ours["car.car.position"][:601])


def test_libcosim_finds_the_packed_profiles_from_any_working_directory(dist, tmp_path, monkeypatch):
    pytest.importorskip("libcosimpy")
    from harness.systems.libcosim import run_libcosim
    ssp = build(own_scenario(tmp_path), tmp_path / "mine.ssp", dist, "native", jacobi=True)
    assert read_ssp(ssp).spec.step_order == ()
    monkeypatch.chdir(tmp_path / "own")
    outputs = ["car.car.position", "ato.traction_force_demand", "ato.ato.mode"]
    ours = run_system(ssp, stop_time=20.0, outputs=outputs)
    cosim = run_libcosim(ssp, stop_time=20.0, outputs=outputs, isolated=True)
    for name in outputs:
        assert ours[name].tobytes() == cosim[name].tobytes(), name
    assert ours["car.car.position"][-1] > 50.0 and Path.cwd() == tmp_path / "own"


def test_libcosim_refuses_a_system_with_a_step_order(nominal):
    pytest.importorskip("libcosimpy")
    from harness.systems.libcosim import run_libcosim
    with pytest.raises(SspError, match=r"ato then car, Gauss-Seidel\); libcosim steps them all at once"):
        run_libcosim(nominal[0], n_steps=2)


@pytest.mark.parametrize("kind", ["missing", "folder"])
def test_a_bad_profile_is_refused_at_build_naming_the_parameter(dist, tmp_path, kind):
    if kind == "folder":
        (tmp_path / "a_folder.csv").mkdir()
    name = "nowhere.csv" if kind == "missing" else "a_folder.csv"
    out = tmp_path / "x.ssp"
    with pytest.raises(InputError) as e:
        build(own_scenario(tmp_path, grade=name), out, dist)
    why = "file not found: " if kind == "missing" else ": is a folder, not a file"
    assert 'parameters."track.grade_profile": ' in str(e.value) and why in str(e.value)
    assert str(tmp_path / name) in str(e.value) and not out.exists()


@pytest.mark.parametrize("kind", ["missing", "folder"])
def test_a_description_s_bad_profile_is_refused_naming_the_line_and_parameter(dist, tmp_path, kind):
    text = (ROOT / "scenarios" / "systems" / "ato_span.toml").read_text()
    if kind == "folder":
        (tmp_path / "a_folder.csv").mkdir()
    name = "nowhere.csv" if kind == "missing" else "a_folder.csv"
    path = tmp_path / "s.toml"
    path.write_text(text.replace('"car.mass" = 30.0, "track.grade_profile" = "../profiles/ato_span_grade.csv"',
                                 f'"car.mass" = 30.0, "track.grade_profile" = "{name}"'))
    line = [i for i, s in enumerate(path.read_text().splitlines(), 1) if name in s][0]
    with pytest.raises(SspError) as e:
        build(path, tmp_path / "s.ssp", dist)
    why = "not found" if kind == "missing" else "it is a folder; a profile is a regular file"
    assert str(e.value) == (f'{path}: line {line}: [components.car] parameters."track.grade_profile": '
                            f"profile file {tmp_path / name}: {why}" + ("" if kind == "missing" else
                                                                        " (packed into the .ssp)"))


def rewritten(ssp: Path, out: Path, member: str, old: bytes, new: bytes) -> Path:
    """A copy of the package ``ssp`` with ``old`` replaced by ``new`` in ``member``."""
    with zipfile.ZipFile(ssp) as z, zipfile.ZipFile(out, "w") as copy:
        for item in z.infolist():
            data = z.read(item)
            if item.filename == member:
                assert old in data
                data = data.replace(old, new)
            copy.writestr(item, data)
    return out


def test_a_packed_path_outside_the_package_is_refused_when_read(nominal, tmp_path):
    bad = rewritten(nominal[0], tmp_path / "bad.ssp", "resources/car.ssv",
                    b"resources/profiles/ato_span_grade.csv", b"resources/profiles/../car.ssv")
    with pytest.raises(SspError, match=r"parameter 'track.grade_profile': 'resources/profiles/\.\./car\.ssv': "
                                       r"a packed file is a plain path below resources/profiles/"):
        read_ssp(bad)


def test_a_step_order_not_understood_is_refused_not_taken_for_jacobi(nominal, tmp_path):
    bad = rewritten(nominal[0], tmp_path / "bad.ssp", "SystemStructure.ssd",
                    b'xmlns:rc="urn:railcar-fmu:ssp"', b'xmlns:rc="urn:another"')
    with pytest.raises(SspError, match="the org.railcar-fmu.master annotation must hold one <rc:StepOrder"):
        read_ssp(bad)


REFUSED = {
    "no span": (ROOT / "scenarios" / "library" / "level_run.toml", "not a span scenario"),
}


@pytest.mark.parametrize("case", list(REFUSED))
def test_what_a_system_cannot_be_is_refused_at_build(dist, tmp_path, case):
    path, words = REFUSED[case]
    with pytest.raises(SspError, match=words):
        build(path, tmp_path / "x.ssp", dist)
    assert not (tmp_path / "x.ssp").exists()


def test_a_wind_that_changes_is_refused_and_a_constant_one_is_a_start_value(dist, tmp_path):
    changing = own_scenario(tmp_path, extra="\n[[wind]]\ntime_s = 0.0\nspeed_mps = 2.0\n"
                                             "[[wind]]\ntime_s = 30.0\nspeed_mps = 5.0\n")
    with pytest.raises(SspError, match="the wind changes at t = 30 s"):
        build(changing, tmp_path / "x.ssp", dist)
    steady = own_scenario(tmp_path, extra="\n[[wind]]\ntime_s = 0.0\nspeed_mps = 2.0\n")
    car = read_ssp(build(steady, tmp_path / "y.ssp", dist)).spec.components[0]
    assert car.parameters["wind_speed"] == 2.0


def test_a_description_s_step_order_is_written_read_and_checked(dist, tmp_path):
    text = (ROOT / "scenarios" / "systems" / "ato_span.toml").read_text()
    path = tmp_path / "ordered.toml"
    text = text.replace('../profiles/', f'{ROOT / "scenarios" / "profiles"}/')
    path.write_text(text.replace('stop_s = 50.0', 'stop_s = 50.0\nstep_order = ["ato", "car"]'))
    assert read_ssp(build(path, tmp_path / "o.ssp", dist)).spec.step_order == ("ato", "car")
    path.write_text(text.replace('stop_s = 50.0', 'stop_s = 50.0\nstep_order = ["ato", "cat"]'))
    line = [i for i, s in enumerate(path.read_text().splitlines(), 1) if s.startswith("step_order")][0]
    with pytest.raises(SspError) as e:
        build(path, tmp_path / "p.ssp", dist)
    assert str(e.value) == f"{path}: line {line}: step_order ['ato', 'cat']: name every component once (car, ato)"


def test_the_jacobi_build_is_the_hand_written_description(dist, tmp_path):
    """scenarios/systems/ato_nominal.toml wrote the library's span by hand (the car, the limits
    CSV in m/s); built from the scenario with --jacobi the system runs the same bits."""
    from harness.systems.cli import build_system
    outputs = ["car.car.position", "car.est.mass", "ato.brake_force_demand", "ato.ato.mode"]
    by_hand = run_system(build_system(ROOT / "scenarios" / "systems" / "ato_nominal.toml", tmp_path / "h.ssp",
                                      dist), n_steps=400, outputs=outputs)
    built = run_system(build(NOMINAL, tmp_path / "b.ssp", dist, "native", jacobi=True), n_steps=400,
                       outputs=outputs)
    for name in outputs:
        assert by_hand[name].tobytes() == built[name].tobytes(), name
