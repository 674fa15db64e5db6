"""One closed loop (harness.run.driver.drive) for the FMU and the models chain.

- every library scenario, run by FmuRunner on the session's RailCar.fmu and by run_on_chain on
  the models chain, gets the same demands, wind and payload at every step: float64 bit patterns
  equal, the same number of steps (a one-ulp change is seen by the comparison);
- a time-table scenario on the chain gets its table's demands (the chain's former loop of its
  own ignored the table and ran no step at all), the same as on the FMU;
- the protocol with a fake stepper and fake drivers: what the driver sees and when, the time
  instants, wind, payload, stop_after_last_phase, max_steps and until; a command with only
  traction and brake plugs in, and models.ato.controller's controller drives the chain through the loop
  exactly as a hand-written loop does;
- FmuRunner.run with a driver's ``reads`` and a restricted output list reads what it must.

About 4 s of its own (the library ~3 s on the FMU, ~0.5 s on the chain), plus the session's
FMU build when run alone (~25 s).
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from harness.run.driver import ChainStepper, chain_result, drive, run_on_chain
from harness.run.phases import INPUTS, Demands, PhaseDriver
from harness.run.regress import library_scenarios
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario, scenario_from_dict

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = library_scenarios()


def bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.uint64)


def input_differences(a, b) -> list[str]:
    """Where two RunResults' times or inputs differ (float64 bits; lengths first)."""
    if len(a.time) != len(b.time):
        return [f"{len(a.time) - 1} steps vs {len(b.time) - 1}"]
    out = [] if np.array_equal(bits(a.time), bits(b.time)) else ["time"]
    for n in INPUTS:
        diff = np.nonzero(bits(a.inputs[n]) != bits(b.inputs[n]))[0]
        if diff.size:
            k = int(diff[0])
            out.append(f"{n}: {diff.size} steps differ, first at t = {a.time[k]:.1f} s: "
                       f"{a.inputs[n][k]!r} vs {b.inputs[n][k]!r}")
    return out


@pytest.fixture(scope="module")
def runner(built_fmus):
    with FmuRunner(built_fmus["RailCar"]) as r:
        yield r


# ------------------------------------------------------------------------------ both ways

@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenario_same_demands_on_fmu_and_chain(runner, path):
    s = load_scenario(path)
    fmu, chain = runner.run(s), run_on_chain(s)
    assert fmu.fmu == "python" and chain.fmu == ""
    assert input_differences(fmu, chain) == []
    steps = len(fmu.time) - 1
    assert steps > 100 and len(fmu.inputs["traction_force_demand"]) == steps + 1
    # the script really drove: its traction and braking phases demanded force (the ATO of a
    # span scenario does both)
    actions = {"traction", "brake"} if s.ato is not None else {p.action for p in s.phases}
    assert (fmu.inputs["traction_force_demand"].max() > 0) == bool(actions & {"traction", "cruise"})
    assert (fmu.inputs["brake_force_demand"].max() > 0) == bool(actions & {"brake", "brake_to_stop", "hold"})
    # the comparison sees one ulp in one demand at one step
    k = steps // 2
    changed = replace(chain, inputs={**chain.inputs})
    tr = changed.inputs["traction_force_demand"] = chain.inputs["traction_force_demand"].copy()
    tr[k] = np.nextafter(tr[k], np.inf)
    assert input_differences(fmu, changed) and input_differences(fmu, changed)[0].startswith(
        "traction_force_demand: 1 steps differ")


# ------------------------------------------------------------------------------ time table

TABLE = {"name": "table", "duration_s": 40.0, "step_s": 0.1, "wind": [{"time_s": 10.0, "speed_mps": 4.0}],
         "driver_table": {"time_s": [0.0, 15.0, 15.1, 40.0], "traction_N": [30e3, 30e3, 0.0, 0.0],
                          "brake_N": [0.0, 0.0, 20e3, 20e3]}}


def test_time_table_scenario_gets_its_demands_on_the_chain(runner):
    """stop_after_last_phase is true by default: the former chain loop took the missing phases
    for a finished script and ran 0 steps; now the table drives, step by step, as on the FMU."""
    s = scenario_from_dict(TABLE, "table.toml", ROOT)
    assert s.stop_after_last_phase and not s.phases
    r = run_on_chain(s)
    assert len(r.time) == 401
    t = r.time[:-1]
    want = np.array([s.time_table.at(float(x)) for x in t])
    assert np.array_equal(bits(r.inputs["traction_force_demand"][:-1]), bits(want[:, 0]))
    assert np.array_equal(bits(r.inputs["brake_force_demand"][:-1]), bits(want[:, 1]))
    assert np.array_equal(r.inputs["wind_speed"][:-1], np.where(t + 1e-9 >= 10.0, 4.0, 0.0))
    assert r["car.speed"].max() > 10.0 and r["car.speed"][-1] == 0.0    # [m/s] it ran and stopped
    assert input_differences(runner.run(s), r) == []


