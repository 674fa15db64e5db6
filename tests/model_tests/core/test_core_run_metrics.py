"""The run metrics in C (models/core/run_metrics.c through models._batch, issue 31) against their
Python reference (harness/metrics/estimation.py with RAILCAR_PURE_PYTHON set): the oracle
filter's speed and distance, the coast-time errors (identified A's in still air, and the truth in
the scenario's wind) and the whole RunMetrics of a run, equal bit for bit on every library
scenario (the span scenarios included), more seeds, the filter kinds 1-4, a speed profile and a
changing wind; a one-ulp change of one expression in run_metrics.c makes them differ; bad arrays
and settings are refused by name.
"""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from harness.metrics import estimation
from harness.metrics.run import run_metrics
from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario, scenario_from_dict
from models import batch
from models.plant.dynamics import VehicleParams

from batch_build import CORE, ONE_ULP, ROOT, build_batch, compile_objects

SOURCE = CORE / "run_metrics.c"
LIBRARY = ROOT / "scenarios" / "library"

GUSTS = {   # a speed profile (filter.kind 1 by default) and a wind that changes during the coast
    "name": "gusts", "step_s": 0.1, "duration_s": 300.0,
    "parameters": {"track.grade_profile": "../profiles/demo_grade.csv",
                   "track.speed_profile": "../profiles/default_speed.csv", "seed": 8},
    "wind": [{"time_s": 10.0, "speed_mps": -3.3}, {"time_s": 45.0, "speed_mps": 8.7},
             {"time_s": 70.0, "speed_mps": 2.2}],
    "driver": [{"action": "traction", "until_speed_kmh": 55.0},
               {"action": "coast", "until_time_s": 90.0},
               {"action": "brake_to_stop", "stop_at_m": 1400.0, "decel_mps2": 0.7},
               {"action": "hold", "until_time_s": 5.0}],
}


def python_reference(monkeypatch, fn):
    """fn() with the C core switched off (the Python reference), then the environment back."""
    with monkeypatch.context() as m:
        m.setenv("RAILCAR_PURE_PYTHON", "1")
        assert estimation.c_metrics() is None
        return fn()


def identical(a, b) -> bool:
    """Equal bit for bit: floats by their bits (NaN and -0.0 included), arrays by their bytes and
    dtype, containers and dataclasses field by field."""
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return (isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.dtype == b.dtype
                and a.shape == b.shape and a.tobytes() == b.tobytes())
    if isinstance(a, float) or isinstance(b, float):
        return type(a) is type(b) and np.float64(a).tobytes() == np.float64(b).tobytes()
    if dataclasses.is_dataclass(a):
        return type(a) is type(b) and all(identical(getattr(a, f.name), getattr(b, f.name))
                                          for f in dataclasses.fields(a))
    if isinstance(a, (list, tuple)):
        return type(a) is type(b) and len(a) == len(b) and all(map(identical, a, b))
    return a == b


def differences(result, setup, monkeypatch) -> list[str]:
    """What differs between the C and the Python metrics of ``result`` (its ``setup``)."""
    car = setup.config.vehicle
    truth = (car.A0, car.A1, car.A2)

    def metrics():
        identified = (lambda last: (float(result["est.A0"][last]), float(result["est.A1"][last]),
                                    float(result["est.A2"][last])))
        return {"oracle": estimation.oracle_filter(result, setup),
                "coasts identified": estimation.coast_time_errors(result, identified, setup=setup),
                "coasts in the wind": estimation.coast_time_errors(result, lambda last: truth,
                                                                   still_air=True, setup=setup)}

    assert estimation.c_metrics() is batch, "the C run metrics are not compiled here"
    ours, reference = metrics(), python_reference(monkeypatch, metrics)
    assert reference["oracle"] is not None
    return [name for name in reference if not identical(ours[name], reference[name])]


@pytest.fixture(scope="module")
def library_runs() -> dict:
    runs = {}
    for path in sorted(LIBRARY.glob("*.toml")):
        scenario = load_scenario(path)
        runs[scenario.name] = (scenario, run_on_chain(scenario))
    return runs


