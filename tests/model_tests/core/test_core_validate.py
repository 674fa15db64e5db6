"""models/core/validate.c against the Python chains' parameter checks, message for message.

A native FMU (no Python) must refuse a bad parameter at initialisation with the message the
pythonfmu FMU gives (adapter.initialise: "initialisation failed: " + the ValueError of
RailCarChain / EstimatorChain). Each bad configuration below is built from FMU parameter
values through fmu_src.adapter (chain_config, estimator_settings, track_settings), flattened
by models.compiled (_config_values) and checked in C (rc_chain_validate / rc_estchain_validate
through tests/core_cases/validate_shim.c): the first failing rule must be Python's, and the
message byte-identical. Options the core does not cover are refused with their own message.
"""
from __future__ import annotations

import ctypes
import math
import re
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import pytest

from fmu_src.adapter import (ParameterError, chain_config, estimator_settings, initialise,
                             load_profiles, track_settings)
from fmu_src.variables import ESTIMATOR, RAILCAR, variables_for
from harness.run.scenario import load_scenario
from models import compiled
from models.chain import EstimatorChain, RailCarChain
from models.plant.track import GradeProfile, SpeedProfile

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "validate_shim.c"
SOURCES = [CORE / f for f in ("validate.c", "plant.c", "filter.c", "singer.c", "repr.c",
                               "config.c", "track.c", "noise.c", "fpmath.c")]   # validate.c and what it needs
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
         "-fPIC"]
LIBRARY = sorted((ROOT / "scenarios" / "library").glob("*.toml"))
GRADE = GradeProfile.level()
SPEED = SpeedProfile(distances=(0.0, 1000.0), speeds=(10.0, 10.0))
MSG = 256


def defaults(fmu: str) -> dict:
    """The FMU's parameter values at their start values (Reals as floats, as fmi2SetReal gives)."""
    return {v.name: float(v.start) if v.type == "Real" else v.start
            for v in variables_for(fmu) if v.causality == "parameter"}


CHAIN_DEFAULTS, EST_DEFAULTS = defaults(RAILCAR), defaults(ESTIMATOR)


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    out = tmp_path_factory.mktemp("core") / "libvalidate.so"
    proc = subprocess.run([gcc, *FLAGS, "-shared", "-Wl,--no-undefined", *map(str, SOURCES),
                           str(SHIM), "-o", str(out), "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    dll = ctypes.CDLL(str(out))
    for name in ("shim_chain_validate", "shim_estchain_validate"):
        f = getattr(dll, name)
        f.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_long, ctypes.c_long, ctypes.c_int,
                      ctypes.c_char_p, ctypes.c_int]
        f.restype = ctypes.c_int
    dll.shim_chain_validate_quiet.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_long,
                                              ctypes.c_long, ctypes.c_int]
    dll.shim_chain_validate_quiet.restype = ctypes.c_int
    return dll


# ------------------------------------------------------------------ both sides of one case

def chain_values(v: dict, start_time: float) -> list[float]:
    return [float(x) for x in compiled._config_values(chain_config(v), start_time)]


def estimator_values(v: dict) -> list[float]:
    ident, filt, station = estimator_settings(v)
    track = track_settings(v)
    return [float(x) for x in (*compiled._estimator_values(ident, filt), station.dwell,
                               station.speed_threshold, station.position_threshold, track.base,
                               track.resolution, track.jitter)]


def python_chain(v: dict, speed, start_time: float) -> str | None:
    """RailCarChain's ValueError text, None when it builds; the FMU's message agrees."""
    def build():
        return RailCarChain(chain_config(v), GRADE, speed, start_time)
    try:
        build()
    except ValueError as e:
        msg = str(e)
    else:
        return None
    with pytest.raises(ParameterError) as fmu:
        initialise(build)
    assert str(fmu.value) == f"initialisation failed: {msg}"
    return msg


def python_estimator(v: dict, speed) -> str | None:
    try:
        ident, filt, station = estimator_settings(v)
        EstimatorChain(ident, filt, station, GRADE, speed, track_settings(v))
    except ValueError as e:
        return str(e)
    return None


