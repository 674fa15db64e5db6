"""The one table of FMU variables: name, causality, variability, type, unit, start, bounds, doc.

It drives the slaves' registration (``adapter.py``), every modelDescription.xml (written by
``fmu_src/build/model_description.py``), the native C tables, and docs/variables.md. The names,
units and value references are a contract with our users' models: they never change
(tests/fmu_tests/value_references.json freezes them; only an appended row may add to it).
"""
from __future__ import annotations

from dataclasses import dataclass

RAILCAR, ESTIMATOR, ATO = "RailCar", "RailCarEstimator", "AtoController"
BOTH = (RAILCAR, ESTIMATOR)
FMUS = (RAILCAR, ESTIMATOR, ATO)


@dataclass(frozen=True)
class Var:
    name: str
    causality: str          # parameter | input | output
    type: str               # Real | Integer | Boolean | String
    unit: str | None
    start: object
    description: str
    fmus: tuple[str, ...] = BOTH
    min: float | None = None
    max: float | None = None
    initial: str = "exact"  # outputs: exact (start is the value after initialisation) or
    #                         calculated (computed from the parameters at initialisation)

    @property
    def variability(self) -> str:
        if self.causality == "parameter":
            return "fixed"
        if self.type == "Real" and not (self.causality == "output" and ATO in self.fmus):
            return "continuous"
        return "discrete"   # the controller's outputs change at communication points only


# (name, SI base-unit exponents, factor): factor converts the unit into SI (FMI 2.0 BaseUnit)
UNITS: dict[str, tuple[dict[str, int], float]] = {
    "N": ({"kg": 1, "m": 1, "s": -2}, 1.0),
    "W": ({"kg": 1, "m": 2, "s": -3}, 1.0),
    "t": ({"kg": 1}, 1000.0),
    "m": ({"m": 1}, 1.0),
    "s": ({"s": 1}, 1.0),
    "m/s": ({"m": 1, "s": -1}, 1.0),
    "m/s2": ({"m": 1, "s": -2}, 1.0),
    "m2/s2": ({"m": 2, "s": -2}, 1.0),
    "m2/s3": ({"m": 2, "s": -3}, 1.0),
    "permille": ({}, 1e-3),
    "N/kN": ({}, 1e-3),
    "N/kN/(m/s)": ({"m": -1, "s": 1}, 1e-3),
    "N/kN/(m/s)2": ({"m": -2, "s": 2}, 1e-3),
    # products of two A's units: the A's covariances
    "(N/kN)2/(m/s)": ({"m": -1, "s": 1}, 1e-6),
    "(N/kN)2/(m/s)2": ({"m": -2, "s": 2}, 1e-6),
    "(N/kN)2/(m/s)3": ({"m": -3, "s": 3}, 1e-6),
    "1/s": ({"s": -1}, 1.0),
    "1/s2": ({"s": -2}, 1.0),
    "1": ({}, 1.0),
}

R, RE = (RAILCAR,), (ESTIMATOR,)

