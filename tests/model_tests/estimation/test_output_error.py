"""Tests of models.estimation.output_error: output-error / filter-error fitting of eq. (2) to a segment.

Theta = (1/(P g), A0, A1, A2) [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]; time [s], speed [m/s],
distance [m], forces [N], grade [permille], process-noise density q [m^2/s^3]. Every random
draw is seeded; every tolerance says where it comes from.
"""
from __future__ import annotations

import numpy as np
import pytest

from harness.metrics.estimation import coast_time
from models.chain import ChainConfig, RailCarChain
from models.plant.dynamics import VehicleParams, rk4_step
from models.filtering.motion_filter import FilterConfig
from models.estimation.output_error import (OutputErrorFit, Prior, ResistanceCarryOver,
                                 estimate_process_noise_psd, fit_initial_state, fit_segment,
                                 fuse_estimates, grade_per_interval, physical_prior, simulate)
from models.plant.track import GradeProfile
from models.units import G, resistance_kmh_to_si

MASS = 32.0                                   # [t]
A_TRUE = (0.89, 0.0288, 0.010498)             # Meleshin's (2011) Table 1 row 1 in m/s units
THETA = np.array([1.0 / (G * MASS), *A_TRUE])
DT = 0.1


def _demands(t: float) -> tuple[float, float]:
    """Traction (within the 40 kN / 400 kW / adhesion limits, so applied = demanded), coasting,
    traction again, braking: every kind of excitation eq. (2) has."""
    if t < 35.0:
        return 18e3, 0.0
    if t < 80.0:
        return 0.0, 0.0
    if t < 100.0:
        return 9e3, 0.0
    if t < 140.0:
        return 0.0, 0.0
    return 0.0, 7e3


def _plant_segment(n: int, grade: GradeProfile, v0: float = 0.5):
    """Noise-free truth from the *plant's* integrator (models.plant.dynamics.rk4_step, two RK4
    substeps per sample, an independent implementation), the demands held per sample."""
    p = VehicleParams(mass=MASS, A0=A_TRUE[0], A1=A_TRUE[1], A2=A_TRUE[2])
    t = np.arange(n) * DT
    F = np.empty(n - 1)
    B = np.empty(n - 1)
    v, x = [v0], [0.0]
    for k in range(n - 1):
        F[k], B[k] = _demands(t[k])
        vv, xx = v[-1], x[-1]
        for _ in range(2):
            vv, xx = rk4_step(vv, xx, DT / 2, F[k], B[k], 0.0, p, grade)
        v.append(vv)
        x.append(xx)
    return t, np.array(v), np.array(x), F, B


def _random_walk_coast(rng, n=600, dt=0.2, v0=18.0, q=1e-4, grade=-1.0, A=A_TRUE):
    """A coast of eq. (2) with white-acceleration process noise q [m^2/s^3] (one kick of
    variance q dt per sample, as the plant's grid) and no measurement noise."""
    p = VehicleParams(mass=165.0, A0=A[0], A1=A[1], A2=A[2])
    gp = GradeProfile((0.0,), (grade,))
    v, x = [v0], [0.0]
    for _ in range(n - 1):
        vv, xx = rk4_step(v[-1], x[-1], dt, 0.0, 0.0, 0.0, p, gp)
        v.append(vv + np.sqrt(q * dt) * rng.standard_normal())
        x.append(xx)
    return np.arange(n) * dt, np.array(v), np.array(x), gp


# ------------------------------------------------------------------ the simulation core