# ------------------------------------------------------------------------------ the protocol

class FakeCar:
    """A stepper: a 1 t point mass without resistance; records every do_step call."""

    def __init__(self):
        self.v = self.x = 0.0
        self.calls = []

    def outputs(self):
        return {"car.speed": self.v, "car.position": self.x, "calls": len(self.calls)}

    def do_step(self, t, h, inputs):
        self.calls.append((t, h, tuple(inputs)))
        traction, brake = inputs[0], inputs[1]
        self.x += self.v * h
        self.v = max(0.0, self.v + (traction - brake) / 1000.0 * h)


class FakeDriver:
    """Records what it sees; boards 2 t at its 4th call; finishes after 6 calls. Its commands
    carry only traction, brake and a mode, like models.ato.controller.AtoCommand, except the boarding."""

    def __init__(self):
        self.seen = []

    @property
    def finished(self):
        return len(self.seen) > 6

    def demands(self, t, outputs):
        self.seen.append((t, dict(outputs)))
        if len(self.seen) == 4:
            return Demands(0.0, 100.0, 2.0)
        return SimpleNamespace(traction=1000.0 * len(self.seen), brake=0.0, mode=3)


SHORT = {"name": "fake", "step_s": 0.1, "duration_s": 1.0, "wind": [{"time_s": 0.2, "speed_mps": 5.0}],
         "driver": [{"action": "coast", "until_time_s": 1.0}]}


def test_the_loop_with_a_fake_stepper_and_driver():
    s = scenario_from_dict(SHORT, "fake.toml")
    car, driver = FakeCar(), FakeDriver()
    trace = drive(car, s, driver)
    # 7 calls: the 7th finds the driver finished, and the run stops (stop_after_last_phase)
    assert trace.finished and len(driver.seen) == 7 and len(car.calls) == 6
    assert [t for t, _ in driver.seen] == [k * 0.1 for k in range(7)]
    assert [c[0] for c in car.calls] == [k * 0.1 for k in range(6)] and {c[1] for c in car.calls} == {0.1}
    # each call sees the outputs after the previous step, and nothing else
    assert [o for _, o in driver.seen] == trace.outputs
    assert [o["calls"] for _, o in driver.seen] == list(range(7))
    # inputs: the demands, the scenario's wind at t_k, the payload boarded so far
    assert [tuple(u) for u in trace.inputs] == [c[2] for c in car.calls] == [
        (1000.0, 0.0, 0.0, 0.0), (2000.0, 0.0, 0.0, 0.0), (3000.0, 0.0, 5.0, 0.0), (0.0, 100.0, 5.0, 2.0),
        (5000.0, 0.0, 5.0, 2.0), (6000.0, 0.0, 5.0, 2.0)]
    r = trace.result(s)
    assert list(r.signals) == ["car.speed", "car.position", "calls"]
    assert list(r.signals["calls"]) == list(range(7))
    assert list(r.inputs["car.payload"]) == [0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 2.0]    # the last held

    # without stop_after_last_phase the run goes to duration_s (10 steps)
    assert len(drive(FakeCar(), replace(s, stop_after_last_phase=False), FakeDriver()).inputs) == 10
    # max_steps and until end it early
    assert len(drive(FakeCar(), s, FakeDriver(), max_steps=3).inputs) == 3
    assert len(drive(FakeCar(), s, FakeDriver(), until=lambda o: o["car.speed"] > 0.5).inputs) == 3