VARIABLES: tuple[Var, ...] = (
    # ---------------------------------------------------------------- RailCar inputs
    Var("traction_force_demand", "input", "Real", "N", 0.0, "traction force asked for, >= 0", R, min=0.0),
    Var("brake_force_demand", "input", "Real", "N", 0.0, "brake force asked for, >= 0", R, min=0.0),
    Var("wind_speed", "input", "Real", "m/s", 0.0, "wind along the track, headwind > 0", R),
    Var("car.payload", "input", "Real", "t", 0.0, "passengers boarded on top of car.mass (changes at station stops)", R),
    # ---------------------------------------------------------------- RailCarEstimator inputs
    Var("traction_force", "input", "Real", "N", 0.0, "measured traction force, >= 0", RE, min=0.0),
    Var("brake_force", "input", "Real", "N", 0.0, "measured brake force, >= 0", RE, min=0.0),
    Var("sensor.speed", "input", "Real", "m/s", 0.0, "measured speed", RE),
    Var("sensor.position", "input", "Real", "m", 0.0, "measured distance from the previous station", RE),
    Var("sensor.track_speed", "input", "Real", "m/s", 0.0, "speed from two track sensors (taken when sensor.track_time is new)", RE, min=0.0),
    Var("sensor.track_time", "input", "Real", "s", 0.0, "time stamp of that speed (second sensor's passage)", RE),
    # ---------------------------------------------------------------- true car (RailCar)
    Var("car.mass", "parameter", "Real", "t", 30.0, "true mass with passengers", R, min=0.0),
    Var("car.A0", "parameter", "Real", "N/kN", 0.89, "true main-resistance coefficient A0, eq. (1)", R, min=0.0),
    Var("car.A1", "parameter", "Real", "N/kN/(m/s)", 0.0288, "true main-resistance coefficient A1, eq. (1)", R, min=0.0),
    Var("car.A2", "parameter", "Real", "N/kN/(m/s)2", 0.010498, "true main-resistance coefficient A2 (air drag), eq. (1)", R, min=0.0),
    Var("car.gamma", "parameter", "Real", "1", 0.0, "rotating-mass factor: acceleration divided by 1 + gamma", R, min=0.0),
    Var("car.traction_force_max", "parameter", "Real", "N", 40e3, "traction force limit (constant-force zone)", R, min=0.0),
    Var("car.traction_power_max", "parameter", "Real", "W", 400e3, "traction power limit (constant-power zone)", R, min=0.0),
    Var("car.brake_force_max", "parameter", "Real", "N", 45e3, "brake force limit (emergency)", R, min=0.0),
    Var("car.adhesion_mass_fraction", "parameter", "Real", "1", 1.0, "share of the mass on driven axles", R, min=0.0, max=1.0),
    Var("car.adhesion_factor", "parameter", "Real", "1", 1.0, "scales the dry-rail adhesion coefficient (Curtius-Kniffler); wet rail ~0.5", R, min=0.0),
    Var("car.process_noise_psd", "parameter", "Real", "m2/s3", 1e-4, "process noise: white acceleration noise density; sigma^2 per step dt = psd * dt", R, min=0.0),
    Var("car.initial_speed", "parameter", "Real", "m/s", 0.0, "speed at the start (at most 200 m/s); > 0 starts the car moving mid-line", R, min=0.0, max=200.0),
    Var("car.initial_position", "parameter", "Real", "m", 0.0, "distance from the previous station at the start", R, min=0.0),
    Var("solver.step", "parameter", "Real", "s", 0.05, "plant's fixed internal integration step (RK4)", R, min=0.0),
    Var("sensor.sample_period", "parameter", "Real", "s", 0.1, "sensor sampling period; the estimator runs at this period", R, min=0.0),
    Var("sensor.track_spacing", "parameter", "Real", "m", 0.0, "a pair of track sensors every this many metres from each station; 0 = none", R, min=0.0),
    Var("seed", "parameter", "Integer", None, 1, "random seed; same seed, same inputs => bit-identical outputs", R),
    # ---------------------------------------------------------------- both: sensors, track, estimator settings
    Var("sensor.speed_std", "parameter", "Real", "m/s", 0.05, "speed measurement noise standard deviation", BOTH, min=0.0),
    Var("sensor.position_std", "parameter", "Real", "m", 1.0, "distance measurement noise standard deviation", BOTH, min=0.0),
    Var("sensor.position_std_rel", "parameter", "Real", "1", 0.0, "plus this share of the distance (odometry drift): std = position_std + rel * distance", BOTH, min=0.0),
    Var("sensor.track_base", "parameter", "Real", "m", 5.0, "two point track sensors (Boynik et al., n.d.): distance between the sensors of a pair", BOTH, min=0.0),
    Var("sensor.track_resolution", "parameter", "Real", "s", 1e-3, "track sensors: timer resolution", BOTH, min=0.0),
    Var("sensor.track_jitter", "parameter", "Real", "s", 0.0, "track sensors: detection-time noise standard deviation", BOTH, min=0.0),
    Var("car.length", "parameter", "Real", "m", 0.0, "car/train length over which the grade is averaged; 0 = point mass", BOTH, min=0.0),
    Var("track.grade_profile", "parameter", "String", None, "", "CSV 'distance_m,grade_permille', grade piecewise constant from each distance; empty = level track"),
    Var("track.speed_profile", "parameter", "String", None, "", "CSV 'distance_m,speed_mps', reference speed V_zad(X), piecewise linear; needed by the linearised filter"),
    Var("track.station_dwell", "parameter", "Real", "s", 20.0, "a standstill at least this long is a station stop", BOTH, min=0.0),
    Var("est.batch_size", "parameter", "Integer", None, 50, "N, samples of the first batch least-squares solve (4 to 100000: held in memory until solved)", BOTH),
    Var("est.method", "parameter", "Integer", None, 2, "0 the paper's recursive LS; 1 LS plus a filter-error refit of each run at the next station stop, the A's carried over between runs; 2 LS on speed and acceleration from Sidorenko's (1997) least-squares differentiation (est.slope_window); 3 LS for the mass, Meleshin's (2011) coasting EKF for the A's", BOTH),
    Var("est.slope_window", "parameter", "Integer", None, 10, "est.method 2: samples of Sidorenko's (1997) least-squares line through the measured speed (2 to 1000; his M + 1 = 6)", BOTH),
    Var("est.physical", "parameter", "Integer", None, 0, "1: est.A0, est.A2 and the filter's model kept >= 0, Theta-hat projected onto A0, A2 >= 0 in its covariance's metric (A1 may be < 0: a tailwind); 0: as identified", BOTH),
    Var("est.sigma2_method", "parameter", "Integer", None, 1, "where est.sigma2 (the filter's process noise) comes from: 0 eq. (12) on sums of 50 LS residuals; 1 the innovation likelihood of a bank of 13 speed filters over a log grid around est.sigma2_initial (Magill 1965)", BOTH),
    Var("est.run_forgetting", "parameter", "Real", "1", 0.0, "share of the A's data information forgotten at each station stop, in [0, 1): the A's carry over from run to run with slow forgetting (0 = none; the prior is never forgotten)", BOTH, min=0.0, max=1.0),
    Var("est.forgetting", "parameter", "Real", "1", 0.0, "mu0 in [0, 1): 0 = mu(n) = 1/n (ordinary LS), else exponential forgetting 1 - mu0", BOTH, min=0.0, max=1.0),
    Var("est.gamma", "parameter", "Real", "1", 0.0, "rotating-mass factor the estimator assumes (0 = the paper's eq. (2))", BOTH, min=0.0, max=1.0),
    Var("est.mass_initial", "parameter", "Real", "t", 30.0, "initial (prior) mass", BOTH, min=1.0, max=1000.0),
    Var("est.mass_std_initial", "parameter", "Real", "t", 10.0, "initial (prior) mass standard deviation", BOTH, min=1e-6, max=1e8),
    Var("est.A0_initial", "parameter", "Real", "N/kN", 1.0, "initial (prior) A0", BOTH, min=-20.0, max=20.0),
    Var("est.A1_initial", "parameter", "Real", "N/kN/(m/s)", 0.03, "initial (prior) A1", BOTH, min=-2.0, max=2.0),
    Var("est.A2_initial", "parameter", "Real", "N/kN/(m/s)2", 0.01, "initial (prior) A2", BOTH, min=-0.2, max=0.2),
    Var("est.A0_std_initial", "parameter", "Real", "N/kN", 2.0, "prior standard deviation of A0", BOTH, min=1e-9, max=1e8),
    Var("est.A1_std_initial", "parameter", "Real", "N/kN/(m/s)", 0.1, "prior standard deviation of A1", BOTH, min=1e-9, max=1e8),
    Var("est.A2_std_initial", "parameter", "Real", "N/kN/(m/s)2", 0.02, "prior standard deviation of A2", BOTH, min=1e-9, max=1e8),
    Var("est.sigma2_initial", "parameter", "Real", "m2/s2", 1e-4, "initial process-noise variance per sample", BOTH, min=1e-20, max=1.0),
    Var("filter.kind", "parameter", "Integer", None, 0, "0 auto (1 if a speed profile is given, else 2); 1 linearised around V_zad, eq. (13), trapezoid distance; 2 EKF; 3 eqs. (13)-(19) verbatim; 4 Singer (Boynik et al., n.d.; model-free)", BOTH),
    Var("filter.singer_tau", "parameter", "Real", "s", 10.0, "Singer filter: correlation time of the acceleration", BOTH, min=0.0),
    Var("filter.singer_p0", "parameter", "Real", "1", 0.3, "Singer filter: probability of zero acceleration", BOTH, min=0.0, max=1.0),
    Var("filter.singer_p_plus", "parameter", "Real", "1", 0.1, "Singer filter: probability of the maximum acceleration", BOTH, min=0.0, max=1.0),
    Var("filter.singer_p_minus", "parameter", "Real", "1", 0.1, "Singer filter: probability of the maximum deceleration", BOTH, min=0.0, max=1.0),
    Var("filter.singer_w_max_plus", "parameter", "Real", "m/s2", 1.3, "Singer filter: maximum acceleration", BOTH),
    Var("filter.singer_w_max_minus", "parameter", "Real", "m/s2", -1.5, "Singer filter: maximum deceleration (negative)", BOTH),
    # ---------------------------------------------------------------- RailCar outputs: truth and measurements
    Var("car.speed", "output", "Real", "m/s", 0.0, "true speed", R),
    Var("car.position", "output", "Real", "m", 0.0, "true distance from the previous station", R),
    Var("car.acceleration", "output", "Real", "m/s2", 0.0, "true acceleration", R),
    Var("car.traction_force", "output", "Real", "N", 0.0, "traction force applied (after traction and adhesion limits)", R),
    Var("car.brake_force", "output", "Real", "N", 0.0, "brake force applied", R),
    Var("car.grade", "output", "Real", "permille", 0.0, "grade under the car (averaged over car.length)", R),
    Var("car.mode", "output", "Integer", None, 0, "0 standstill, 1 traction, 2 coasting, 3 braking", R),
    Var("car.total_mass", "output", "Real", "t", 30.0, "true mass now: car.mass + car.payload", R),
    Var("sensor.speed", "output", "Real", "m/s", 0.0, "measured speed", R),
    Var("sensor.position", "output", "Real", "m", 0.0, "measured distance", R),
    Var("sensor.track_speed", "output", "Real", "m/s", 0.0, "last speed from two track sensors, b / (t2 - t1) (Boynik et al., n.d.); needs sensor.track_spacing > 0", R),
    Var("sensor.track_time", "output", "Real", "s", 0.0, "time stamp of sensor.track_speed (second sensor's passage, as the timer read it)", R),
    # ---------------------------------------------------------------- estimator outputs (both)
    Var("est.mass", "output", "Real", "t", 30.0, "identified mass P = 1/(g Theta1) (effective mass P(1+gamma) if est.gamma = 0 < car.gamma)"),
    Var("est.mass_std", "output", "Real", "t", 10.0, "standard deviation of est.mass from the estimator's covariance"),
    Var("est.A0", "output", "Real", "N/kN", 1.0, "identified A0"),
    Var("est.A1", "output", "Real", "N/kN/(m/s)", 0.03, "identified A1"),
    Var("est.A2", "output", "Real", "N/kN/(m/s)2", 0.01, "identified A2"),
    Var("est.A0_std", "output", "Real", "N/kN", 2.0, "standard deviation of est.A0"),
    Var("est.A1_std", "output", "Real", "N/kN/(m/s)", 0.1, "standard deviation of est.A1"),
    Var("est.A2_std", "output", "Real", "N/kN/(m/s)2", 0.02, "standard deviation of est.A2"),
    Var("est.sigma2", "output", "Real", "m2/s2", 1e-4, "identified process-noise variance per sample: eq. (12) less the speed sensor's share (est.sigma2_method 0), or the likelihood bank's (1)"),
    Var("est.samples", "output", "Integer", None, 0, "samples used by the identification so far"),
    Var("est.station_stops", "output", "Integer", None, 0, "station stops recognised (mass identification restarts)"),
    Var("est.status", "output", "Integer", None, 0, "0 prior only (no data used yet), 1 identifying (the last sample pair was used), 2 holding (the last pair carried no information: standing, a steady state held over 20 s, a refused measurement), 3 degraded (est.mass left [est.mass_initial / 5, 5 est.mass_initial]: its last good value with at least est.mass_std_initial)"),
    Var("filter.speed", "output", "Real", "m/s", 0.0, "filtered speed"),
    Var("filter.position", "output", "Real", "m", 0.0, "filtered distance"),
    Var("filter.speed_std", "output", "Real", "m/s", 0.0, "standard deviation of filter.speed"),
    Var("filter.position_std", "output", "Real", "m", 0.0, "standard deviation of filter.position"),
    Var("filter.rejected", "output", "Integer", None, 0, "speeds and distances refused by the innovation gate (beyond 6 sigma of their innovation: once in 5e8 for a good one): spikes, dropouts, a stuck sensor"),
    Var("sensor.speed_std_rel", "parameter", "Real", "1", 0.0, "plus this share of the speed (Meleshin's (2011) 'within 2 %'): std = speed_std + rel * speed", BOTH, min=0.0),
    # ---------------------------------------------------------------- appended: earlier value references stay
    Var("est.cov_A0_A1", "output", "Real", "(N/kN)2/(m/s)", 0.0, "covariance of est.A0 and est.A1 (the variances are est.A0_std^2 ..): w0(V)'s variance is [1 V V^2] C [1 V V^2]^T; 0 while a variance is 0"),
    Var("est.cov_A0_A2", "output", "Real", "(N/kN)2/(m/s)2", 0.0, "covariance of est.A0 and est.A2 (see est.cov_A0_A1)"),
    Var("est.cov_A1_A2", "output", "Real", "(N/kN)2/(m/s)3", 0.0, "covariance of est.A1 and est.A2 (see est.cov_A0_A1)"),
    Var("car.traction_force_mean", "output", "Real", "N", 0.0, "the traction force averaged over the last sample interval, as the estimator was fed it (the plant's impulse over the interval / sensor.sample_period); 0 before the first interval ends. A log of it replays to est.* bit for bit", R),
    Var("car.brake_force_mean", "output", "Real", "N", 0.0, "the brake force averaged over the last sample interval, as the estimator was fed it (see car.traction_force_mean)", R),
    Var("est.A0_drift_std", "parameter", "Real", "N/kN", 0.0, "est.method 0 and 2: the carried est.A0 may move by this much (std, a random walk) between runs, at each station stop: a wind Vw moves A0 by A2 Vw^2. Widens the stated covariance only (est.mass_std, est.A*_std, est.cov_*; the filter's model term follows it), not the identification's arithmetic (0 = none; studies/service_day.py uses 0.04 for its wind changes)", BOTH, min=0.0, max=10.0),
    Var("est.A1_drift_std", "parameter", "Real", "N/kN/(m/s)", 0.0, "as est.A0_drift_std for est.A1 (a wind Vw moves A1 by 2 A2 Vw; studies/service_day.py uses 0.03)", BOTH, min=0.0, max=1.0),
)