def test_simulation_matches_the_plant_and_its_sensitivities_are_exact():
    """One RK4 step per sample against the plant's two substeps: the global RK4 error is
    O(h^4) and the dynamics nearly linear (measured 5e-14 m/s over 150 s), so 1e-6 m/s.
    Sensitivities: the exact derivative of the RK4 recursion, so central finite differences
    agree to their own truncation error (relative 1e-5; measured 4e-9)."""
    gp = GradeProfile((0.0,), (5.0,))
    t, v, x, F, B = _plant_segment(1500, gp)
    g = grade_per_interval(x, gp)
    tr = simulate(THETA, v[0], 0.0, t, F - B, g)
    assert np.max(np.abs(tr.speed - v)) < 1e-6
    assert np.max(np.abs(tr.distance - x)) < 1e-5
    steps = [1e-9, 1e-5, 1e-6, 1e-7, 1e-5]
    for j, h in enumerate(steps):
        th_p, th_m = THETA.copy(), THETA.copy()
        v0_p = v0_m = v[0]
        if j < 4:
            th_p[j] += h
            th_m[j] -= h
        else:
            v0_p, v0_m = v[0] + h, v[0] - h
        sp = simulate(th_p, v0_p, 0.0, t, F - B, g, sensitivities=False)
        sm = simulate(th_m, v0_m, 0.0, t, F - B, g, sensitivities=False)
        for fd, an in (((sp.speed - sm.speed) / (2 * h), tr.dv[:, j]),
                       ((sp.distance - sm.distance) / (2 * h), tr.dx[:, j])):
            assert np.max(np.abs(fd - an)) <= 1e-5 * np.max(np.abs(an))


def test_grade_break_is_integrated_by_interval_means():
    """A grade step inside a sample interval: holding the interval's distance-mean grade is
    within 1 mm/s of a 100x finer plant run (measured 2e-5 m/s; a point grade at the RK4
    stages misses by ~4 mm/s per 25 permille step, measured)."""
    gp = GradeProfile((0.0, 300.0, 800.0), (0.0, 15.0, -10.0))
    t, v, x, F, B = _plant_segment(1400, gp)
    p = VehicleParams(mass=MASS, A0=A_TRUE[0], A1=A_TRUE[1], A2=A_TRUE[2])
    vf, xf = [v[0]], [0.0]
    for k in range(len(t) - 1):
        vv, xx = vf[-1], xf[-1]
        for _ in range(100):
            vv, xx = rk4_step(vv, xx, DT / 100, F[k], B[k], 0.0, p, gp)
        vf.append(vv)
        xf.append(xx)
    tr = simulate(THETA, v[0], 0.0, t, F - B, grade_per_interval(np.array(xf), gp))
    assert np.max(np.abs(tr.speed - np.array(vf))) < 1e-3


# ------------------------------------------------------------------ noise-free recovery

@pytest.mark.parametrize("method", ["output_error", "filter_error"])
def test_noise_free_segment_recovers_theta(method):
    """Noise-free data of the plant (traction, coasting, braking on a 5 permille grade) and a
    weak physical prior 5-35 % away from the truth: the data's information is ~1e10 times the
    prior's (noise stds estimated from the data's second differences, ~5e-7 m/s), and the only
    model mismatch is the RK4 step (5e-14 m/s). Filter error weighs each one-step prediction by
    1/(q dt), so q must be small against that too: q = 1e-10 (with q = 1e-6 the prior's pull
    is 4e-4 relative on A0, measured). Measured relative errors: output error 1e-15 (mass) and
    3e-12 (A's), filter error 7e-11 and 4e-7; tolerances 1e-5 and 1e-4 leave room for
    platform differences in the optimiser's stopping point."""
    gp = GradeProfile((0.0,), (5.0,))
    t, v, x, F, B = _plant_segment(1600, gp)
    q = 1e-10 if method == "filter_error" else None
    f = fit_segment(t, v, F, B, distance=x, grade_profile=gp, prior=physical_prior(30.0, 10.0),
                    process_noise_psd=q, method=method)
    assert f.success and f.fit_mass
    assert f.mass == pytest.approx(MASS, rel=1e-5)
    assert f.A == pytest.approx(A_TRUE, rel=1e-4)
    assert f.v0 == pytest.approx(v[0], abs=1e-6)


def test_coast_holds_the_mass_and_fits_only_the_resistance():
    """F = B = 0: 1/(P g) is unobservable, so it is held (zero variance) and the A's and V0 are
    fitted; noise-free, the A's come back to 1e-4 relative (as above; measured 1.5e-10)."""
    gp = GradeProfile((0.0,), (-1.117,))
    t = np.arange(800) * 0.2
    g = np.full(799, -1.117)
    tr = simulate([0.0, *A_TRUE], 22.0, 0.0, t, np.zeros(799), g, sensitivities=False)
    f = fit_segment(t, tr.speed, distance=tr.distance, grade_profile=gp, prior=physical_prior())
    assert not f.fit_mass and f.cov[0, 0] == 0.0 and f.mass_std == 0.0
    assert f.A == pytest.approx(A_TRUE, rel=1e-4)