def test_every_library_scenario_gives_the_python_metrics(library_runs, monkeypatch):
    """Scripted and span scenarios: the oracle's arrays, both coast measures and the whole
    RunMetrics (the summary row, the covariance, the ATO table) bit for bit."""
    assert len(library_runs) >= 19
    coasts = 0
    for name, (scenario, result) in library_runs.items():
        assert differences(result, scenario.chain_setup(), monkeypatch) == [], name
        ours = run_metrics(result)
        assert identical(ours, python_reference(monkeypatch, lambda: run_metrics(result))), name
        coasts += len(ours.summary.coast_time_errors_s)
    assert coasts >= 20          # the comparison saw coasts, not empty lists


@pytest.mark.parametrize("name, seeds", [("station_day", (1, 2)), ("level_run", (3, 11)),
                                         ("headwind_change", (5,))])
def test_other_seeds_give_the_python_metrics(name, seeds, monkeypatch):
    scenario = load_scenario(LIBRARY / f"{name}.toml")
    for seed in seeds:
        setup = scenario.chain_setup({"seed": seed})
        result = run_on_chain(scenario, {"seed": seed})
        assert differences(result, setup, monkeypatch) == [], (name, seed)


@pytest.mark.parametrize("kind", [1, 2, 3, 4])
def test_each_filter_kind_with_a_speed_profile_and_gusts(kind, monkeypatch):
    scenario = scenario_from_dict(GUSTS, "<gusts>", LIBRARY)
    setup = scenario.chain_setup({"filter.kind": kind})
    assert setup.speed is not None and setup.config.filter.kind == kind
    result = run_on_chain(scenario, {"filter.kind": kind})
    assert len(estimation.coast_segments(result["car.mode"], 100)) == 1   # the gust blows over it
    assert differences(result, setup, monkeypatch) == [], kind


def test_run_metrics_of_a_scenario_with_a_speed_profile(monkeypatch):
    scenario = scenario_from_dict(GUSTS, "<gusts>", LIBRARY)
    result = run_on_chain(scenario)
    assert identical(run_metrics(result), python_reference(monkeypatch, lambda: run_metrics(result)))


def test_without_recorded_demands_the_trapezoid_forces_feed_the_c_oracle(library_runs, monkeypatch):
    scenario, result = library_runs["level_run"]
    bare = dataclasses.replace(result, inputs={})
    setup = scenario.chain_setup()
    ours = estimation.oracle_filter(bare, setup)
    assert identical(ours, python_reference(monkeypatch, lambda: estimation.oracle_filter(bare, setup)))
    assert not identical(ours, estimation.oracle_filter(result, setup))   # the forces mattered


def test_the_segments_are_the_loops_they_replaced():
    """stop_indices and _segments (vectorised for speed) against the loops they were, and the C
    coast_segments against the Python one, on random speed and mode sequences."""
    def stops(v):
        return [k for k in range(1, len(v)) if v[k] <= 0.0 < v[k - 1]]

    def segments(v):
        out = []
        for k in stops(v):
            dep = k - 1
            while dep > 0 and v[dep - 1] > 0.0:
                dep -= 1
            out.append((max(dep - 1, 0), k))
        return out

    rng = np.random.default_rng(31)
    for _ in range(2000):
        n = int(rng.integers(0, 40))
        v = rng.choice([0.0, -0.0, -1.0, 0.5, 3.0, math.nan], size=n)
        assert estimation.stop_indices(v) == stops(v), v
        assert estimation._segments(v) == segments(v), v
        mode = rng.choice([0.0, 1.0, 2.0, 2.0, 2.0, 3.0], size=n)
        min_rows = int(rng.integers(0, 5))
        assert batch.coast_segments(mode, min_rows) == estimation.coast_segments(mode, min_rows), mode


def test_the_vehicle_layout_is_vehicle_params():
    assert batch.VEHICLE_FIELDS == tuple(f.name for f in dataclasses.fields(VehicleParams))
    assert batch._batch.VEHICLE_VALUES == len(batch.VEHICLE_FIELDS)
    assert batch._batch.COAST_VALUES == len(batch.COAST_FIELDS)