def test_scenario_driver_by_default_and_a_models_chain_like_stepper():
    """drive() without a driver runs the scenario's own; ChainStepper spreads the inputs over
    the chain's do_step(t, h, traction, brake, wind, payload)."""
    class Chain:
        def __init__(self):
            self.car, self.args = FakeCar(), []

        def outputs(self):
            return self.car.outputs()

        def do_step(self, t, h, traction, brake, wind, payload):
            self.args.append((traction, brake, wind, payload))
            self.car.do_step(t, h, (traction, brake, wind, payload))

    phases = [{"action": "traction", "force_N": 500.0, "until_time_s": 0.3},
              {"action": "hold", "until_time_s": 0.2, "mass_change_t": 1.5}]
    s = scenario_from_dict({**SHORT, "driver": phases}, "fake.toml")
    chain = Chain()
    r = chain_result(chain, s)
    assert chain.args == [(500.0, 0.0, 0.0, 0.0), (500.0, 0.0, 0.0, 0.0), (500.0, 0.0, 5.0, 0.0),
                          (0.0, 0.3 * s.parameter("car.brake_force_max"), 5.0, 1.5),
                          (0.0, 0.3 * s.parameter("car.brake_force_max"), 5.0, 1.5)]
    assert len(r.time) == 6 and r.time[-1] == 5 * 0.1
    # the phase driver answers the outputs mapping and the two numbers alike
    a, b = s.new_driver(), s.new_driver()
    for k, t in enumerate(r.time):
        o = {n: float(r[n][k]) for n in ("car.speed", "car.position")}
        assert a.demands(t, o) == b.demands(t, o["car.speed"], o["car.position"])
    assert isinstance(a, PhaseDriver) and ChainStepper(chain).outputs() == chain.outputs()


def test_fmu_runner_reads_what_the_driver_needs_and_records_only_what_was_asked(runner):
    """outputs=["est.mass"]: the phase driver still gets car.speed and car.position (its
    ``reads``), the result holds est.mass alone, bit-identical to a full run's."""
    s = load_scenario(ROOT / "scenarios" / "library" / "level_run.toml")
    s = replace(s, duration_s=60.0)
    full, only = runner.run(s), runner.run(s, outputs=["est.mass"])
    assert list(only.signals) == ["est.mass"] and only.units == {"est.mass": "t"}
    assert np.array_equal(bits(only["est.mass"]), bits(full["est.mass"]))
    assert input_differences(full, only) == []
    # a driver of one's own (here: the scenario's, wrapped) is used as given
    seen = []

    class Watch:
        reads = ("filter.speed",) + PhaseDriver.reads

        def __init__(self):
            self.inner = s.new_driver()

        @property
        def finished(self):
            return self.inner.finished

        def demands(self, t, outputs):
            seen.append(outputs["filter.speed"])
            return self.inner.demands(t, outputs)

    watched = runner.run(s, outputs=["est.mass"], driver=Watch())
    assert np.array_equal(bits(watched["est.mass"]), bits(full["est.mass"]))
    assert np.array_equal(bits(seen), bits(full["filter.speed"][:-1]))


def test_the_ato_controller_plugs_into_the_loop():
    """models.ato.controller's controller (demands(t, outputs) -> AtoCommand, no payload) drives the chain
    through ``drive`` exactly as a hand-written loop of the same steps drives it: until it
    stands at the mark, the same commands at every step (floats equal) and the same end state."""
    from models.ato.controller import AtoController
    from models.planning.span import CarTraction, Span
    from models.plant.track import GradeProfile
    from models.units import kmh_to_mps

    grade = GradeProfile((0.0, 300.0, 800.0, 1100.0, 1500.0), (0.0, 15.0, -10.0, 0.0, 5.0))
    span = Span(2200.0, 135.0, stop=2150.0, grade=grade, limit_distances=(0.0, 900.0, 1300.0),
                limit_speeds=(kmh_to_mps(80.0), kmh_to_mps(60.0), kmh_to_mps(80.0)))
    s = scenario_from_dict({"name": "ato", "step_s": 0.1, "duration_s": 400.0, "stop_after_last_phase": False,
                            "driver": [{"action": "coast", "until_time_s": 1.0}]},   # (not used)
                           "ato.toml")
    setup = replace(s.chain_setup({"seed": 4}), grade=span.grade)

    chain, ctrl, by_hand = setup.open(), AtoController(span, CarTraction()), []
    out = chain.outputs()
    for k in range(4000):
        cmd = ctrl.demands(k * 0.1, out)
        by_hand.append([cmd.traction, cmd.brake, 0.0, 0.0])
        chain.do_step(k * 0.1, 0.1, cmd.traction, cmd.brake, 0.0, 0.0)
        out = chain.outputs()
        if ctrl.finished and out["car.speed"] == 0.0:
            break

    ato = AtoController(span, CarTraction())
    trace = drive(ChainStepper(setup.open()), s, ato,
                  until=lambda o: ato.finished and o["car.speed"] == 0.0)
    assert np.array_equal(bits(trace.inputs), bits(by_hand))
    assert list(trace.outputs[-1]) == list(out)
    assert np.array_equal(bits(list(trace.outputs[-1].values())), bits(list(out.values())))
    assert 1000 < len(by_hand) < 4000 and abs(out["car.position"] - span.stop) < 1.0    # [m]
