"""The C chain (models/core/ through models/_railcar.c, models/compiled.py) against the Python
reference (models/chain.py): bit for bit.

Each library scenario, and variants that reach the other covered paths (forgetting, run
forgetting, grade averaging over the car's length, odometry drift, the linearised and the paper
filter on a speed profile, a coarser solver step, gamma, a small batch), runs on both chains with
the same closed-loop driver; every output at every step, and the internal state at the end, must
be *equal* -- no tolerance: same seed, same numbers. The estimator alone (RailCarEstimator's
chain) is replayed through faults (spikes, a stuck sensor, a distance jump, station stops).
"""
from __future__ import annotations

import math
import os
import random
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.run.driver import drive_chain
from harness.run.scenario import load_scenario
from models import compiled
from models.chain import (ChainConfig, EstimatorChain, RailCarChain, StepRejected,
                          TrackSensorConfig)
from models.compiled import CompiledChain, CompiledEstimatorChain, open_chain, open_estimator_chain
from models.plant.dynamics import VehicleParams
from models.estimation.online import StationConfig
from models.filtering.motion_filter import FilterConfig, MotionFilter
from models.estimation.identification import IdentifierConfig
from models.plant.track import GradeProfile, SpeedProfile

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = sorted((ROOT / "scenarios" / "library").glob("*.toml"))


def test_the_c_core_is_built():
    """pip install -e . compiles models/_railcar (gcc and the Python headers are on every machine
    we support); without it everything still runs, in Python (test_pure_python_switch)."""
    assert compiled._railcar is not None, "models/_railcar was not compiled: pip install -e ."
    assert compiled.enabled()


def same(a, b) -> bool:
    """Equal bit for bit (NaN equals NaN; ints and floats compared by value and type)."""
    if isinstance(a, float) and isinstance(b, float):
        return a == b and math.copysign(1.0, a) == math.copysign(1.0, b) or (math.isnan(a) and math.isnan(b))
    if isinstance(a, dict) and isinstance(b, dict):
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b


def python_state(chain: RailCarChain) -> tuple:
    """The Python chain's internal state in CompiledChain.state()'s order (models/_railcar.c)."""
    ident, f, st, p = chain.estimator.ident, chain.estimator.filter, chain.estimator.station, chain.plant
    S = ident._S if ident._S is not None else [math.nan] * 16
    values = [*ident._theta, *S, *ident._W, *ident._D, ident.n, ident.q_e, ident.s2, ident.c0,
              ident.c1, math.nan if ident.cL is None else ident.cL, ident._n_cL, ident._n_c1,
              *f.x_bar, f.M[0][0], f.M[0][1], f.M[1][1], *f.x_hat, f.P[0][0], f.P[0][1], f.P[1][1],
              st.still_time, st._fast_run, p.time, p._grid_index, p.traction_impulse,
              p.brake_impulse, p.state.still_time, p.state.stops, chain._sample_index,
              math.nan if chain._track_t1 is None else chain._track_t1,
              *(chain._pending_track or (math.nan, math.nan))]
    return tuple(float(x) for x in values)


def scenario_setup(path: Path, overrides: dict):
    """(config, grade profile, speed profile) of a library scenario with ``overrides``."""
    sc = load_scenario(path)
    s = replace(sc, parameters={**sc.parameters, **overrides}).chain_setup()
    return s.config, s.grade, s.speed


def scenario_chains(path: Path, overrides: dict):
    sc = load_scenario(path)
    sc = replace(sc, parameters={**sc.parameters, **overrides})
    s = sc.chain_setup()            # each chain runs a private copy of the configuration
    return sc, RailCarChain(s.config, s.grade, s.speed), CompiledChain(s.config, s.grade, s.speed)


def assert_identical(path: Path, overrides: dict, max_steps: int | None = None) -> int:
    sc, py, c = scenario_chains(path, overrides)
    rows_py, rows_c = drive_chain(py, sc, max_steps), drive_chain(c, sc, max_steps)
    assert len(rows_py) == len(rows_c)
    for i, (a, b) in enumerate(zip(rows_py, rows_c)):
        if not same(a, b):
            diff = [(k, a[k], b[k]) for k in a if not same(a[k], b.get(k))]
            raise AssertionError(f"{path.stem} {overrides}: row {i} differs: {diff[:4]}")
    state_py, state_c = python_state(py), c.state()
    diff = [k for k, (x, y) in enumerate(zip(state_py, state_c)) if not same(x, y)]
    assert not diff, f"{path.stem} {overrides}: internal state differs at {diff}"
    return len(rows_py)


@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenario_bit_identical(path):
    assert assert_identical(path, {}) > 100


