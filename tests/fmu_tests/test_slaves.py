"""The pythonfmu slave classes, instantiated directly in Python (no build, no FMI binary)."""
import math

import pytest

import pythonfmu  # noqa: F401
from fmu_src.adapter import ParameterError
from fmu_src.railcar import RailCar
from fmu_src.railcar_estimator import RailCarEstimator
from fmu_src.variables import RAILCAR, ESTIMATOR, variables_for


def make(cls, **params):
    slave = cls(instance_name="test", resources=None)
    for name, value in params.items():
        slave.values[name] = value
    slave.enter_initialization_mode()
    slave.exit_initialization_mode()
    return slave


def vr_of(slave, name):
    return next(vr for vr, v in slave.vars.items() if v.name == name)


def test_every_table_variable_is_registered_once():
    """The one variable table drives registration: names, order and count match."""
    for cls, fmu in ((RailCar, RAILCAR), (RailCarEstimator, ESTIMATOR)):
        slave = cls(instance_name="t", resources=None)
        assert [v.name for v in slave.vars.values()] == [v.name for v in variables_for(fmu)]


def test_railcar_steps_and_reports_through_the_fmi_getters():
    """Traction accelerates the car; outputs are readable by value reference."""
    slave = make(RailCar, **{"traction_force_demand": 30e3})
    for k in range(50):
        assert slave.do_step(k * 0.1, 0.1) is True
    speed = slave.get_real([vr_of(slave, "car.speed")])[0]
    assert 3.0 < speed < 6.0          # ~1 m/s^2 for 5 s, less resistance
    assert slave.get_integer([vr_of(slave, "car.mode")])[0] == 1


@pytest.mark.parametrize("name,value", [("traction_force_demand", math.nan),
                                        ("traction_force_demand", -1.0),
                                        ("brake_force_demand", math.inf),
                                        ("wind_speed", math.nan)])
def test_bad_input_discards_the_step_and_keeps_the_instance(name, value):
    """A bad input: do_step returns False with a log naming the variable; then it runs on."""
    slave = make(RailCar)
    assert slave.do_step(0.0, 0.1)
    before = slave.get_real([vr_of(slave, "car.position")])
    slave.values[name] = value
    assert slave.do_step(0.1, 0.1) is False
    assert any(name in m.msg for m in slave.log_queue)
    assert slave.get_real([vr_of(slave, "car.position")]) == before   # nothing changed
    slave.values[name] = 0.0
    assert slave.do_step(0.1, 0.1) is True


@pytest.mark.parametrize("step", [0.0, -0.1, math.nan])
def test_bad_step_size_is_discarded(step):
    slave = make(RailCar)
    assert slave.do_step(0.0, step) is False
    assert any("step size" in m.msg for m in slave.log_queue)
    assert slave.do_step(0.0, 0.1) is True


def test_time_that_does_not_continue_is_discarded():
    slave = make(RailCar)
    assert slave.do_step(0.0, 0.1)
    assert slave.do_step(5.0, 0.1) is False
    assert any("does not continue" in m.msg for m in slave.log_queue)


@pytest.mark.parametrize("name,value,needle", [
    ("car.mass", -1.0, "car.mass"),
    ("est.batch_size", 2, "est.batch_size"),
    ("est.forgetting", 1.0, "est.forgetting"),
    ("sensor.speed_std", 0.0, "sensor.speed_std"),
    ("track.grade_profile", "no/such/file.csv", "track.grade_profile"),
    ("filter.kind", 1, "track.speed_profile"),
])
def test_bad_parameter_fails_initialisation_naming_it(name, value, needle):
    with pytest.raises(ParameterError, match=needle.replace(".", r"\.")):
        make(RailCar, **{name: value})


def test_malformed_profile_names_file_and_line(tmp_path):
    bad = tmp_path / "grade.csv"
    bad.write_text("distance_m,grade_permille\n0,0\n100,abc\n")
    with pytest.raises(ParameterError, match=r"grade\.csv: line 3"):
        make(RailCar, **{"track.grade_profile": str(bad)})


def test_relative_profile_path_resolves_in_resources_first(tmp_path):
    (tmp_path / "g.csv").write_text("distance_m,grade_permille\n0,20\n")
    slave = RailCar(instance_name="t", resources=str(tmp_path))
    slave.values["track.grade_profile"] = "g.csv"
    slave.exit_initialization_mode()
    assert slave.do_step(0.0, 0.1)
    assert slave.get_real([vr_of(slave, "car.grade")])[0] == 20.0


def test_estimator_slave_rejects_non_finite_measurement_then_continues():
    slave = make(RailCarEstimator)
    assert slave.do_step(0.0, 0.1)
    slave.values["sensor.speed"] = math.nan
    assert slave.do_step(0.1, 0.1) is False
    assert any("sensor.speed" in m.msg for m in slave.log_queue)
    slave.values["sensor.speed"] = 0.0
    assert slave.do_step(0.1, 0.1) is True
