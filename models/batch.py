"""Whole scripted runs in the C core, many per call (issue 31): the Python face of models/_batch.c.

A *script* is a scripted driver, its wind schedule and the run's length, as flat numbers
(models/core/scenario_driver.h gives the layout; ``script_values`` writes it). ``run_scripts``
runs one script per chain configuration in C -- the driver (phases or a time table), the wind,
the payload boarded, stop_after_last_phase and the chain -- without returning to Python per step,
and gives every run's outputs and inputs. It is the C twin of harness.run.driver.drive on a
models chain; harness.run.batch turns scenarios and their chains' configurations into these
flat arrays and the results into RunResults. ``run_spans`` does the same for span scenarios, the
ATO's line driving (models/core/span_driver.h, the twin of harness.run.span_scenario.AtoDriver):
a *span script* (``span_script_values``) instead of a script, and every ATO call and log line
back with the rows.

The metrics of a recorded run that run a model again are here too, in C
(models/core/run_metrics.h): ``oracle_filter`` (the estimator with a frozen identifier holding
the truth, replaying the measurements), ``interval_forces``, ``coast_segments`` and
``coast_times``; harness.metrics.estimation calls them when the C core runs (its Python functions
stay the reference, equal bit for bit). ``ServiceDay`` runs studies/service_day.py's 24 h day in
blocks of steps (models/core/service_day.h: its driver, faulty sensors, both chains and scores;
the driver's draws handed in from the study's numpy Generator). Only numbers here: this module sits in the models base
layer (docs/architecture.md), importing nothing of ours but its extension.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

try:
    from . import _batch
except ImportError:          # not compiled (no compiler at install, or another Python)
    _batch = None

ACTIONS = ("traction", "coast", "cruise", "brake", "brake_to_stop", "hold")
"""A phase's action codes 0..5 (scenario_driver.h RC_ACTION_*)."""
PHASE_FIELDS = ("action", "force_N", "until_speed_mps", "until_distance_m", "until_time_s",
                "until_brake_curve", "stop_at_m", "decel_mps2", "mass_change_t", "target_speed_mps")
"""A phase's numbers in the script, in this order (scenario_driver.h RC_PHASE_*); None -> NaN."""
REQUIRED_FIELDS = ("until_brake_curve", "decel_mps2", "mass_change_t")
"""The phase's numbers that are never None (the others may be: not given)."""
HEADER = 10
OUTPUTS = 34
"""The chain's outputs per row: models.compiled.OUTPUT_NAMES (models/core/railcar.h's order)."""
INPUTS = 4
"""Per step: traction and brake demand [N], wind [m/s], payload boarded so far [t]."""
KIND_PHASES, KIND_TABLE = 0, 1
MAX_STEPS = 1_000_000_000
"""The most steps a script may have (scenario_driver.h RC_SCRIPT_MAX_STEPS)."""


def available() -> bool:
    """True when the C scenario runner (models._batch) is compiled."""
    return _batch is not None


def script_values(*, step_s: float, duration_s: float, stop_after_last_phase: bool, mass_t: float,
                  traction_force_max: float, brake_force_max: float,
                  phases: Sequence[Mapping[str, float | bool | str | None]] = (),
                  table: tuple[Sequence[float], Sequence[float], Sequence[float]] | None = None,
                  wind: Sequence[tuple[float, float]] = ()) -> np.ndarray:
    """The flat script (scenario_driver.h) of a phase driver (``phases``: each a mapping of
    PHASE_FIELDS, ``action`` by name, an optional one missing or None -> NaN) or a time table (``table``:
    time [s], traction [N], brake [N]), the wind schedule (``wind``: (time [s], speed [m/s]) in
    the order Scenario.wind_at reads them), the run's step and duration [s], and the phase
    driver's car: mass [t] and force limits [N]. The C side checks the values (rc_script_init)."""
    if bool(phases) == (table is not None):
        raise ValueError("script: give phases or a time table, one of the two")
    rows = []
    for i, p in enumerate(phases):
        action = p.get("action")
        if action not in ACTIONS:
            raise ValueError(f"driver[{i}].action: must be one of {', '.join(ACTIONS)}, got {action!r}")
        row = [float(ACTIONS.index(action))]
        for name in PHASE_FIELDS[1:]:
            value = p.get(name)
            if value is None and name in REQUIRED_FIELDS:
                raise ValueError(f"driver[{i}] ({action}).{name}: missing (DriverPhase always has it)")
            row.append(math.nan if value is None else float(value))
        rows.append(row)
    t, f, b = table if table is not None else ((), (), ())
    if not len(t) == len(f) == len(b):
        raise ValueError("driver_table: time_s, traction_N and brake_N must have one length")
    header = [KIND_PHASES if phases else KIND_TABLE, step_s, duration_s,
              1.0 if stop_after_last_phase else 0.0, mass_t, traction_force_max, brake_force_max,
              len(rows), len(t), len(wind)]
    body = [x for row in rows for x in row] + [x for r in zip(t, f, b) for x in r] + \
        [float(x) for w in wind for x in w]
    return np.array(header + body, dtype=float)