# a relative profile path is looked up where the RailCar FMU looks (Scenario.chain_setup): its
# resources, i.e. scenarios/ (build.py bundles scenarios/profiles)
VARIANTS = {
    "forgetting": {"est.forgetting": 0.002},
    "run_forgetting": {"est.run_forgetting": 0.3},
    "run_forgetting_and_drift": {"est.run_forgetting": 0.3, "est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03},
    "forgetting_and_drift": {"est.forgetting": 0.002, "est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03},
    "car_length_and_odometry_drift": {"car.length": 60.0, "sensor.position_std_rel": 0.01},
    "relative_speed_noise": {"sensor.speed_std_rel": 0.02, "sensor.speed_std": 0.01},
    "singer_relative_speed_noise": {"filter.kind": 4, "sensor.speed_std_rel": 0.02,
                                    "sensor.position_std_rel": 0.001},
    "paper_filter": {"filter.kind": 3, "track.speed_profile": "profiles/default_speed.csv"},
    "linearised_filter": {"filter.kind": 1, "track.speed_profile": "profiles/default_speed.csv"},
    "solver_step_0.1": {"solver.step": 0.1},
    "gamma_and_small_batch": {"car.gamma": 0.08, "est.gamma": 0.08, "est.batch_size": 4},
    "start_time": {"seed": 2147483647},
}


@pytest.mark.parametrize("name", VARIANTS)
def test_variant_bit_identical(name):
    path = ROOT / "scenarios" / "library" / ("station_day.toml" if "forgetting" in name else "steep_grades.toml")
    assert assert_identical(path, dict(VARIANTS[name]), max_steps=3000) > 100


# ---------------------------------------------------------------- est.method 2 (SlopeLS)

PHYSICAL = {"est.physical": 1}
"""est.physical 1: Theta-hat reported and predicted with projected onto A0, A2 >= 0
(identification.project_physical, models/core/estimator.c rc_project_physical)."""

SLOPE_LS = {"est.method": 2}
"""est.method 2: the LS on Sidorenko's centred slopes (models/estimation/methods.py SlopeLS,
models/core/estimator.c slope_identify; ident.c its end factor, prior weights and reweight_prior)."""


@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenario_with_slope_ls_bit_identical(path):
    assert open_chain(*scenario_setup(path, SLOPE_LS)).engine == "c"
    assert assert_identical(path, SLOPE_LS) > 100


# station_day: station stops (the prior's reweighting, run forgetting), whole days
SLOPE_VARIANTS = {
    "forgetting": ("station_day", {"est.forgetting": 0.002}),
    "run_forgetting": ("station_day", {"est.run_forgetting": 0.3}),
    "drift": ("station_day", {"est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03}),
    "drift_A1_forgetting": ("station_day", {"est.A1_drift_std": 0.03, "est.forgetting": 0.002,
                                            "est.run_forgetting": 0.3}),
    "shortest_window": ("station_day", {"est.slope_window": 2}),
    "window_6_small_batch": ("station_day", {"est.slope_window": 6, "est.batch_size": 4}),
    "long_window_noisy": ("etcs_noisy_sensors", {"est.slope_window": 25}),
    "singer_relative_speed_noise": ("steep_grades", {"filter.kind": 4, "sensor.speed_std_rel": 0.02}),
    "odd_steps_car_length_drift": ("steep_grades", {"solver.step": 0.1, "car.length": 60.0,
                                                    "sensor.position_std_rel": 0.01}),
}


@pytest.mark.parametrize("name", SLOPE_VARIANTS)
def test_slope_ls_variant_bit_identical(name):
    scenario, overrides = SLOPE_VARIANTS[name]
    path = ROOT / "scenarios" / "library" / f"{scenario}.toml"
    assert assert_identical(path, {**SLOPE_LS, **overrides}) > 100


def test_slope_ls_reweights_the_prior_at_stops_and_one_ulp_shows():
    """station_day reaches SlopeLS's own paths: the prior reweighted at a stop once the LAG sums
    exist (s2_prior no longer the configured one), identical in C; and one ulp off in an
    estimate of the last row is a difference."""
    path = ROOT / "scenarios" / "library" / "station_day.toml"
    sc, py, c = scenario_chains(path, SLOPE_LS)
    rows_py, rows_c = drive_chain(py, sc, None), drive_chain(c, sc, None)
    ident = py.estimator.ident
    assert ident.mass_restarts >= 3
    assert ident.s2_prior[1] == ident.s2_prior[0] != IdentifierConfig().sigma2_initial
    assert ident.s2_prior[0] != ident.s2_ref   # reweighted from the LAG sums
    assert same(rows_py, rows_c)
    for name in ("est.mass", "est.A0", "est.A2_std", "est.sigma2"):
        assert not same(rows_py[-1], one_ulp_off(rows_c[-1], name)), name


# ---------------------------------------------------------------- est.sigma2_method 1

LIKELIHOOD = {"est.sigma2_method": 1}
"""est.sigma2_method 1: sigma^2 from the likelihood bank (models/filtering/motion_filter.py
ProcessNoiseBank via methods.LikelihoodNoise; models/core/estimator.c bank_*)."""


@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenario_with_the_likelihood_bank_bit_identical(path):
    assert open_chain(*scenario_setup(path, LIKELIHOOD)).engine == "c"
    assert assert_identical(path, LIKELIHOOD) > 100


LIKELIHOOD_VARIANTS = {
    "slopes_physical": ("station_day", {**SLOPE_LS, **PHYSICAL}),
    "slopes_physical_drift": ("station_day", {**SLOPE_LS, **PHYSICAL, "est.run_forgetting": 0.3,
                                              "est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03}),
    "relative_speed_noise": ("steep_grades", {"sensor.speed_std_rel": 0.02, "sensor.speed_std": 0.01}),
    "singer_slopes_relative_noise": ("steep_grades", {**SLOPE_LS, "filter.kind": 4,
                                                      "sensor.speed_std_rel": 0.02}),
    "noisy_sensors_forgetting": ("etcs_noisy_sensors", {"est.forgetting": 0.002}),
}


@pytest.mark.parametrize("name", LIKELIHOOD_VARIANTS)
def test_likelihood_bank_variant_bit_identical(name):
    scenario, overrides = LIKELIHOOD_VARIANTS[name]
    path = ROOT / "scenarios" / "library" / f"{scenario}.toml"
    assert assert_identical(path, {**LIKELIHOOD, **overrides}) > 100


def test_the_likelihood_bank_moves_sigma2_and_one_ulp_shows():
    """station_day with the bank: est.sigma2 leaves its prior (the bank ran through the stops),
    equal in C; one ulp off in est.sigma2 is a difference."""
    path = ROOT / "scenarios" / "library" / "station_day.toml"
    sc, py, c = scenario_chains(path, LIKELIHOOD)
    rows_py, rows_c = drive_chain(py, sc, None), drive_chain(c, sc, None)
    assert py.estimator.noise.bank.estimate() != IdentifierConfig().sigma2_initial
    assert same(rows_py, rows_c)
    assert not same(rows_py[-1], one_ulp_off(rows_c[-1], "est.sigma2"))


def test_slope_ls_without_a_window_and_other_methods_are_refused_by_name():
    """The core runs est.method 0 and 2, est.physical and est.sigma2_method 0 and 1; CompiledChain refuses the rest
    naming exactly them, and the C core itself refuses est.method 2 without est.slope_window (a
    host that hands it only the flat configuration; the native FMUs hand it the window)."""
    path = ROOT / "scenarios" / "library" / "level_run.toml"
    for overrides in ({"est.method": 1}, {"est.method": 3},
                      {"est.method": 1, "est.physical": 1, "est.sigma2_method": 1}):
        cfg, grade, speed = scenario_setup(path, overrides)
        with pytest.raises(ValueError, match="^the C core does not cover est.method 1 or 3: "
                           "use open_chain"):
            CompiledChain(cfg, grade, speed)
        assert open_chain(cfg, grade, speed).engine == "python"
        assert compiled.core_not_covered(cfg.identifier) == compiled.NOT_COVERED
    for overrides in (SLOPE_LS, PHYSICAL, LIKELIHOOD, {**SLOPE_LS, **PHYSICAL, **LIKELIHOOD}):
        cfg = scenario_setup(path, overrides)[0]
        assert compiled.core_not_covered(cfg.identifier) is None
        # the native FMUs run them too (they hand the core est.slope_window after their values)
        assert compiled.not_covered(cfg) is None
    cfg, grade, _ = scenario_setup(path, SLOPE_LS)
    with pytest.raises(ValueError, match=r"does not cover est.method 2 without est.slope_window"):
        compiled._railcar.Chain(compiled._config_values(compiled.validate(cfg, None, 0.0), 0.0),
                                grade.distances, grade.grades, (), (), compiled.OUTPUT_NAMES,
                                tuple(n in compiled.INTEGER_OUTPUTS for n in compiled.OUTPUT_NAMES),
                                StepRejected)


def test_start_time_and_odd_steps_bit_identical():
    """A host that starts at t = 1000 s and steps at irregular points (0.037 s, 0.5 s, 1.3 s)."""
    cfg = ChainConfig(vehicle=VehicleParams(mass=34.0), seed=7)
    grade = GradeProfile((0.0, 300.0, 800.0), (0.0, 15.0, -10.0))
    py, c = RailCarChain(cfg, grade, start_time=1000.0), CompiledChain(cfg, grade, start_time=1000.0)
    rng = random.Random(5)
    t = 1000.0
    for k in range(3000):
        h = rng.choice((0.037, 0.1, 0.5, 1.3))
        args = (t, h, 40e3 if k < 400 else 0.0, 30e3 if 1500 < k < 1800 else 0.0, rng.uniform(-5, 5))
        py.do_step(*args)
        c.do_step(*args)
        assert same(py.outputs(), c.outputs()), f"step {k}"
        t += h
    assert same(python_state(py), c.state())


def test_batched_run_equals_the_step_by_step_outputs():
    cfg = ChainConfig(seed=11)
    grade = GradeProfile((0.0, 300.0), (0.0, 10.0))
    n = 4000
    t = np.arange(n) * 0.1
    inputs = np.column_stack([t, np.full(n, 0.1), np.where(t < 30, 40e3, 0.0),
                              np.where((t > 200) & (t < 240), 30e3, 0.0), np.zeros(n), np.zeros(n)])
    batched = CompiledChain(cfg, grade).run_steps(inputs)
    py = RailCarChain(cfg, grade)
    for k in range(n):
        py.do_step(*inputs[k])
        row = py.outputs()
        assert list(row) == list(compiled.OUTPUT_NAMES)
        assert same([float(x) for x in row.values()], batched[k].tolist()), f"step {k}"


def test_batched_run_names_the_rejected_row_and_keeps_the_rows_before():
    chain = CompiledChain(ChainConfig(), GradeProfile.level())
    inputs = np.array([[0.0, 0.1, 40e3, 0.0, 0.0, 0.0], [0.1, 0.1, 40e3, 0.0, 0.0, 0.0],
                       [0.2, 0.1, math.nan, 0.0, 0.0, 0.0]])
    with pytest.raises(StepRejected, match="inputs row 2: traction_force_demand"):
        chain.run_steps(inputs)
    assert chain.next_sample_time() == pytest.approx(0.3, abs=1e-12)   # two steps done, 0.1 s each
    with pytest.raises(ValueError, match="6 columns"):
        chain.run_steps(np.zeros((3, 5)))


@pytest.mark.parametrize("bad", [
    dict(traction_demand=math.nan), dict(brake_demand=-1.0), dict(wind_speed=math.inf),
    dict(wind_speed=150.0), dict(payload=-400.0), dict(payload=-100.0), dict(current_time=5.0),
    dict(step_size=0.0), dict(step_size=4000.0), dict(current_time=math.nan),
    dict(traction_demand=1e300), dict(payload=1e-320),
])
def test_bad_input_same_message_and_the_next_step_continues_exactly(bad):
    def fresh(kind):
        chain = kind(ChainConfig(), GradeProfile.level())
        for k in range(30):
            chain.do_step(k * 0.1, 0.1, 40e3, 0.0, 0.0)
        return chain
    py, c = fresh(RailCarChain), fresh(CompiledChain)
    args = dict(current_time=3.0, step_size=0.1, traction_demand=40e3, brake_demand=0.0,
                wind_speed=0.0, payload=0.0)
    messages = []
    for chain in (py, c):
        try:
            chain.do_step(**{**args, **bad})
            messages.append(None)
        except StepRejected as e:
            messages.append(str(e))
    assert messages[0] == messages[1]
    for chain in (py, c):
        chain.do_step(**{**args, "current_time": 3.0 if messages[0] else 3.1})
    assert same(py.outputs(), c.outputs())


def test_messages_write_values_as_python_repr():
    """rc_repr (models/core/repr.c) is Python's repr() of a float: 2,000 values, edge cases too."""
    rng = random.Random(3)
    values = [0.0, -0.0, 1e16, 1e15, 9999999999999998.0, 1e-4, 1e-5, 0.1, 123.456, 5e-324,
              1.7976931348623157e308, -2.5e-7, 1234567890123456789.0, 100.0, 1e22]
    values += [rng.uniform(-1e3, 1e3) for _ in range(500)]
    values += [math.ldexp(rng.random(), rng.randint(-1070, 1020)) for _ in range(1500)]
    chain = CompiledChain(ChainConfig(), GradeProfile.level())
    for x in values:
        with pytest.raises(StepRejected) as e:
            chain.do_step(0.0, 0.1, -abs(x) - 1e-300 if x else -1.0, 0.0, 0.0)
        x_bad = -abs(x) - 1e-300 if x else -1.0
        assert str(e.value) == f"traction_force_demand must be finite and >= 0 [N], got {x_bad!r}"


# ---------------------------------------------------------------- the estimator alone (faults)

def measurements(seconds: float, seed: int, stops: int) -> list[tuple]:
    """(t, h, traction, brake, speed, distance) of a 34 t car that runs ``stops`` station legs
    (traction, cruise, brake, 30 s dwell), recorded from the Python chain."""
    chain = RailCarChain(ChainConfig(vehicle=VehicleParams(mass=34.0), seed=seed), GradeProfile.level())
    rows, t, leg = [], 0.0, 0
    phase_t = 0.0
    while t < seconds and leg < stops:
        out = chain.outputs()
        v = out["car.speed"]
        if phase_t < 40.0:
            f, b = 40e3, 0.0
        elif phase_t < 120.0:
            d = 1000.0 * 34.0 * 0.5 * (16.7 - v)
            f, b = (min(d, 40e3), 0.0) if d >= 0 else (0.0, min(-d, 45e3))
        elif v > 0.0 or phase_t < 130.0:
            f, b = 0.0, 40e3
        else:
            f, b = 0.0, 0.0
        if phase_t > 120.0 and v <= 0.0 and phase_t > 200.0:
            leg, phase_t = leg + 1, 0.0
        rows.append((t, 0.1, out["car.traction_force"], out["car.brake_force"],
                     out["sensor.speed"], out["sensor.position"]))
        chain.do_step(t, 0.1, f, b, 0.0)
        t += 0.1
        phase_t += 0.1
    return rows


def replay(chain, rows) -> list[dict]:
    outs = []
    for r in rows:
        chain.do_step(*r)
        outs.append(chain.outputs())
    return outs


def with_faults(rows, seed: int):
    """Spikes, a stuck speed sensor for 30 s, a distance jump that the filter must reacquire."""
    rng = random.Random(seed)
    rows = [list(r) for r in rows]
    for k in rng.sample(range(100, len(rows)), 40):
        rows[k][4] += rng.choice((-1, 1)) * rng.uniform(2.0, 30.0)
    stuck = len(rows) // 3
    for k in range(stuck, min(stuck + 300, len(rows))):
        rows[k][4] = rows[stuck][4]
    jump = len(rows) // 2
    for k in range(jump, min(jump + 200, len(rows))):
        rows[k][5] += 250.0
    return [tuple(r) for r in rows]


@pytest.mark.parametrize("kind, faulty, method, physical, sigma2_method", [
    (2, False, 0, 0, 0), (2, True, 0, 0, 0), (0, True, 0, 0, 0), (2, False, 2, 0, 0),
    (2, True, 2, 0, 0), (0, True, 2, 0, 0), (2, True, 0, 1, 0), (0, True, 2, 1, 0),
    (2, True, 2, 0, 1), (0, True, 2, 1, 1), (2, True, 0, 0, 1)])
def test_estimator_chain_bit_identical_through_faults_and_stops(kind, faulty, method, physical,
                                                                 sigma2_method):
    rows = measurements(1500.0, seed=4, stops=4)
    if faulty:
        rows = with_faults(rows, seed=9)
    args = (IdentifierConfig(mass_initial=30.0, method=method, physical=physical,
                             sigma2_method=sigma2_method),
            FilterConfig(kind=kind), StationConfig(dwell=20.0), GradeProfile.level())
    py, c = EstimatorChain(*args), CompiledEstimatorChain(*args)
    assert c.outputs() == py.outputs() == {}
    out_py, out_c = replay(py, rows), replay(c, rows)
    assert out_py[-1]["est.station_stops"] >= (2 if faulty else 3)   # a fault can hide a stop
    if faulty:
        assert out_py[-1]["filter.rejected"] > 40
    for k, (a, b) in enumerate(zip(out_py, out_c)):
        assert same(a, b), f"row {k}: {[(n, a[n], b[n]) for n in a if not same(a[n], b[n])][:4]}"


DOWNHILL = GradeProfile((0.0,), (-25.0,))
DOWNHILL_SPEED = SpeedProfile((0.0, 50.0, 77.0, 302.0, 406.0, 458.5, 461.0),
                              (0.0, 12.3, 14.7, 17.5, 11.0, 2.2, 0.0))
"""V_zad of downhill_dwells' legs over the distance from the station (kinds 1, 3)."""


def downhill_dwells(seed: int) -> list[tuple]:
    """(t, h, traction, brake, speed, distance) of a 30 t car on -25 permille, speed noise 0.01
    m/s + 1 %: 30 s at the station, two legs (traction 10 s, coast 15 s, brake to a stop, 30 s
    dwell), a departure; the plant held by 13.5 kN while it stands, which the log leaves out
    (brake 0 for every step the car stands through): OnlineEstimator.holding's case."""
    sensor = FilterConfig(speed_std=0.01, speed_std_rel=0.01)
    chain = RailCarChain(ChainConfig(vehicle=VehicleParams(mass=30.0), seed=seed, filter=sensor),
                         DOWNHILL)
    plan = [((0.0, 13.5e3), 300)] + [((40e3, 0.0), 100), ((0.0, 0.0), 150), ((0.0, 40e3), None),
                                     ((0.0, 13.5e3), 300)] * 2 + [((40e3, 0.0), 100)]
    rows, t = [], 0.0
    for forces, steps in plan:
        k = 0
        while (k < steps) if steps else chain.outputs()["car.speed"] > 0.0:
            before = chain.outputs()
            chain.do_step(t, 0.1, *forces, 0.0)
            after = chain.outputs()
            standing = before["car.speed"] == 0.0 and after["car.speed"] == 0.0
            rows.append((t, 0.1, after["car.traction_force_mean"],
                         0.0 if standing else after["car.brake_force_mean"],
                         before["sensor.speed"], before["sensor.position"]))
            t += 0.1
            k += 1
    return rows


@pytest.mark.parametrize("kind", [1, 2, 3, 4])
@pytest.mark.parametrize("method, sigma2_method", [(0, 0), (0, 1), (2, 0), (2, 1)])
def test_estimator_chain_bit_identical_through_a_held_standstill(kind, method, sigma2_method,
                                                                 monkeypatch):
    """The virtual holding brake (OnlineEstimator.holding, MotionFilter.cap_predicted_speed; C:
    rc_estimator_propagate, rc_filter_cap_predicted_speed) on dwells whose brake the log leaves
    out, every filter kind: bit for bit, and the cap did change predictions (else this case
    would not exercise it)."""
    capped = []
    original = MotionFilter.cap_predicted_speed

    def counting(self, v_max, dt):
        before = self.x_bar
        original(self, v_max, dt)
        capped.append(self.x_bar != before)

    monkeypatch.setattr(MotionFilter, "cap_predicted_speed", counting)
    rows = downhill_dwells(seed=5)
    args = (IdentifierConfig(mass_initial=30.0, method=method, sigma2_method=sigma2_method),
            FilterConfig(speed_std=0.01, speed_std_rel=0.01, kind=kind), StationConfig(dwell=20.0),
            DOWNHILL, DOWNHILL_SPEED if kind in (1, 3) else None)
    out_py = replay(EstimatorChain(*args), rows)
    out_c = replay(CompiledEstimatorChain(*args), rows)
    assert sum(capped) > 100 and out_py[-1]["est.station_stops"] == 3
    for k, (a, b) in enumerate(zip(out_py, out_c)):
        assert same(a, b), f"row {k}: {[(n, a[n], b[n]) for n in a if not same(a[n], b[n])][:4]}"


def test_estimator_chain_track_speeds_bit_identical():
    rows = measurements(400.0, seed=6, stops=1)
    track = TrackSensorConfig(spacing=200.0, base=5.0, resolution=1e-3, jitter=1e-4)
    args = (IdentifierConfig(), FilterConfig(), StationConfig(), GradeProfile.level(), None, track)
    py, c = EstimatorChain(*args), CompiledEstimatorChain(*args)
    rng = random.Random(2)
    last = 0.0
    for k, r in enumerate(rows):
        extra = ()
        if k % 50 == 0 and r[4] > 1.0:
            last = r[0] - rng.uniform(0.0, 0.1)
            extra = (r[4] + rng.gauss(0.0, 0.05), last)
        py.do_step(*r, *extra)
        c.do_step(*r, *extra)
        assert same(py.outputs(), c.outputs()), f"row {k}"
    assert py.estimator.track_speeds > 5


def test_estimator_chain_bad_input_same_message():
    args = (IdentifierConfig(), FilterConfig(), StationConfig(), GradeProfile.level())
    for bad in [(0.0, 0.1, 0.0, 0.0, math.nan, 0.0), (0.0, 0.1, 0.0, 0.0, 0.0, 2e7),
                (0.0, 0.1, -5.0, 0.0, 0.0, 0.0), (0.0, 0.1, 3e7, 0.0, 0.0, 0.0),
                (0.0, 0.1, 0.0, 0.0, 0.0, 0.0, math.inf)]:
        messages = []
        for kind in (EstimatorChain, CompiledEstimatorChain):
            with pytest.raises(StepRejected) as e:
                kind(*args).do_step(*bad)
            messages.append(str(e.value))
        assert messages[0] == messages[1]


# ---------------------------------------------------------------- the A's covariance outputs

COVARIANCES = ("est.cov_A0_A1", "est.cov_A0_A2", "est.cov_A1_A2")
A_STDS = ("est.A0_std", "est.A1_std", "est.A2_std")


def one_ulp_off(row: dict, name: str) -> dict:
    """``row`` with ``name`` one ulp further from zero."""
    x = row[name]
    return {**row, name: math.nextafter(x, math.copysign(math.inf, x))}


def test_covariance_outputs_bit_identical_from_the_stds_matrix_and_seen_to_the_ulp():
    """est.cov_* come from the covariance est.A*_std are the roots of (the same doubles), are
    bit-identical in C, identified by the end (not the prior's zeros), make a positive
    semidefinite A block with the stds, and one ulp off in any of them is a difference."""
    sc, py, c = scenario_chains(ROOT / "scenarios" / "library" / "station_day.toml", {})
    rows_py, rows_c = drive_chain(py, sc, 3000), drive_chain(c, sc, 3000)
    assert list(rows_c[-1])[-5:-2] == list(COVARIANCES) == list(compiled.ESTIMATOR_OUTPUT_NAMES[-3:])
    assert all(r[n] == 0.0 for r in rows_py[:2] for n in COVARIANCES)   # the prior: diagonal
    last = rows_py[-1]
    cov = py.estimator.method.with_resistance_covariance(py.estimator.ident.covariance())
    for name, i, j in py.estimator.A_COVARIANCES:
        assert same(last[name], float(cov[i, j])) and last[name] != 0.0, name
    for k, name in enumerate(A_STDS, start=1):
        assert same(last[name], math.sqrt(cov[k, k])), name
    block = np.diag([last[n] ** 2 for n in A_STDS])
    block[0, 1] = block[1, 0] = last["est.cov_A0_A1"]
    block[0, 2] = block[2, 0] = last["est.cov_A0_A2"]
    block[1, 2] = block[2, 1] = last["est.cov_A1_A2"]
    assert np.linalg.eigvalsh(block).min() > -1e-12 * np.abs(block).max()
    for k, (a, b) in enumerate(zip(rows_py, rows_c)):
        assert same(a, b), f"row {k}: {[(n, a[n], b[n]) for n in a if not same(a[n], b[n])][:4]}"
    for name in COVARIANCES:
        assert not same(rows_py[-1], one_ulp_off(rows_c[-1], name)), name


# ---------------------------------------------------------------- the forces the estimator was fed

FORCE_MEANS = ("car.traction_force_mean", "car.brake_force_mean")


def test_force_means_are_what_the_estimator_was_fed_bit_identical_and_seen_to_the_ulp():
    """car.*_force_mean after a step are the forces the estimator's last propagate() received
    (0 before the first sample interval ends), are bit-identical in C, are the interval's means
    (not the instantaneous car.*_force at the row), and one ulp off in either is a difference."""
    sc, py, c = scenario_chains(ROOT / "scenarios" / "library" / "station_day.toml", {})
    assert list(compiled.OUTPUT_NAMES[-2:]) == list(FORCE_MEANS)
    fed = []                                   # (traction, brake) of each propagate [N]
    propagate = py.estimator.propagate

    def recording_propagate(traction, brake, dt):
        fed.append((traction, brake))
        return propagate(traction, brake, dt)

    py.estimator.propagate = recording_propagate
    rows_py, rows_c = drive_chain(py, sc, 3000), drive_chain(c, sc, 3000)
    assert all(rows_py[0][n] == 0.0 and rows_c[0][n] == 0.0 for n in FORCE_MEANS)
    assert len(fed) >= 3000 - 1, "the scenario's step is not the sample period"
    assert list(rows_py[-1])[-2:] == list(FORCE_MEANS)
    for k, (a, b) in enumerate(zip(rows_py, rows_c)):
        assert same(a, b), f"row {k}: {[(n, a[n], b[n]) for n in a if not same(a[n], b[n])][:4]}"
        assert all(math.isfinite(a[n]) and a[n] >= 0.0 for n in FORCE_MEANS), f"row {k}"
    last_traction, last_brake = fed[-1]
    assert same(rows_py[-1]["car.traction_force_mean"], last_traction)
    assert same(rows_py[-1]["car.brake_force_mean"], last_brake)
    # the run both drives and brakes, and the means are not the instantaneous forces
    assert any(r["car.traction_force_mean"] > 1e3 for r in rows_py)
    assert any(r["car.brake_force_mean"] > 1e3 for r in rows_py)
    assert any(r["car.traction_force_mean"] != r["car.traction_force"] for r in rows_py)
    for name in FORCE_MEANS:
        moving = next(r for r in reversed(rows_c) if r[name] != 0.0)
        assert not same(moving, one_ulp_off(moving, name)), name


def test_force_means_hold_between_samples_and_restart_at_reset():
    """A communication step shorter than the sample period leaves the means as they were until
    the next sample (the estimator is fed once a sample); reset gives 0 again; C as Python."""
    grade = GradeProfile.level()
    cfg = ChainConfig(sample_period=0.1, solver_step=0.05)
    py, c = RailCarChain(cfg, grade), CompiledChain(cfg, grade)
    seen = []
    t = 0.0
    for k in range(40):                       # 0.025 s steps: a sample every fourth step
        for chain in (py, c):
            chain.do_step(t, 0.025, 20e3 + 500.0 * k, 0.0, 0.0)
        t += 0.025
        a, b = py.outputs(), c.outputs()
        assert same(a, b), f"step {k}"
        seen.append(a["car.traction_force_mean"])
    assert seen[:3] == [0.0, 0.0, 0.0] and seen[3] > 0.0
    for k in range(3, 40):
        assert (seen[k] != seen[k - 1]) == ((k + 1) % 4 == 0), f"step {k}: {seen[k - 1]} -> {seen[k]}"
    c.reset()
    assert all(c.outputs()[n] == 0.0 for n in FORCE_MEANS)


def test_covariance_outputs_finite_and_zero_without_a_variance():
    """A frozen identifier (covariance 0) reports 0, not NaN; the estimator alone (C and Python)
    and a Python-only method (carried A's, est.method 1) report finite covariances."""
    grade = GradeProfile.level()
    frozen = IdentifierConfig(frozen=True)
    for chain in (RailCarChain(ChainConfig(identifier=frozen), grade),
                  CompiledChain(ChainConfig(identifier=frozen), grade)):
        for k in range(300):
            chain.do_step(k * 0.1, 0.1, 30e3, 0.0, 0.0)
            assert all(chain.outputs()[n] == 0.0 for n in COVARIANCES)
    rows = measurements(600.0, seed=3, stops=2)
    args = (IdentifierConfig(), FilterConfig(), StationConfig(), grade)
    out_py, out_c = replay(EstimatorChain(*args), rows), replay(CompiledEstimatorChain(*args), rows)
    assert list(out_c[-1])[-3:] == list(COVARIANCES) and out_c[-1]["est.cov_A0_A1"] != 0.0
    assert same(out_py, out_c)
    assert not same(out_py[-1], one_ulp_off(out_c[-1], "est.cov_A1_A2"))
    refit = replay(EstimatorChain(IdentifierConfig(method=1), *args[1:]), rows)
    assert all(math.isfinite(r[n]) for r in refit for n in COVARIANCES)
    assert refit[-1]["est.cov_A0_A1"] != 0.0


# ---------------------------------------------------------------- which engine runs

def test_open_chain_runs_c_where_covered_and_python_elsewhere():
    grade = GradeProfile.level()
    before = dict(compiled.ENGINES)
    assert open_chain(ChainConfig(), grade).engine == "c"
    assert open_chain(ChainConfig(track=TrackSensorConfig(spacing=200.0)), grade).engine == "c"
    assert open_chain(ChainConfig(filter=FilterConfig(kind=4)), grade).engine == "c"   # Singer
    assert open_chain(ChainConfig(identifier=IdentifierConfig(method=2)), grade).engine == "c"
    assert open_chain(ChainConfig(identifier=IdentifierConfig(physical=1)), grade).engine == "c"
    assert open_chain(ChainConfig(identifier=IdentifierConfig(sigma2_method=1)), grade).engine == "c"
    for cfg in (ChainConfig(identifier=IdentifierConfig(method=3)),
                ChainConfig(identifier=IdentifierConfig(method=1, physical=1))):
        chain = open_chain(cfg, grade)
        assert chain.engine == "python" and isinstance(chain, RailCarChain)
    assert compiled.ENGINES["c"] == before.get("c", 0) + 6
    assert compiled.ENGINES["python"] == before.get("python", 0) + 2
    assert open_estimator_chain(IdentifierConfig(), FilterConfig(), StationConfig(), grade).engine == "c"
    assert open_estimator_chain(IdentifierConfig(method=2), FilterConfig(), StationConfig(),
                                grade).engine == "c"
    assert open_estimator_chain(IdentifierConfig(method=1), FilterConfig(), StationConfig(),
                                grade).engine == "python"


def test_a_bad_configuration_reads_as_in_python():
    for cfg in (ChainConfig(seed=-1), ChainConfig(sample_period=0.0),
                ChainConfig(identifier=IdentifierConfig(batch_size=2)),
                ChainConfig(filter=FilterConfig(kind=1)),
                ChainConfig(station=StationConfig(dwell=0.0)),
                ChainConfig(vehicle=VehicleParams(mass=-1.0))):
        messages = []
        for kind in (RailCarChain, CompiledChain):
            with pytest.raises(ValueError) as e:
                kind(cfg, GradeProfile.level())
            messages.append(str(e.value))
        assert messages[0] == messages[1]


def test_pure_python_switch():
    """RAILCAR_PURE_PYTHON=1 (and a machine without the compiled core) runs the Python chain."""
    code = ("from models.compiled import open_chain, enabled\n"
            "from models.chain import ChainConfig\nfrom models.plant.track import GradeProfile\n"
            "c = open_chain(ChainConfig(), GradeProfile.level())\n"
            "c.do_step(0.0, 0.1, 1e4, 0.0, 0.0)\nprint(enabled(), c.engine)\n")
    env = {**os.environ, "RAILCAR_PURE_PYTHON": "1"}
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False", "python"]


def test_reset_gives_the_first_run_again():
    chain = CompiledChain(ChainConfig(seed=3), GradeProfile.level())
    first = [chain.outputs()]
    for k in range(500):
        chain.do_step(k * 0.1, 0.1, 30e3, 0.0, 0.0)
        first.append(chain.outputs())
    chain.reset()
    again = [chain.outputs()]
    for k in range(500):
        chain.do_step(k * 0.1, 0.1, 30e3, 0.0, 0.0)
        again.append(chain.outputs())
    assert same(first, again)


# ---------------------------------------------------------------- est.physical 1

@pytest.mark.parametrize("method", [0, 2])
@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenario_with_physical_bit_identical(path, method):
    overrides = {**PHYSICAL, "est.method": method}
    assert open_chain(*scenario_setup(path, overrides)).engine == "c"
    assert assert_identical(path, overrides) > 100


@pytest.mark.parametrize("method", [0, 2])
def test_physical_projects_what_the_ls_left_negative_and_one_ulp_shows(method):
    """ato_speed_noise: without est.physical an A0 or A2 goes negative at some rows; with it, none
    does (the projection ran, in C as in Python), and one ulp off in a projected A is a
    difference."""
    path = ROOT / "scenarios" / "library" / "ato_speed_noise.toml"
    sc, _, free = scenario_chains(path, {"est.method": method})
    rows_free = drive_chain(free, sc, None)
    negative = [k for k, r in enumerate(rows_free) if r["est.A0"] < 0.0 or r["est.A2"] < 0.0]
    assert len(negative) > 10
    sc, py, c = scenario_chains(path, {**PHYSICAL, "est.method": method})
    rows_py, rows_c = drive_chain(py, sc, None), drive_chain(c, sc, None)
    assert same(rows_py, rows_c)
    assert all(r["est.A0"] >= 0.0 and r["est.A2"] >= 0.0 for r in rows_c)
    moved = [k for k in negative                          # (the closed loop may end sooner)
             if k < len(rows_c) and not same(rows_c[k]["est.A1"], rows_free[k]["est.A1"])]
    assert moved
    k = moved[0]
    assert not same(rows_py[k], one_ulp_off(rows_c[k], "est.A1"))


def test_project_physical_in_c_is_python_s_on_random_and_singular_cases(tmp_path):
    """rc_project_physical (the core compiled as a shared library, called through ctypes) against
    identification.project_physical on 400 seeded random cases (random correlations, signs and
    scales) and covariances singular along A0 or A2: equal bit for bit."""
    import ctypes
    import shutil as _shutil
    from models.estimation.identification import project_physical
    lib_path = tmp_path / "core.so"
    core = sorted(str(p) for p in (ROOT / "models" / "core").glob("*.c"))
    proc = subprocess.run([_shutil.which("gcc"), "-std=c99", "-O2", "-ffp-contract=off", "-fPIC",
                           "-shared", "-I", str(ROOT / "models" / "core"), *core, "-lm", "-o",
                           str(lib_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lib = ctypes.CDLL(str(lib_path))
    vec4, mat4 = ctypes.c_double * 4, ctypes.c_double * 16
    rng = np.random.default_rng(7)
    cases = []
    for _ in range(400):
        L = rng.normal(size=(4, 4)) * rng.choice([1e-3, 1.0, 30.0])
        cases.append((rng.normal(size=4) * rng.choice([0.1, 1.0, 5.0]), L @ L.T))
    for zero in (1, 3):                                    # singular along A0 or A2
        c = np.diag([1e-4, 2.0, 0.5, 1e-3])
        c[zero, :] = c[:, zero] = 0.0
        cases.append((np.array([1e-4, -1.0, 0.2, -0.01]), c))
    projected = 0
    for theta, cov in cases:
        th = vec4(*theta)
        lib.rc_project_physical(th, mat4(*cov.ravel()))
        want = project_physical(theta, cov)
        assert same([float(x) for x in th], [float(x) for x in want]), (theta, cov)
        projected += theta[1] < 0.0 or theta[3] < 0.0
    assert projected > 250