# ------------------------------------------------------------------ the published row

A_ROW1 = resistance_kmh_to_si(0.89, 0.008, 0.00081)
GRADE_ROW1 = GradeProfile((0.0,), (-1.117,))


def _row1_log(seed: int):
    """A coasting log shaped like Meleshin's Table 1 row 1 (scenarios/library/coasting_rusich_row1
    .toml): 5 cars / 165 t, 68.1 km/h, 1991 m on -1.117 permille, speed noise 0.1 km/h and
    distance noise 1 m at 0.2 s, plant process noise 1e-4 m^2/s^3; run on models.chain."""
    veh = VehicleParams(mass=165.0, A0=A_ROW1[0], A1=A_ROW1[1], A2=A_ROW1[2])
    chain = RailCarChain(ChainConfig(vehicle=veh, sample_period=0.2, seed=seed,
                                     initial_speed=68.1 / 3.6,
                                     filter=FilterConfig(speed_std=0.1 / 3.6, position_std=1.0)),
                         GRADE_ROW1)
    rows = [(0.0, chain.plant.state.speed, chain.plant.state.position, chain.sensor_speed,
             chain.sensor_position)]
    k = 0
    while chain.plant.state.position < 1991.0:
        chain.do_step(k * 0.2, 0.2, 0.0, 0.0, 0.0)
        k += 1
        s = chain.plant.state
        rows.append((k * 0.2, s.speed, s.position, chain.sensor_speed, chain.sensor_position))
    return np.array(rows).T


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_row1_coast_time_within_the_published_bound(seed):
    """Meleshin's Table 1 row 1: run time predicted with the identified coefficients within 0.25 s
    (harness.metrics.estimation.coast_time from the true initial speed, as harness.metrics.estimation.summarise).

    Filter error with the plant's process-noise density (a configured constant, the study
    estimates it). Measured over seeds 1-20: |dT| mean 0.07 s, max 0.20 s; these seeds 0.01,
    0.05, 0.10 s. The true coefficients themselves miss by up to 0.87 s on those 20 seeds (the
    plant's process noise moves the realised coast), which is why output error with the true
    start speed (max 0.63 s) is not the tool for this metric (studies/estimation_quality.py)."""
    t, v, x, vm, xm = _row1_log(seed)
    f = fit_segment(t, vm, distance=xm, grade_profile=GRADE_ROW1, prior=physical_prior(),
                    speed_std=0.1 / 3.6, distance_std=1.0, process_noise_psd=1e-4,
                    method="filter_error")
    predicted = coast_time(v[0], x[0], x[-1], tuple(f.A), 165.0, 0.0, 0.0, GRADE_ROW1)
    assert abs(predicted - (t[-1] - t[0])) <= 0.25


def test_initial_state_of_a_given_model():
    """fit_initial_state with the true Theta on a noise-free coast returns its start (1e-6)."""
    t = np.arange(400) * 0.2
    tr = simulate([0.0, *A_TRUE], 15.0, 7.0, t, np.zeros(399), np.zeros(399), sensitivities=False)
    v0, x0 = fit_initial_state([0.0, *A_TRUE], t, tr.speed, distance=tr.distance)
    assert v0 == pytest.approx(15.0, abs=1e-6) and x0 == pytest.approx(7.0, abs=1e-6)


# ------------------------------------------------------------------ honest covariance

def test_covariance_matches_errors_under_process_noise():
    """40 seeded coasts with process noise q = 1e-4 and speed noise 0.05 m/s. The white
    formula (J^T J)^-1 s^2 is far too small (z-scores of w0 at 16 m/s: std 20, measured); the
    output-error sandwich and the filter error are honest: z std within [0.7, 1.35] (measured
    0.98 and 0.96; the std of a 40-sample std is ~11 %, so +-3 SE)."""
    rng = np.random.default_rng(7)
    z = {"white": [], "sandwich": [], "filter": []}
    for _ in range(40):
        t, v, x, gp = _random_walk_coast(rng)
        vm = v + 0.05 * rng.standard_normal(len(v))
        xm = x + rng.standard_normal(len(x))
        kw = dict(distance=xm, grade_profile=gp, prior=physical_prior(), speed_std=0.05,
                  distance_std=1.0)
        oe = fit_segment(t, vm, process_noise_psd=1e-4, **kw)
        fe = fit_segment(t, vm, process_noise_psd=1e-4, method="filter_error", **kw)
        w_true = A_TRUE[0] + A_TRUE[1] * 16.0 + A_TRUE[2] * 256.0
        phi = np.array([1.0, 16.0, 256.0])
        z["white"].append((oe.w0(16.0) - w_true) / np.sqrt(phi @ oe.cov_white[1:, 1:] @ phi))
        z["sandwich"].append((oe.w0(16.0) - w_true) / oe.w0_std(16.0)[0])
        z["filter"].append((fe.w0(16.0) - w_true) / fe.w0_std(16.0)[0])
    assert np.std(z["white"]) > 5.0
    assert 0.7 <= np.std(z["sandwich"]) <= 1.35
    assert 0.7 <= np.std(z["filter"]) <= 1.35