def steps_of(script: np.ndarray) -> int:
    """The script's number of steps, int(round(duration_s / step_s)) as drive() counts them, to
    size the arrays (the C side counts them again and checks they fit); 0 for a header it will
    refuse (it names the value then), a non-finite count or more than MAX_STEPS among them."""
    if len(script) < HEADER or not (script[1] > 0 and script[2] >= 0):
        return 0
    steps = float(script[2]) / float(script[1])
    return int(round(steps)) if math.isfinite(steps) and steps <= MAX_STEPS else 0


@dataclass
class BatchRuns:
    """What ``run_scripts`` gives: for run r, ``outputs[r, :rows[r]]`` (the chain's OUTPUTS: at
    t = 0 and after every step) and ``inputs[r, :rows[r] - 1]`` (INPUTS columns, held over each
    step); ``finished[r]``: the run ended early, its driver done and stop_after_last_phase."""
    outputs: np.ndarray
    inputs: np.ndarray
    rows: np.ndarray
    finished: np.ndarray


def run_scripts(runs: Sequence[tuple[np.ndarray, ...]], rejected: type[Exception] = ValueError
                ) -> BatchRuns:
    """Each run whole in C, on a fresh chain each. A run is six float64 arrays: the C chain's flat
    configuration (models.compiled's order, est.slope_window after it, as CompiledChain hands it
    to the core), the grade profile's distances [m] and grades [permille], the speed profile's
    distances [m] and speeds [m/s] (empty: none), and its script (``script_values``). Everything
    is checked before the first run starts (ValueError naming the run and the value); a step the
    chain rejects raises ``rejected`` (harness.run.batch passes models.chain.StepRejected) naming
    the run and the step. RuntimeError if models._batch is not compiled."""
    if _batch is None:
        raise RuntimeError("the C scenario runner (models._batch) is not compiled")
    flat = [tuple(np.ascontiguousarray(a, dtype=float) for a in run) for run in runs]
    steps = max((steps_of(run[-1]) for run in flat), default=0)
    outputs = np.empty((len(flat), steps + 1, OUTPUTS))
    inputs = np.empty((len(flat), steps, INPUTS))
    done = _batch.run(flat, outputs, inputs, rejected)
    rows = np.array([n for n, _ in done], dtype=np.int64)
    finished = np.array([f for _, f in done], dtype=bool)
    return BatchRuns(outputs, inputs, rows, finished)


# ---------------------------------------------------------------- span runs: the ATO drives

SPAN_HEADER = 5
SPAN_CAR_FIELDS = 18
"""CarTraction's fields (models/planning/span.py), in declaration order."""
SPAN_STEP_FIELDS = ("t", "span", "traction", "brake", "mode", "planned_speed", "ep_stage", "dwell",
                    "payload_change")
"""One ATO call in ``run_spans``' steps (models.ato.line.LineStep: t [s], span 0-based, the
AtoCommand's traction [N], brake [N], mode, planned_speed [m/s], ep_stage, dwell 0/1, payload
change [t]); models/core/span_driver.h RC_SPAN_STEP_FIELDS."""
SPAN_STATION_STOPS = 22
"""est.station_stops' column in the chain's outputs (span_driver.h RC_SPAN_STATION_STOPS)."""
LOG_CAP = 32
"""The log lines a span run keeps (a controller logs once per episode: a few; ~0.6 kB each, held
for every run of a call); a run that logs more says so (``SpanRuns.log_lines`` > LOG_CAP) and
its caller runs it again in Python."""


