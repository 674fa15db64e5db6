"""Estimation quality of the resistance identification on our simulated data (a study, not a test).

    python studies/estimation_quality.py [--quick] [--seeds N] [--day-seeds N]

Compares, on runs of the models chain (plant -> sensors -> online estimator, no FMI; each run whole in
C on the batch engine, harness.run.batch, many seeds per call: the Python chain's outputs bit for bit):

  paper LS   models.estimation.identification.ParameterIdentifier with default settings, as
             models.estimation.online.OnlineEstimator feeds it (read from est.* of models.chain.RailCarChain)
  LS slopes  the same chain with est.method 2: the LS fed with Sidorenko's (1997) centred least-squares
             slopes of the measured speed (est.slope_window 10), online as in the FMU
  OE         models.estimation.output_error.fit_segment, output error (deterministic simulation of eq. (2)),
             covariance the process-noise sandwich
  FE         fit_segment(method="filter_error"): output error refined by the filter-error method
             (Kalman innovations as residuals, maximum likelihood under process noise)
  EKF        models.estimation.coast_ekf.CoastEKF, Meleshin's (2011) coasting EKF (coasting rows only)
  oracle     the true coefficients

(a) the four coasting logs shaped like rows 1-4 of Meleshin's (2011) Table 1 (scenarios/library/
    coasting_rusich_row*.toml): coast run-time prediction error with each method's coefficients
    (harness.metrics.estimation.coast_time) against the published bounds (0.25, 0.15, 0.12, 1.45 s), for the
    library seed and over Monte Carlo seeds (mean |error|, share within the bound);
(b) ten consecutive inter-station runs with the same resistance (station_day.toml's car and line,
    10 stops, passengers boarding and alighting at every stop): w0(V) relative RMS error over the
    travelled speed range after the ten runs (harness.metrics.estimation.w0_relative_rms_error), the A's
    carried over from run to run;
(c) coverage of +-2 sigma for A0, A1, A2 and w0 at a few speeds over the Monte Carlo seeds;
(d) the FMU's online estimator over station_day's Monte Carlo seeds (every stop's mass within 1 %,
    +-2 sigma coverage of the mass at the stops and of the filter's speed and distance while
    moving) and over the library (studies/method_table.py: the filter's RMSE against the raw
    sensor's and the oracle filter's), for the paper's LS and LS slopes, each with the LAG and
    the likelihood sigma^2 (est.sigma2_method 0 / 1). With (a)-(c) every issue-5 target is in the
    final comparison, met or its gap in numbers.

Conventions (decided here, printed with the results):
- The coast time is computed two ways. "true v0" is harness.metrics.estimation.summarise's convention: the
  re-run starts from the *true* speed at the coast's first row; the targets are judged on it.
  "recomputed" re-runs the coast from the initial speed each model fits best to the measured
  coast (models.estimation.output_error.fit_initial_state), a reading of Meleshin's "recomputed coast". It
  is printed to show that it measures nothing: a fitted start speed absorbs any reasonable w0's
  error (every method, even the paper LS with 13 % w0 error, lands within 0.04 s).
- Process noise density q is not taken from the truth: it is estimated by restricted maximum
  likelihood from the output-error fits (models.estimation.output_error.estimate_process_noise_psd),
  pooled over each row's coasts in (a) (the library seed and the Monte Carlo seeds: the same
  train and line; one 33 s coast cannot pin q down and its coverage then falls to 87 %), over
  the day's ten runs in (b). Sensor noise stds are the configured sensor.speed_std /
  sensor.position_std (the estimator knows its sensors).
- Priors: OE, FE and EKF use the weak physical prior A0 = 1 +- 1, A1 = 0.03 +- 0.03, A2 = 0.01 +-
  0.01 (models.estimation.output_error.physical_prior) and a mass prior of 30 +- 10 t. In the Monte Carlo
  its mean is drawn per seed from N(truth, prior std) (simulation-based calibration, Cook, Gelman
  & Rubin 2006): a prior centred on the truth would make the coverage of prior-dominated
  directions meaninglessly 100 %. The library-seed rows use the nominal prior. LS slopes gets
  the same prior (the same draw) through est.A*_initial and est.A*_std_initial (slopes_run).

Seeded and reproducible; prints tables only, writes nothing. --quick keeps it under a minute.
"""
from __future__ import annotations

import argparse
import sys
import time
import tomllib
from dataclasses import dataclass, replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from fmu_src.variables import FORMER_DEFAULTS  # noqa: E402
from harness.metrics.estimation import coast_segments, coast_time, w0_relative_rms_error  # noqa: E402
from harness.run.scenario import Scenario, load_scenario, scenario_from_dict  # noqa: E402
from models.estimation.coast_ekf import CoastEKF, CoastEKFConfig  # noqa: E402
from models.estimation.output_error import (Prior, ResistanceCarryOver, estimate_process_noise_psd,  # noqa: E402
                                 fit_initial_state, fit_segment, grade_per_interval,
                                 reference_track)
from models.units import G  # noqa: E402

