"""The C model core (models/core/, bound by models/_railcar.c) behind RailCarChain's interface.

``open_chain(cfg, grade, speed, start_time)`` is what the FMU, the harness and the studies
build: a ``CompiledChain`` when the C core is compiled and covers the configuration, else the
Python reference ``models.chain.RailCarChain``. Both give bit-identical outputs for the same seed
(tests/model_tests/core/test_core_chain.py). Which one runs is visible: ``chain.engine`` is "c" or "python", and
``ENGINES`` counts the chains opened with each.

The C core covers filter kinds 0-4 (the Singer filter included), est.method 0 and 2 (the LS on
Sidorenko's slopes: est.slope_window follows the flat configuration, models/core/config.c),
est.physical 0 and 1, est.sigma2_method 0 and 1, any forgetting, car length, odometry drift and track
sensors; NOT_COVERED runs in Python (core_not_covered). The native FMUs run the same options
(they hand the core est.slope_window after their flat configuration; estimator_not_covered is the
rule harness/run/fmus.py picks an FMU by). ``RAILCAR_PURE_PYTHON=1``
runs Python always (and a machine without a C compiler installs without the core and does the
same).

``run_ato_closed_loop`` runs whole ATO closed-loop spans in C (models/core/ato_closed_loop.h: this
chain driven by the C AtoController, the study's metrics accumulated in C), one call per list of
seeds: studies/ato_closed_loop.py's native controller.
"""
from __future__ import annotations

import collections
import dataclasses
import math
import os
from dataclasses import replace

import numpy as np

from models.chain import (ChainConfig, EstimatorChain, RailCarChain, StepRejected, TrackSensorConfig,
                    build_estimator)
from models.estimation.online import StationConfig
from models.filtering.motion_filter import FilterConfig
from models.estimation.identification import IdentifierConfig
from models.plant.track import GradeProfile, SpeedProfile

try:
    from . import _railcar
except ImportError:          # not compiled (no compiler at install, or another Python)
    _railcar = None

ENGINES: collections.Counter = collections.Counter()   # chains opened per engine ("c", "python")

OUTPUT_NAMES = (
    "car.speed", "car.position", "car.acceleration", "car.traction_force", "car.brake_force",
    "car.grade", "car.mode", "car.total_mass", "sensor.speed", "sensor.position",
    "sensor.track_speed", "sensor.track_time",
    "est.mass", "est.mass_std", "est.A0", "est.A1", "est.A2", "est.A0_std", "est.A1_std",
    "est.A2_std", "est.sigma2", "est.samples", "est.station_stops", "filter.speed",
    "filter.position", "filter.speed_std", "filter.position_std", "est.status", "filter.rejected",
    "est.cov_A0_A1", "est.cov_A0_A2", "est.cov_A1_A2", "car.traction_force_mean",
    "car.brake_force_mean",
)
"""RailCarChain.outputs()'s names in the C core's order (models/core/railcar.h)."""
INTEGER_OUTPUTS = frozenset({"car.mode", "est.samples", "est.station_stops", "est.status",
                             "filter.rejected"})
INPUT_COLUMNS = ("current_time", "step_size", "traction_force_demand", "brake_force_demand",
                 "wind_speed", "car.payload")
"""Columns of ``CompiledChain.run``'s inputs: [s], [s], [N], [N], [m/s], [t]."""


def enabled() -> bool:
    """True when the C core is compiled and not switched off (RAILCAR_PURE_PYTHON)."""
    return _railcar is not None and not os.environ.get("RAILCAR_PURE_PYTHON")


NOT_COVERED = "est.method 1 or 3"
"""The estimator options the C core does not run (models/core/estimator.h RC_NOT_COVERED)."""

COVERAGE_PARAMETERS = ("est.method",)
"""The RailCar parameters (FMU names) core_not_covered's answer depends on: runs that share them
share it (a sweep decides its engine from one run unless it sweeps one of these)."""