def test_process_noise_estimate_pooled_over_segments():
    """REML estimate of q from 8 pooled two-minute output-error coasts (measurement noise
    known): within +-40 % of the truth. Measured over 10 such pools: mean 1.17e-4 (the
    output-error fits' absorption is not fully undone), spread 10 %; this seed 1.09e-4."""
    rng = np.random.default_rng(11)
    fits = []
    for _ in range(8):
        t, v, x, gp = _random_walk_coast(rng)
        vm = v + 0.05 * rng.standard_normal(len(v))
        fits.append(fit_segment(t, vm, distance=x + rng.standard_normal(len(x)), grade_profile=gp,
                                prior=physical_prior(), speed_std=0.05, distance_std=1.0))
    q = estimate_process_noise_psd(fits)
    assert 0.6e-4 <= q <= 1.4e-4


# ------------------------------------------------------------------ across runs

def test_fusion_counts_a_common_prior_once():
    """One run fused into ResistanceCarryOver (its base prior = the fit's prior) gives back
    the fit's own posterior: the prior is removed from the run's data information and added
    once. With q = 0 given, cov = (J^T J)^-1 without the s^2 rescaling, so the identity holds
    to the linearisation (measured 3e-9 on the A's, 1e-11 on cov; tolerance 1e-6). Two equal
    pure-data estimates fuse to the same mean and half the covariance; forgetting 1/2 weights
    the newer one 2:1."""
    rng = np.random.default_rng(3)
    t, v, x, gp = _random_walk_coast(rng, q=0.0)
    vm = v + 0.05 * rng.standard_normal(len(v))
    xm = x + rng.standard_normal(len(x))
    co = ResistanceCarryOver()
    f = co.fit(t, vm, distance=xm, grade_profile=gp, speed_std=0.05, distance_std=1.0,
               process_noise_psd=0.0)
    assert co.A == pytest.approx(f.A, rel=1e-6)
    assert co.cov_A == pytest.approx(f.cov_A, rel=1e-6)
    C = np.diag([0.04, 1e-4, 1e-6])
    A, cov = fuse_estimates([((1.0, 0.03, 0.01), C), ((1.0, 0.03, 0.01), C)])
    assert A == pytest.approx([1.0, 0.03, 0.01]) and cov == pytest.approx(C / 2)
    A, _ = fuse_estimates([((0.0, 0.0, 0.0), C), ((3.0, 0.0, 0.0), C)], forgetting=0.5)
    assert A[0] == pytest.approx(2.0)


def test_priors_and_validation():
    """Prior.from_std: inf / None mean no prior; bad inputs raise ValueError naming them."""
    pr = Prior.from_std([0.0, 1.0, 0.03, 0.01], [None, 1.0, float("inf"), 0.01])
    assert np.diag(pr.info) == pytest.approx([0.0, 1.0, 0.0, 1e4])
    t = np.arange(10) * 0.1
    with pytest.raises(ValueError, match="process_noise_psd"):
        fit_segment(t, np.ones(10), method="filter_error")
    with pytest.raises(ValueError, match="method"):
        fit_segment(t, np.ones(10), method="equation_error")
    with pytest.raises(ValueError, match="increase"):
        fit_segment(t[::-1], np.ones(10))
    with pytest.raises(ValueError, match="traction"):
        fit_segment(t, np.ones(10), traction=np.ones(3))
    assert isinstance(fit_segment(t, 10.0 - 0.01 * t), OutputErrorFit)