LIBRARY = ROOT / "scenarios" / "library"
ROW_BOUNDS = {1: 0.25, 2: 0.15, 3: 0.12, 4: 1.45}     # Meleshin (2011) Table 1, identified coefficients [s]
ROW_PAPER_LS = {1: 0.67, 2: 0.36, 3: 0.10, 4: 0.24}   # out/library/library.md (for reference) [s]
W0_TARGET = 0.02                                      # ten runs: w0 within 2 % RMS
COVERAGE = (0.90, 0.98)                               # +-2 sigma
PRIOR_MEAN = np.array([1.0, 0.03, 0.01])              # physical_prior's A's
PRIOR_STD = np.array([1.0, 0.03, 0.01])
MASS_PRIOR = (30.0, 10.0)                             # [t] the estimator's default est.mass_initial
DAY_MASS_CHANGES = (4.0, -3.0, 6.0, -5.0, 2.0, -4.0, 3.0, 5.0, -6.0)   # [t] at the nine stops
METHODS = ("paper LS", "LS slopes", "OE", "FE", "EKF", "oracle")
SLOPES = {"est.method": 2}                            # the FMU parameter of "LS slopes"
ONLINE = {"paper LS": FORMER_DEFAULTS, "paper LS, lik. s2": {**FORMER_DEFAULTS, "est.sigma2_method": 1},
          "LS slopes": {**FORMER_DEFAULTS, **SLOPES},
          "LS slopes, lik. s2": {**FORMER_DEFAULTS, **SLOPES, "est.sigma2_method": 1}}   # (d)
# (d)'s rows keep the former default A0 prior (std 5 N/kN); "LS slopes, lik. s2" with A0's std
# 2 N/kN is today's FMU default (docs/estimation.md measures it)
MASS_WITHIN, MASS_SHARE = 0.01, 0.95                  # every stop within 1 % in >= 95 % of seeds
FILTER_VS_SENSOR, FILTER_VS_ORACLE = 0.6, 1.10        # speed and distance RMSE ratios


# ------------------------------------------------------------------ running a scenario

@dataclass
class Run:
    """One run of the models chain, one row per communication step (= sensor sample here)."""
    scenario: Scenario
    seed: int
    time: np.ndarray                 # [s]
    sig: dict                        # car.*, sensor.*, est.* arrays
    forces: np.ndarray               # (n-1, 2) mean applied traction, brake over each interval [N]
    grade_profile: object
    A_cov: np.ndarray                # the online LS's A0, A1, A2 covariance at the last row (3x3)

    def p(self, name):
        return self.scenario.parameter(name)

    @property
    def A_true(self) -> np.ndarray:
        return np.array([self.p("car.A0"), self.p("car.A1"), self.p("car.A2")])


SIGNALS = ("car.speed", "car.position", "car.mode", "car.total_mass", "sensor.speed",
           "sensor.position", "est.A0", "est.A1", "est.A2")


def with_parameters(scenario: Scenario, extra: dict) -> Scenario:
    """The scenario with some parameters set (by their FMU names)."""
    return replace(scenario, parameters={**scenario.parameters, **extra})


def est_A(run: Run, row: int) -> np.ndarray:
    """est.A0..A2 [N/kN, N/kN/(m/s), N/kN/(m/s)^2] of a run at a row."""
    return np.array([run.sig["est.A0"][row], run.sig["est.A1"][row], run.sig["est.A2"][row]])


def run_scenario(scenario: Scenario, seed: int) -> Run:
    """The scenario's driver on the models chain (what the RailCar FMU runs, without FMI), whole
    in C on the batch engine: run_scenarios of one run."""
    return run_scenarios([(scenario, seed)])[0]


def run_scenarios(jobs) -> list[Run]:
    """Each (scenario, seed) on the models chain, whole in C on the batch engine
    (harness.run.batch.run_batch: run_on_chain's outputs bit for bit, the Python RailCarChain's
    too), CALL_RUNS per call. The estimator starts from FORMER_DEFAULTS (the paper's LS) under
    the scenario's own parameters: the study names its rows by method ("paper LS", "LS slopes"
    adds est.method 2). From the outputs: the forces the estimator was given over each sample
    interval (car.traction_force_mean, car.brake_force_mean after the interval) and the A's
    covariance at the end (est.A*_std squared, est.cov_*: the LS's own to an ulp here, measured on
    the ten-run day with est.method 0 and 2; with est.run_forgetting or a drift it is the carried
    A's the FMU states)."""
    from harness.run.batch import run_batch
    scenarios, setups = [], []
    for scenario, seed in jobs:
        scenario = replace(scenario, parameters={**FORMER_DEFAULTS, **scenario.parameters})
        setup = scenario.chain_setup({"seed": int(seed)})
        if abs(scenario.step_s - setup.config.sample_period) > 1e-12:
            raise ValueError(f"{scenario.name}: the study needs step_s == sensor.sample_period "
                             "(one sample per row)")
        scenarios.append(scenario)
        setups.append(setup)
    out = []
    for k in range(0, len(jobs), CALL_RUNS):
        results = run_batch(scenarios[k:k + CALL_RUNS], [{"seed": int(seed)} for _, seed in jobs[k:k + CALL_RUNS]],
                            setups[k:k + CALL_RUNS])
        for (scenario, setup, (_, seed)), r in zip(zip(scenarios[k:], setups[k:], jobs[k:]), results):
            std = [r[f"est.A{i}_std"][-1] for i in range(3)]
            A_cov = np.diag(np.square(std))
            for name, i, j in (("est.cov_A0_A1", 0, 1), ("est.cov_A0_A2", 0, 2), ("est.cov_A1_A2", 1, 2)):
                A_cov[i, j] = A_cov[j, i] = r[name][-1]
            forces = np.column_stack([r["car.traction_force_mean"][1:], r["car.brake_force_mean"][1:]])
            out.append(Run(scenario, seed, r.time, {name: r[name] for name in SIGNALS}, forces,
                           setup.grade, A_cov))
    return out


CALL_RUNS = 8
"""Runs per run_batch call: its arrays hold every run's rows at once (~8 MB a ten-run day)."""