def span_script_values(*, step_s: float, duration_s: float, stop_after_last_phase: bool,
                       car: Sequence[float], tuning: Sequence[float],
                       spans: Sequence[Mapping[str, object]],
                       wind: Sequence[tuple[float, float]] = ()) -> np.ndarray:
    """The flat span script (models/core/span_driver.h) of a line: the configured car's
    SPAN_CAR_FIELDS values, the tuning's values (AtoTuning's fields in order), and ``spans``, each
    a mapping of length [m], schedule [s], stop [m], dwell_s [s], boarding_t [t],
    limit_distances [m], limit_speeds [m/s], grade_distances [m], grades [permille]; the wind
    schedule (``wind``: (time [s], speed [m/s]) in the order Scenario.wind_at reads them), the
    run's step and duration [s]. The C side checks the values (rc_span_script_init)."""
    if len(car) != SPAN_CAR_FIELDS:
        raise ValueError(f"car: expected {SPAN_CAR_FIELDS} values (CarTraction's fields), got {len(car)}")
    header = [step_s, duration_s, 1.0 if stop_after_last_phase else 0.0, len(wind), len(spans)]
    body: list[float] = [float(x) for x in car] + [float(x) for x in tuning]
    for i, sp in enumerate(spans):
        ld, lv = list(sp["limit_distances"]), list(sp["limit_speeds"])
        gd, gg = list(sp["grade_distances"]), list(sp["grades"])
        if len(ld) != len(lv) or len(gd) != len(gg):
            raise ValueError(f"span[{i}]: the limits' and the grade's distances and values must "
                             f"have one length")
        body += [float(sp[k]) for k in ("length", "schedule", "stop", "dwell_s", "boarding_t")]
        body += [len(ld), len(gd), *ld, *lv, *gd, *gg]
    body += [float(x) for w in wind for x in w]
    return np.array(header + body, dtype=float)


def span_steps_of(script: np.ndarray) -> int:
    """The span script's number of steps, as ``steps_of`` counts a script's (0 for a header the
    C side will refuse)."""
    if len(script) < SPAN_HEADER or not (script[0] > 0 and script[1] >= 0):
        return 0
    steps = float(script[1]) / float(script[0])
    return int(round(steps)) if math.isfinite(steps) and steps <= MAX_STEPS else 0


@dataclass
class SpanRuns(BatchRuns):
    """``run_spans``' result: BatchRuns' arrays, and for run r ``steps[r, :calls[r]]`` (every ATO
    call, SPAN_STEP_FIELDS columns), ``log[r]`` its log lines ("span k: ATO at t = ..."; the first
    LOG_CAP) and ``log_lines[r]`` how many it logged (more than len(log[r]): some did not fit)."""
    steps: np.ndarray = None
    calls: np.ndarray = None
    log: list = None
    log_lines: np.ndarray = None


def run_spans(runs: Sequence[tuple[np.ndarray, ...]], rejected: type[Exception] = ValueError
              ) -> SpanRuns:
    """Each span run whole in C (the ATO's line drives the chain), on a fresh chain each: a run is
    ``run_scripts``' six arrays with a span script (``span_script_values``) for the script. The
    scripts are checked before the first run starts (ValueError naming the run and the value);
    a line the ATO refuses raises ValueError naming the run and the span, a step the chain rejects
    ``rejected``. RuntimeError if models._batch is not compiled."""
    if _batch is None:
        raise RuntimeError("the C scenario runner (models._batch) is not compiled")
    flat = [tuple(np.ascontiguousarray(a, dtype=float) for a in run) for run in runs]
    steps = max((span_steps_of(run[-1]) for run in flat), default=0)
    outputs = np.empty((len(flat), steps + 1, OUTPUTS))
    inputs = np.empty((len(flat), steps, INPUTS))
    calls = np.empty((len(flat), steps, len(SPAN_STEP_FIELDS)))
    done = _batch.run_spans(flat, outputs, inputs, calls, LOG_CAP, rejected)
    return SpanRuns(outputs, inputs, np.array([d[0] for d in done], dtype=np.int64),
                    np.array([d[1] for d in done], dtype=bool), steps=calls,
                    calls=np.array([d[2] for d in done], dtype=np.int64),
                    log=[d[4] for d in done], log_lines=np.array([d[3] for d in done], dtype=np.int64))