def c_call(lib, fn, values: list[float], slope_window: int, has_speed: bool) -> tuple[int, str]:
    arr = (ctypes.c_double * len(values))(*values)
    buf = ctypes.create_string_buffer(MSG)
    st = fn(arr, len(values), slope_window, int(has_speed), buf, MSG)
    assert st in (0, 2), f"status {st} (-1: the flat array has the wrong length)"
    return st, buf.value.decode()


def c_chain(lib, v: dict, speed, start_time: float) -> tuple[int, str]:
    values = chain_values(v, start_time)
    st, msg = c_call(lib, lib.shim_chain_validate, values, int(v["est.slope_window"]),
                     speed is not None)
    arr = (ctypes.c_double * len(values))(*values)
    assert lib.shim_chain_validate_quiet(arr, len(values), int(v["est.slope_window"]),
                                         int(speed is not None)) == st     # err may be NULL
    return st, msg


def c_estimator(lib, v: dict, speed) -> tuple[int, str]:
    return c_call(lib, lib.shim_estchain_validate, estimator_values(v), int(v["est.slope_window"]),
                  speed is not None)


def assert_same_message(py: str | None, st: int, c: str, case: str) -> None:
    if py is None:
        assert (st, c) == (0, ""), f"{case}: Python accepts it, C says {c!r}"
        return
    assert st == 2, f"{case}: Python refuses it ({py!r}), C accepts it"
    assert c == py, f"{case}:\n  Python {py!r}\n  C      {c!r}"


# ------------------------------------------------------------------ the catalogue

NAN, INF = math.nan, math.inf
TINY = 5e-324

