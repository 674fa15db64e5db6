"""Metrics of a run, as functions of result arrays. Units in each docstring.

Input arrays come from ``RunResult`` (one value per communication step); the car's
configuration and track profiles from a ``fmu_src.adapter.ChainSetup`` (the scenario's, resolved
once when it was loaded: ``result.setup.chain``). Nothing here reads or writes files, and
nothing runs the model but ``oracle_filter`` (the same filter knowing the truth, once a run) and
``coast_time_errors`` (each coast re-run with the identified resistance).

Those two run in C when the C core runs in this process (models.batch, models/core/run_metrics.c:
compiled, and RAILCAR_PURE_PYTHON not set; ``c_metrics``): 0.4 ms instead of ~120 ms for a
station_day run (issue 31). The Python code below is the reference they equal bit for bit
(tests/model_tests/core/test_core_run_metrics.py), and what runs without the C core.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def rmse(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Root-mean-square error, in the unit of the arrays."""
    e = np.asarray(estimate) - np.asarray(truth)
    if mask is not None:
        e = e[mask]
    return float(np.sqrt(np.mean(e * e))) if e.size else float("nan")


def stop_indices(speed: np.ndarray) -> list[int]:
    """Row at which the car comes to rest after moving (speed [m/s]): the arrival at each stop.

    Metrics "at a stop" are taken there, before passengers board and change the mass.
    """
    v = np.asarray(speed)
    return (np.flatnonzero((v[1:] <= 0.0) & (v[:-1] > 0.0)) + 1).tolist()


def time_to_stay_within(time: np.ndarray, rel_err: np.ndarray, bound: float,
                        start: int = 0, end: int | None = None) -> float:
    """First time [s] from which |rel_err| <= bound until ``end``; nan if never."""
    seg = np.abs(rel_err[start:end]) > bound
    if not seg.any():
        return float(time[start])
    last_bad = start + int(np.nonzero(seg)[0][-1])
    stop = len(time) if end is None else end
    return float(time[last_bad + 1]) if last_bad + 1 < stop else float("nan")


def w0(v: np.ndarray, a0: float, a1: float, a2: float) -> np.ndarray:
    """Specific main resistance eq. (1) [N/kN] at speeds v [m/s] (still air)."""
    return a0 + a1 * v + a2 * v * v


def w0_relative_rms_error(speeds: np.ndarray, est: tuple, true: tuple) -> float:
    """RMS of w0_est - w0_true over the travelled speed range, relative to RMS of w0_true [-].

    The range is [min, max] of the speeds [m/s] while moving, sampled at 100 points.
    """
    moving = speeds[speeds > 0.0]
    if moving.size == 0:
        return float("nan")
    v = np.linspace(moving.min(), moving.max(), 100)
    wt = w0(v, *true)
    return float(np.sqrt(np.mean((w0(v, *est) - wt) ** 2)) / np.sqrt(np.mean(wt ** 2)))


def normalised_error_squared(estimate: np.ndarray, truth: np.ndarray, std: np.ndarray,
                             mask: np.ndarray | None = None) -> float:
    """Mean of ((estimate - truth) / std)^2 over samples with std > 0 [-]; ~1 for an honest filter."""
    std = np.asarray(std)
    ok = std > 0
    if mask is not None:
        ok &= mask
    e = (np.asarray(estimate)[ok] - np.asarray(truth)[ok]) / std[ok]
    return float(np.mean(e * e)) if e.size else float("nan")


@dataclass
class RunSummary:
    """Truth vs estimates for one RailCar run (units in the field comments)."""
    scenario: str
    duration_s: float
    stops: int
    mass_true_t: float                 # [t] at the end
    mass_est_t: float                  # [t] at the end
    mass_std_t: float                  # [t]
    mass_error_pct: float              # [%] at the end
    mass_errors_at_stops_pct: list     # [%] at each stop
    mass_time_within_1pct_s: list      # [s] after each departure until |error| <= 1 % to that stop
    A_true: tuple                      # (A0, A1, A2)
    A_est: tuple
    w0_rel_rms_error: float            # [-] over the travelled speed range
    coast_time_errors_s: list          # [s] predicted - actual time of each coast, identified w0
    speed_rmse_sensor: float           # [m/s]
    speed_rmse_filter: float           # [m/s]
    speed_rmse_oracle: float           # [m/s] the same filter knowing the true parameters
    position_rmse_sensor: float        # [m]
    position_rmse_filter: float        # [m]
    position_rmse_oracle: float        # [m]
    speed_nees: float                  # [-]
    position_nees: float               # [-]