# ---------------------------------------------------------------- metrics of a recorded run

VEHICLE_FIELDS = ("mass", "A0", "A1", "A2", "gamma", "length", "traction_force_max",
                  "traction_power_max", "brake_force_max", "adhesion_mass_fraction", "adhesion_factor")
"""A car's numbers in the C arrays, models.plant.dynamics.VehicleParams' fields in its order."""
COAST_FIELDS = ("v0", "x0", "x1", "A0", "A1", "A2", "mass", "t0")
"""One coast of ``coast_times``: start speed [m/s], start and end distance [m], the resistance's
A0, A1, A2, the mass [t], the time the coast starts in the run [s] (where its wind is read)."""


def _doubles(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=float)


def _needs_c() -> None:
    if _batch is None:
        raise RuntimeError("the C run metrics (models._batch) are not compiled")


def interval_forces(vehicle: Sequence[float], speed, mass, traction_demand, brake_demand
                    ) -> tuple[np.ndarray, np.ndarray]:
    """harness.metrics.estimation._interval_forces in C, from recorded demands: the mean applied
    traction and brake force [N] over each of the n - 1 intervals of n rows of car speed [m/s] and
    total mass [t], the demands [N] (at least n - 1 of each) held over each interval; ``vehicle``:
    the car's VEHICLE_FIELDS (its mass replaced by each interval's). ValueError naming a wrong
    array."""
    _needs_c()
    speed = _doubles(speed)
    n = max(len(speed) - 1, 0)
    f_mean, b_mean = np.empty(n), np.empty(n)
    _batch.interval_forces(_doubles(vehicle), speed, _doubles(mass), _doubles(traction_demand),
                           _doubles(brake_demand), f_mean, b_mean)
    return f_mean, b_mean


def oracle_filter(config: Sequence[float], grade: tuple, speed_profile: tuple, A: Sequence[float],
                  step: float, wind: Sequence[tuple[float, float]], time, mass, speed_meas,
                  position_meas, traction_mean, brake_mean) -> tuple[np.ndarray, np.ndarray]:
    """harness.metrics.estimation.oracle_filter's loop in C: speed [m/s] and distance [m] of the
    estimator with a frozen identifier holding the truth at each of the n rows (mass [t], the
    still-air ``A`` moved by the wind of ``wind``'s (time [s], speed [m/s]) schedule at ``time``
    [s]), fed the measurements and, over each step of ``step`` [s], the interval forces [N] (n - 1).
    ``config``: the estimator's numbers in EstimatorChain's flat layout (models/core/config.c;
    identifier frozen, est.method 0); ``grade``: (distances [m], grades [permille]);
    ``speed_profile``: (distances [m], speeds [m/s]), empty for none. ValueError naming a wrong
    array or the first bad setting."""
    _needs_c()
    time = _doubles(time)
    v_out, x_out = np.empty(len(time)), np.empty(len(time))
    _batch.oracle_filter(_doubles(config), _doubles(grade[0]), _doubles(grade[1]),
                         _doubles(speed_profile[0]), _doubles(speed_profile[1]), _doubles(A),
                         float(step), _doubles([x for w in wind for x in w]), time, _doubles(mass),
                         _doubles(speed_meas), _doubles(position_meas), _doubles(traction_mean),
                         _doubles(brake_mean), v_out, x_out)
    return v_out, x_out


def coast_segments(mode, min_rows: int) -> list[tuple[int, int]]:
    """harness.metrics.estimation.coast_segments in C: (first, last) row of each run of
    car.mode == 2 (coasting) at least ``min_rows`` long."""
    _needs_c()
    return _batch.coast_segments(_doubles(mode), int(min_rows))


