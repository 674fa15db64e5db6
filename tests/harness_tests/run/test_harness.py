"""Harness: scenario validation, drivers, metrics, and the main job end to end."""
import math
from pathlib import Path

import numpy as np
import pytest

from harness.run.phases import PhaseDriver, parse_phase
from harness.metrics.estimation import rmse, stop_indices, time_to_stay_within, w0_relative_rms_error
from harness.run.scenario import ScenarioError, load_scenario, scenario_from_dict

ROOT = Path(__file__).resolve().parents[3]
MINIMAL = {"name": "t", "driver": [{"action": "traction", "until_speed_mps": 5.0}]}


def test_default_scenario_loads_and_resolves_profiles():
    s = load_scenario(ROOT / "scenarios" / "default.toml")
    assert s.parameter("car.mass") == 34.0
    assert Path(s.parameter("track.grade_profile")).is_file()
    assert [p.action for p in s.phases] == ["traction", "coast", "brake_to_stop", "hold"]
    assert s.parameter("est.batch_size") == 50          # FMU default where the file is silent


@pytest.mark.parametrize("patch,needle", [
    ({"parameters": {"car.mas": 3.0}}, 'parameters."car.mas": not a RailCar parameter (see docs/variables.md); '
                                       "did you mean 'car.mass'?"),
    ({"parameters": {"colour.depth": 3.0}}, 'parameters."colour.depth": not a RailCar parameter '
                                            '(see docs/variables.md)'),
    ({"parameters": {"car.mass": "heavy"}}, 'parameters."car.mass": expected a finite number'),
    ({"parameters": {"seed": 1.5}}, 'parameters."seed": expected an integer'),
    ({"parameters": {"track.grade_profile": "nope.csv"}}, "file not found"),
    ({"step_s": 0.0}, "step_s must be > 0"),
    ({"driver": [{"action": "fly"}]}, "driver[0].action: must be one of"),
    ({"driver": [{"action": "brake_to_stop"}]}, "driver[0]: brake_to_stop needs stop_at_m"),
    ({"driver": [{"action": "coast", "until_speed_kmh": 5, "until_speed_mps": 1}]}, "not both"),
    ({"wind": [{"time_s": 1.0}]}, "wind[0].speed_mps: expected a finite number"),
    ({"colour": "red"}, "unknown key 'colour'"),
])
def test_invalid_scenarios_name_file_key_and_reason(patch, needle):
    data = dict(MINIMAL, **patch)
    with pytest.raises(ScenarioError) as e:
        scenario_from_dict(data, "my.toml", ROOT / "scenarios")
    assert "my.toml" in str(e.value) and needle in str(e.value)


def test_an_unknown_parameter_gets_the_close_names_or_none():
    """One message builder (harness.run.scenario.unknown_parameter) for scenarios, overrides and
    (later) sweeps: it points to the table of names and offers the close ones, and only those."""
    from harness.run.scenario import RAILCAR_PARAMETERS, unknown_parameter
    assert unknown_parameter("sensor.speed_sd", RAILCAR_PARAMETERS) == (
        "not a RailCar parameter (see docs/variables.md); did you mean 'sensor.speed_std' or "
        "'sensor.speed_std_rel'?")
    assert unknown_parameter("car.a0", RAILCAR_PARAMETERS).endswith("did you mean 'car.A0' or 'car.A2'?")   # the case ignored
    assert unknown_parameter("est.method", {"est.method_x": None}, "a sweep key").startswith(
        "not a sweep key (see docs/variables.md); did you mean 'est.method_x'?")
    assert unknown_parameter("colour", RAILCAR_PARAMETERS).endswith("(see docs/variables.md)")
    assert (ROOT / "docs" / "variables.md").is_file()