def ten_run_day() -> Scenario:
    """station_day.toml's car, line and dwell, driven ten times to the next station, the mass
    changing at each of the nine stops (DAY_MASS_CHANGES)."""
    path = LIBRARY / "station_day.toml"
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    phases = []
    for k in range(10):
        phases += [{"action": "traction", "until_speed_kmh": 60.0},
                   {"action": "coast", "until_brake_curve": True},
                   {"action": "brake_to_stop", "stop_at_m": 1200.0, "decel_mps2": 0.8}]
        if k < 9:
            phases.append({"action": "hold", "until_time_s": 25.0, "mass_change_t": DAY_MASS_CHANGES[k]})
        else:
            phases.append({"action": "hold", "until_time_s": 5.0})
    data.update(name="ten_runs", driver=phases, duration_s=3000.0,
                purpose="station_day's car and line, ten runs")
    return scenario_from_dict(data, str(path), path.parent)


def moving_segments(speed_meas: np.ndarray, threshold: float, min_rows: int) -> list[tuple[int, int]]:
    """(first, last) rows of each stretch with measured speed above threshold [m/s]: the
    inter-station runs, found from the measurements (as the estimator's station detection)."""
    mv = np.asarray(speed_meas) > threshold
    out, start = [], None
    for k, m in enumerate(list(mv) + [False]):
        if m and start is None:
            start = k
        elif not m and start is not None:
            if k - start >= min_rows:
                out.append((start, k - 1))
            start = None
    return out


# ------------------------------------------------------------------ helpers

def z_scores(A, cov_A, A_true, speeds) -> np.ndarray:
    """(A - A_true)/std for the three A's, then (w0 - w0_true)/std at ``speeds`` [m/s]."""
    A, A_true = np.asarray(A), np.asarray(A_true)
    sd = np.sqrt(np.maximum(np.diag(cov_A), 1e-300))
    phi = np.column_stack([np.ones(len(speeds)), speeds, np.asarray(speeds) ** 2])
    w_sd = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", phi, cov_A, phi), 1e-300))
    return np.concatenate([(A - A_true) / sd, (phi @ (A - A_true)) / w_sd])


def prior_for(rng: np.random.Generator | None, A_true) -> tuple[np.ndarray, Prior]:
    """The physical prior, its A-mean drawn from N(A_true, prior std) when rng is given."""
    mean = PRIOR_MEAN.copy() if rng is None else np.asarray(A_true) + PRIOR_STD * rng.standard_normal(3)
    return mean, Prior.from_A(mean, np.diag(PRIOR_STD ** 2), *MASS_PRIOR)


def slopes_run(scenario: Scenario, seed: int, rng_seed) -> "Run":
    """run_scenario of slopes_scenario(scenario, rng_seed)."""
    return run_scenario(slopes_scenario(scenario, rng_seed), seed)


def slopes_scenario(scenario: Scenario, rng_seed) -> Scenario:
    """The scenario with est.method 2 ("LS slopes") and the study's physical prior on the A's,
    the same one OE, FE and the EKF get (prior_for with a generator seeded ``rng_seed``, so the
    same draw; None: PRIOR_MEAN), as est.A*_initial and est.A*_std_initial."""
    A_true = [scenario.parameter(f"car.A{i}") for i in range(3)]
    mean, _ = prior_for(None if rng_seed is None else np.random.default_rng(rng_seed), A_true)
    extra = dict(SLOPES)
    extra.update({f"est.A{i}_initial": float(mean[i]) for i in range(3)})
    extra.update({f"est.A{i}_std_initial": float(PRIOR_STD[i]) for i in range(3)})
    return with_parameters(scenario, extra)


def paired_runs(scenario: Scenario, seeds) -> list[tuple[Run, Run]]:
    """(run_scenario(scenario, seed), slopes_run(scenario, seed, rng_seed)) for each (seed,
    rng_seed), all in one run_scenarios."""
    runs = run_scenarios([(scenario, seed) for seed, _ in seeds]
                         + [(slopes_scenario(scenario, rng_seed), seed) for seed, rng_seed in seeds])
    return list(zip(runs[:len(seeds)], runs[len(seeds):]))


def fmt(x, f="{:+.2f}"):
    return "n/a" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f.format(x)


# ------------------------------------------------------------------ (a) coasting rows

@dataclass
class CoastResult:
    dT_true: dict        # method -> coast time error with the true v0 [s]
    dT_rec: dict         # method -> with the method's own fitted v0 [s]
    z: dict              # method -> z-scores (A0, A1, A2, w0 at 3 speeds)
    w0_err: dict         # method -> w0 relative RMS error over the coast's speed range
    q: float


@dataclass
class Coast:
    """A coasting run prepared for the study: its coast, prior and first output-error fit."""
    run: Run
    first: int
    last: int
    prior_mean: np.ndarray
    prior: Prior
    common: dict
    oe0: object
    slopes: Run | None = None        # the same seed with est.method 2


def coast_prepare(run: Run, rng: np.random.Generator | None, slopes: Run | None = None) -> Coast:
    """The coast (car.mode == 2 rows), the prior and an output-error fit without q (for q-hat)."""
    p = run.p
    s = run.sig
    (first, last), = coast_segments(s["car.mode"], 50)
    sl = slice(first, last + 1)
    prior_mean, prior = prior_for(rng, run.A_true)
    common = dict(distance=s["sensor.position"][sl], grade_profile=run.grade_profile,
                  length=p("car.length"), gamma=p("car.gamma"), speed_std=p("sensor.speed_std"),
                  distance_std=p("sensor.position_std"))
    oe0 = fit_segment(run.time[sl], s["sensor.speed"][sl], prior=prior, **common)
    return Coast(run, first, last, prior_mean, prior, common, oe0, slopes)