# ---------------------------------------------------------------- bad input, named

def oracle_arguments(library_runs) -> dict:
    from models.compiled import _estimator_values
    from models.estimation.identification import IdentifierConfig
    from models.filtering.motion_filter import FilterConfig
    scenario, result = library_runs["level_run"]
    setup = scenario.chain_setup()
    cfg = setup.config
    ident = IdentifierConfig(dt=0.1, frozen=True, gamma=cfg.vehicle.gamma)
    filt = FilterConfig(dt=0.1, speed_std=cfg.filter.speed_std, position_std=cfg.filter.position_std)
    st = cfg.station
    n = len(result.time)
    return dict(config=[*_estimator_values(ident, filt), st.dwell, st.speed_threshold,
                        st.position_threshold, 0.0, 0.0, 0.0, int(ident.slope_window)],
                grade=(setup.grade.distances, setup.grade.grades), speed_profile=((), ()),
                A=(1.0, 0.01, 0.001), step=0.1, wind=[], time=result.time,
                mass=result["car.total_mass"], speed_meas=result["sensor.speed"],
                position_meas=result["sensor.position"], traction_mean=np.zeros(n - 1),
                brake_mean=np.zeros(n - 1))


@pytest.mark.parametrize("change, message", [
    (dict(mass=np.ones(5)), "mass: expected"),
    (dict(traction_mean=np.zeros(3)), "traction_mean: expected"),
    (dict(position_meas=np.zeros(2)), "position_meas: expected"),
    (dict(A=(1.0, 2.0)), "A: expected 3 values"),
    (dict(time=np.zeros(0)), "time: a run has at least one row"),
    (dict(step=0.0), "step must be > 0"),
    (dict(step=math.nan), "step must be > 0"),
    (dict(grade=((), ())), "track.grade_profile must have at least one row"),
    (dict(speed_profile=((0.0, 1.0), (5.0,))), "speeds: expected 2 values"),
])
def test_the_oracle_refuses_bad_arrays_by_name(library_runs, change, message):
    args = oracle_arguments(library_runs)
    args.update(change)
    with pytest.raises(ValueError, match=message):
        batch.oracle_filter(**args)


def test_the_oracle_refuses_bad_settings_with_the_python_message(library_runs):
    args = oracle_arguments(library_runs)
    config = list(args["config"])
    with pytest.raises(ValueError, match="config: the oracle takes .* got 3"):
        batch.oracle_filter(**{**args, "config": config[:3]})
    dwell = len(config) - 7                     # StationConfig.dwell, after the estimator's numbers
    config[dwell] = 0.0
    with pytest.raises(ValueError, match=r"oracle: track.station_dwell must be > 0, got 0"):
        batch.oracle_filter(**{**args, "config": config})
    with pytest.raises(ValueError, match="must be float64"):
        batch._batch.oracle_filter(np.array(args["config"], dtype=np.float32), *([np.zeros(1)] * 5),
                                   0.1, *([np.zeros(1)] * 9))