def _segments(speed: np.ndarray) -> list[tuple[int, int]]:
    """(departure row, arrival row) of each run that ends at rest."""
    v = np.asarray(speed)
    stops = stop_indices(v)
    still = np.flatnonzero(~(v > 0.0))     # rows not moving; the departure follows the last before k - 1
    before = np.searchsorted(still, np.asarray(stops, dtype=np.int64) - 1) - 1
    out = []
    for k, j in zip(stops, before.tolist()):
        dep = int(still[j]) + 1 if j >= 0 else 0
        out.append((max(dep - 1, 0), k))
    return out


def summarise(result, true_A: tuple | None = None, setup=None) -> RunSummary:
    """Compute the summary of a ``RunResult`` of RailCar (true A's default to the scenario's);
    ``setup``: the run's ChainSetup (default: the scenario's, resolved at loading). The
    estimates are the FMU run's outputs; the one model run here is the oracle filter."""
    s = result.scenario
    setup = s.chain_setup() if setup is None else setup
    if true_A is None:   # the coefficients at the end, moved by the wind then blowing
        car = setup.config.vehicle
        A = (car.A0, car.A1, car.A2)
        true_A = tuple(float(x) for x in true_theta(1.0, A, s.wind_at(float(result.time[-1])))[1:])
    t = result.time
    v = result["car.speed"]
    mass = result["car.total_mass"]
    est_mass = result["est.mass"]
    rel = (est_mass - mass) / mass
    segments = _segments(v)
    moving = v > 0.0
    est_A = (float(result["est.A0"][-1]), float(result["est.A1"][-1]), float(result["est.A2"][-1]))
    oracle = oracle_filter(result, setup)
    nan = float("nan")

    coast_errors = coast_time_errors(
        result, lambda last: (float(result["est.A0"][last]), float(result["est.A1"][last]),
                              float(result["est.A2"][last])), setup=setup)

    return RunSummary(
        scenario=s.name, duration_s=float(t[-1]), stops=len(segments),
        mass_true_t=float(mass[-1]), mass_est_t=float(est_mass[-1]),
        mass_std_t=float(result["est.mass_std"][-1]), mass_error_pct=100.0 * float(rel[-1]),
        mass_errors_at_stops_pct=[100.0 * float(rel[k]) for _, k in segments],
        mass_time_within_1pct_s=[time_to_stay_within(t, rel, 0.01, d, k + 1) - float(t[d])
                                 for d, k in segments],
        A_true=tuple(true_A), A_est=est_A,
        w0_rel_rms_error=w0_relative_rms_error(v, est_A, true_A),
        coast_time_errors_s=coast_errors,
        speed_rmse_sensor=rmse(result["sensor.speed"], v),
        speed_rmse_filter=rmse(result["filter.speed"], v),
        speed_rmse_oracle=rmse(oracle[0], v) if oracle else nan,
        position_rmse_sensor=rmse(result["sensor.position"], result["car.position"]),
        position_rmse_filter=rmse(result["filter.position"], result["car.position"]),
        position_rmse_oracle=rmse(oracle[1], result["car.position"]) if oracle else nan,
        speed_nees=normalised_error_squared(result["filter.speed"], v, result["filter.speed_std"], moving),
        position_nees=normalised_error_squared(result["filter.position"], result["car.position"],
                                               result["filter.position_std"], moving),
    )


