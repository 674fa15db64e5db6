"""AtoController.fmu (fmu_src/ato_controller.py): the controller of models.ato.controller behind FMI 2.0.

- fed the outputs of a closed-loop run of the models chain, the FMU's commands are the Python
  controller's bit for bit (same span, car, tuning: the parameters reach models.ato.controller unchanged);
- after initialisation it outputs a holding brake and the plan's predicted arrival;
- bad parameters fail exitInitializationMode with a message naming them, and the instance can
  still be reset and initialised, or freed;
- a NaN input gives the safe brake (ato.mode 9) with a warning, never a failed step, held
  until the inputs have been sane for 1 s; a doStep before initialisation is refused (the
  catalogue of bad inputs, steps and parameters: test_ato_supervision.py).
"""
from __future__ import annotations

import math

import pytest

from conftest import ERROR, OK, STATUS_LABEL
from models.ato.controller import AtoController
from models.ato.interface import ALL_INPUTS as INPUTS, AtoMode
from models.planning.span import CarTraction, Span
from models.plant.track import GradeProfile

STEP = 0.1    # [s]
GRADE_CSV = "distance_m,grade_permille\n0,0\n300,15\n800,-10\n1100,0\n1500,5\n"
LIMIT_CSV = "distance_m,speed_limit_mps\n0,22.2222222222\n900,16.6666666667\n1300,22.2222222222\n"
SPAN = Span(2200.0, 135.0, stop=2150.0,
            grade=GradeProfile((0.0, 300.0, 800.0, 1100.0, 1500.0), (0.0, 15.0, -10.0, 0.0, 5.0)),
            limit_distances=(0.0, 900.0, 1300.0),
            limit_speeds=(22.2222222222, 16.6666666667, 22.2222222222))
OUTPUTS = ("traction_force_demand", "brake_force_demand", "ato.mode", "ato.planned_speed",
           "ato.ep_stage")


