"""The compiled per-step path (models/_fastcore.c) against the Python reference: bit for bit.

Each library scenario (and variants that reach the other code paths: forgetting, grade
averaging over the car's length, relative odometry noise, a speed profile with the linearised
filter, track sensors, the filter-error refit, the frozen oracle) is run on the models chain
twice, once with ``models._fast.core`` and once with it set to None (pure Python), and every
output at every step, plus the estimator's internal state at the end, must be *equal* — no
tolerance: issue 7 asks for bit-identical results.
"""
from __future__ import annotations

import math
import zipfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fmu_src.adapter import chain_config, load_profiles
from fmu_src.variables import RAILCAR, variables_for
from harness.driver import drive_chain
from harness.scenario import load_scenario
from models import _fast
from models.chain import RailCarChain, StepRejected

ROOT = Path(__file__).resolve().parent.parent
LIBRARY = sorted((ROOT / "scenarios" / "library").glob("*.toml"))
PARAMETERS = [v.name for v in variables_for(RAILCAR) if v.causality == "parameter"]
CORE = _fast.core


def test_compiled_core_is_built():
    """pip install -e . compiles models/_fastcore.c (gcc and the Python headers are on every
    machine we support); without it everything still runs, in Python, ~7x slower."""
    assert CORE is not None, "models/_fastcore.c was not compiled: run pip install -e . with a C compiler"