def coast_study(c: Coast, q: float) -> CoastResult:
    """Every method on one coast, with process-noise density q [m^2/s^3]."""
    run, first, last, common = c.run, c.first, c.last, c.common
    p = run.p
    s = run.sig
    sl = slice(first, last + 1)
    t = run.time[sl]
    v_meas, x_meas = s["sensor.speed"][sl], s["sensor.position"][sl]
    length, gamma = p("car.length"), p("car.gamma")
    grade = run.grade_profile
    A_true = run.A_true
    v0_true, x0, x1 = s["car.speed"][first], s["car.position"][first], s["car.position"][last]
    actual = run.time[last] - run.time[first]
    speeds = np.linspace(s["car.speed"][sl].min(), s["car.speed"][sl].max(), 3)
    oe = fit_segment(t, v_meas, prior=c.prior, process_noise_psd=q, **common)
    fe = fit_segment(t, v_meas, prior=c.prior, process_noise_psd=q, method="filter_error", **common)
    g_iv = grade_per_interval(reference_track(t, v_meas, x_meas), grade, length)
    pm = c.prior_mean
    ekf = CoastEKF(CoastEKFConfig(A0=pm[0], A1=pm[1], A2=pm[2], A0_std=PRIOR_STD[0],
                                  A1_std=PRIOR_STD[1], A2_std=PRIOR_STD[2],
                                  speed_std=p("sensor.speed_std"), process_noise_psd=q,
                                  gamma=gamma)).run(t, v_meas, g_iv)
    ls_A = np.array([s["est.A0"][last], s["est.A1"][last], s["est.A2"][last]])
    cand = {"paper LS": (ls_A, run.A_cov if last == len(run.time) - 1 else None),
            "OE": (oe.A, oe.cov_A), "FE": (fe.A, fe.cov_A), "EKF": (ekf.A, ekf.cov_A),
            "oracle": (A_true, None)}
    if c.slopes is not None:
        cand["LS slopes"] = (est_A(c.slopes, last),
                             c.slopes.A_cov if last == len(c.slopes.time) - 1 else None)
    mass = p("car.mass")
    res = CoastResult({}, {}, {}, {}, q)
    for name, (A, cov) in cand.items():
        ct = lambda v0: coast_time(v0, x0, x1, tuple(A), mass, gamma, length, grade) - actual  # noqa: E731
        res.dT_true[name] = ct(v0_true)
        v0_fit, _ = fit_initial_state([1.0 / (G * mass), *A], t, v_meas, **common)
        res.dT_rec[name] = ct(v0_fit)
        res.w0_err[name] = w0_relative_rms_error(s["car.speed"][sl], tuple(A), tuple(A_true))
        res.z[name] = None if cov is None else z_scores(A, cov, A_true, speeds)
    return res


# ------------------------------------------------------------------ (b) ten runs

@dataclass
class DayResult:
    w0_err: dict         # method -> w0 relative RMS error after the ten runs
    w0_err_by_run: dict  # method -> list over runs 1..10
    w0_err_pred: dict    # method -> the RMS relative error its covariance predicts
    w0_std: dict         # method -> std of w0 at the study's speeds [N/kN]
    z: dict
    q: float
    runs: int
    mass_err_pct: float  # largest |mass error| of the per-run OE fits [%]


def day_study(run: Run, rng: np.random.Generator | None, speeds, slopes: Run | None = None) -> DayResult:
    p = run.p
    s = run.sig
    A_true = run.A_true
    sv, sx = p("sensor.speed_std"), p("sensor.position_std")
    segs = moving_segments(s["sensor.speed"], 6.0 * sv, 100)
    _, prior = prior_for(rng, A_true)
    common = dict(grade_profile=run.grade_profile, length=p("car.length"), gamma=p("car.gamma"),
                  speed_std=sv, distance_std=sx)
    data = []
    for a, b in segs:
        sl = slice(a, b + 1)
        data.append(((run.time[sl], s["sensor.speed"][sl], run.forces[a:b, 0], run.forces[a:b, 1]),
                     dict(distance=s["sensor.position"][sl], **common)))
    oe0 = [fit_segment(*args, prior=prior, **kw) for args, kw in data]
    q = estimate_process_noise_psd(oe0)
    speeds_run = s["car.speed"]
    out = DayResult({}, {}, {}, {}, {}, q, len(segs), 0.0)
    moving = speeds_run[speeds_run > 0.0]
    vv = np.linspace(moving.min(), moving.max(), 100)
    phi = np.column_stack([np.ones_like(vv), vv, vv * vv])
    w0_rms = float(np.sqrt(np.mean((phi @ A_true) ** 2)))
    for name, method in (("OE", "output_error"), ("FE", "filter_error")):
        co = ResistanceCarryOver(base_prior=prior)
        errs = []
        for args, kw in data:
            co.fit(*args, mass=MASS_PRIOR[0], mass_std=MASS_PRIOR[1], process_noise_psd=q,
                   method=method, **kw)
            errs.append(w0_relative_rms_error(speeds_run, tuple(co.A), tuple(A_true)))
        out.w0_err[name] = errs[-1]
        out.w0_err_by_run[name] = errs
        out.z[name] = z_scores(co.A, co.cov_A, A_true, speeds)
        ph = np.column_stack([np.ones(len(speeds)), speeds, np.asarray(speeds) ** 2])
        out.w0_std[name] = np.sqrt(np.einsum("ij,jk,ik->i", ph, co.cov_A, ph))
        out.w0_err_pred[name] = float(np.sqrt(np.mean(np.einsum("ij,jk,ik->i", phi, co.cov_A, phi)))) / w0_rms
        if name == "OE":
            masses = [(f.mass, s["car.total_mass"][a + 2]) for f, (a, _) in zip(co.fits, segs)]
            out.mass_err_pct = 100.0 * max(abs(m - mt) / mt for m, mt in masses)
    ls_A = np.array([s["est.A0"][-1], s["est.A1"][-1], s["est.A2"][-1]])
    # the paper LS after each run: est.* at each run's last moving row
    out.w0_err_by_run["paper LS"] = [
        w0_relative_rms_error(speeds_run, (s["est.A0"][b], s["est.A1"][b], s["est.A2"][b]), tuple(A_true))
        for _, b in segs]
    out.w0_err["paper LS"] = w0_relative_rms_error(speeds_run, tuple(ls_A), tuple(A_true))
    out.z["paper LS"] = z_scores(ls_A, run.A_cov, A_true, speeds)
    out.w0_err["oracle"] = 0.0
    if slopes is not None:         # est.method 2 online, the same seed (same truth and noise)
        sA = est_A(slopes, -1)
        out.w0_err_by_run["LS slopes"] = [w0_relative_rms_error(speeds_run, tuple(est_A(slopes, b)), tuple(A_true))
                                          for _, b in segs]
        out.w0_err["LS slopes"] = w0_relative_rms_error(speeds_run, tuple(sA), tuple(A_true))
        out.z["LS slopes"] = z_scores(sA, slopes.A_cov, A_true, speeds)
        out.w0_std["LS slopes"] = np.sqrt(np.einsum("ij,jk,ik->i", ph, slopes.A_cov, ph))
        out.w0_err_pred["LS slopes"] = float(np.sqrt(np.mean(
            np.einsum("ij,jk,ik->i", phi, slopes.A_cov, phi)))) / w0_rms
    return out