def format_summary(s: RunSummary) -> str:
    """A plain-text table of a summary, for the terminal."""
    def f(x, fmt="{:.4g}"):
        return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else fmt.format(x)

    rows = [
        ("scenario", s.scenario, ""),
        ("duration", f(s.duration_s, "{:.1f}"), "s"),
        ("station stops", str(s.stops), ""),
        ("mass: true / estimated", f"{s.mass_true_t:.3f} / {s.mass_est_t:.3f} +- {s.mass_std_t:.3f}", "t"),
        ("mass error at the end", f(s.mass_error_pct, "{:+.3f}"), "%"),
        ("mass error at each stop", ", ".join(f"{e:+.3f}" for e in s.mass_errors_at_stops_pct) or "n/a", "%"),
        ("mass within 1 % after departure", ", ".join(f(x, "{:.1f}") for x in s.mass_time_within_1pct_s) or "n/a", "s"),
        ("A0 true / est", f"{s.A_true[0]:.4g} / {s.A_est[0]:.4g}", "N/kN"),
        ("A1 true / est", f"{s.A_true[1]:.4g} / {s.A_est[1]:.4g}", "N/kN/(m/s)"),
        ("A2 true / est", f"{s.A_true[2]:.4g} / {s.A_est[2]:.4g}", "N/kN/(m/s)²"),
        ("w0(V) relative RMS error", f(100 * s.w0_rel_rms_error, "{:.1f}"), "%"),
        ("coast run-time prediction error", ", ".join(f"{e:+.2f}" for e in s.coast_time_errors_s) or "n/a", "s"),
        ("speed RMSE sensor / filter / oracle", f"{s.speed_rmse_sensor:.4f} / {s.speed_rmse_filter:.4f} / "
         f"{f(s.speed_rmse_oracle, '{:.4f}')} (filter/sensor {s.speed_rmse_filter / s.speed_rmse_sensor:.2f})", "m/s"),
        ("distance RMSE sensor / filter / oracle", f"{s.position_rmse_sensor:.3f} / {s.position_rmse_filter:.3f} / "
         f"{f(s.position_rmse_oracle, '{:.3f}')} (filter/sensor {s.position_rmse_filter / s.position_rmse_sensor:.2f})", "m"),
        ("filter NEES speed / distance", f"{s.speed_nees:.2f} / {s.position_nees:.2f}", "-"),
    ]
    w = max(len(r[0]) for r in rows)
    return "\n".join(f"  {name:<{w}}  {val} {unit}".rstrip() for name, val, unit in rows)


A_COVARIANCE_COLUMNS = {(0, 1): "est.cov_A0_A1", (0, 2): "est.cov_A0_A2", (1, 2): "est.cov_A1_A2"}
"""The FMU outputs of the A's covariances off the diagonal [(N/kN)^2 / (m/s)^(i+j)]; the
diagonal is est.A0_std^2, est.A1_std^2, est.A2_std^2."""


def resistance_covariance(result, row: int = -1) -> tuple[np.ndarray, bool]:
    """(covariance 3x3 of (A0, A1, A2) at ``row``, full): the stds on the diagonal and the
    est.cov_* outputs off it when the run recorded them (``full`` True). The A's are strongly
    correlated (A0 with A2 about -0.8 at the end of the default scenario), so without those
    columns (an FMU built before they existed) the diagonal alone overstates w0's uncertainty
    at speed; ``full`` False says so."""
    sd = [float(result[f"est.A{j}_std"][row]) for j in range(3)]
    cov = np.diag(np.square(sd))
    full = all(name in result.signals for name in A_COVARIANCE_COLUMNS.values())
    if full:
        for (i, j), name in A_COVARIANCE_COLUMNS.items():
            cov[i, j] = cov[j, i] = float(result[name][row])
    return cov, full


# ---------------------------------------------------------------- oracle filter and coast times

def c_metrics():
    """models.batch when the C twins of the oracle filter and the coast times run in this
    process (models._batch compiled, the C core enabled: models.compiled.enabled, so
    RAILCAR_PURE_PYTHON forces the Python here as it does for the chains), else None."""
    from models import batch
    from models.compiled import enabled
    return batch if batch.available() and enabled() else None


def _vehicle_values(p) -> tuple:
    """A models.plant.dynamics.VehicleParams as the C arrays hold a car (models.batch.VEHICLE_FIELDS,
    the dataclass's field order: test_core_run_metrics holds them equal)."""
    from models.compiled import dataclass_values
    return tuple(dataclass_values(p))


def true_theta(mass_t: float, A: tuple, wind: float) -> np.ndarray:
    """Theta = (1/(Pg), A0', A1', A2) of eq. (2) for a mass [t], still-air A's and wind [m/s].

    Wind moves the coefficients (docs/model.md, Forces on the car): A0' = A0 + A2 Vw^2, A1' = A1 + 2 A2 Vw.
    """
    from models.units import G
    a0, a1, a2 = A
    return np.array([1.0 / (G * mass_t), a0 + a2 * wind * wind, a1 + 2.0 * a2 * wind, a2])


