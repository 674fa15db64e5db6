"""The ATO closed around RailCar as an FMI system (scenarios/systems/ato_nominal.toml): the
library's 2.15 km span, RailCarNative <-> AtoController, run by our master (harness.systems.master) and
by libcosim from the same .ssp package.

- both masters give the same numbers, bit for bit, at every time point;
- the run meets the ATO's targets with the actuator delay the Jacobi scheme adds (the demand
  computed from the outputs at t is applied from t + 0.1 s): arrival within +-2.5 s of the
  schedule, the stop within +-0.3 m of the mark, the true speed never above the limit, no
  safety intervention (metrics of harness.metrics.ato, as for a span scenario).
"""
from __future__ import annotations

import numpy as np
import pytest

from conftest import ROOT
from harness.metrics.ato import span_metrics
from harness.systems.master import run_system
from harness.systems.ssp import write_ssp
from harness.systems.libcosim import run_libcosim
from harness.systems.cli import load_system
from models.plant.dynamics import VehicleParams
from models.planning.span import CarTraction, Span
from models.plant.track import GradeProfile
from models.units import kmh_to_mps

SPAN = Span(2200.0, 135.0, stop=2150.0,
            grade=GradeProfile((0.0, 300.0, 800.0, 1100.0, 1500.0), (0.0, 15.0, -10.0, 0.0, 5.0)),
            limit_distances=(0.0, 900.0, 1300.0),
            limit_speeds=(kmh_to_mps(80.0), kmh_to_mps(60.0), kmh_to_mps(80.0)))
OUTPUTS = ["car.car.speed", "car.car.position", "car.filter.position", "ato.traction_force_demand",
           "ato.brake_force_demand", "ato.ato.mode", "ato.ato.planned_speed"]


@pytest.fixture(scope="module")
def runs(built_fmus, tmp_path_factory):
    system = load_system(ROOT / "scenarios" / "systems" / "ato_nominal.toml", built_fmus["RailCar"].parent)
    ssp = write_ssp(system, tmp_path_factory.mktemp("ssp_ato") / "ato_nominal.ssp")
    return run_system(ssp, outputs=OUTPUTS), run_libcosim(ssp, outputs=OUTPUTS, isolated=True)


def test_both_masters_give_the_same_bits(runs):
    ours, cosim = runs
    assert len(ours.time) == len(cosim.time) == 1501
    assert np.array_equal(ours.time, cosim.time)
    for name in OUTPUTS:
        a, b = np.asarray(ours.signals[name]), np.asarray(cosim.signals[name])
        assert a.tobytes() == b.tobytes(), f"{name}: first difference at row {np.flatnonzero(a != b)[:1]}"


def test_the_system_meets_the_ato_targets(runs):
    r, _ = runs
    sig = {n: np.asarray(r.signals[n]) for n in OUTPUTS}
    m = span_metrics(0, SPAN, range(0, len(r.time)), r.time, sig["car.car.speed"],
                     sig["car.car.position"], sig["ato.traction_force_demand"],
                     sig["ato.brake_force_demand"], VehicleParams(), CarTraction(), 0.0,
                     sig["ato.ato.mode"], True, 0.1)
    assert abs(m.arrival_error_s) <= 2.5, m          # Meleshin (2011), Sidorenko (1997)
    assert abs(m.stop_error_m) <= 0.3, m             # Sidorenko (1997)
    assert m.margin_mps > 0.0 and m.interventions == 0, m
    assert sig["car.car.speed"][-1] == 0.0 and sig["ato.ato.mode"][-1] == 8    # holding at the mark
    # a real run: full traction, the 60 km/h zone and the EP relay stages were all passed through
    assert {0, 7, 8} <= set(sig["ato.ato.mode"].astype(int))
    assert sig["car.car.speed"][(sig["car.car.position"] > 950) & (sig["car.car.position"] < 1250)].max() \
        <= kmh_to_mps(60.0)