def coast_times(vehicle: Sequence[float], grade: tuple, wind: Sequence[tuple[float, float]],
                coasts, h: float = 0.05, t_max: float = 3600.0) -> np.ndarray:
    """harness.metrics.estimation.coast_time of each row of ``coasts`` (COAST_FIELDS) in C: the
    time [s] to coast from x0 to x1, RK4 steps of h [s] up to t_max [s], on ``grade``
    ((distances [m], grades [permille])), the car ``vehicle`` (VEHICLE_FIELDS; its mass and A's
    each coast's) in the wind of the (time [s], speed [m/s]) schedule read at t0 + the time into
    the coast (no rows: still air); inf when the car stops short."""
    _needs_c()
    rows = _doubles(coasts).reshape(-1)
    out = np.empty(len(rows) // len(COAST_FIELDS)) if len(rows) % len(COAST_FIELDS) == 0 else np.empty(0)
    _batch.coast_times(_doubles(vehicle), _doubles(grade[0]), _doubles(grade[1]),
                       _doubles([x for w in wind for x in w]), float(h), float(t_max), rows, out)
    return out


# ---------------------------------------------------------------- the service day (studies/service_day.py)

SERVICE_DAY_FIELDS = ("steps", "step_s", "run_time_lo", "run_time_hi", "dwell_lo", "dwell_hi",
                      "target_kmh_lo", "target_kmh_hi", "traction_max_s", "short_cruise_share",
                      "short_cruise_lo", "short_cruise_hi", "long_cruise_share", "long_cruise_min_lo",
                      "long_cruise_min_hi", "decel_lo", "decel_hi", "payload_change_t", "payload_lo",
                      "payload_hi", "traction_force_max", "brake_force_max", "cruise_gain",
                      "batch_size", "car_mass_t", "first_dwell_end", "first_payload")
"""The day's numbers in models/core/service_day.h's order (RC_SD_*): [s], [km/h], [min], [m/s^2],
[t], [N], [1/s] as in studies/service_day.DayConfig; the first dwell's end [s] and the first
payload [t] are the Python driver's first draws."""
FAULT_KINDS = ("speed", "position", "zero", "hold")
"""FaultySensors' fault kinds, codes 0..3 (service_day.h RC_SD_FAULT_*)."""
SERVICE_DAY_DRAWS_PER_STEP = getattr(_batch, "SERVICE_DAY_DRAWS_PER_STEP", None)
"""The most driver draws one step takes (departure 5, arrival 1, boarding 1): service_day.h's
RC_SD_DRAWS_PER_STEP as built (None without models._batch)."""
SERVICE_DAY_EXPORT_NAMES = ("steps_done", "stops", "long_cruises", "cruise_s", "distance_m",
                            "moving_steps", "mass_min", "mass_max", "faults", "rejected")
"""The day part of the export, read by name (service_day.h RC_SD_X_*; "faults" starts
len(FAULT_KINDS) counts)."""
SERVICE_DAY_SCORE_NAMES = ("nonfinite", "has_first", "first_t", "first_output", "sigma_in",
                           "sigma_n", "se_all", "n_all", "has_rejected", "rejected_last",
                           "rejected_max", "hour_len", "n_stops", "n_status", "n_outputs")
"""An estimator's fixed part of the export, read by name (service_day.h RC_SD_S_*)."""


@dataclass(frozen=True)
class _ExportLayout:
    """service_day.h's export layout as models._batch was built with it: the fixed sizes and
    {name: index} of the day part and of an estimator's part."""
    day_fixed: int
    score_fixed: int
    day: dict
    score: dict


def _service_day_layout() -> _ExportLayout:
    """The built module's layout, checked against this module's names (RuntimeError: a stale
    build)."""
    stale = "(a stale build): setup.py build_ext --inplace"
    names = ("SERVICE_DAY_VALUES", "SERVICE_DAY_EXPORT_FIXED", "SERVICE_DAY_SCORE_FIXED",
             "SERVICE_DAY_DRAWS_PER_STEP", "SERVICE_DAY_EXPORT_OFFSETS", "SERVICE_DAY_SCORE_OFFSETS")
    missing = [name for name in names if not hasattr(_batch, name)]
    if missing:
        raise RuntimeError(f"models._batch has no {', '.join(missing)} {stale}")
    if _batch.SERVICE_DAY_VALUES != len(SERVICE_DAY_FIELDS):
        raise RuntimeError(f"models._batch takes {_batch.SERVICE_DAY_VALUES} day values, this "
                           f"module writes {len(SERVICE_DAY_FIELDS)} {stale}")
    layout = _ExportLayout(int(_batch.SERVICE_DAY_EXPORT_FIXED), int(_batch.SERVICE_DAY_SCORE_FIXED),
                           dict(_batch.SERVICE_DAY_EXPORT_OFFSETS), dict(_batch.SERVICE_DAY_SCORE_OFFSETS))
    for part, offsets, expected, fixed in (("day", layout.day, SERVICE_DAY_EXPORT_NAMES, layout.day_fixed),
                                           ("score", layout.score, SERVICE_DAY_SCORE_NAMES,
                                            layout.score_fixed)):
        if set(offsets) != set(expected) or not all(0 <= at < fixed for at in offsets.values()):
            raise RuntimeError(f"models._batch's service day export ({part} part) {offsets} does not "
                               f"hold this module's names {expected} within {fixed} values {stale}")
    if layout.day["rejected"] != layout.day["faults"] + len(FAULT_KINDS):
        raise RuntimeError(f"models._batch's service day export counts faults of "
                           f"{layout.day['rejected'] - layout.day['faults']} kinds, this module "
                           f"{len(FAULT_KINDS)} {stale}")
    return layout


@dataclass
class ServiceDayScore:
    """One estimator's accumulators (studies/service_day._Score's, as numbers): non-finite values
    per output index, the first (t [s], output index), 3-sigma hits and samples, squared speed
    errors [(m/s)^2] over all samples and per hour (moving), the order the outputs first went
    non-finite (first_seen, where nonfinite_by_output counts), rejected last/max (None: never
    seen), est.status value -> samples in first-seen order, stop errors [-]."""
    nonfinite: int
    nonfinite_by_output: list
    first_seen: list
    first: tuple | None
    sigma_in: int
    sigma_n: int
    se_all: float
    n_all: int
    hour_se: list
    hour_n: list
    rejected_last: float | None
    rejected_max: float | None
    status: list
    stop_errors: list


@dataclass
class ServiceDayFigures:
    """What ServiceDay.export gives: the steps done, the driver's counts, the distance [m], the
    moving steps, the total mass range [t], the fault counts by FAULT_KINDS, the estimator steps
    redone with the held sample, and the clean and faulty ServiceDayScore."""
    steps_done: int
    stops: int
    long_cruises: int
    cruise_s: float
    distance_m: float
    moving_steps: int
    mass_min: float
    mass_max: float
    faults: dict
    rejected: int
    clean: ServiceDayScore
    faulty: ServiceDayScore


def _score_of(x: np.ndarray, at: int, layout: _ExportLayout) -> tuple[ServiceDayScore, int]:
    """The estimator's part of the export starting at ``at`` and where the next starts."""
    f = {name: x[at + i] for name, i in layout.score.items()}
    n_out, hours, n_status, n_stops = (int(f[n]) for n in ("n_outputs", "hour_len", "n_status", "n_stops"))
    p = at + layout.score_fixed
    by_output = [int(c) for c in x[p:p + n_out]]
    first_seen = [int(c) for c in x[p + n_out:p + 2 * n_out]]
    p += 2 * n_out
    hour_se = [float(v) for v in x[p:p + hours]]
    hour_n = [int(v) for v in x[p + hours:p + 2 * hours]]
    p += 2 * hours
    status = [(float(x[p + 2 * i]), int(x[p + 2 * i + 1])) for i in range(n_status)]
    p += 2 * n_status
    stops = [float(v) for v in x[p:p + n_stops]]
    p += n_stops
    has_rej = f["has_rejected"] != 0.0
    score = ServiceDayScore(
        nonfinite=int(f["nonfinite"]), nonfinite_by_output=by_output, first_seen=first_seen,
        first=(float(f["first_t"]), int(f["first_output"])) if f["has_first"] != 0.0 else None,
        sigma_in=int(f["sigma_in"]), sigma_n=int(f["sigma_n"]), se_all=float(f["se_all"]),
        n_all=int(f["n_all"]), hour_se=hour_se, hour_n=hour_n,
        rejected_last=float(f["rejected_last"]) if has_rej else None,
        rejected_max=float(f["rejected_max"]) if has_rej else None, status=status, stop_errors=stops)
    return score, p


class ServiceDay:
    """studies/service_day.py's run_day loop in C (models/core/service_day.h), run in blocks:
    ``run(steps, draws)`` the next steps with the driver's numpy Generator.random() doubles
    (returns how many it took; a step may take SERVICE_DAY_DRAWS_PER_STEP, and a run refuses
    with ValueError naming the step before one with fewer left: never past the array),
    ``export()`` the figures so far (ServiceDayFigures).

    ``day``: SERVICE_DAY_FIELDS' values; ``plant``: the C chain's flat configuration (as
    CompiledChain hands it to the core, est.slope_window after it); ``est``: the EstimatorChain's
    (as CompiledEstimatorChain's); ``grade``: (distances [m], grades [permille]); ``wind``:
    [(from time [s], wind [m/s])]; ``faults``: {step: (kind in FAULT_KINDS, value)} (FaultySensors'
    schedule); ``rejected``: the class a chain's refused step raises (StepRejected). The chains'
    configurations are taken as validated (open_chain does). RuntimeError if models._batch is not
    compiled or is a stale build; ValueError naming a bad value.

    A refusal in the middle of a step (``rejected`` for a plant's StepRejected or the retry's,
    ArithmeticError for RC_MATH where Python raises, ValueError otherwise) ends the day: every
    later ``run`` raises ValueError "the day stopped at step k: ...". A short supply of draws
    does not (nothing moved: more draws and the day goes on)."""

    def __init__(self, day: Sequence[float], plant: Sequence[float], est: Sequence[float],
                 grade: tuple, wind: Sequence[tuple[float, float]], faults: Mapping[int, tuple],
                 rejected: type[Exception] = ValueError):
        if _batch is None:
            raise RuntimeError("the C scenario runner (models._batch) is not compiled")
        self._layout = _service_day_layout()
        if len(day) != len(SERVICE_DAY_FIELDS):
            raise ValueError(f"service day: expected {len(SERVICE_DAY_FIELDS)} day values "
                             f"{SERVICE_DAY_FIELDS}, got {len(day)}")
        rows = []
        for k in sorted(faults):
            kind, value = faults[k]
            if kind not in FAULT_KINDS:
                raise ValueError(f"service day: fault at step {k}: kind must be one of "
                                 f"{', '.join(FAULT_KINDS)}, got {kind!r}")
            rows += [float(k), float(FAULT_KINDS.index(kind)), float(value)]
        self._day = _batch.service_day(_doubles(day), _doubles(plant), _doubles(est),
                                       _doubles(grade[0]), _doubles(grade[1]),
                                       _doubles([x for w in wind for x in w]), _doubles(rows), rejected)

    def run(self, steps: int, draws: np.ndarray) -> int:
        """The next ``steps`` steps; returns the draws taken from the front of ``draws``.
        RuntimeError if another thread's run is under way (export() too)."""
        return self._day.run(int(steps), _doubles(draws))

    def export(self) -> ServiceDayFigures:
        """The figures so far."""
        layout = self._layout
        x = np.frombuffer(self._day.export(), dtype=float)
        clean, at = _score_of(x, layout.day_fixed, layout)
        faulty, _ = _score_of(x, at, layout)
        d = {name: x[i] for name, i in layout.day.items()}
        faults = layout.day["faults"]
        return ServiceDayFigures(
            steps_done=int(d["steps_done"]), stops=int(d["stops"]), long_cruises=int(d["long_cruises"]),
            cruise_s=float(d["cruise_s"]), distance_m=float(d["distance_m"]),
            moving_steps=int(d["moving_steps"]), mass_min=float(d["mass_min"]),
            mass_max=float(d["mass_max"]),
            faults={kind: int(x[faults + i]) for i, kind in enumerate(FAULT_KINDS)},
            rejected=int(d["rejected"]), clean=clean, faulty=faulty)