def test_compiled_core_compiles_without_a_warning():
    """models/_fastcore.c under -Wall -Wextra -Werror (setup.py builds it without -Werror, so that
    a newer compiler's warning cannot silently drop the optional extension)."""
    import shutil
    import subprocess
    import sysconfig
    gcc = shutil.which("gcc")
    assert gcc
    proc = subprocess.run([gcc, "-fsyntax-only", "-Wall", "-Wextra", "-Werror", "-ffp-contract=off",
                           f"-I{sysconfig.get_paths()['include']}", str(ROOT / "models" / "_fastcore.c")],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def _run(path: Path, core, overrides: dict, max_steps: int | None = None):
    """Outputs at every step and the internal state at the end, with the given core."""
    _fast.core = core
    try:
        sc = load_scenario(path)
        sc = replace(sc, parameters={**sc.parameters, **overrides})
        v = {n: sc.parameter(n) for n in PARAMETERS}
        chain = RailCarChain(chain_config(v), *load_profiles(v, str(path.parent)))
        rows = drive_chain(chain, sc, max_steps)
        return rows, _internal_state(chain)
    finally:
        _fast.core = CORE


def _internal_state(chain: RailCarChain) -> dict:
    ident, filt, st = chain.estimator.ident, chain.estimator.filter, chain.estimator.station
    out = {name: getattr(ident, name) for name in
           ("_theta", "_S", "_W", "_D", "_last_phi", "_window", "_window_sum", "cL", "c0", "c1",
            "q_e", "s2", "n", "_n_cL", "_n_c1", "_last_err")}
    out.update({f"filter.{n}": getattr(filt, n) for n in
                ("_xb0", "_xb1", "_m00", "_m01", "_m11", "_xh0", "_xh1", "_p00", "_p01", "_p11")})
    out.update({"station.still_time": st.still_time, "station._fast_run": st._fast_run,
                "plant.time": chain.plant.time, "plant._grid_index": chain.plant._grid_index,
                "plant.impulses": (chain.plant.traction_impulse, chain.plant.brake_impulse),
                "plant.state": vars(chain.plant.state).copy(), "samples": chain._sample_index})
    return out


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    return a == b


def _assert_identical(path: Path, overrides: dict, max_steps: int | None = None) -> int:
    (rows_py, state_py), (rows_c, state_c) = (_run(path, None, overrides, max_steps),
                                              _run(path, CORE, overrides, max_steps))
    assert len(rows_py) == len(rows_c)
    for i, (a, b) in enumerate(zip(rows_py, rows_c)):
        assert list(a) == list(b), f"{path.stem}: output names differ at row {i}"
        diff = [(k, a[k], b[k]) for k in a if not _same(a[k], b[k])]
        assert not diff, f"{path.stem} {overrides}: row {i} differs: {diff[:3]}"
    diff = [k for k in state_py if not _same(state_py[k], state_c[k])]
    assert not diff, f"{path.stem} {overrides}: internal state differs in {diff}"
    return len(rows_py)


@pytest.mark.parametrize("path", LIBRARY, ids=[p.stem for p in LIBRARY])
def test_library_scenario_bit_identical(path):
    assert CORE is not None
    assert _assert_identical(path, {}) > 100


VARIANTS = {
    "forgetting": {"est.forgetting": 0.002},                       # Python step, compiled plant
    "car_length_and_odometry_drift": {"car.length": 60.0, "sensor.position_std_rel": 0.01},
    "track_sensors": {"sensor.track_spacing": 200.0, "sensor.track_jitter": 1e-4},
    "refit": {"est.method": 1},
    "paper_filter": {"filter.kind": 3, "track.speed_profile": "../profiles/default_speed.csv"},
    "singer_filter": {"filter.kind": 4},
    "solver_step_0.1": {"solver.step": 0.1},
}


@pytest.mark.parametrize("name", VARIANTS)
def test_variant_bit_identical(name):
    overrides = dict(VARIANTS[name])
    path = ROOT / "scenarios" / "library" / "steep_grades.toml"
    profile = overrides.get("track.speed_profile")
    if profile is not None:
        assert (path.parent / profile).is_file(), f"missing test profile {profile}"
    assert _assert_identical(path, overrides, max_steps=1500) > 100


def _faulty_cruise(core, seconds: float, faults: dict[int, float], position_faults: dict[int, float]):
    """tests/test_robust_estimator.py's cruise with planted speed-sensor faults, on one core."""
    from test_robust_estimator import FaultyStream, demands
    from models.dynamics import VehicleParams
    from models.chain import ChainConfig
    from models.track import GradeProfile
    _fast.core = core
    try:
        chain = RailCarChain(ChainConfig(vehicle=VehicleParams(mass=34.0), seed=3), GradeProfile.level())
        chain._speed_noise = FaultyStream(chain._speed_noise, faults)
        chain._position_noise = FaultyStream(chain._position_noise, position_faults)
        rows, t = [], 0.0
        for _ in range(round(seconds / 0.1)):
            chain.do_step(t, 0.1, *demands(chain, t, 34.0), 0.0, 0.0)
            t += 0.1
            rows.append(chain.outputs())
        state = _internal_state(chain)
        est = chain.estimator
        state.update({n: getattr(est, n) for n in ("_net_force", "_steady_speed", "_steady_force",
                                                    "_steady_time", "_prev_fit", "_pair_used")})
        state.update({f"filter.{n}": getattr(est.filter, n) for n in
                      ("rejected", "speed_run", "position_run", "speed_fit", "reacquired",
                       "_use_speed", "_use_position", "_reacquire")})
        return rows, state
    finally:
        _fast.core = CORE


def test_gate_reacquire_and_steady_cap_bit_identical():
    """The innovation gate (a spike, a dropout long enough to reacquire) and the information cap
    of a steady cruise (OnlineEstimator._excited), compiled and in Python: equal at every step."""
    faults = {1500: 200.0, **{k: -300.0 for k in range(2000, 2080)}, 2500: -150.0,
              **{k: -20.0 for k in range(3000, 3010)}}             # a spike, dropouts
    position_faults = {2700: 100.0, 3300: -80.0, **{k: 50.0 for k in range(4000, 4060)}}
    steps = 6000                                       # 600 s: 9 min of cruise, capped
    rows_py, state_py = _faulty_cruise(None, steps * 0.1, faults, position_faults)
    compiled_before = CORE.step_counts()[0]
    rows_c, state_c = _faulty_cruise(CORE, steps * 0.1, faults, position_faults)
    assert CORE.step_counts()[0] - compiled_before == steps     # every step ran compiled
    for i, (a, b) in enumerate(zip(rows_py, rows_c)):
        diff = [(k, a[k], b[k]) for k in a if not _same(a[k], b[k])]
        assert not diff, f"row {i} differs: {diff[:3]}"
    diff = [k for k in state_py if not _same(state_py[k], state_c[k])]
    assert not diff, f"internal state differs in {diff}"
    assert state_c["filter.reacquired"] >= 2 and state_c["filter.rejected"] >= 100
    assert state_c["_steady_time"] > 20.0               # the cap was reached


def _faulty_stations(core, faults: dict, position_faults: dict, stops: int, rel: float = 0.0):
    """Station runs (traction, coast, brake to a stop at 1200 m, 25 s held) with planted
    speed and distance faults, on one core: rows and the estimator's state at the end."""
    from test_robust_estimator import FaultyStream, station_runs
    from models.chain import ChainConfig
    from models.dynamics import VehicleParams
    from models.filters import FilterConfig
    from models.track import GradeProfile
    _fast.core = core
    try:
        chain = RailCarChain(ChainConfig(vehicle=VehicleParams(mass=34.0), seed=2,
                                         filter=FilterConfig(position_std_rel=rel)), GradeProfile.level())
        chain._speed_noise = FaultyStream(chain._speed_noise, faults)
        chain._position_noise = FaultyStream(chain._position_noise, position_faults)
        rows = list(station_runs(chain, stops))
        state = _internal_state(chain)
        est = chain.estimator
        state.update({n: getattr(est, n) for n in ("_prev", "_prev_fit", "_pair_used", "station_stops")})
        state.update({f"filter.{n}": getattr(est.filter, n) for n in
                      ("rejected", "speed_run", "position_run", "speed_fit", "reacquired", "_reacquire")})
        return rows, state
    finally:
        _fast.core = CORE


_BOTH = range(700, 706)                                    # both refused: the hold path
STATION_FAULTS = {
    "scattered_and_both": ({**{k: (200.0, -300.0, 7.0)[k % 3] for k in range(50, 4000, 37)},
                            **{k: 250.0 for k in _BOTH}},
                           {**{k: (100.0, -60.0)[k % 2] for k in range(60, 4000, 71)},
                            **{k: 90.0 for k in _BOTH}}, 0.0),
    "with_odometry_drift": ({k: 200.0 for k in range(50, 4000, 41)},
                            {k: 80.0 for k in range(90, 4000, 83)}, 0.01),
    "speed_stuck_distance_good": ({k: -300.0 for k in range(600, 900)}, {}, 0.0),
    "distance_jump": ({}, {k: 40.0 for k in range(1500, 1600)}, 0.0),
}


@pytest.mark.parametrize("name", STATION_FAULTS)
def test_gate_across_station_stops_bit_identical(name):
    """Faults through departures (the gate in restart_filter), at the same sample on both
    sensors (hold), with odometry drift, a speed stuck for 30 s with good distances (refused
    throughout, no reacquire) and a 10 s distance jump (the distance alone reacquired)."""
    faults, position_faults, rel = STATION_FAULTS[name]
    rows_py, state_py = _faulty_stations(None, faults, position_faults, 3, rel)
    compiled_before = CORE.step_counts()[0]
    rows_c, state_c = _faulty_stations(CORE, faults, position_faults, 3, rel)
    assert CORE.step_counts()[0] - compiled_before == len(rows_c)
    for i, (a, b) in enumerate(zip(rows_py, rows_c)):
        diff = [(k, a[k], b[k]) for k in a if not _same(a[k], b[k])]
        assert not diff, f"{name}: row {i} differs: {diff[:3]}"
    diff = [k for k in state_py if not _same(state_py[k], state_c[k])]
    assert not diff, f"{name}: internal state differs in {diff}"
    assert state_c["station_stops"] >= 2 and state_c["filter.rejected"] > 0   # the 3rd confirms on departure
    if name == "speed_stuck_distance_good":
        assert state_c["filter.reacquired"] == 0 and state_c["filter.rejected"] >= 290
    if name == "distance_jump":
        assert state_c["filter.reacquired"] >= 1


def test_oracle_bit_identical(monkeypatch):
    """The frozen identifier (the harness's oracle filter) takes the Python covariance path."""
    from models import identification
    original = identification.IdentifierConfig.validate

    def frozen_validate(self):
        self.frozen = True
        original(self)
    monkeypatch.setattr(identification.IdentifierConfig, "validate", frozen_validate)
    assert _assert_identical(LIBRARY[0], {}, max_steps=600) > 100


@pytest.mark.parametrize("bad, name", [
    (dict(traction_demand=float("nan")), "traction_force_demand"),
    (dict(brake_demand=-1.0), "brake_force_demand"),
    (dict(wind_speed=float("inf")), "wind_speed"),
    (dict(payload=-100.0), "car.payload"),
    (dict(current_time=5.0), "does not continue"),
    (dict(step_size=0.0), "step size"),
])
def test_bad_input_rejected_with_name_and_nothing_changed(bad, name):
    """The compiled step refuses bad input before touching anything; the Python checks then
    raise StepRejected naming the variable, and the next good step continues exactly."""
    assert CORE is not None
    from models.chain import ChainConfig
    from models.track import GradeProfile

    def fresh():
        c = RailCarChain(ChainConfig(), GradeProfile.level())
        for k in range(30):
            c.do_step(k * 0.1, 0.1, 40e3, 0.0, 0.0)
        return c
    chain, reference = fresh(), fresh()
    args = dict(current_time=3.0, step_size=0.1, traction_demand=40e3, brake_demand=0.0,
                wind_speed=0.0, payload=0.0)
    with pytest.raises(StepRejected, match=name):
        chain.do_step(**{**args, **bad})
    chain.do_step(**args)
    reference.do_step(**args)
    assert _same(chain.outputs(), reference.outputs())


def test_built_fmu_bundles_the_compiled_core(built_fmus):
    with zipfile.ZipFile(built_fmus["RailCar"]) as z:
        names = z.namelist()
    assert any(n.startswith("resources/models/_fastcore") and n.endswith(".so") for n in names), \
        "RailCar.fmu lacks the compiled core"
    assert "resources/models/_fastcore.c" in names       # the source travels with it


def test_method_replaced_on_an_instance_is_honoured():
    """A study wraps estimator.propagate on the instance to record the forces: the compiled step
    must then leave the step to Python (same results), or the wrapper would never be called."""
    from models.chain import ChainConfig
    from models.track import GradeProfile
    plain = RailCarChain(ChainConfig(), GradeProfile.level())
    wrapped = RailCarChain(ChainConfig(), GradeProfile.level())
    recorded = []
    propagate = wrapped.estimator.propagate

    def recording(traction, brake, dt):
        recorded.append((traction, brake))
        propagate(traction, brake, dt)
    wrapped.estimator.propagate = recording
    for k in range(200):
        for c in (plain, wrapped):
            c.do_step(k * 0.1, 0.1, 30e3 if k < 120 else 0.0, 0.0, 0.0)
    assert len(recorded) == 200 and recorded[0][0] > 0.0 and recorded[-1] == (0.0, 0.0)
    assert _same(plain.outputs(), wrapped.outputs())


def _drive(chain, steps=400):
    for k in range(steps):
        chain.do_step(k * 0.1, 0.1, 30e3 if k < 150 else 0.0, 20e3 if 300 < k < 380 else 0.0, 0.0)
    return chain.outputs()


def _patched_run(patch, core):
    """Outputs after 400 steps of a default chain with ``patch(chain)`` applied after it was built."""
    from models.chain import ChainConfig
    from models.track import GradeProfile
    _fast.core = core
    try:
        chain = RailCarChain(ChainConfig(), GradeProfile.level())
        patch(chain)
        return _drive(chain)
    finally:
        _fast.core = CORE


# Methods the compiled step inlines (it replicates their bodies, not only the ones it is bound
# to): pinning each on the instance must change the result exactly as in Python. Found by
# handing the filter the true sigma^2 this way in a study: the compiled step ignored it.
INLINED = {
    "ident.sigma2": lambda c: setattr(c.estimator.ident, "sigma2", lambda: 1e-6),
    "est.model_theta": lambda c: setattr(c.estimator, "model_theta",
                                         lambda: np.array([1.0 / (9.81 * 30.0), 1.0, 0.03, 0.01])),
    "est.process_noise": lambda c: setattr(c.estimator, "process_noise", lambda f, b, dt: 1e-3),
    "station.observe": lambda c: setattr(c.estimator.station, "observe", lambda v, x, dt: False),
    "ident._process_share": lambda c: setattr(c.estimator.ident, "_process_share", lambda a, b: 10.0 * b),
    "plant.next_grid_time": lambda c: setattr(c.plant, "next_grid_time",
                                              lambda: (c.plant._grid_index + 1) * c.plant.h * 0.5),
}


@pytest.mark.parametrize("name", sorted(INLINED))
def test_an_inlined_method_replaced_on_an_instance_is_honoured(name):
    patch = INLINED[name]
    plain = _patched_run(lambda c: None, CORE)
    python, compiled = _patched_run(patch, None), _patched_run(patch, CORE)
    assert not _same(python, plain), f"the replacement of {name} changes nothing: a useless test"
    assert _same(compiled, python), f"{name} replaced on the instance was ignored by the compiled step"


def test_a_method_replaced_on_the_class_is_honoured(monkeypatch):
    """A class patched after the chain was built (the core remembers the classes' state at
    import); once the patch is undone, the compiled step runs again."""
    from models.chain import ChainConfig
    from models.identification import ParameterIdentifier
    from models.track import GradeProfile
    results = {}
    for label, core in (("python", None), ("compiled", CORE)):
        with monkeypatch.context() as m:          # patched once the chain is built, undone after
            results[label] = _patched_run(lambda c: m.setattr(ParameterIdentifier, "sigma2",
                                                              lambda self: 1e-6), core)
    assert not _same(results["python"], _patched_run(lambda c: None, CORE))
    assert _same(results["compiled"], results["python"])
    before = CORE.step_counts()                       # the class restored: compiled again
    _drive(RailCarChain(ChainConfig(), GradeProfile.level()), 10)
    assert tuple(a - b for a, b in zip(CORE.step_counts(), before)) == (10, 0)


def test_a_module_function_replaced_before_the_chain_is_built_is_honoured(monkeypatch):
    """models.dynamics.held_input_dynamics is replicated by the compiled plant: replaced in its
    module, the chain must not bind the compiled step."""
    import models.dynamics as dynamics
    original = dynamics.held_input_dynamics

    def weaker_traction(p, grade_profile, traction, brake, wind):
        return original(p, grade_profile, 0.5 * traction, brake, wind)
    monkeypatch.setattr(dynamics, "held_input_dynamics", weaker_traction)
    python, compiled = _patched_run(lambda c: None, None), _patched_run(lambda c: None, CORE)
    monkeypatch.undo()
    assert not _same(python, _patched_run(lambda c: None, CORE))
    assert _same(compiled, python)


def test_the_compiled_step_runs_for_the_default_configuration():
    """Bit-identity cannot tell whether the compiled step ran at all (the Python step gives the
    same numbers): a dict-cache collision once made it decline silently. 3000 steps of the
    default chain (several chains alive, so addresses vary) must all be compiled."""
    from models.chain import ChainConfig
    from models.track import GradeProfile
    chains = [RailCarChain(ChainConfig(seed=s), GradeProfile((0.0, 300.0), (0.0, 10.0))) for s in range(3)]
    before = CORE.step_counts()
    for k in range(1000):
        for c in chains:
            c.do_step(k * 0.1, 0.1, 30e3 if k < 300 else 0.0, 20e3 if 700 < k < 900 else 0.0, 0.0)
            c.outputs()
    compiled, declined = (a - b for a, b in zip(CORE.step_counts(), before))
    assert (compiled, declined) == (3000, 0)


def test_in_place_writes_never_change_what_someone_else_holds():
    """The compiled update overwrites the identifier's lists and their floats in place only when
    nothing else references them: a list or a float held by the caller keeps its value (the
    identifier gets new objects instead), exactly as with the Python code's new lists."""
    from models.chain import ChainConfig
    from models.track import GradeProfile
    chain = RailCarChain(ChainConfig(), GradeProfile.level())
    for k in range(100):
        chain.do_step(k * 0.1, 0.1, 30e3, 0.0, 0.0)
    ident = chain.estimator.ident
    held_S, held_W0, held_cov = ident._S, ident._W[0], ident._covariance_flat()
    values = (list(held_S), float(held_W0), list(held_cov))
    chain.do_step(10.0, 0.1, 30e3, 0.0, 0.0)
    assert (list(held_S), float(held_W0), list(held_cov)) == values
    assert ident._S is not held_S and ident._S != values[0] and ident._W[0] != values[1]