# ------------------------------------------------------------------ (d) online, stations and filter

@dataclass
class StationDay:
    """One seed of station_day through the online estimator (one configuration of ONLINE)."""
    mass_err_max: float          # max |est - true| / true over the stops [-]
    mass_inside: list            # per stop: |est - true| <= 2 est.mass_std
    speed_inside: float          # share of moving rows with |filter - true| <= 2 std (speed)
    dist_inside: float           # the same for the distance
    n_moving: int


def station_day_run(job) -> StationDay:
    """(configuration, seed): station_day on the models chain, the mass at each arrival (the
    run's last row before the stop is confirmed) and the filter's coverage while moving."""
    return station_day_runs([job])[0]


def station_day_runs(jobs) -> list[StationDay]:
    """station_day_run of each (configuration, seed), the runs whole in C on the batch engine
    (harness.run.batch.run_batch: run_on_chain's results bit for bit), CALL_RUNS per call."""
    from harness.run.batch import run_batch
    scenario = load_scenario(LIBRARY / "station_day.toml")
    out = []
    for k in range(0, len(jobs), CALL_RUNS):
        part = jobs[k:k + CALL_RUNS]
        results = run_batch([scenario] * len(part), [{"seed": int(seed), **ONLINE[config]} for config, seed in part])
        out += [_station_day(r) for r in results]
    return out


def _station_day(r) -> StationDay:
    """A station_day RunResult's StationDay."""
    from harness.metrics.estimation import _segments
    m, est, sd = r["car.total_mass"], r["est.mass"], r["est.mass_std"]
    stops = [k for _, k in _segments(r["car.speed"])]
    moving = r["car.speed"] > 0.0
    inside = lambda e, t, s: float(np.mean(np.abs(e[moving] - t[moving]) <= 2.0 * s[moving]))  # noqa: E731
    return StationDay(max(abs(est[k] - m[k]) / m[k] for k in stops),
                      [abs(est[k] - m[k]) <= 2.0 * sd[k] for k in stops],
                      inside(r["filter.speed"], r["car.speed"], r["filter.speed_std"]),
                      inside(r["filter.position"], r["car.position"], r["filter.position_std"]),
                      int(moving.sum()))


def online_study(n_seeds: int, processes: int = 2) -> dict:
    """{config: (share of seeds with every stop within 1 %, mass coverage, speed coverage,
    distance coverage, number of stops)} over station_day seeds 1..n_seeds; the runs split in
    one chunk per process (station_day_runs)."""
    from multiprocessing import Pool
    jobs = [(c, s) for c in ONLINE for s in range(1, n_seeds + 1)]
    chunks = [jobs[i::processes] for i in range(processes)]
    if processes > 1:
        with Pool(processes) as pool:
            done = pool.map(station_day_runs, chunks)
    else:
        done = [station_day_runs(jobs)]
    by_job = {job: day for chunk, days in zip(chunks if processes > 1 else [jobs], done)
              for job, day in zip(chunk, days)}
    runs = [by_job[job] for job in jobs]
    out = {}
    for c in ONLINE:
        rs = [r for (cc, _), r in zip(jobs, runs) if cc == c]
        stops = [x for r in rs for x in r.mass_inside]
        w = np.array([r.n_moving for r in rs], dtype=float)
        out[c] = (float(np.mean([r.mass_err_max <= MASS_WITHIN for r in rs])), float(np.mean(stops)),
                  float(np.average([r.speed_inside for r in rs], weights=w)),
                  float(np.average([r.dist_inside for r in rs], weights=w)), len(stops))
    return out