# ------------------------------------------------------------------------------- AtoController
# The controller (models.ato.controller.AtoController) as an FMU: inputs are the estimator's outputs it reads
# (same names, so a system connects them name to name), parameters the span, the configured car
# (models.planning.span.CarTraction) and the tuning (models.ato.controller.AtoTuning, defaults taken from there),
# outputs the demands RailCar takes (same names) and what the controller is doing.
A = (ATO,)
_CAR_ROWS = (   # CarTraction field, unit, description (the car as configured, not the truth)
    ("mass", "t", "configured mass with passengers (the plan's mass until est.mass is usable)"),
    ("A0", "N/kN", "configured main-resistance coefficient A0"),
    ("A1", "N/kN/(m/s)", "configured main-resistance coefficient A1"),
    ("A2", "N/kN/(m/s)2", "configured main-resistance coefficient A2"),
    ("gamma", "1", "rotating-mass factor"),
    ("length", "m", "car/train length the grade is averaged over; 0 = point mass"),
    ("traction_force_max", "N", "traction force limit (constant-force zone)"),
    ("traction_power_max", "W", "traction power limit (constant-power zone)"),
    ("brake_force_max", "N", "total brake limit (regenerative + electro-pneumatic)"),
    ("regen_force_max", "N", "regenerative brake limit (constant-force zone)"),
    ("regen_power_max", "W", "regenerative brake power limit"),
    ("regen_fade_speed", "m/s", "full regenerative brake at and above this speed (Meleshin 2011: 7 km/h)"),
    ("regen_off_speed", "m/s", "no regenerative brake at and below this speed"),
    ("mech_force_max", "N", "electro-pneumatic brake limit"),
    ("adhesion_mass_fraction", "1", "share of the mass on driven axles"),
    ("adhesion_factor", "1", "scales the dry-rail adhesion coefficient"),
    ("eta_f", "1", "traction efficiency: wheel energy / network energy"),
    ("eta", "1", "share of the regenerated energy the network takes back"),
)
_TUNING_ROWS = (   # AtoTuning field, unit, description
    ("replan", None, "re-plan the rest of the span every ato.replan_period (the running-time regulator)"),
    ("use_estimates", None, "plan and feed forward with est.* once usable (else the configured car.*)"),
    ("replan_period", "s", "time between re-plans"),
    ("grid_step", "m", "re-planner's distance grid"),
    ("time_tol", "s", "re-plan's running-time tolerance"),
    ("min_samples", None, "est.samples needed before est.* are used"),
    ("mass_band", "1", "the planned mass (est.mass blended with car.mass) is kept within [car.mass / this, car.mass x this]"),
    ("limit_margin", "m/s", "planned speeds stay this far below the speed limit"),
    ("k_sigma", "1", "supervisor: filter.speed + k_sigma x filter.speed_std must stay under the supervision curve"),
    ("gap_sigma", "1", "and this many filter.speed_std more (filter.speed jumps under speed noise)"),
    ("supervisor_gap", "m/s", "the controller keeps that speed this far below the supervision curve"),
    ("mass_reserve", "1", "the supervisor's braking curves assume this share more mass"),
    ("brake_share", "1", "share of the electric brake the planned braking curves use"),
    ("approach_gain", "1/s", "speed feedback gain of holding and curve tracking"),
    ("brake_integral_gain", "1/s2", "integral feedback on the final braking curve"),
    ("brake_integral_max", "m/s2", "bound of that integral term"),
    ("a_ep", "m/s2", "programmed deceleration of the electro-pneumatic stage"),
    ("ep_stages", None, "electro-pneumatic brake stages of car.mech_force_max / ep_stages each"),
    ("relay_hysteresis", "m/s", "relay: a stage on above +, off below - this speed error"),
    ("relay_stage_speed", "m/s", "relay: one more stage per this much further speed error"),
    ("relay_dwell", "s", "relay: time between stage changes"),
    ("stand_speed", "m/s", "at or below this speed for ato.stand_time the car stands"),
    ("stand_time", "s", "see ato.stand_speed"),
    ("creep_speed", "m/s", "speed of creeping on to the mark after a short stop"),
    ("creep_accel", "m/s2", "acceleration of creeping on"),
    ("stop_window", "m", "standing closer than this to the aim point: arrived"),
    ("aim_sigma", "1", "aim this many filter.speed_std x (the stage's duration) short of the mark"),
    ("aim_max", "m", "at most this far short"),
    ("settle_std", "m", "filter.position_std above this at the final braking curve: stop short, stand, creep on"),
    ("settle_sigma", "1", "the short stop aims this many filter.position_std short of the mark"),
    ("settle_aim_max", "m", "at most this far short"),
    ("settle_time", "s", "standing before the creep while the filter's distance settles; 0 = never a short stop"),
    ("settle_window", "m", "after the stand: standing closer than this to the aim is arrived"),
    ("creep_aim", "m", "the creep after the stand aims this far short of the mark"),
    ("safe_brake", "1", "share of car.brake_force_max on a bad input (missing, non-finite, outside physics or inconsistent: docs/ato.md)"),
    ("hold_brake", "1", "share of car.brake_force_max held at the stop"),
)
_TUNING_ROWS_APPENDED = (   # AtoTuning fields added later: after the outputs (value references stay)
    ("config_mass_std", "1", "the configured car.mass's own uncertainty, a share of it: est.mass gets the weight ato.config_mass_std^2 / (that + est.mass_std^2)"),
    ("config_resistance_std", "N/kN", "the configured resistance's own uncertainty: est.A0..A2 get the weight of its variance against w0's stated variance"),
    ("est_gate", "1", "est.* further than this many combined sigmas from the configured resistance get no weight, nearer than ato.est_gate - 1 full weight"),
    ("time_reserve", "1", "re-plans aim this share of the remaining running time early while est.* and the configured car disagree"),
)