@pytest.fixture(scope="module")
def profiles(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ato_profiles")
    (folder / "grade.csv").write_text(GRADE_CSV)
    (folder / "limits.csv").write_text(LIMIT_CSV)
    return {"span.grade_profile": str(folder / "grade.csv"),
            "span.speed_limit_profile": str(folder / "limits.csv"),
            "span.stop": 2150.0, "span.length": 2200.0, "span.schedule": 135.0}


def closed_loop_on_chain(seed: int = 4):
    """The Python controller drives the models chain (default RailCar parameters) over SPAN:
    the outputs it saw at each step and its commands."""
    from harness.run.scenario import railcar_values
    from fmu_src.adapter import chain_config
    from models.compiled import open_chain
    chain = open_chain(chain_config(railcar_values({"seed": seed})), SPAN.grade)
    ctrl = AtoController(SPAN, CarTraction())
    seen, commands = [], []
    out = chain.outputs()
    for k in range(2000):
        t = k * STEP
        inputs = {n: out[n] for n in (*INPUTS, "filter.position_std")}
        cmd = ctrl.demands(t, inputs)
        seen.append(inputs)
        commands.append(cmd)
        if ctrl.finished:
            break
        chain.do_step(t, STEP, cmd.traction, cmd.brake, 0.0, 0.0)
        out = chain.outputs()
    return seen, commands, ctrl


def test_fmu_commands_are_the_python_controllers_bit_for_bit(ato_fmu, slave_factory, profiles):
    seen, commands, ctrl = closed_loop_on_chain()
    assert ctrl.finished and abs(seen[-1]["filter.position"] - SPAN.stop) < 0.5   # a real run
    s = slave_factory(ato_fmu)
    s.initialize(profiles)
    modes = set()
    for k, (inputs, cmd) in enumerate(zip(seen, commands)):
        s.set(inputs)
        assert s.do_step(k * STEP, STEP) == OK, s.log_text()
        got = [s.get(n) for n in OUTPUTS]
        assert got == [cmd.traction, cmd.brake, cmd.mode, cmd.planned_speed, cmd.ep_stage], \
            f"step {k} (t = {k * STEP:.1f} s): FMU {got}, Python {cmd}"
        modes.add(cmd.mode)
    assert s.get("ato.finished") is True or s.get("ato.finished") == 1
    assert s.get("ato.replans") == ctrl.replans > 10
    # the run went through traction, braking and the EP relay stages to the holding brake
    assert {AtoMode.TG, AtoMode.EP, AtoMode.HOLD} <= modes


def test_after_initialisation_the_outputs_are_a_holding_brake_and_the_plan(ato_fmu, slave_factory,
                                                                            profiles):
    s = slave_factory(ato_fmu)
    s.initialize(profiles)
    assert s.get("traction_force_demand") == 0.0
    assert s.get("brake_force_demand") == 0.5 * 45e3          # ato.hold_brake x car.brake_force_max
    assert s.get("ato.mode") == AtoMode.HOLD
    # the initial plan arrives on schedule within the planner's tolerance ato.time_tol (0.05 s)
    assert abs(s.get("ato.predicted_arrival") - 135.0) <= 0.05


@pytest.mark.parametrize("parameters, words", [
    ({"span.schedule": 60.0}, ["span.schedule = 60.00 s is infeasible"]),
    ({"span.stop": 2500.0}, ["span.stop = 2500.0 m is beyond the span", "span.length = 2200.0"]),
    ({"span.speed_limit_profile": ""},   # the 80 km/h limit held down a -170 permille grade
     ["span.speed_limit = 22.2", "cannot be met", "-170"]),
    ({"ato.a_ep": 0.0}, ["ato.a_ep must be > 0"]),
    ({"car.eta_f": 1.5}, ["car.eta_f must be in (0, 1]"]),
    ({"span.grade_profile": "no_such_grade.csv"}, ["span.grade_profile: cannot read 'no_such_grade.csv'"]),
    ({"span.speed_limit_profile": "BAD"}, ["span.speed_limit_profile", "limits_bad.csv: line 2"]),
])
def test_bad_parameters_fail_initialisation_naming_them(ato_fmu, slave_factory, profiles, tmp_path,
                                                       parameters, words):
    values = dict(profiles, **parameters)
    if parameters.get("span.speed_limit_profile") == "":
        (tmp_path / "steep.csv").write_text("distance_m,grade_permille\n0,0\n1000,-170\n1100,0\n")
        values["span.grade_profile"] = str(tmp_path / "steep.csv")
    if parameters.get("span.speed_limit_profile") == "BAD":
        (tmp_path / "limits_bad.csv").write_text("distance_m,speed_limit_mps\n0,fast\n")
        values["span.speed_limit_profile"] = str(tmp_path / "limits_bad.csv")
    s = slave_factory(ato_fmu)
    s.setup(values)
    status = s.exit_init()
    assert status == ERROR, f"exitInitializationMode -> {STATUS_LABEL[status]}\n{s.log_text()}"
    text = s.log_text()
    for w in words:
        assert w in text, f"{w!r} not in the log:\n{text}"
    assert s.do_step(0.0, STEP) != OK                      # not initialised: refused, no crash
    assert s.reset() == OK                                  # and the instance is usable again
    s.initialize(profiles)
    assert s.do_step(0.0, STEP) == OK


def test_a_nan_input_gives_the_safe_brake_with_a_warning(ato_fmu, slave_factory, profiles):
    s = slave_factory(ato_fmu)
    s.initialize(profiles)
    s.set({"filter.speed": 0.0, "filter.position": 0.0})
    assert s.do_step(0.0, STEP) == OK
    assert s.get("traction_force_demand") > 0.0            # departs
    s.set({"filter.speed": math.nan})
    assert s.do_step(STEP, STEP) == OK
    assert s.get("ato.mode") == AtoMode.SAFE
    assert (s.get("traction_force_demand"), s.get("brake_force_demand")) == (0.0, 45e3)
    assert "filter.speed" in s.log_text() and "[warning]" in s.log_text()
    # the safe brake latches: held until the inputs have been sane for 1 s, then driving again
    for k in range(2, 13):
        s.set({"filter.speed": 0.2, "filter.position": 0.01 * k, "filter.speed_std": 0.03,
               "filter.position_std": 0.01})
        assert s.do_step(k * STEP, STEP) == OK
        assert (s.get("ato.mode") == AtoMode.SAFE) == (k < 12), f"step {k}: {s.get('ato.mode')}"
    assert "the safe brake is released" in s.log_text()


def test_do_step_before_initialisation_is_refused(ato_fmu, slave_factory):
    s = slave_factory(ato_fmu)
    s.fmu.setupExperiment(startTime=0.0)
    assert s.do_step(0.0, STEP) == ERROR
    assert "fmi2DoStep: not allowed in state 'instantiated'" in s.log_text()
    s.fmu.enterInitializationMode()                         # the defaults: a feasible level span
    assert s.exit_init() == OK
    assert s.do_step(0.0, STEP) == OK


def test_outputs_have_no_direct_feedthrough_and_are_initial_unknowns(ato_fmu):
    """A system that loops RailCar -> AtoController -> RailCar has no algebraic loop: the
    controller's outputs depend on no input within a step (dependencies=""), and each output,
    calculated at initialisation, is an initial unknown (FMI 2.0 section 2.2.8)."""
    md = ato_fmu.md
    outputs = [v for v in md.modelVariables if v.causality == "output"]
    assert len(outputs) == 11
    assert [u.variable for u in md.outputs] == outputs
    assert all(u.dependencies == [] for u in md.outputs)
    assert [u.variable for u in md.initialUnknowns] == outputs
    assert all(v.initial == "calculated" and v.start is None for v in outputs)


def test_every_tuning_field_and_input_of_the_controller_is_a_variable(ato_fmu):
    """The FMU exposes all of models.ato.controller: each AtoTuning field as ato.<field> (its type and its
    default as the start value), each CarTraction field as car.<field>, each INPUTS as an input."""
    from dataclasses import fields
    from models.ato.interface import AtoTuning
    v = ato_fmu.variables
    tuning = AtoTuning()
    typed = {"bool": "Boolean", "int": "Integer", "float": "Real"}
    for f in fields(AtoTuning):
        var = v.get(f"ato.{f.name}")
        assert var is not None and var.causality == "parameter", f"ato.{f.name} missing"
        assert var.type == typed[f.type], f"ato.{f.name}: {var.type}"
        start = {"Real": float, "Integer": int, "Boolean": lambda x: x in ("true", "1", True)}[var.type](var.start)
        assert start == getattr(tuning, f.name), f"ato.{f.name}: start {var.start}"
    car = CarTraction()
    for f in fields(CarTraction):
        if f.init:
            assert float(v[f"car.{f.name}"].start) == getattr(car, f.name), f"car.{f.name}"
    assert {n for n, x in v.items() if x.causality == "input"} == set(INPUTS) | {"est.station_stops"}


def test_terminate_and_free_after_a_failed_initialisation(ato_fmu, slave_factory):
    """pythonfmu's own binary segfaults on freeInstance after a failed initialisation; ours
    (the same glue as RailCar's) refuses nothing and frees the instance, and the next instance
    in the process runs."""
    s = slave_factory(ato_fmu)
    s.setup({"span.schedule": 10.0})
    assert s.exit_init() == ERROR
    assert s.call("terminate") in (OK, ERROR)
    assert s.call("freeInstance") == OK
    s.freed = True
    t = slave_factory(ato_fmu)
    t.initialize({})
    assert t.do_step(0.0, STEP) == OK and t.get("traction_force_demand") > 0.0


def test_every_tuning_parameter_reaches_the_controller(monkeypatch, profiles):
    """fmu_src.adapter.open_ato builds AtoTuning from every ato.<field> the FMU declares, the
    fields appended after the outputs too (ato.config_mass_std, ato.est_gate, ... were once left
    at their defaults whatever the user set): each parameter set to a marker value arrives."""
    from dataclasses import fields
    import models.ato.controller as controller_module
    import models.ato.interface as interface
    from fmu_src.adapter import open_ato
    from fmu_src.variables import variables_for
    v = {x.name: x.start for x in variables_for("AtoController")}
    v.update(profiles)
    markers = {}
    for k, f in enumerate(fields(interface.AtoTuning)):
        markers[f.name] = not v[f"ato.{f.name}"] if f.type == "bool" else 1000 + k
        v[f"ato.{f.name}"] = markers[f.name]
    seen = {}
    monkeypatch.setattr(interface, "AtoTuning", lambda **kw: seen.update(kw) or "tuning")
    monkeypatch.setattr(controller_module, "AtoController", lambda span, car, tuning: tuning)
    assert open_ato(v, None) == "tuning"
    assert seen == markers