def test_bad_toml_names_the_file(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("name = \n")
    with pytest.raises(ScenarioError, match="bad.toml: not valid TOML"):
        load_scenario(p)


def test_phase_driver_runs_phases_on_speed_distance_and_time():
    phases = tuple(parse_phase(p, "x") for p in [
        {"action": "traction", "until_speed_mps": 10.0},
        {"action": "coast", "until_brake_curve": True},
        {"action": "brake_to_stop", "stop_at_m": 1000.0, "decel_mps2": 1.0},
        {"action": "hold", "until_time_s": 5.0, "mass_change_t": 2.0}])
    d = PhaseDriver(phases, 30.0, 40e3, 45e3)
    assert d.demands(0.0, 0.0, 0.0)[:2] == (40e3, 0.0)
    assert d.demands(1.0, 10.0, 100.0)[:2] == (0.0, 0.0)            # coasting
    f, b, _ = d.demands(2.0, 10.0, 951.0)                             # 100/(2*49) >= 1 m/s^2: brake
    assert f == 0.0 and b == pytest.approx(1000 * 30 * 100 / (2 * 49), rel=1e-12)
    _, b, dm = d.demands(3.0, 0.0, 1000.0)                            # stopped: hold, passengers board
    assert dm == 2.0 and b > 0
    d.demands(8.0, 0.0, 1000.0)
    assert d.finished


def test_metrics_on_hand_made_arrays():
    assert rmse(np.array([1.0, 3.0]), np.array([0.0, 0.0])) == pytest.approx(math.sqrt(5.0), rel=1e-15)
    assert stop_indices(np.array([0, 1, 2, 0, 0, 1, 0])) == [3, 6]
    t = np.arange(6.0)
    assert time_to_stay_within(t, np.array([0.5, 0.2, 0.005, 0.02, 0.001, 0.0]), 0.01) == 4.0
    v = np.array([0.0, 5.0, 10.0])
    assert w0_relative_rms_error(v, (1.0, 0.0, 0.01), (1.0, 0.0, 0.01)) == 0.0


def test_main_job_meets_the_backbone_targets(built_fmus, tmp_path):
    """Issue 2's default run: est.mass within 1 % of car.mass, filter beats the sensor (RMSE)."""
    from harness.__main__ import main
    from harness.metrics.estimation import summarise
    from harness.run.runner import FmuRunner
    s = load_scenario(ROOT / "scenarios" / "default.toml")
    with FmuRunner(built_fmus["RailCar"]) as runner:
        result = runner.run(s)
    summary = summarise(result, (0.89, 0.0288, 0.010498))
    assert summary.stops == 1
    assert abs(summary.mass_error_pct) < 1.0
    assert summary.speed_rmse_filter < summary.speed_rmse_sensor
    assert summary.position_rmse_filter < summary.position_rmse_sensor
    # and the CLI writes the report
    assert main(["run", str(ROOT / "scenarios" / "default.toml"), "--out", str(tmp_path),
                 "--dist", str(built_fmus["RailCar"].parent)]) == 0
    for name in ("summary.md", "speed.png", "estimates.png", "resistance.png", "default_result.csv"):
        assert (tmp_path / name).stat().st_size > 0
    header = (tmp_path / "default_result.csv").read_text().splitlines()[0]
    assert header.startswith("time [s],") and "car.speed [m/s]" in header


def test_cli_exit_code_2_on_invalid_scenario(tmp_path, capsys):
    from harness.__main__ import main
    p = tmp_path / "s.toml"
    p.write_text('name = "x"\n')
    assert main(["run", str(p)]) == 2
    assert "no driving script" in capsys.readouterr().err


def test_time_table_driver_is_piecewise_linear_and_validated(tmp_path):
    from harness.run.phases import parse_time_table
    tt = parse_time_table({"time_s": [0.0, 10.0, 20.0], "traction_N": [0.0, 10e3, 10e3],
                           "brake_N": [0.0, 0.0, 5e3]}, "x", None)
    assert tt.at(5.0) == pytest.approx((5e3, 0.0), rel=1e-15)
    assert tt.at(15.0) == pytest.approx((10e3, 2.5e3), rel=1e-15)
    assert tt.at(99.0) == (10e3, 5e3)                      # held after the last row
    f = tmp_path / "d.csv"
    f.write_text("time_s,traction_N,brake_N\n0,0,0\n5,-1,0\n")
    with pytest.raises(ScenarioError, match=r"row 2: demands must be >= 0"):
        scenario_from_dict({"name": "t", "driver_table": {"file": str(f)}}, "s.toml", tmp_path)


def test_time_table_scenario_runs_to_its_stop_time(built_fmus):
    """An open-loop table: the run reaches duration_s exactly (no early end, no coarsening)."""
    from harness.run.runner import FmuRunner
    s = scenario_from_dict({"name": "table", "duration_s": 30.0, "step_s": 0.1, "driver_table": {
        "time_s": [0.0, 15.0, 15.1, 30.0], "traction_N": [30e3, 30e3, 0.0, 0.0],
        "brake_N": [0.0, 0.0, 40e3, 40e3]}}, "t.toml", ROOT)
    with FmuRunner(built_fmus["RailCar"]) as runner:
        r = runner.run(s)
    assert r.time[-1] == pytest.approx(30.0, abs=1e-9)
    assert r["car.speed"].max() > 10.0 and r["car.speed"][-1] == 0.0


def test_filters_table_compares_every_kind(built_fmus):
    """`harness filters`: the paper's Euler distance (kind 3) is over-confident, Singer is
    model-free and worse than the model-based filters, all beat the raw sensor."""
    from harness.metrics.filter_compare import compare_filters
    from harness.run.runner import FmuRunner
    s = load_scenario(ROOT / "scenarios" / "library" / "level_run.toml")
    with FmuRunner(built_fmus["RailCar"]) as runner:
        rows = {r["filter"]: r for r in compare_filters([s], runner)}
    assert set(rows) == {"linearised", "EKF", "paper (13)-(19)", "Singer"}
    for r in rows.values():
        assert r["speed_rmse"] < r["speed_rmse_sensor"] and r["distance_rmse"] < r["distance_rmse_sensor"]
    assert rows["paper (13)-(19)"]["distance_nees"] > 5 * rows["linearised"]["distance_nees"]
    assert rows["Singer"]["speed_rmse"] > rows["EKF"]["speed_rmse"]


def test_oracle_gets_each_intervals_force_not_the_trapezoid_of_the_outputs():
    """The force output at t_k was applied with the previous interval's demand; the oracle must
    use the interval's own demand (through the plant's force law). A traction cut at t = 0.1 s
    belongs wholly to [0.1, 0.2]: forces (40, 0, 0) kN, where the trapezoid of the outputs gave
    (40, 20, 0) kN -- 0.07 m/s of prediction error for a 30 t car."""
    from harness.metrics.estimation import _interval_forces

    class Recorded:                      # what the oracle reads of a RunResult
        def __init__(self, inputs):
            self.scenario, self.inputs, self.time = sc, inputs, np.arange(4) * 0.1

        def __getitem__(self, name):
            return signals[name]

    sc = scenario_from_dict({"name": "cut", "step_s": 0.1, "duration_s": 0.3,
                             "driver": [{"action": "coast", "until_time_s": 1.0}]}, "test")
    signals = {"car.traction_force": np.array([40e3, 40e3, 0.0, 0.0]), "car.brake_force": np.zeros(4),
               "car.speed": np.full(4, 10.0), "car.total_mass": np.full(4, 30.0)}
    demands = {"traction_force_demand": np.array([40e3, 0.0, 0.0, 0.0]), "brake_force_demand": np.zeros(4)}
    car = sc.chain_setup().config.vehicle
    F, B = _interval_forces(Recorded(demands), car)
    np.testing.assert_array_equal(F, [40e3, 0.0, 0.0])      # 40 kN is within every limit at 10 m/s
    np.testing.assert_array_equal(B, [0.0, 0.0, 0.0])
    F, _ = _interval_forces(Recorded({}), car)               # no recorded demands: the trapezoid
    np.testing.assert_array_equal(F, [40e3, 20e3, 0.0])


def test_coast_time_follows_a_wind_that_changes_mid_coast():
    """A headwind rising 20 s into a coast: the coast takes longer than in still air and less
    than with the headwind throughout; a constant function equals the constant."""
    from harness.metrics.estimation import coast_time
    from models.plant.track import GradeProfile
    args = (20.0, 0.0, 1500.0, (1.0, 0.03, 0.01), 40.0, 0.0, 20.0, GradeProfile.level())
    still, windy = coast_time(*args, wind=0.0), coast_time(*args, wind=12.0)
    rising = coast_time(*args, wind=lambda t: 12.0 if t >= 20.0 else 0.0)
    assert coast_time(*args, wind=lambda t: 12.0) == windy      # same arithmetic, exactly
    assert still + 1.0 < rising < windy - 1.0                    # [s]; the gap is ~10 s each side


def test_true_resistance_predicts_headwind_change_coast_within_process_noise():
    """The truth, re-run in the wind as it blows over the coast, predicts the coast's time to
    within the process noise's spread (about 1 s; the wind at the coast's start alone: -17 s)."""
    from harness.run.driver import run_on_chain
    from harness.metrics.estimation import coast_time_errors
    s = load_scenario(ROOT / "scenarios" / "library" / "headwind_change.toml")
    result = run_on_chain(s)
    A = (s.parameter("car.A0"), s.parameter("car.A1"), s.parameter("car.A2"))
    errors = coast_time_errors(result, lambda last: A, still_air=True)
    assert errors and max(abs(e) for e in errors) < 2.0    # [s]


def test_list_shows_every_scenario_and_sweep_with_its_purpose(capsys):
    """python -m harness list: one line per scenario, sweep and system file, name and purpose."""
    from harness.__main__ import main
    from harness.run.regress import library_scenarios
    root = Path(__file__).resolve().parents[3] / "scenarios"
    assert main(["list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    files = ["default.toml"] + [f"library/{p.name}" for p in library_scenarios()] + \
            [f"sweeps/{p.name}" for p in sorted((root / "sweeps").glob("*.toml"))] + \
            [f"systems/{p.name}" for p in sorted((root / "systems").glob("*.toml"))]
    for f in files:
        line = next((x for x in lines if x.strip().startswith(f)), None)
        assert line is not None and len(line.strip()) > len(f) + 10, f"{f}: {line!r}"
    assert len(lines) == len(files) + 3                 # and the three headings


def test_a_scenario_gives_its_railcar_parameters_and_chain_setup(monkeypatch, tmp_path):
    """Scenario.railcar_parameters: every RailCar parameter (the file's, else the FMU's default),
    overrides on top, a misspelt override refused; Scenario.chain_setup: the FMU's own
    configuration of them (chain_config, load_profiles), a relative profile path found where the
    FMU finds it (its resources, i.e. scenarios/profiles) whatever the working directory."""
    from fmu_src.adapter import chain_config, load_profiles
    from harness.run.scenario import RAILCAR_PARAMETERS
    s = load_scenario(ROOT / "scenarios" / "default.toml")
    v = s.railcar_parameters({"seed": 7})
    assert set(v) == set(RAILCAR_PARAMETERS) and v["seed"] == 7
    assert s.railcar_parameters()["seed"] == s.parameter("seed") != 7
    assert v["car.mass"] == 34.0 and v["est.batch_size"] == 50
    with pytest.raises(ValueError, match="car.mas: not a RailCar parameter"):
        s.railcar_parameters({"car.mas": 1.0})
    setup = s.chain_setup({"seed": 7})
    assert setup.config == chain_config(v) and setup.config.seed == 7
    assert (setup.grade, setup.speed) == load_profiles(v, None) and len(setup.grade.distances) > 1
    monkeypatch.chdir(tmp_path)                     # no profiles/ here
    relative = scenario_from_dict({**MINIMAL, "parameters": {"track.grade_profile": "profiles/demo_grade.csv"}},
                                  "t.toml")
    assert relative.parameter("track.grade_profile") == "profiles/demo_grade.csv"
    assert relative.chain_setup().grade == setup.grade