def _ato_rows() -> tuple[Var, ...]:
    from models.ato.interface import UPPER_BOUNDS, AtoTuning
    from models.planning.span import CarTraction
    from models.units import kmh_to_mps
    car, tuning = CarTraction(), AtoTuning()
    typed = {"bool": "Boolean", "int": "Integer", "float": "Real"}
    hints = {f: t for f, t in AtoTuning.__annotations__.items()}
    rows = [
        Var("filter.speed", "input", "Real", "m/s", 0.0, "filtered speed (RailCar or RailCarEstimator)", A),
        Var("filter.position", "input", "Real", "m", 0.0, "filtered distance from the previous station", A),
        Var("filter.speed_std", "input", "Real", "m/s", 0.0, "standard deviation of filter.speed", A),
        Var("filter.position_std", "input", "Real", "m", 0.0, "standard deviation of filter.position", A),
        Var("est.mass", "input", "Real", "t", 30.0, "identified mass", A),
        Var("est.A0", "input", "Real", "N/kN", 1.0, "identified A0", A),
        Var("est.A1", "input", "Real", "N/kN/(m/s)", 0.03, "identified A1", A),
        Var("est.A2", "input", "Real", "N/kN/(m/s)2", 0.01, "identified A2", A),
        Var("est.status", "input", "Integer", None, 0, "the estimator's status (1 identifying and 2 holding are usable)", A),
        Var("est.samples", "input", "Integer", None, 0, "samples the identification has used", A),
        Var("span.stop", "parameter", "Real", "m", 2000.0, "the stop mark: distance from the departure station where the car must stand", A, min=0.0),
        Var("span.length", "parameter", "Real", "m", 0.0, "span length (>= span.stop); 0 = span.stop", A, min=0.0),
        Var("span.schedule", "parameter", "Real", "s", 125.0, "scheduled running time from departure (t = 0) to standing at the stop mark", A, min=0.0),
        Var("span.grade_profile", "parameter", "String", None, "", "CSV 'distance_m,grade_permille' (as RailCar's track.grade_profile: give the same file); empty = level", A),
        Var("span.speed_limit", "parameter", "Real", "m/s", kmh_to_mps(80.0), "speed limit over the whole span when span.speed_limit_profile is empty", A, min=0.0),
        Var("span.speed_limit_profile", "parameter", "String", None, "", "CSV 'distance_m,speed_limit_mps': the limit piecewise constant from each distance (the first 0)", A),
    ]
    rows += [Var(f"car.{f}", "parameter", "Real", u, getattr(car, f), d, A, min=0.0)
             for f, u, d in _CAR_ROWS]
    def tuning_row(f: str, u: str, d: str) -> Var:
        t = typed[hints[f]]
        return Var(f"ato.{f}", "parameter", t, u if t == "Real" else None, getattr(tuning, f), d, A,
                   min=0.0 if t == "Real" else None,
                   max=UPPER_BOUNDS[f][0] if t == "Real" and f in UPPER_BOUNDS else None)

    rows += [tuning_row(*r) for r in _TUNING_ROWS]
    rows += [
        Var("traction_force_demand", "output", "Real", "N", 0.0, "traction force asked of the car (RailCar's input)", A, initial="calculated"),
        Var("brake_force_demand", "output", "Real", "N", 0.0, "brake force asked of the car (RailCar's input); a holding brake before the first step", A, initial="calculated"),
        Var("ato.planned_speed", "output", "Real", "m/s", 0.0, "the speed the current plan wants here", A, initial="calculated"),
        Var("ato.mode", "output", "Integer", None, 8, "0 full traction, 1 holding by traction, 2 coasting, 3 holding by regenerative brake, 4 regenerative braking, 5 holding by regenerative + mechanical brake, 6 mechanical braking, 7 electro-pneumatic relay stages, 8 holding brake, 9 safe brake (bad input), 10 supervisor brake (overspeed), 11 creeping to the mark, 12 standing short of the mark while the filter's distance settles", A, initial="calculated"),
        Var("ato.ep_stage", "output", "Integer", None, 0, "electro-pneumatic brake stages on (mode 7)", A, initial="calculated"),
        Var("ato.finished", "output", "Boolean", None, False, "the car stands at the stop mark", A, initial="calculated"),
        Var("ato.replans", "output", "Integer", None, 0, "re-plans so far", A, initial="calculated"),
        Var("ato.using_estimates", "output", "Boolean", None, False, "est.* have weight in the plan now (models.ato.controller.blend_estimates; else the configured car.*)", A, initial="calculated"),
        Var("ato.predicted_arrival", "output", "Real", "s", 0.0, "when the current plan stands at the stop mark", A, initial="calculated"),
    ]
    from models.ato.interface import STATED_INPUTS
    units = {"est.mass_std": "t", "est.A0_std": "N/kN", "est.A1_std": "N/kN/(m/s)",
             "est.A2_std": "N/kN/(m/s)2", "est.cov_A0_A1": "(N/kN)2/(m/s)",
             "est.cov_A0_A2": "(N/kN)2/(m/s)2", "est.cov_A1_A2": "(N/kN)2/(m/s)3"}
    for name, prior in STATED_INPUTS:   # appended: the stated uncertainty the regulator weighs est.* by
        rows.append(Var(name, "input", "Real", units[name], prior,
                        f"the estimator's {name} (the regulator weighs est.* by it; the start value is "
                        f"the estimator's prior, which gives est.* little weight)", A))
    rows += [tuning_row(*r) for r in _TUNING_ROWS_APPENDED]
    rows += [
        # a line (models.ato.line): appended after the stated uncertainty, the rows above keep their value references
        Var("est.station_stops", "input", "Integer", None, 0, "station stops the estimator has recognised (a line: until it grows after a departure the filter still counts from the previous station); connect it for a line", A),
        Var("line.profile", "parameter", "String", None, "", "CSV 'stop_m,length_m,schedule_s,dwell_s,boarding_t': one row per span after the first (span.*), in order: its stop mark [m], length [m] (0 = stop_m), schedule [s], the standstill at the station before it [s] (> 0, at least the estimator's track.station_dwell) and the passengers boarding there [t] (leaving: < 0); every span over span.grade_profile from its station; empty = one span", A),
        Var("line.speed_limit_profile", "parameter", "String", None, "", "CSV 'span,distance_m,speed_limit_mps': the speed limits of line.profile's spans (span 2 is its first row), piecewise constant from each distance (each span's first 0); a span without rows: span.speed_limit over it", A),
        Var("ato.payload", "output", "Real", "t", 0.0, "passengers boarded at the line's stations so far, from the dwell's start (RailCar's car.payload input)", A, initial="calculated"),
        Var("ato.span", "output", "Integer", None, 1, "the span running (1: span.*, 2, 3, ..: line.profile's rows); during a dwell the span just finished, and ato.finished is that span's", A, initial="calculated"),
    ]
    return tuple(rows)


