"""The car a span scenario's ATO is configured with, and the estimator's prior mass
(harness/run/span_scenario.py, "The configured car"):

- without [ato.car], the configured car is the plant's car as [parameters] set it (every
  CarTraction field that is a RailCar car.* parameter), and est.mass_initial is its mass;
- a field [ato.car] gives wins (a disturbance: the plant differs on purpose), and an explicit
  est.mass_initial wins over the configured mass;
- a copy of a scenario with other car.* parameters (a sweep's, a test's) configures the ATO for
  that plant, except the fields [ato.car] gave;
- the fields without a RailCar parameter (eta, regen_*) stay CarTraction's defaults.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from harness.run.scenario import ScenarioError, load_scenario
from harness.run.span_scenario import PLANT_CAR_FIELDS
from models.planning.span import CarTraction

ROOT = Path(__file__).resolve().parents[3]
GRADE = (ROOT / "scenarios" / "profiles" / "ato_span_grade.csv").as_posix()
SPAN = '''
[span]
stop_m = 2150.0
length_m = 2200.0
schedule_s = 150.0
limit_kmh = [[0, 80], [900, 60], [1300, 80]]
'''


def scenario(tmp_path: Path, parameters: str, extra: str = ""):
    p = tmp_path / "own_line.toml"
    p.write_text(f'name = "own"\nstep_s = 0.1\n[parameters]\n"track.grade_profile" = "{GRADE}"\n'
                 f'{parameters}\n{SPAN}{extra}', encoding="utf-8")
    return load_scenario(p)


def test_the_fields_that_follow_the_plant_are_the_railcar_car_parameters():
    assert set(PLANT_CAR_FIELDS) == {"mass", "A0", "A1", "A2", "gamma", "length", "traction_force_max",
                                     "traction_power_max", "brake_force_max", "adhesion_mass_fraction",
                                     "adhesion_factor"}


def test_without_ato_car_the_atos_car_and_the_prior_mass_are_the_plants(tmp_path):
    s = scenario(tmp_path, '"car.mass" = 42.0\n"car.A0" = 1.2\n"car.traction_force_max" = 50e3\n')
    car = s.ato.car
    assert (car.mass, car.A0, car.traction_force_max) == (42.0, 1.2, 50e3)
    assert car.eta == CarTraction().eta and car.regen_force_max == CarTraction().regen_force_max
    assert s.parameters["est.mass_initial"] == 42.0          # the estimator starts from the same car
    assert s.setup.chain.config.identifier.mass_initial == 42.0
    assert s.new_driver().controllers[0].car == car          # what the run's ATO plans with


def test_ato_car_states_a_disturbance_and_est_mass_initial_wins(tmp_path):
    s = scenario(tmp_path, '"car.mass" = 36.0\n"car.A0" = 1.335\n', "[ato.car]\nmass = 30.0\n")
    assert s.ato.car.mass == 30.0 and s.ato.car.A0 == 1.335     # A0 not given: the plant's
    assert s.ato.car_given == ("mass",)
    assert s.setup.chain.config.identifier.mass_initial == 30.0   # the configured car's, not the plant's
    s = scenario(tmp_path, '"car.mass" = 36.0\n"est.mass_initial" = 33.0\n')
    assert s.ato.car.mass == 36.0 and s.parameters["est.mass_initial"] == 33.0


def test_the_default_car_changes_nothing(tmp_path):
    """No car.* set: the configured car is CarTraction() and no prior is added (the library's
    nominal scenarios run as before)."""
    s = scenario(tmp_path, "")
    assert s.ato.car == CarTraction() and "est.mass_initial" not in s.parameters


def test_a_copy_with_another_plant_configures_the_ato_for_it(tmp_path):
    s = scenario(tmp_path, "", "[ato.car]\nA0 = 0.89\n")
    copy = replace(s, parameters={**s.parameters, "car.mass": 40.0, "car.A0": 2.0})
    assert copy.ato_setup().car.mass == 40.0                 # followed the copy's plant
    assert copy.ato_setup().car.A0 == 0.89                   # [ato.car] gave it
    assert s.ato_setup() is s.ato                            # the original untouched


def test_a_plant_the_ato_cannot_be_configured_for_names_the_parameter(tmp_path):
    with pytest.raises(ScenarioError) as e:
        scenario(tmp_path, '"car.traction_force_max" = 1.0\n')   # cannot start the span: infeasible
    assert "own_line.toml" in str(e.value) and "span" in str(e.value)