def test_the_coast_and_force_calls_refuse_bad_arrays_by_name():
    vehicle = [getattr(VehicleParams(), name) for name in batch.VEHICLE_FIELDS]
    grade = ((0.0,), (0.0,))
    coast = [[10.0, 0.0, 100.0, 1.0, 0.01, 0.001, 30.0, 0.0]]
    assert batch.coast_times(vehicle, grade, [], coast)[0] > 0.0
    for kwargs, message in [
            (dict(coasts=[[1.0, 2.0, 3.0]]), "coasts: expected rows of 8 values"),
            (dict(wind=[(1.0, 2.0)], h=0.0), "h: the RK4 step must be > 0"),
            (dict(vehicle=vehicle[:-1]), "vehicle: expected 11 values"),
            (dict(grade=((), ())), "grade_distances: the grade profile needs at least one row"),
            (dict(grade=((0.0, 5.0), (1.0,))), "grades: expected 2 values")]:
        args = dict(vehicle=vehicle, grade=grade, wind=[], coasts=coast) | kwargs
        with pytest.raises(ValueError, match=message):
            batch.coast_times(**args)
    with pytest.raises(ValueError, match="wind: expected .* pairs, got 3 values"):
        batch._batch.coast_times(np.array(vehicle), np.zeros(1), np.zeros(1), np.zeros(3), 0.05,
                                 10.0, np.array(coast[0]), np.zeros(1))
    with pytest.raises(ValueError, match="traction_demand: expected at least 4 values, got 2"):
        batch.interval_forces(vehicle, np.ones(5), np.ones(5), np.ones(2), np.ones(2))
    with pytest.raises(ValueError, match="brake_demand: expected 4 values, got 3"):
        batch.interval_forces(vehicle, np.ones(5), np.ones(5), np.ones(4), np.ones(3))
    with pytest.raises(ValueError, match="mass: expected 5 values, got 4"):
        batch.interval_forces(vehicle, np.ones(5), np.ones(4), np.ones(4), np.ones(4))


# ---------------------------------------------------------------- one ulp in run_metrics.c

MUTATIONS = {
    "true_theta": ("level_run", "oracle", "theta[0] = 1.0 / (RC_G * mass_t);",
                   f"theta[0] = 1.0 / (RC_G * mass_t) * {ONE_ULP};"),
    "interval_force": ("level_run", "oracle", "traction_mean[k] = 0.5 * (f0 + f1);",
                       f"traction_mean[k] = 0.5 * (f0 + f1) * {ONE_ULP};"),
    "adhesion": ("low_adhesion", "oracle",
                 "return 1000.0 * p->mass * p->adhesion_mass_fraction * RC_G * psi * p->adhesion_factor;",
                 "return 1000.0 * p->mass * p->adhesion_mass_fraction * RC_G * (psi * p->adhesion_factor);"),
    "coast_end": ("level_run", "coasts identified", "return t + h * (x1 - x) / (x_new - x);",
                  f"return (t + h * (x1 - x) / (x_new - x)) * {ONE_ULP};"),
    "coast_speed": ("station_day", "coasts identified", "        v = v_new;",
                    f"        v = v_new * {ONE_ULP};"),
}
"""name: (the scenario it shows on, the metric it changes, the expression in run_metrics.c, its
one-ulp change: an operand times (1 + 2**-52), or a product re-associated)"""


@pytest.fixture(scope="module")
def objects(tmp_path_factory) -> list[Path]:
    """The batch binding and every core source but run_metrics.c, compiled once."""
    return compile_objects(tmp_path_factory.mktemp("metrics_objects"), (SOURCE,))


def build(objects: list[Path], source_text: str, directory: Path):
    """models._batch with ``source_text`` as run_metrics.c (strict flags, -pedantic included),
    imported from ``directory``."""
    return build_batch(objects, {"run_metrics.c": source_text}, directory, ("-pedantic",))


def test_one_ulp_in_run_metrics_is_caught(objects, tmp_path, library_runs, monkeypatch):
    text = SOURCE.read_text()
    unchanged = build(objects, text, tmp_path / "unchanged")
    gusts_scenario = scenario_from_dict(GUSTS, "<gusts>", LIBRARY)     # winds whose squares round
    gusts = (gusts_scenario, run_on_chain(gusts_scenario))
    for name, (scenario_name, metric, expression, changed) in MUTATIONS.items():
        assert text.count(expression) == 1, f"{expression!r} is not once in {SOURCE.name}"
        scenario, result = library_runs[scenario_name] if scenario_name != "gusts" else gusts
        setup = scenario.chain_setup()
        monkeypatch.setattr(batch, "_batch", unchanged)
        assert differences(result, setup, monkeypatch) == [], f"unchanged build on {scenario_name}"
        monkeypatch.setattr(batch, "_batch", build(objects, text.replace(expression, changed), tmp_path / name))
        assert metric in differences(result, setup, monkeypatch), \
            f"{name}: the one-ulp change left {metric} of {scenario_name} the same"
        monkeypatch.undo()