# (overrides of the RailCar parameters, with speed profile, start time): each the first rule it
# breaks in Python's order; the comment says which
CHAIN_CASES = [
    # VehicleParams.validate: finite (field order), > 0, >= 0, the two ranges
    {"car.mass": NAN}, {"car.A0": INF}, {"car.A1": -INF}, {"car.A2": NAN}, {"car.gamma": INF},
    {"car.length": NAN}, {"car.traction_force_max": INF}, {"car.traction_power_max": NAN},
    {"car.brake_force_max": -INF}, {"car.adhesion_mass_fraction": NAN},
    {"car.adhesion_factor": INF},
    {"car.mass": 0.0}, {"car.mass": -0.0}, {"car.mass": -1.0}, {"car.traction_force_max": 0.0},
    {"car.traction_power_max": -1.0}, {"car.brake_force_max": -TINY},
    {"car.gamma": -1e-300}, {"car.length": -1.0}, {"car.A0": -0.5}, {"car.A1": -1e-3},
    {"car.A2": -2.0}, {"car.A0": -0.0}, {"car.length": -0.0},
    {"car.adhesion_mass_fraction": 0.0}, {"car.adhesion_mass_fraction": -0.0},
    {"car.adhesion_mass_fraction": 1.0000000000000002}, {"car.adhesion_mass_fraction": 1.0},
    {"car.adhesion_factor": 0.0}, {"car.adhesion_factor": 1.5000000000000002},
    {"car.adhesion_factor": 1.5}, {"car.adhesion_factor": TINY},
    {"car.mass": -1.0, "car.A0": NAN},            # every finite check before the signs
    {"car.A0": -1.0, "car.mass": 0.0},            # > 0 before >= 0
    {"car.gamma": -1.0, "car.A0": -1.0},          # gamma, length, A0, A1, A2
    # TrackSensorConfig.validate
    {"sensor.track_spacing": -1.0}, {"sensor.track_spacing": NAN}, {"sensor.track_jitter": -0.1},
    {"sensor.track_jitter": INF}, {"sensor.track_base": 0.0}, {"sensor.track_base": -0.0},
    {"sensor.track_base": NAN}, {"sensor.track_resolution": -1e-3},
    {"sensor.track_resolution": INF}, {"sensor.track_resolution": 0.0},
    {"sensor.track_spacing": 5.0}, {"sensor.track_spacing": 4.0},
    {"sensor.track_spacing": 5.000000000000001}, {"sensor.track_spacing": -0.0},
    {"sensor.track_jitter": -1.0, "sensor.track_spacing": -1.0},
    # seed, sample period, initial state, solver step vs sample period
    {"seed": -1}, {"seed": 2 ** 31}, {"seed": 2 ** 31 - 1}, {"seed": 0}, {"seed": -2 ** 31},
    {"seed": -1, "sensor.track_base": 0.0},
    {"sensor.sample_period": 0.0}, {"sensor.sample_period": -0.0}, {"sensor.sample_period": NAN},
    {"sensor.sample_period": INF}, {"sensor.sample_period": -1.0},
    {"car.initial_speed": -1e-9}, {"car.initial_speed": NAN}, {"car.initial_speed": -0.0},
    {"car.initial_position": -1.0}, {"car.initial_position": INF},
    {"solver.step": 0.2}, {"solver.step": 0.1 + 2e-12}, {"solver.step": 0.1 + 1e-13},
    {"solver.step": INF},
    # the start time, then CarPlant: solver.step and car.process_noise_psd
    ({}, None, NAN), ({}, None, INF), ({}, None, -1e9),
    {"solver.step": 0.0}, {"solver.step": -1.0}, {"solver.step": NAN}, {"solver.step": -0.0},
    {"car.process_noise_psd": -1e-4}, {"car.process_noise_psd": NAN},
    {"car.process_noise_psd": INF}, {"car.process_noise_psd": -0.0},
    # IdentifierConfig.validate (dt = sensor.sample_period, speed_std = sensor.speed_std)
    {"est.batch_size": 3}, {"est.batch_size": 0}, {"est.batch_size": -2 ** 31},
    {"est.batch_size": 4}, {"est.method": -1}, {"est.method": 4}, {"est.method": 2 ** 31 - 1},
    {"est.sigma2_method": 2}, {"est.sigma2_method": -1}, {"est.physical": 2},
    {"est.physical": -1}, {"est.slope_window": 1}, {"est.slope_window": -5},
    {"est.slope_window": 2},
    {"est.run_forgetting": 1.0}, {"est.run_forgetting": -1e-300}, {"est.run_forgetting": NAN},
    {"est.run_forgetting": -0.0}, {"est.run_forgetting": 0.9999999999999999},
    {"est.forgetting": 1.0}, {"est.forgetting": NAN}, {"est.forgetting": -INF},
    {"est.mass_initial": 0.0}, {"est.mass_initial": INF}, {"est.mass_initial": NAN},
    {"est.mass_std_initial": -1.0}, {"est.A0_std_initial": 0.0}, {"est.A1_std_initial": NAN},
    {"est.A2_std_initial": -INF}, {"est.sigma2_initial": 0.0}, {"est.sigma2_initial": -0.0},
    {"est.sigma2_initial": TINY},
    {"est.A0_initial": NAN}, {"est.A1_initial": INF}, {"est.A2_initial": -INF},
    {"est.A0_initial": -5.0}, {"est.gamma": NAN}, {"est.gamma": -1e-9}, {"est.gamma": -0.0},
    {"sensor.speed_std": NAN}, {"sensor.speed_std": INF},   # named est.speed_std by Python
    # identification.PRIOR_BOUNDS and the sizes: each bound's both sides
    {"est.sigma2_initial": 1e300}, {"est.sigma2_initial": 1.0000000000000002}, {"est.sigma2_initial": 1.0},
    {"est.sigma2_initial": 1e-20}, {"est.sigma2_initial": 9.9e-21},
    {"est.mass_std_initial": 1e-300}, {"est.mass_std_initial": 1e-6}, {"est.mass_std_initial": 1.0001e8},
    {"est.mass_initial": 0.999}, {"est.mass_initial": 1000.0}, {"est.mass_initial": 1000.5},
    {"est.A0_initial": 20.0}, {"est.A0_initial": -20.000001}, {"est.A1_initial": 2.5},
    {"est.A1_initial": -2.0}, {"est.A2_initial": 0.2}, {"est.A2_initial": -0.3},
    {"est.A0_std_initial": 1e300}, {"est.A0_std_initial": 1e4}, {"est.A1_std_initial": 1e-10},
    {"est.A2_std_initial": 2e8}, {"est.A2_std_initial": 1e-9},
    {"est.gamma": 1.0}, {"est.gamma": 1.5},
    # the carried A's drift per stop (identification.PRIOR_BOUNDS, then DRIFT_METHODS)
    {"est.A0_drift_std": -5e-324}, {"est.A0_drift_std": NAN}, {"est.A0_drift_std": INF},
    {"est.A0_drift_std": 10.0}, {"est.A0_drift_std": 10.000000000000002}, {"est.A0_drift_std": -0.0},
    {"est.A1_drift_std": -1e-9}, {"est.A1_drift_std": NAN}, {"est.A1_drift_std": 1.0},
    {"est.A1_drift_std": 1.0000000000000002},
    {"est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03},
    {"est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03, "est.method": 0},
    {"est.A1_drift_std": NAN, "est.gamma": 2.0},             # gamma's bound first
    {"est.A1_drift_std": 2.0, "est.batch_size": 10 ** 6},      # before the batch's size
    {"est.batch_size": 100000}, {"est.batch_size": 100001}, {"est.batch_size": 2 ** 31 - 1},
    {"est.slope_window": 1000}, {"est.slope_window": 1001, "est.method": 2},
    {"est.slope_window": 2 ** 31 - 1},
    {"est.A0_initial": 50.0, "est.batch_size": 10 ** 6},    # the first bound in Python's order
    {"car.initial_speed": 1e300}, {"car.initial_speed": 200.0}, {"car.initial_speed": 200.00000000000003},
    {"est.batch_size": 3, "est.method": 9},
    {"est.forgetting": 2.0, "est.run_forgetting": 2.0},
    # FilterConfig.validate (length = car.length)
    {"sensor.position_std_rel": -0.1}, {"sensor.position_std_rel": NAN},
    {"sensor.position_std_rel": -0.0},
    {"sensor.speed_std_rel": -0.1}, {"sensor.speed_std_rel": NAN}, {"sensor.speed_std_rel": INF},
    {"sensor.speed_std_rel": -0.0}, {"sensor.speed_std_rel": 0.02},
    {"sensor.speed_std_rel": -1.0, "car.length": -1.0}, {"sensor.position_std_rel": NAN, "sensor.speed_std_rel": NAN},
    {"sensor.speed_std": 0.0}, {"sensor.speed_std": -1.0}, {"sensor.speed_std": -0.0},
    {"sensor.position_std": 0.0}, {"sensor.position_std": NAN}, {"sensor.position_std": 0.3},
    {"filter.kind": 5}, {"filter.kind": -1},
    ({"filter.kind": 1}, None, 0.0), ({"filter.kind": 3}, None, 0.0),
    ({"filter.kind": 1}, SPEED, 0.0), ({"filter.kind": 3}, SPEED, 0.0),
    ({"filter.kind": 0}, SPEED, 0.0),
    {"filter.kind": 4, "filter.singer_tau": 0.0}, {"filter.kind": 4, "filter.singer_tau": NAN},
    {"filter.kind": 4, "filter.singer_tau": -1.0},
    {"filter.kind": 4, "filter.singer_p0": NAN}, {"filter.kind": 4, "filter.singer_p_plus": -0.1},
    {"filter.kind": 4, "filter.singer_p_minus": INF},
    {"filter.kind": 4, "filter.singer_p0": 0.5, "filter.singer_p_plus": 0.3,
     "filter.singer_p_minus": 0.3},
    {"filter.kind": 4, "filter.singer_p0": 0.8, "filter.singer_p_plus": 0.1,
     "filter.singer_p_minus": 0.1},
    {"filter.kind": 4, "filter.singer_w_max_plus": -0.1},
    {"filter.kind": 4, "filter.singer_w_max_minus": 0.1},
    {"filter.kind": 4, "filter.singer_w_max_plus": 0.0, "filter.singer_w_max_minus": 0.0},
    {"filter.kind": 4, "filter.singer_w_max_plus": INF},
    {"filter.kind": 4, "filter.singer_w_max_minus": -0.0},
    {"filter.kind": 2, "filter.singer_tau": 0.0},            # only kind 4 reads them
    ({"filter.kind": 1, "filter.singer_tau": 0.0}, None, 0.0),
    {"filter.kind": 4, "filter.singer_tau": 0.0, "sensor.speed_std": -1.0},
    # StationConfig.validate
    {"track.station_dwell": 0.0}, {"track.station_dwell": NAN}, {"track.station_dwell": -1.0},
    {"track.station_dwell": INF}, {"track.station_dwell": TINY},
    # several bad at once: the first in Python's order
    {"est.batch_size": 3, "car.mass": 0.0}, {"sensor.speed_std": -1.0, "track.station_dwell": 0.0},
    {"track.station_dwell": 0.0, "est.gamma": -1.0},
    {"solver.step": -1.0, "sensor.sample_period": 0.0},
    ({"car.process_noise_psd": -1.0}, None, NAN),
    # uncovered options behind an earlier bad setting: Python's message
    {"est.method": 2, "car.mass": 0.0}, {"est.method": 3, "est.batch_size": 2},
    {"est.physical": 1, "est.sigma2_method": 5}, {"est.sigma2_method": 1, "seed": -1},
    # the likelihood bank's own check (R = speed_std^2 > 0), and behind a bad filter setting
    {"est.sigma2_method": 1, "sensor.speed_std": 0.0},
    {"est.sigma2_method": 1, "sensor.speed_std": 0.0, "sensor.speed_std_rel": 0.01},
    {"est.sigma2_method": 1, "sensor.speed_std": 0.0, "sensor.position_std": -1.0},
]

# RailCarEstimator: TrackSensorConfig (no spacing), then build_estimator with dt = 1
EST_CASES = [
    {"sensor.track_base": 0.0}, {"sensor.track_base": NAN}, {"sensor.track_jitter": NAN},
    {"sensor.track_resolution": -1.0}, {"sensor.track_jitter": -1.0, "est.batch_size": 1},
    {"est.batch_size": 3}, {"est.method": 4}, {"est.sigma2_method": 3}, {"est.physical": 7},
    {"est.slope_window": 0}, {"est.forgetting": 1.0}, {"est.run_forgetting": -0.5},
    {"est.mass_initial": -1.0}, {"est.sigma2_initial": INF}, {"est.A2_initial": NAN},
    {"est.gamma": -2.0}, {"sensor.speed_std": NAN},
    {"est.sigma2_initial": 1e300}, {"est.mass_std_initial": 1e-300}, {"est.batch_size": 2 ** 31 - 1},
    {"est.A1_initial": -3.0}, {"est.slope_window": 5000},
    {"sensor.position_std_rel": -1.0}, {"car.length": -1.0}, {"car.length": NAN},
    {"sensor.speed_std_rel": -1.0}, {"sensor.speed_std_rel": INF}, {"sensor.speed_std_rel": NAN},
    {"car.length": -0.0}, {"car.length": INF},
    {"sensor.speed_std": 0.0}, {"sensor.position_std": -2.5}, {"filter.kind": 9},
    {"est.sigma2_method": 1, "sensor.speed_std": 0.0},
    {"est.sigma2_method": 1, "sensor.speed_std": 0.0, "sensor.position_std": -1.0},
    ({"filter.kind": 1}, None), ({"filter.kind": 1}, SPEED), ({"filter.kind": 3}, None),
    {"filter.kind": 4, "filter.singer_tau": -0.0},
    {"filter.kind": 4, "filter.singer_p0": 1.5},
    {"track.station_dwell": -0.0}, {"track.station_dwell": INF},
    {"car.length": -1.0, "track.station_dwell": 0.0},
    {"est.method": 1, "sensor.track_base": -1.0},
    {"est.A0_drift_std": -1.0}, {"est.A1_drift_std": 1.5}, {"est.A1_drift_std": 0.03},
    {"est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03, "est.method": 0},
]


def _chain_case(case):
    return case if isinstance(case, tuple) else (case, None, 0.0)


def _est_case(case):
    return case if isinstance(case, tuple) else (case, None)


def test_the_catalogue_is_large_and_mostly_bad():
    bad = [c for c in CHAIN_CASES
           if python_chain({**CHAIN_DEFAULTS, **_chain_case(c)[0]}, *_chain_case(c)[1:])]
    assert len(bad) >= 60, len(bad)
    rules = {re.sub(r"got .*|\(.*", "", python_chain({**CHAIN_DEFAULTS, **_chain_case(c)[0]},
                                                     *_chain_case(c)[1:])) for c in bad}
    assert len(rules) >= 45, sorted(rules)       # distinct rules, not one rule many times


@pytest.mark.parametrize("case", CHAIN_CASES, ids=lambda c: repr(c)[:80])
def test_chain_message_is_pythons(lib, case):
    overrides, speed, start = _chain_case(case)
    v = {**CHAIN_DEFAULTS, **overrides}
    st, c = c_chain(lib, v, speed, start)
    assert_same_message(python_chain(v, speed, start), st, c, repr(case))


@pytest.mark.parametrize("case", EST_CASES, ids=lambda c: repr(c)[:80])
def test_estimator_message_is_pythons(lib, case):
    overrides, speed = _est_case(case)
    v = {**EST_DEFAULTS, **overrides}
    st, c = c_estimator(lib, v, speed)
    assert_same_message(python_estimator(v, speed), st, c, repr(case))


def test_a_different_value_gives_a_different_message(lib):
    """The comparison can fail: one ulp in the value shows in the message."""
    v = {**CHAIN_DEFAULTS, "car.mass": -1.0}
    _, c = c_chain(lib, v, None, 0.0)
    v2 = {**v, "car.mass": math.nextafter(-1.0, 0.0)}
    py2 = python_chain(v2, None, 0.0)
    assert c != py2 and py2 == "car.mass must be > 0, got -0.9999999999999999"


# ------------------------------------------------------------------ good configurations

def scenario_values(path: Path, fmu: str) -> tuple[dict, SpeedProfile | None]:
    sc = load_scenario(path)
    v = {n: sc.parameter(n) for n in defaults(fmu)}
    grade, speed = load_profiles(v, str(path.parent))
    return v, speed


@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenarios_pass(lib, path):
    v, speed = scenario_values(path, RAILCAR)
    assert python_chain(v, speed, 0.0) is None
    assert c_chain(lib, v, speed, 0.0) == (0, "")
    assert c_chain(lib, v, speed, 1e9) == (0, "")
    ve, speed = scenario_values(path, ESTIMATOR)
    assert python_estimator(ve, speed) is None
    assert c_estimator(lib, ve, speed) == (0, "")


def test_defaults_pass(lib):
    assert c_chain(lib, CHAIN_DEFAULTS, None, 0.0) == (0, "")
    assert c_estimator(lib, EST_DEFAULTS, None) == (0, "")


def test_the_fields_the_chain_sets_itself_are_not_read(lib):
    """identifier.dt / speed_std and filter.length come from sensor.sample_period,
    sensor.speed_std and car.length, as build_estimator sets them."""
    cfg = chain_config(CHAIN_DEFAULTS)
    cfg = replace(cfg, identifier=replace(cfg.identifier, dt=-1.0, speed_std=math.nan),
                  filter=replace(cfg.filter, length=-1.0))
    values = [float(x) for x in compiled._config_values(cfg, 0.0)]
    assert c_call(lib, lib.shim_chain_validate, values, 10, False) == (0, "")
    ident, filt, station = estimator_settings(EST_DEFAULTS)
    values = estimator_values(EST_DEFAULTS)
    values[0], values[13] = 0.0, math.inf            # identifier.dt, identifier.speed_std
    assert c_call(lib, lib.shim_estchain_validate, values, 10, False) == (0, "")


# ------------------------------------------------------------------ options the core lacks

NATIVE_METHODS = "the paper's LS, or 2, LS on Sidorenko's slopes"
"""What the native FMUs' refusal of est.method lists after "only 0, " (validate.c)."""

UNCOVERED = [
    ("est.method", 1, NATIVE_METHODS), ("est.method", 3, NATIVE_METHODS),
]


@pytest.mark.parametrize("name,value,only", UNCOVERED)
def test_uncovered_options_name_the_fmu_that_runs_them(lib, name, value, only):
    v = {**CHAIN_DEFAULTS, name: value}
    assert python_chain(v, None, 0.0) is None                 # a good configuration in Python
    assert compiled.not_covered(chain_config(v)) is not None   # ... that the core does not run
    assert c_chain(lib, v, None, 0.0) == (
        2, f"{name} = {value} is not in the native RailCar FMU (only 0, {only}): use RailCar.fmu "
           f"(pythonfmu) for it")
    ve = {**EST_DEFAULTS, name: value}
    assert python_estimator(ve, None) is None
    assert c_estimator(lib, ve, None) == (
        2, f"{name} = {value} is not in the native RailCarEstimator FMU (only 0, {only}): use "
           f"RailCarEstimator.fmu (pythonfmu) for it")


@pytest.mark.parametrize("option", [{"est.physical": 1}, {"est.method": 2},
                                    {"est.method": 2, "est.slope_window": 6},
                                    {"est.method": 2, "est.physical": 1}])
def test_physical_and_slope_ls_are_in_the_native_fmus(lib, option):
    """est.physical 1 and est.method 2 run in the core, and the native FMUs' validation lets
    them through."""
    v = {**CHAIN_DEFAULTS, **option}
    assert c_chain(lib, v, None, 0.0) == (0, "") and python_chain(v, None, 0.0) is None
    assert compiled.not_covered(chain_config(v)) is None
    ve = {**EST_DEFAULTS, **option}
    assert c_estimator(lib, ve, None) == (0, "") and python_estimator(ve, None) is None


def test_slope_ls_with_a_bad_window_is_refused_as_python_words_it(lib):
    """est.method 2 now passes the native refusal, so est.slope_window's own check speaks."""
    v = {**CHAIN_DEFAULTS, "est.method": 2, "est.slope_window": 1}
    st, c = c_chain(lib, v, None, 0.0)
    assert_same_message(python_chain(v, None, 0.0), st, c, "slope_window 1")
    assert c.startswith("est.slope_window must be >= 2")
    ve = {**EST_DEFAULTS, "est.method": 2, "est.slope_window": 1}
    st, c = c_estimator(lib, ve, None)
    assert_same_message(python_estimator(ve, None), st, c, "estimator slope_window 1")


def test_uncovered_options_are_refused_where_python_checks_them(lib):
    """Refused at Python's check of their value: before every later rule, after every earlier."""
    v = {**CHAIN_DEFAULTS, "est.method": 3, "est.forgetting": 1.5, "track.station_dwell": 0.0}
    assert c_chain(lib, v, None, 0.0)[1].startswith("est.method = 3 is not in the native")
    v = {**CHAIN_DEFAULTS, "est.method": 1, "est.sigma2_method": 7}    # est.method first
    assert c_chain(lib, v, None, 0.0)[1].startswith("est.method = 1 is not in the native")
    v = {**CHAIN_DEFAULTS, "est.method": 1, "est.batch_size": 3}
    assert c_chain(lib, v, None, 0.0)[1] == python_chain(v, None, 0.0)


IDENT_VALIDATE_SHIM = r"""
#include <string.h>
#include "validate.h"

/* rc_ident_validate (no native FMU: every est.method Python knows) on IdentifierConfig's numbers */
int shim_ident_validate(const double *c, int method, char *msg, int n)
{
    rc_ident_config cfg = {c[0], (long)c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9], c[10],
                           c[11], c[12], c[13], (int)c[14], c[15], c[16], c[17], c[18]};
    rc_error err;
    int st = rc_ident_validate(&cfg, method, 0, 0, 10, &err);
    strncpy(msg, st ? err.msg : "", (size_t)n - 1);
    msg[n - 1] = '\0';
    return st;
}
"""


@pytest.mark.parametrize("method", [1, 3])
def test_drift_with_a_method_that_carries_its_own_as_is_refused_naming_both(method, tmp_path):
    """est.method 1 and 3 carry their A's themselves: a nonzero est.A0_drift_std or
    est.A1_drift_std is refused, in Python's words by rc_ident_validate (the native FMUs refuse
    est.method 1 and 3 before: test_uncovered_options_are_refused_where_python_checks_them)."""
    from models.estimation.identification import IdentifierConfig
    shim = tmp_path / "ident_validate_shim.c"
    shim.write_text(IDENT_VALIDATE_SHIM)
    so = tmp_path / "libidentvalidate.so"
    proc = subprocess.run([shutil.which("gcc"), *FLAGS, "-shared", "-Wl,--no-undefined",
                           f"-I{CORE}", *map(str, SOURCES), str(shim), "-o", str(so), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    dll = ctypes.CDLL(str(so))
    dll.shim_ident_validate.argtypes = [ctypes.POINTER(ctypes.c_double), ctypes.c_int, ctypes.c_char_p,
                                        ctypes.c_int]
    for drift in ({"A0_drift_std": 0.05}, {"A1_drift_std": 0.03}, {"A0_drift_std": 0.05, "A1_drift_std": 1.0},
                  {}, {"A0_drift_std": -0.0}):
        cfg = IdentifierConfig(method=method, **drift)
        try:
            cfg.validate()
            py = None
        except ValueError as e:
            py = str(e)
        c = [cfg.dt, cfg.batch_size, cfg.forgetting, cfg.gamma, cfg.mass_initial, cfg.mass_std_initial,
             cfg.A0_initial, cfg.A1_initial, cfg.A2_initial, cfg.A0_std_initial, cfg.A1_std_initial,
             cfg.A2_std_initial, cfg.sigma2_initial, cfg.speed_std, float(cfg.frozen), cfg.run_forgetting,
             cfg.speed_std_rel, cfg.A0_drift_std, cfg.A1_drift_std]
        buf = ctypes.create_string_buffer(MSG)
        st = dll.shim_ident_validate((ctypes.c_double * len(c))(*c), method, buf, MSG)
        if any(drift.values()):
            assert py and py.startswith("est.A0_drift_std and est.A1_drift_std apply to est.method 0 and 2")
            assert f"with est.method {method}" in py
        else:
            assert py is None
        assert_same_message(py, st, buf.value.decode(), repr(drift))


def test_python_overflow_is_not_a_valueerror(lib):
    """Where Python's build raises OverflowError (not a ValueError: the pythonfmu FMU does not
    word it), C refuses naming the parameter (filter.c's ** 2 check)."""
    v = {**CHAIN_DEFAULTS, "sensor.speed_std": 1e200}
    with pytest.raises(OverflowError):
        RailCarChain(chain_config(v), GRADE)
    st, c = c_chain(lib, v, None, 0.0)
    assert st == 2 and c.startswith("sensor.speed_std ** 2 overflows (OverflowError), got ")


# ------------------------------------------------------------------ sanitizers

def test_sanitized_run_of_the_catalogue(lib, tmp_path):
    gcc = shutil.which("gcc")
    exe = tmp_path / "validate_san"
    proc = subprocess.run([gcc, *FLAGS, "-g", "-O1", "-fno-omit-frame-pointer",
                           "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                           "-DVALIDATE_MAIN", *map(str, SOURCES), str(SHIM), "-o", str(exe),
                           "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    lines, expected = [], []
    for case in CHAIN_CASES:
        overrides, speed, start = _chain_case(case)
        v = {**CHAIN_DEFAULTS, **overrides}
        values = chain_values(v, start)
        lines.append(f"c {int(v['est.slope_window'])} {int(speed is not None)} {len(values)} "
                     + " ".join(x.hex() for x in values))
        expected.append(c_chain(lib, v, speed, start))
    for case in EST_CASES + [({n: x}, None) for n, x, _ in UNCOVERED]:
        overrides, speed = _est_case(case)
        v = {**EST_DEFAULTS, **overrides}
        values = estimator_values(v)
        lines.append(f"e {int(v['est.slope_window'])} {int(speed is not None)} {len(values)} "
                     + " ".join(x.hex() for x in values))
        expected.append(c_estimator(lib, v, speed))
    run = subprocess.run([str(exe)], input="\n".join(lines) + "\n", capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "runtime error" not in run.stderr and "Sanitizer" not in run.stderr, run.stderr[-3000:]
    got = [tuple(line.split(" ", 1)) for line in run.stdout.splitlines()]
    assert len(got) == len(expected)
    for (st, msg), (est, emsg) in zip(got, expected):
        assert (int(st), msg) == (est, emsg)


def test_coverage_reads_only_the_parameters_it_names():
    """models.compiled.core_not_covered reads only what COVERAGE_PARAMETERS names, est.method
    (IdentifierConfig.method): a sweep decides its engine from one run when it sweeps none of
    them (harness.sweep.main.choose_engine). Changing any other field of the identifier leaves
    the answer alone, for every method; the method changes it."""
    from dataclasses import fields, replace
    from models.estimation.identification import IdentifierConfig
    assert compiled.COVERAGE_PARAMETERS == ("est.method",)
    base = IdentifierConfig()
    for method in (0, 1, 2, 3):
        ident = replace(base, method=method)
        expected = compiled.core_not_covered(ident)
        changed = 0
        for f in fields(IdentifierConfig):
            value = getattr(ident, f.name)
            if f.name == "method" or not isinstance(value, (bool, int, float)):
                continue
            other = (not value) if isinstance(value, bool) else value + 1
            assert compiled.core_not_covered(replace(ident, **{f.name: other})) == expected, f.name
            changed += 1
        assert changed >= 15                                      # every setting of the identifier
    assert compiled.core_not_covered(replace(base, method=1)) != compiled.core_not_covered(base)
