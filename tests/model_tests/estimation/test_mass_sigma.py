"""Is est.mass_std honest for est.method 2 (LS on Sidorenko's slopes)? Its measurement-noise part
against the spread of the mass error over seeded replays of the same runs (relative speed noise
and none); and the residual statistics behind sigma^2 forget with the runs (est.run_forgetting).

Units: speeds [m/s], forces [N], mass [t], dt [s]; Theta as in models/estimation/identification.py.
"""
from __future__ import annotations

import math

import numpy as np

from models.estimation.identification import IdentifierConfig, ParameterIdentifier
from models.estimation.least_squares import theta_from_params
from models.estimation.methods import SlopeLS
from models.units import G

DT = 0.1
A = (0.89, 0.0288, 0.010498)          # Rusich resistance [N/kN, N/kN/(m/s), N/kN/(m/s)^2]
SPEED_STD, SPEED_STD_REL = 0.01, 0.01  # studies/speed_noise_line.py's sensor
PROCESS_STD = 1e-3                     # process noise per step [m/s]


class _Est:
    """What SlopeLS.identify needs of an OnlineEstimator: the identifier and the nominal step."""

    def __init__(self, ident: ParameterIdentifier):
        self.ident = ident
        self.dt_nominal = DT


def _run(est, method, mass_t, rng, *, traction=30e3, cruise=16.0, coast_s=40.0, brake=25e3,
         process_std=PROCESS_STD, rel=SPEED_STD_REL, at_score=None):
    """One run from rest: traction to ``cruise`` [m/s], ``coast_s`` of coasting, braking to rest;
    every sample pair to ``method``; the sensor's noise std SPEED_STD + ``rel`` V. Returns (mass
    error [t], est.mass_std [t]) at the coast's end, where ``at_score()`` is called and the run
    ends (no braking)."""
    theta = theta_from_params(mass_t, *A)
    v, v_meas = 0.0, SPEED_STD * rng.standard_normal()
    phase, t_coast, scored = "traction", 0.0, None
    contiguous = False
    while True:
        f = traction if phase == "traction" else 0.0
        b = brake if phase == "brake" else 0.0
        phi = (f - b, -1.0, -v, -v * v)
        v_next = v + G / 1000.0 * float(np.dot(theta, phi)) * DT + process_std * rng.standard_normal()
        if v_next <= 0.0:
            return scored
        meas_next = v_next + (SPEED_STD + rel * v_next) * rng.standard_normal()
        method.identify(est, f, b, v_meas, meas_next, 0.0, DT, contiguous)
        contiguous = True
        v, v_meas = v_next, meas_next
        if phase == "traction" and v >= cruise:
            phase = "coast"
        elif phase == "coast":
            t_coast += DT
            if t_coast >= coast_s:
                ident = est.ident
                scored = (ident.mass - mass_t, ident.mass_std())
                if at_score is not None:
                    at_score()
                    return scored
                phase = "brake"


def _measurement_share(ident) -> float:
    """The measurement-noise part of est.mass_std [t]: sqrt of the sandwich with b = 0 and no prior
    term (J^-1 a D J^-1, delta method as mass_std)."""
    zero = [0.0] * 4
    a, _ = ident.noise_split()
    Ji = [x / ident._n_info() for x in ident._S]
    return math.sqrt(ident._sandwich(Ji, a, 0.0, zero, zero)[0]) / (G * ident._theta[0] ** 2)


def _second_run_errors(seeds, rel):
    """The second run of a fixed two-run day (run 1 at 33 t, then 35 t after the restart; no
    process noise), replayed with the speed sensor's noise drawn from each seed: (mass errors
    [t], the measurement part of est.mass_std [t]) at the end of the second run's coast."""
    errs, shares = [], []
    for seed in seeds:
        rng = np.random.default_rng([27, 2, seed])
        cfg = IdentifierConfig(dt=DT, method=2, slope_window=10, speed_std=SPEED_STD,
                               speed_std_rel=rel, sigma2_initial=1e-5)
        ident = ParameterIdentifier(cfg)
        est, method = _Est(ident), SlopeLS(cfg.slope_window)
        _run(est, method, 33.0, rng, rel=rel, process_std=1e-6)
        ident.restart_mass()
        seen = []
        err, _ = _run(est, method, 35.0, rng, rel=rel, process_std=1e-6,
                      at_score=lambda: seen.append(_measurement_share(ident)))
        errs.append(err)
        shares.append(seen[0])
    return np.array(errs), np.array(shares)


def test_method_2_measurement_share_of_the_mass_std_matches_the_spread():
    """The same two runs with 200 draws of the sensor's noise (1 % relative): the mass error's
    spread over the draws against the measurement part of the stated est.mass_std (RMS over the
    draws). The D of each sample's own noise through every slope row that holds it states it
    exactly: 1.01 here (1.00 and 0.87 on two other sets of 60 draws; 1.06 and 0.91 with
    speed_std alone); the paper's differenced D with the day's mean a stated 1.28 here (1.16x
    the new share with speed_std alone). 200 draws: the spread's relative standard error is
    ~5 %, so [0.85, 1.1] holds an exact share (2 standard errors each side) and rejects the old."""
    errs, shares = _second_run_errors(range(200), SPEED_STD_REL)
    ratio = float(np.sqrt(np.mean(shares ** 2)) / np.std(errs))
    assert 0.85 <= ratio <= 1.1, f"stated / actual {ratio:.3f}"


def _sigma2_after(noise_by_run, run_forgetting):
    """est.method 0's sigma^2 [(m/s)^2] after runs with the given process noise std [m/s] each."""
    rng = np.random.default_rng([27, 3])
    cfg = IdentifierConfig(dt=DT, speed_std=SPEED_STD, sigma2_initial=1e-5, run_forgetting=run_forgetting)
    ident = ParameterIdentifier(cfg)
    theta = theta_from_params(32.0, *A)
    for std in noise_by_run:
        v, v_meas, contiguous = 0.0, 0.0, False
        for k in range(1500):
            f, b = (25e3, 0.0) if k < 400 else ((0.0, 0.0) if k < 1100 else (0.0, 12e3))
            phi = (f - b, -1.0, -v, -v * v)
            v_next = v + G / 1000.0 * float(np.dot(theta, phi)) * DT + std * rng.standard_normal()
            if v_next <= 0.0:
                break
            meas_next = v_next + SPEED_STD * rng.standard_normal()
            ident.update(f, b, v_meas, meas_next, 0.0, DT, contiguous=contiguous)
            v, v_meas, contiguous = v_next, meas_next, True
        ident.restart_mass()
    return ident.sigma2()


def test_the_process_noise_share_forgets_with_the_runs():
    """Ten calm runs, then three with 4x the process noise (a windy hour): with est.run_forgetting
    = 0.3 the LAG sums behind sigma^2 (and b in the mass's sandwich) weigh the last runs as the A's
    information does, and sigma^2 is within 30 % of what the windy runs alone give (the share of
    the calm runs left is 0.7^3 / (1 + 0.7 + ... ) ~ 11 %); a day-long mean still holds ~10/13 of
    the calm runs (~1/4 of the windy level). Without run forgetting the mean stays day-long."""
    calm, windy = [1e-3] * 10, [4e-3] * 3
    alone = _sigma2_after(windy, 0.3)
    forgetting = _sigma2_after(calm + windy, 0.3)
    day_long = _sigma2_after(calm + windy, 0.0)
    assert 0.7 * alone <= forgetting <= 1.3 * alone, (forgetting, alone)
    assert day_long < 0.5 * alone, (day_long, alone)