VARIABLES = VARIABLES + _ato_rows()

PAPER_ESTIMATOR = {"est.method": 0, "est.sigma2_method": 0}
"""The paper's scheme exactly: the recursive LS of eq. (4)-(11) and sigma^2 by eq. (12) on LAG
sums (the table's defaults are the measured best, est.method 2 with est.sigma2_method 1)."""
FORMER_DEFAULTS = {**PAPER_ESTIMATOR, "est.A0_std_initial": 5.0}
"""The estimator's defaults before est.method 2 became the default: the paper's scheme with A0's
prior std 5 N/kN (docs/estimation.md compares the two)."""


def variables_for(fmu: str) -> tuple[Var, ...]:
    """The variables of one FMU, in value-reference order."""
    return tuple(v for v in VARIABLES if fmu in v.fmus)


def markdown_table(fmu: str) -> str:
    """docs/variables.md's table of one FMU's variables, generated from this table."""
    lines = ["| name | causality | type | unit | start | description |", "|---|---|---|---|---|---|"]
    for v in variables_for(fmu):
        start = f'"{v.start}"' if v.type == "String" else f"{v.start:g}" if isinstance(v.start, float) else str(v.start)
        lines.append(f"| `{v.name}` | {v.causality} | {v.type} | {v.unit or '–'} | {start} | {v.description} |")
    return "\n".join(lines)


def docs_block() -> str:
    """What stands between the variables markers of docs/variables.md."""
    return "\n" + "\n\n".join(f"### `{n}`\n\n{markdown_table(n)}" for n in FMUS) + "\n"


if __name__ == "__main__":
    import sys
    from pathlib import Path
    if "--update-docs" in sys.argv:
        page = Path(__file__).resolve().parent.parent / "docs" / "variables.md"
        text = page.read_text(encoding="utf-8")
        head, rest = text.split("<!-- variables:start -->")
        tail = rest.split("<!-- variables:end -->")[1]
        page.write_text(f"{head}<!-- variables:start -->{docs_block()}<!-- variables:end -->{tail}",
                        encoding="utf-8")
        print(f"updated {page}")
    else:
        print(docs_block())