def core_not_covered(identifier: IdentifierConfig) -> str | None:
    """Why the C core does not run this estimator in this process (CompiledChain,
    CompiledEstimatorChain: NOT_COVERED), or None when it does. Reads only what
    COVERAGE_PARAMETERS names: keep the two in step."""
    if identifier.method not in (0, 2):
        return NOT_COVERED
    return None


def estimator_not_covered(identifier: IdentifierConfig, filt: FilterConfig) -> str | None:
    """Why the native FMUs do not run this estimator, or None when they do: the C core's rule
    (core_not_covered; models/core/validate.c refuses the same options in a native FMU)."""
    return core_not_covered(identifier)


def not_covered(cfg: ChainConfig) -> str | None:
    """Why the native RailCar FMU does not run this chain, or None when it does."""
    return estimator_not_covered(cfg.identifier, cfg.filter)


def _estimator_values(ic: IdentifierConfig, fc: FilterConfig) -> list[float]:
    """The identifier's and the filter's numbers, in _railcar.c's order."""
    return [ic.dt, int(ic.batch_size), ic.forgetting, ic.gamma, ic.mass_initial,
            ic.mass_std_initial, ic.A0_initial, ic.A1_initial, ic.A2_initial, ic.A0_std_initial,
            ic.A1_std_initial, ic.A2_std_initial, ic.sigma2_initial, ic.speed_std,
            1.0 if ic.frozen else 0.0, ic.run_forgetting, int(ic.method), int(ic.physical),
            int(ic.sigma2_method),
            fc.dt, fc.speed_std, fc.position_std, fc.position_std_rel, fc.gamma, int(fc.kind),
            fc.length, fc.singer_tau, fc.singer_p0, fc.singer_p_plus, fc.singer_p_minus,
            fc.singer_w_max_plus, fc.singer_w_max_minus, fc.speed_std_rel,
            ic.A0_drift_std, ic.A1_drift_std]   # added after the filter's: the indices before stay


def _config_values(cfg: ChainConfig, start_time: float) -> list[float]:
    """The numbers the C chain's configuration is made of, in _railcar.c's order."""
    v, st = cfg.vehicle, cfg.station
    return [v.mass, v.A0, v.A1, v.A2, v.gamma, v.length, v.traction_force_max,
            v.traction_power_max, v.brake_force_max, v.adhesion_mass_fraction, v.adhesion_factor,
            cfg.solver_step, cfg.process_noise_psd, cfg.sample_period, int(cfg.seed),
            cfg.initial_speed, cfg.initial_position,
            st.dwell, st.speed_threshold, st.position_threshold,
            *_estimator_values(cfg.identifier, cfg.filter), cfg.track.spacing, cfg.track.base,
            cfg.track.resolution, cfg.track.jitter, start_time]


def chain_values(cfg: ChainConfig, start_time: float) -> list[float]:
    """A RailCar chain's flat configuration as the C core takes it: _config_values, then
    est.slope_window (CompiledChain, the batch engine, the ATO study, the service day)."""
    return [*_config_values(cfg, start_time), int(cfg.identifier.slope_window)]


def estimator_chain_values(identifier: IdentifierConfig, filt: FilterConfig, station,
                           track: TrackSensorConfig) -> list[float]:
    """An EstimatorChain's flat configuration as the C core takes it (CompiledEstimatorChain, the
    C oracle filter, the service day): the estimator's numbers, the station's, the track
    sensor's, est.slope_window."""
    return [*_estimator_values(identifier, filt), station.dwell, station.speed_threshold,
            station.position_threshold, track.base, track.resolution, track.jitter,
            int(identifier.slope_window)]