def library_filter_study() -> dict:
    """{config: (mean and worst speed filter/oracle, mean and worst speed filter/sensor, mean and
    worst distance filter/sensor)} over the library scenarios with speed noise <= 0.05 m/s
    (studies/method_table.py's rows)."""
    sys.path.insert(0, str(ROOT / "studies"))
    import method_table as mt
    split = {c: (p.get("est.method", 0), {k: x for k, x in p.items() if k != "est.method"})
             for c, p in ONLINE.items()}
    methods = sorted({m for m, _ in split.values()})
    extras = [dict(t) for t in dict.fromkeys(tuple(sorted(e.items())) for _, e in split.values())]
    rows = mt.compute_rows(None, methods, extras=tuple(extras))
    out = {}
    for c, (method, extra) in split.items():
        # compute_rows labels a row by its parameter set as handed over: sorted by name (above)
        label = mt.method_label(method, dict(sorted(extra.items())))
        sel = [r for r in rows if r.method == label and not r.rejected and r.speed_noise <= mt.LOW_NOISE + 1e-12]
        so, ss, ds = ([r.speed_ratio for r in sel], [r.speed_vs_sensor for r in sel],
                      [r.dist_vs_sensor for r in sel])
        out[c] = (float(np.mean(so)), float(np.max(so)), float(np.mean(ss)), float(np.max(ss)),
                  float(np.mean(ds)), float(np.max(ds)))
    return out


# ------------------------------------------------------------------ main