def oracle_filter(result, setup) -> tuple[np.ndarray, np.ndarray] | None:
    """Speed [m/s] and distance [m] of the same filter fed with the true parameters.

    Replays the recorded measurements and applied forces through the models' estimator with a
    frozen identifier holding the truth (mass per row, A's moved by the wind, sigma^2 =
    psd * dt); the car, the sensors and the profiles are the run's ``setup`` (ChainSetup). Needs
    one sample per row (communication step = sensor.sample_period); else None.

    The forces over [t_k, t_k+1] are what the chain's own estimator gets (the applied impulse
    over the interval): the plant's force law with the demands held over that interval
    (``result.inputs``), averaged over the interval's true end speeds. The forces *output* at
    t_k were applied with the previous interval's demand: their trapezoid put half of every
    demand change into the wrong interval (0.07 m/s of prediction error at a 40 kN cut-off),
    which let the learning filter beat this "oracle" on station_day. Without recorded
    inputs, that trapezoid is the fallback.

    With the C core (``c_metrics``) the forces and the filter's loop run in C
    (models.batch.interval_forces, oracle_filter): the same arrays bit for bit, ~200x faster.
    """
    from models.estimation.online import OnlineEstimator
    from models.filtering.motion_filter import FilterConfig
    from models.estimation.identification import IdentifierConfig

    s = result.scenario
    h = s.step_s
    cfg = setup.config
    if abs(h - cfg.sample_period) > 1e-12:
        return None
    car, sensors = cfg.vehicle, cfg.filter
    A = (car.A0, car.A1, car.A2)
    ident = IdentifierConfig(dt=h, frozen=True, gamma=car.gamma, mass_initial=car.mass,
                             sigma2_initial=max(cfg.process_noise_psd * h, 1e-12))
    filt = FilterConfig(dt=h, speed_std=sensors.speed_std, position_std=sensors.position_std,
                        position_std_rel=sensors.position_std_rel,
                        speed_std_rel=sensors.speed_std_rel, gamma=car.gamma,
                        kind=sensors.kind, length=car.length)
    F, B = _interval_forces(result, car)
    mass = result["car.total_mass"]
    core = c_metrics()
    if core is not None:
        from models.compiled import estimator_chain_values
        sp = setup.speed
        config = estimator_chain_values(ident, filt, cfg.station, cfg.track)
        return core.oracle_filter(config, (setup.grade.distances, setup.grade.grades),
                                  (sp.distances, sp.speeds) if sp is not None else ((), ()), A, h,
                                  [(w.time_s, w.speed_mps) for w in s.wind], result.time, mass,
                                  result["sensor.speed"], result["sensor.position"], F, B)
    est = OnlineEstimator(ident, filt, cfg.station, setup.grade, setup.speed)
    n = len(result.time)
    v_out, x_out = np.empty(n), np.empty(n)
    for k in range(n):
        est.ident.theta = true_theta(mass[k], A, s.wind_at(result.time[k]))
        est.measure(result["sensor.speed"][k], result["sensor.position"][k])
        v_out[k], x_out[k] = est.filter.speed, est.filter.position
        if k + 1 < n:
            est.propagate(F[k], B[k], h)
    return v_out, x_out


def _interval_forces(result, vehicle) -> tuple[np.ndarray, np.ndarray]:
    """Mean applied traction and brake force [N] over each interval [t_k, t_k+1] (see
    oracle_filter): the plant's force law for the car ``vehicle`` (models.plant.dynamics.VehicleParams)
    with the interval's demands at both end speeds."""
    from dataclasses import replace

    from models.plant.dynamics import applied_forces
    F, B = result["car.traction_force"], result["car.brake_force"]
    inputs = getattr(result, "inputs", None) or {}
    if "traction_force_demand" not in inputs or len(inputs["traction_force_demand"]) < len(F) - 1:
        return 0.5 * (F[:-1] + F[1:]), 0.5 * (B[:-1] + B[1:])
    v, mass = result["car.speed"], result["car.total_mass"]
    td, bd = inputs["traction_force_demand"], inputs["brake_force_demand"]
    core = c_metrics()
    if core is not None:
        return core.interval_forces(_vehicle_values(vehicle), v, mass, td, bd)
    f_mean, b_mean = np.empty(len(F) - 1), np.empty(len(F) - 1)
    for k in range(len(F) - 1):
        p = replace(vehicle, mass=float(mass[k + 1]))       # payload of this interval
        f0, b0 = applied_forces(float(v[k]), float(td[k]), float(bd[k]), p)
        f1, b1 = applied_forces(float(v[k + 1]), float(td[k]), float(bd[k]), p)
        f_mean[k], b_mean[k] = 0.5 * (f0 + f1), 0.5 * (b0 + b1)
    return f_mean, b_mean