def validate(cfg: ChainConfig, speed_profile: SpeedProfile | None, start_time: float) -> ChainConfig:
    """Raise ValueError naming the first bad setting, in the order RailCarChain meets them;
    returns the private copy the chain runs."""
    cfg = replace(cfg, vehicle=replace(cfg.vehicle))
    cfg.validate()
    if not math.isfinite(start_time):
        raise ValueError(f"start time must be finite, got {start_time}")
    if not (cfg.solver_step > 0 and math.isfinite(cfg.solver_step)):
        raise ValueError(f"solver.step must be > 0, got {cfg.solver_step}")
    if not (cfg.process_noise_psd >= 0 and math.isfinite(cfg.process_noise_psd)):
        raise ValueError(f"car.process_noise_psd must be >= 0, got {cfg.process_noise_psd}")
    replace(cfg.identifier, dt=cfg.sample_period, speed_std=cfg.filter.speed_std).validate()
    replace(cfg.filter, length=cfg.vehicle.length).validate(speed_profile is not None)
    cfg.station.validate()
    return cfg


class CompiledChain(_railcar.Chain if _railcar is not None else object):
    """RailCarChain in C: ``do_step``, ``outputs``, ``next_sample_time``, ``reset`` and the
    batched ``run``. Raises StepRejected (naming the variable) on bad input, as RailCarChain;
    ArithmeticError where Python's arithmetic would raise (an overflowing square)."""

    engine = "c"

    def __init__(self, cfg: ChainConfig, grade_profile: GradeProfile,
                 speed_profile: SpeedProfile | None = None, start_time: float = 0.0):
        if _railcar is None:
            raise RuntimeError("the C core (models._railcar) is not compiled")
        cfg = validate(cfg, speed_profile, start_time)
        why = core_not_covered(cfg.identifier)
        if why:
            raise ValueError(f"the C core does not cover {why}: use open_chain()")
        self.cfg = cfg
        self.start_time = start_time
        sp = speed_profile
        super().__init__(chain_values(cfg, start_time),
                         grade_profile.distances,
                         grade_profile.grades, sp.distances if sp else (), sp.speeds if sp else (),
                         OUTPUT_NAMES, tuple(n in INTEGER_OUTPUTS for n in OUTPUT_NAMES),
                         StepRejected)

    def run_steps(self, inputs) -> np.ndarray:
        """Many steps at once: ``inputs`` rows are INPUT_COLUMNS; returns the outputs after each
        step, one row per step, columns OUTPUT_NAMES. Raises StepRejected (or ArithmeticError, as
        do_step) naming the row."""
        x = np.ascontiguousarray(inputs, dtype=float)
        if x.ndim != 2 or x.shape[1] != len(INPUT_COLUMNS):
            raise ValueError(f"inputs must have {len(INPUT_COLUMNS)} columns {INPUT_COLUMNS}, "
                             f"got shape {x.shape}")
        out = np.empty((len(x), len(OUTPUT_NAMES)))
        self.run(x, out)
        return out


def open_chain(cfg: ChainConfig, grade_profile: GradeProfile,
               speed_profile: SpeedProfile | None = None, start_time: float = 0.0):
    """The chain for this configuration: C when it is compiled, enabled and covers it, else the
    Python reference. ``chain.engine`` says which; ENGINES counts them."""
    if enabled() and core_not_covered(cfg.identifier) is None:
        chain = CompiledChain(cfg, grade_profile, speed_profile, start_time)
    else:
        chain = RailCarChain(cfg, grade_profile, speed_profile, start_time)
    ENGINES[chain.engine] += 1
    return chain


ESTIMATOR_OUTPUT_NAMES = OUTPUT_NAMES[12:-2]
"""EstimatorChain.outputs()'s names in the C core's order: RailCar's after its 12 car.* and
sensor.* outputs, without its last two (the forces its estimator was fed, RailCar's own)."""
assert ESTIMATOR_OUTPUT_NAMES[-1] == "est.cov_A1_A2", "RailCar's outputs after the estimator's moved"