def _wilson(p: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion p observed in n trials (Wilson 1927)."""
    den = 1.0 + z * z / n
    mid = (p + z * z / (2 * n)) / den
    half = z * np.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / den
    return mid - half, mid + half


def coverage(zs: list) -> np.ndarray:
    z = np.array([x for x in zs if x is not None])
    return np.mean(np.abs(z) <= 2.0, axis=0) if len(z) else np.full(6, np.nan)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer Monte Carlo seeds (< 1 min)")
    ap.add_argument("--seeds", type=int, default=None, help="Monte Carlo seeds per coasting row")
    ap.add_argument("--day-seeds", type=int, default=None, help="Monte Carlo seeds of the ten-run day")
    args = ap.parse_args(argv)
    n_rows = args.seeds or (8 if args.quick else 40)
    n_day = args.day_seeds or (3 if args.quick else 30)
    n_low = 2 if args.quick else 10
    n_online = 10 if args.quick else 100
    t_start = time.perf_counter()
    print(f"Estimation quality study ({'quick' if args.quick else 'full'}): {n_rows} seeds per coasting "
          f"row, {n_day} ten-run days. Units: s, m/s, N/kN.\n")

    # ---------------------------------------------------------------- (a)
    print("(a) Coasting logs shaped like Meleshin's (2011) Table 1 (coast run-time error of the identified w0)")
    print("    dT = predicted - actual coast time [s]; 'true v0' = harness convention (re-run from the true")
    print("    initial speed; the targets use it); 'rec' = re-run from the initial speed each model fits best")
    print("    (shown to make a point: a fitted start speed hides any w0 error, every method lands near 0).\n")
    row_summary = {}
    coast_z = {m: [] for m in METHODS}
    for r in (1, 2, 3, 4):
        scn = load_scenario(LIBRARY / f"coasting_rusich_row{r}.toml")
        lib_seed = int(scn.parameter("seed"))
        runs = paired_runs(scn, [(lib_seed, None)] + [(1000 + seed, [r, seed]) for seed in range(1, n_rows + 1)])
        lib_c = coast_prepare(runs[0][0], None, runs[0][1])
        mc_c = [coast_prepare(run, np.random.default_rng([r, seed]), slopes)
                for seed, (run, slopes) in zip(range(1, n_rows + 1), runs[1:])]
        # q calibrated over the row's coasts (same train and line): one 33-120 s coast cannot
        # estimate it (row 3: REML collapses towards 0 in ~1 coast of 8, coverage falls to 87 %)
        q = estimate_process_noise_psd([lib_c.oe0] + [c.oe0 for c in mc_c])
        lib = coast_study(lib_c, q)
        mc = [coast_study(c, q) for c in mc_c]
        bound = ROW_BOUNDS[r]
        print(f"  row {r}: bound {bound:.2f} s; library seed {int(scn.parameter('seed'))}; q-hat {q:.2e} m2/s3 "
              f"(REML over the row's {len(mc) + 1} coasts; plant {scn.parameter('car.process_noise_psd'):.0e})")
        print(f"    {'method':9s} {'lib dT true':>11s} {'lib dT rec':>10s} | {'MC mean|dT| true':>16s} "
              f"{'within':>6s} | {'MC mean|dT| rec':>15s} {'within':>6s} | {'w0 err %':>8s}")
        for m in METHODS:
            dt_t = np.array([x.dT_true[m] for x in mc])
            dt_r = np.array([x.dT_rec[m] for x in mc])
            w0e = np.mean([x.w0_err[m] for x in mc])
            row_summary[(r, m)] = (np.mean(np.abs(dt_t)), np.mean(np.abs(dt_t) <= bound),
                                   np.mean(np.abs(dt_r)), np.mean(np.abs(dt_r) <= bound),
                                   lib.dT_true[m], lib.dT_rec[m])
            print(f"    {m:9s} {lib.dT_true[m]:+11.3f} {lib.dT_rec[m]:+10.3f} | {np.mean(np.abs(dt_t)):16.3f} "
                  f"{np.mean(np.abs(dt_t) <= bound):6.0%} | {np.mean(np.abs(dt_r)):15.3f} "
                  f"{np.mean(np.abs(dt_r) <= bound):6.0%} | {100 * w0e:8.2f}")
            coast_z[m] += [x.z[m] for x in mc]
        print()

    # ---------------------------------------------------------------- (b)
    print("(b) Ten consecutive inter-station runs, same resistance, mass changing at every stop")
    day = ten_run_day()
    speeds = np.array([2.0, 5.0, 10.0, 15.0])
    runs = paired_runs(day, [(int(day.parameter("seed")), None)]
                       + [(2000 + seed, [9, seed]) for seed in range(1, n_day + 1)])
    lib_run = runs[0][0]
    A_true_day = lib_run.A_true
    lib = day_study(lib_run, None, speeds, runs[0][1])
    days = [day_study(run, np.random.default_rng([9, seed]), speeds, slopes)
            for seed, (run, slopes) in zip(range(1, n_day + 1), runs[1:])]
    print(f"    runs found: {lib.runs}; q-hat (pooled, REML) median {np.median([d.q for d in days]):.2e} "
          f"m2/s3 (plant {day.parameter('car.process_noise_psd'):.0e}); largest per-run mass error (OE) "
          f"{max(d.mass_err_pct for d in days):.2f} %")
    print(f"    {'method':9s} {'library seed':>12s} | {'MC mean':>8s} {'MC median':>9s} {'MC max':>7s} "
          f"{'share<=2%':>9s} {'predicted':>9s}   (w0 relative RMS error after 10 runs, %; predicted = RMS error")
    print(f"    {'':9s} {'':12s}   {'':8s} {'':9s} {'':7s} {'':9s} {'':9s}    its own covariance expects)")
    day_summary = {}
    for m in ("paper LS", "LS slopes", "OE", "FE", "oracle"):
        e = np.array([d.w0_err[m] for d in days])
        day_summary[m] = (e.mean(), np.mean(e <= W0_TARGET), lib.w0_err[m])
        pred = np.mean([d.w0_err_pred[m] for d in days]) if m in days[0].w0_err_pred else float("nan")
        print(f"    {m:9s} {100 * lib.w0_err[m]:12.2f} | {100 * e.mean():8.2f} {100 * np.median(e):9.2f} "
              f"{100 * e.max():7.2f} {np.mean(e <= W0_TARGET):9.0%} {fmt(100 * pred, '{:9.2f}'):>9s}")
    print("    mean w0 error [%] after k runs, k = 1..10:")
    for m in ("paper LS", "LS slopes", "OE", "FE"):
        by = np.array([d.w0_err_by_run[m] for d in days if len(d.w0_err_by_run[m]) == 10])
        print(f"      {m:9s} " + " ".join(f"{100 * x:5.1f}" for x in by.mean(axis=0)))
    w0t = A_true_day[0] + A_true_day[1] * speeds + A_true_day[2] * speeds ** 2
    print("    where the uncertainty sits after 10 runs: std of w0 [N/kN] at " + ", ".join(f"{v:g}" for v in speeds)
          + " m/s (true w0 " + ", ".join(f"{w:.2f}" for w in w0t) + "):")
    for m in ("LS slopes", "OE", "FE"):
        print(f"      {m:9s} " + " ".join(f"{x:6.3f}" for x in np.mean([d.w0_std[m] for d in days], axis=0)))
    # the same day with ten times less process noise: is the 2 % target information-limited?
    low = with_parameters(day, {"car.process_noise_psd": 1e-5})
    lows = [day_study(run, np.random.default_rng([10, seed]), speeds, slopes)
            for seed, (run, slopes) in zip(range(1, n_low + 1),
                                            paired_runs(low, [(3000 + seed, [10, seed]) for seed in range(1, n_low + 1)]))]
    print(f"    sensitivity, plant process noise 1e-05 m2/s3 ({n_low} days): mean w0 error after 10 runs "
          + ", ".join(f"{m} {100 * np.mean([d.w0_err[m] for d in lows]):.2f} %" for m in ("paper LS", "LS slopes", "OE", "FE"))
          + f" (share <= 2 %: FE {np.mean([d.w0_err['FE'] <= W0_TARGET for d in lows]):.0%})")
    print()

    # ---------------------------------------------------------------- (c)
    print("(c) Coverage of +-2 sigma over the Monte Carlo runs (target 90-98 %)")
    labels = ["A0", "A1", "A2", "w0 lo", "w0 mid", "w0 hi"]
    print(f"    coasting rows (all four, w0 at the coast's min / mid / max speed), {4 * n_rows} runs:")
    print(f"      {'method':9s} " + " ".join(f"{x:>6s}" for x in labels))
    cov_summary = {}
    for m in ("paper LS", "LS slopes", "OE", "FE", "EKF"):
        c = coverage(coast_z[m])
        cov_summary[("coast", m)] = c
        print(f"      {m:9s} " + " ".join(f"{x:6.0%}" for x in c))
    labels_d = ["A0", "A1", "A2"] + [f"w0@{v:g}" for v in speeds]
    print(f"    ten-run days (after the ten runs), {n_day} days:")
    print(f"      {'method':9s} " + " ".join(f"{x:>6s}" for x in labels_d))
    for m in ("paper LS", "LS slopes", "OE", "FE"):
        c = coverage([d.z[m] for d in days])
        cov_summary[("day", m)] = c
        print(f"      {m:9s} " + " ".join(f"{x:6.0%}" for x in c))
    print()

    # ---------------------------------------------------------------- (d)
    print(f"(d) The online estimator: station_day over {n_online} seeds, and the library's filter")
    online = online_study(n_online)
    lib_f = library_filter_study()
    print(f"    {'configuration':20s} {'stops <= 1 %':>12s} {'mass 2s':>8s} {'speed 2s':>8s} {'dist 2s':>8s} |"
          f" {'speed f/oracle':>15s} {'speed f/sensor':>15s} {'dist f/sensor':>14s}   (library: mean / worst)")
    for c in ONLINE:
        share, mc, sc, dc, n_stops = online[c]
        so, sw, ss, ssw, ds, dsw = lib_f[c]
        print(f"    {c:20s} {share:12.0%} {mc:8.1%} {sc:8.1%} {dc:8.1%} | {so:6.3f} / {sw:6.3f} "
              f"{ss:6.3f} / {ssw:6.3f} {ds:5.3f} / {dsw:5.3f}")
    print(f"    ({n_stops} stops per configuration; coverage of speed and distance over the moving rows)\n")

    # ---------------------------------------------------------------- comparison
    names = METHODS
    print("Comparison with the targets. Coast rows: |dT| from the true initial speed (harness convention);")
    print("'MC' = mean over the seeds (share within the bound), met when the mean is within the bound.")
    print("Coverage: the lowest and highest over the quantities of (c); met when every one lies in 90-98 %,")
    print("met* when not but each one's Wilson 95 % interval still overlaps [90, 98] % (within Monte Carlo")
    print("noise), else gap."
          + (" --quick: too few runs for coverage to say much." if args.quick else ""))
    print(f"  {'target':38s} " + " ".join(f"{m:>21s}" for m in names))

    def verdict(v, bound):
        return "met" if v <= bound else f"gap {v - bound:+.2f}"

    for r in (1, 2, 3, 4):
        b_ = ROW_BOUNDS[r]
        lib_cells = [f"{abs(row_summary[(r, m)][4]):.2f} {verdict(abs(row_summary[(r, m)][4]), b_)}" for m in names]
        mc_cells = [f"{row_summary[(r, m)][0]:.2f} ({row_summary[(r, m)][1]:.0%}) {verdict(row_summary[(r, m)][0], b_)}"
                    for m in names]
        print(f"  {f'row {r} |dT| <= {b_:.2f} s, library seed':38s} " + " ".join(f"{c:>21s}" for c in lib_cells))
        print(f"  {f'row {r} |dT| <= {b_:.2f} s, MC':38s} " + " ".join(f"{c:>21s}" for c in mc_cells))
    cells = []
    for m in names:
        if m not in day_summary:
            cells.append("n/a")
            continue
        v, share, _ = day_summary[m]
        cells.append(f"{100 * v:.2f}% ({share:.0%}) "
                     + ("met" if v <= W0_TARGET else f"gap {100 * (v - W0_TARGET):+.2f}"))
    print(f"  {'10 runs: w0 RMS error <= 2 %, MC':38s} " + " ".join(f"{c:>21s}" for c in cells))
    for where, what, n in (("coast", "coasts", 4 * n_rows), ("day", "10-run days", n_day)):
        cells = []
        for m in names:
            c = cov_summary.get((where, m))
            if c is None:
                cells.append("n/a")
                continue
            inside = all(COVERAGE[0] <= x <= COVERAGE[1] for x in c)
            consistent = all(_wilson(x, n)[0] <= COVERAGE[1] and _wilson(x, n)[1] >= COVERAGE[0] for x in c)
            verdict_c = "met" if inside else ("met*" if consistent else "gap")
            cells.append(f"{100 * np.nanmin(c):.0f}-{100 * np.nanmax(c):.0f}% {verdict_c}")
        print(f"  {f'coverage +-2 sigma 90-98 % ({what}, n={n})':38s} " + " ".join(f"{c:>21s}" for c in cells))
    print("\n  online estimator (d)                   " + " ".join(f"{c:>21s}" for c in ONLINE))

    def cov_verdict(x, n):
        if COVERAGE[0] <= x <= COVERAGE[1]:
            return "met"
        lo, hi = _wilson(x, n)
        return "met*" if lo <= COVERAGE[1] and hi >= COVERAGE[0] else "gap"
    rows_d = [
        ("every stop within 1 %, >= 95 % of seeds",
         [f"{online[c][0]:.0%} " + ("met" if online[c][0] >= MASS_SHARE else "gap") for c in ONLINE]),
        ("coverage +-2 sigma 90-98 %, mass",
         [f"{online[c][1]:.1%} {cov_verdict(online[c][1], online[c][4])}" for c in ONLINE]),
        ("coverage, filter speed / distance",
         [f"{online[c][2]:.1%}/{online[c][3]:.1%} "
          + ("met" if all(COVERAGE[0] <= x <= COVERAGE[1] for x in online[c][2:4]) else "gap") for c in ONLINE]),
        ("filter/sensor <= 0.6, worst speed/dist",
         [f"{lib_f[c][3]:.2f}/{lib_f[c][5]:.2f} " + ("met" if max(lib_f[c][3], lib_f[c][5]) <= FILTER_VS_SENSOR
                                                     else "gap") for c in ONLINE]),
        ("filter/oracle <= 1.10 each: mean (worst)",
         [f"{lib_f[c][0]:.3f} ({lib_f[c][1]:.2f}) " + ("met" if lib_f[c][1] <= FILTER_VS_ORACLE
                                                        else f"gap {lib_f[c][1] - FILTER_VS_ORACLE:+.2f}")
          for c in ONLINE]),
    ]
    for label, cells in rows_d:
        print(f"  {label:38s} " + " ".join(f"{c:>21s}" for c in cells))
    print(f"\nruntime {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