def coast_segments(mode: np.ndarray, min_rows: int) -> list[tuple[int, int]]:
    """(first, last) row of each run of coasting (car.mode == 2) at least ``min_rows`` long."""
    out, start = [], None
    for k, m in enumerate(list(mode) + [-1]):
        if m == 2 and start is None:
            start = k
        elif m != 2 and start is not None:
            if k - start >= min_rows:
                out.append((start, k - 1))
            start = None
    return out


def coast_time_errors(result, A_at, still_air: bool = False, setup=None) -> list[float]:
    """Predicted - actual time [s] of each coast of at least 10 s in a RailCar ``RunResult``,
    re-run with the resistance ``A_at(last)`` gives for the coast ending at row ``last`` (seed
    003's measure) on the run's grade with its car's gamma and length (``setup``, the run's
    ChainSetup; default: the scenario's, resolved at loading).

    Identified A's are the coefficients of eq. (2) as the car met them, the wind included
    (A0' = A0 + A2 Vw^2, ...): the coast is re-run in still air. With ``still_air`` the A's are
    the car's own (the truth) and the coast is re-run in the scenario's wind as it blows over
    the coast, changes included. With the C core (``c_metrics``) the coasts are found and re-run
    in C (_coast_time_errors_c): the same numbers bit for bit.
    """
    s = result.scenario
    t, v, mass = result.time, result["car.speed"], result["car.total_mass"]
    min_rows = int(round(10.0 / s.step_s))
    core = c_metrics()
    if core is not None:
        return _coast_time_errors_c(core, result, A_at, still_air, setup, min_rows)
    out = []
    for first, last in coast_segments(result["car.mode"], min_rows):
        setup = s.chain_setup() if setup is None else setup
        car = setup.config.vehicle
        x0, x1 = float(result["car.position"][first]), float(result["car.position"][last])
        t0 = float(t[first])
        wind = (lambda tc, t0=t0: s.wind_at(t0 + tc)) if still_air else 0.0
        predicted = coast_time(float(v[first]), x0, x1, A_at(last), float(mass[first]), car.gamma,
                               car.length, setup.grade, wind)
        out.append(predicted - float(t[last] - t[first]))
    return out


def _coast_time_errors_c(core, result, A_at, still_air: bool, setup, min_rows: int) -> list[float]:
    """coast_time_errors with the segments and the re-runs in C (``core``: models.batch): the
    same numbers, one call for all the run's coasts."""
    from models.plant.dynamics import VehicleParams
    segments = core.coast_segments(result["car.mode"], min_rows)
    if not segments:
        return []
    s = result.scenario
    setup = s.chain_setup() if setup is None else setup
    car = setup.config.vehicle
    t, v, x, mass = result.time, result["car.speed"], result["car.position"], result["car.total_mass"]
    rows = []
    for first, last in segments:
        A = A_at(last)
        rows.append((float(v[first]), float(x[first]), float(x[last]), float(A[0]), float(A[1]),
                     float(A[2]), float(mass[first]), float(t[first])))
    wind = [(w.time_s, w.speed_mps) for w in s.wind] if still_air else []     # []: still air
    predicted = core.coast_times(_vehicle_values(VehicleParams(gamma=car.gamma, length=car.length)),
                                 (setup.grade.distances, setup.grade.grades), wind, rows)
    return [float(p) - float(t[last] - t[first]) for p, (first, last) in zip(predicted, segments)]


def coast_time(v0: float, x0: float, x1: float, A: tuple, mass_t: float, gamma: float, length: float,
               grade_profile, wind=0.0, h: float = 0.05, t_max: float = 3600.0) -> float:
    """Time [s] to coast from x0 to x1 [m] starting at v0 [m/s] with resistance A (eq. (1)).

    Meleshin's (2011) measure of identified resistance: re-run the coast with it and compare times.
    ``wind`` [m/s] is a constant or a function of the time since the coast's start [s] (held
    over each RK4 step of h [s]).
    """
    wind_at = wind if callable(wind) else (lambda _t, w=float(wind): w)
    from models.plant.dynamics import VehicleParams, rk4_step
    p = VehicleParams(mass=mass_t, A0=A[0], A1=A[1], A2=A[2], gamma=gamma, length=length)
    v, x, t = v0, x0, 0.0
    while x < x1 and t < t_max:
        v_new, x_new = rk4_step(v, x, h, 0.0, 0.0, wind_at(t), p, grade_profile)
        if x_new >= x1:
            return t + h * (x1 - x) / (x_new - x)
        if v_new <= 0.0:
            return float("inf")
        v, x, t = v_new, x_new, t + h
    return float("inf")