class CompiledEstimatorChain(_railcar.Estimator if _railcar is not None else object):
    """EstimatorChain (RailCarEstimator without FMI) in C: ``do_step`` and ``outputs``."""

    engine = "c"

    def __init__(self, identifier: IdentifierConfig, filt: FilterConfig, station: StationConfig,
                 grade_profile: GradeProfile, speed_profile: SpeedProfile | None = None,
                 track: TrackSensorConfig | None = None):
        if _railcar is None:
            raise RuntimeError("the C core (models._railcar) is not compiled")
        track = track or TrackSensorConfig()
        track.validate()
        build_estimator(identifier, filt, station, grade_profile, speed_profile, dt=1.0)  # validates
        why = core_not_covered(identifier)
        if why:
            raise ValueError(f"the C core does not cover {why}: use open_estimator_chain()")
        sp = speed_profile
        super().__init__(estimator_chain_values(identifier, filt, station, track),
                         grade_profile.distances, grade_profile.grades,
                         sp.distances if sp else (), sp.speeds if sp else (),
                         ESTIMATOR_OUTPUT_NAMES,
                         tuple(n in INTEGER_OUTPUTS for n in ESTIMATOR_OUTPUT_NAMES), StepRejected)


def open_estimator_chain(identifier: IdentifierConfig, filt: FilterConfig, station: StationConfig,
                         grade_profile: GradeProfile, speed_profile: SpeedProfile | None = None,
                         track: TrackSensorConfig | None = None):
    """EstimatorChain for this configuration: C when it can, else the Python reference."""
    if enabled() and core_not_covered(identifier) is None:
        chain = CompiledEstimatorChain(identifier, filt, station, grade_profile, speed_profile, track)
    else:
        chain = EstimatorChain(identifier, filt, station, grade_profile, speed_profile, track)
    ENGINES[chain.engine] += 1
    return chain


ATO_LOOP_FIELDS = ("arrival", "settle", "stop", "margin", "energy", "interventions", "replans",
                   "steps", "finished")
"""run_ato_closed_loop's metrics per run ([s], [s], [m], [m/s], [kWh], [steps], count, count,
bool; models/core/ato_closed_loop.h ato_loop_result)."""


def dataclass_values(obj) -> list[float]:
    """The values of a dataclass's init fields in declaration order, as floats: the order the C
    core takes CarTraction's (18), AtoTuning's (ATO_N_TUNING_FIELDS) and VehicleParams' (11) in."""
    return [float(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init]


def run_ato_closed_loop(cfg: ChainConfig, span, car, tuning, truth, wind: float, step: float,
                        max_steps: int, seeds) -> list[dict]:
    """One closed-loop run per seed, all in C: the chain ``cfg`` (its seed replaced by each of
    ``seeds``; the grade is the span's) under AtoController(span, car, tuning) (models.planning.span
    Span and CarTraction, models.ato.interface AtoTuning: not imported here, the layer below them;
    ``truth`` a models.plant.dynamics.VehicleParams), stepped by ``step``
    [s] in the wind [m/s] for at most ``max_steps`` steps, as studies/ato_closed_loop.py's
    python_run steps it; ``truth`` is the car step_work clips the demands with. Returns per seed
    ATO_LOOP_FIELDS as a dict, bit-identical to the Python loop's metrics. Raises ValueError naming
    the first bad setting (the chain's, in RailCarChain's words; the controller's, in
    AtoController's), StepRejected for a step the chain refuses."""
    if _railcar is None:
        raise RuntimeError("the C core (models._railcar) is not compiled")
    seeds = [int(s) for s in seeds]
    for seed in seeds:
        validate(replace(cfg, seed=seed), None, 0.0)
    cfg = validate(cfg, None, 0.0)
    why = core_not_covered(cfg.identifier)
    if why:
        raise ValueError(f"the C core does not cover {why}: run the Python loop")
    g = span.grade
    rows = _railcar.ato_closed_loop(
        chain_values(cfg, 0.0), g.distances, g.grades,
        (span.length, span.schedule, span.stop), span.limit_distances, span.limit_speeds,
        dataclass_values(car), dataclass_values(tuning), dataclass_values(truth), float(step),
        float(wind),
        int(max_steps), seeds, StepRejected)
    out = []
    for row in rows:
        d = dict(zip(ATO_LOOP_FIELDS, row))
        d["finished"] = bool(d["finished"])
        out.append(d)
    return out
