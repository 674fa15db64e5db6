"""Analytic tests of models.plant.dynamics: eq. (1)-(2) of MODEL.md, RK4 plant, limits, noise scaling.

Units: speed [m/s], distance [m], force [N], mass [t], specific force [N/kN], grade [permille].
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from models.plant.dynamics import (
    STANDSTILL, TRACTION, CarPlant, VehicleParams, acceleration, adhesion_force_limit,
    applied_forces, brake_force_limit, main_resistance, rk4_step, traction_force_limit,
)
from models.plant.noise import NormalStream
from models.plant.track import GradeProfile
from models.units import G

LEVEL = GradeProfile.level()


def _no_noise():
    """normal_draws for a noise-free plant: fails loudly if the plant ever draws."""
    raise AssertionError("a plant with noise_psd = 0 must not draw noise")


def _plant(params, *, step=0.05, noise_psd=0.0, grade=LEVEL, draws=_no_noise, dwell=20.0):
    return CarPlant(params, grade, step=step, noise_psd=noise_psd, station_dwell=dwell,
                    normal_draws=draws)


# ----------------------------------------------------------------- closed forms

def test_constant_force_level_track_matches_closed_form():
    """A1 = A2 = 0, no wind, level: dV/dt = g/1000 (F/(Pg) - A0) is constant, so RK4 in the
    plant reproduces V = a t, X = a t^2 / 2 to rounding."""
    p = VehicleParams(mass=30.0, A0=0.89, A1=0.0, A2=0.0)
    F = 20e3                                  # below F_max, P_max / V and adhesion for V < 20 m/s
    a = G / 1000.0 * (F / (p.mass * G) - p.A0)
    plant = _plant(p, step=0.05)
    for k in range(1, 26):                    # 25 s: V reaches 16 m/s (power limit 400 kW / 16 m/s = 25 kN > F)
        t = float(k)
        plant.advance(t, F, 0.0, 0.0)
        # RK4 is exact for a constant derivative; 500 steps of rounding stay far below 1e-12 relative
        assert plant.state.speed == pytest.approx(a * t, rel=1e-12)
        # same argument for the quadratic distance
        assert plant.state.position == pytest.approx(0.5 * a * t * t, rel=1e-12)
    # the output acceleration is the closed-form constant (same float expression, reordered)
    assert plant.state.acceleration == pytest.approx(a, rel=1e-12)
    assert plant.state.mode == TRACTION
    assert plant.state.traction_force == F


def test_linear_resistance_gives_exponential_approach_rk4_h005():
    """A1 > 0, A2 = 0: dV/dt = k (f - A0 - A1 V), k = g/1000/(1+gamma), so
    V = V_inf (1 - exp(-t/T)), T = 1/(k A1), V_inf = (f - A0)/A1, X = V_inf (t - T (1 - exp(-t/T))).
    RK4 at h = 0.05 s must match to its truncation error (this also checks gamma's 1/(1+gamma))."""
    p = VehicleParams(mass=30.0, A0=0.89, A1=5.0, A2=0.0, gamma=0.2)
    F = 20e3
    f = F / (p.mass * G)                      # [N/kN]
    k = G / 1000.0 / (1.0 + p.gamma)
    T = 1.0 / (k * p.A1)                      # ~24.5 s
    v_inf = (f - p.A0) / p.A1                 # ~13.4 m/s: F stays below P_max / V = 30 kN
    h = 0.05
    v, x = 0.0, 0.0
    for n in range(1, 1201):                  # 60 s
        v, x = rk4_step(v, x, h, F, 0.0, 0.0, p, LEVEL)
        t = n * h
        v_exact = v_inf * (1.0 - math.exp(-t / T))
        x_exact = v_inf * (t - T * (1.0 - math.exp(-t / T)))
        # RK4 on y' = -y/T: local error (h/T)^5/120 |y|, summed over t/h steps gives a global
        # error <= (t/T) (h/T)^4 V_inf (the 1/120 dropped as margin), plus 1e-12 for rounding
        tol_v = (t / T) * (h / T) ** 4 * v_inf + 1e-12
        assert abs(v - v_exact) <= tol_v     # truncation bound derived above
        # distance integrates the speed error over t, plus rounding of a ~600 m sum of 1200 terms
        assert abs(x - x_exact) <= tol_v * t + 1e-12 * max(x_exact, 1.0) * n
    assert v == pytest.approx(v_inf * (1.0 - math.exp(-60.0 / T)), rel=1e-9)  # see tol_v above


# ----------------------------------------------------------------- standstill and stopping

def test_no_backward_roll_at_rest_on_uphill():
    """A car at rest on a 20 permille uphill with zero force (and with a too-small force) stays
    at V = 0 with X unchanged, even with process noise switched on."""
    uphill = GradeProfile((0.0,), (20.0,))
    p = VehicleParams()
    rng = np.random.default_rng(11)
    for traction in (0.0, 3e3):               # 3 kN: f = 10.2 N/kN < A0 + i = 20.89 N/kN
        plant = _plant(p, grade=uphill, noise_psd=1e-2, draws=rng.standard_normal)
        plant.state.position = 123.0
        for k in range(1, 61):
            plant.advance(k * 1.0, traction, 0.0, 0.0)
            assert plant.state.speed == 0.0
            assert plant.state.position == 123.0
        assert plant.state.mode == STANDSTILL
        assert plant.state.acceleration == 0.0


def test_coasting_uphill_stops_and_never_rolls_back():
    """Coasting up a 20 permille grade from 5 m/s: speed falls to 0, never goes negative, and
    the car stays where it stopped (X never decreases)."""
    uphill = GradeProfile((0.0,), (20.0,))
    plant = _plant(VehicleParams(), grade=uphill)
    plant.state.speed = 5.0
    x_prev = plant.state.position
    speeds = []
    for k in range(1, 1201):                  # 60 s at 0.05 s communication steps
        plant.advance(k * 0.05, 0.0, 0.0, 0.0)
        speeds.append(plant.state.speed)
        assert plant.state.speed >= 0.0
        assert plant.state.position >= x_prev
        x_prev = plant.state.position
    assert 0.0 in speeds
    i_stop = speeds.index(0.0)
    assert all(s == 0.0 for s in speeds[i_stop:])
    assert plant.state.position == x_prev


def test_braking_to_stop_stops_and_stays():
    """Braking from 10 m/s with A's = 0: constant deceleration d = g/1000 B/(Pg); the car
    stops at v0^2/(2d), speed never negative, and stays at rest with X fixed while braked."""
    p = VehicleParams(A0=0.0, A1=0.0, A2=0.0)
    B = 20e3
    d = G / 1000.0 * B / (p.mass * G)         # [m/s^2]
    h = 0.05
    for v0 in (10.0, 10.013, 9.97):           # different stopping instants inside the last step
        plant = _plant(p, step=h)
        plant.state.speed = v0
        stopped_at = None
        for k in range(1, 801):               # 40 s; stop after ~15 s
            plant.advance(k * h, 0.0, B, 0.0)
            assert plant.state.speed >= 0.0
            if plant.state.speed == 0.0 and stopped_at is None:
                stopped_at = plant.state.position
            if stopped_at is not None:
                assert plant.state.speed == 0.0
                assert plant.state.position == stopped_at
        assert stopped_at is not None
        # see test_stopping_distance_error_is_within_last_step_bound for the d h^2 / 8 bound
        assert abs(stopped_at - v0 ** 2 / (2.0 * d)) <= d * h * h / 8.0
        assert plant.state.mode == STANDSTILL
        assert plant.state.brake_force == B


def test_stopping_distance_error_is_within_last_step_bound():
    """Constant deceleration d (A's = 0): every step before the stop is exact (RK4 on a
    parabola); in the last step RK4's stages are clipped at V = 0 and the stop instant is
    interpolated. Worst case (v < d h / 2 left): stage 2 sees V < 0 and gives a = 0, so
    V_new = v - d h / 2, t_stop = 2 v / d and X gains v^2/d instead of v^2/(2d): an error of
    v^2/(2d) <= d h^2 / 8. Scanned over stopping phases, the error stays within d h^2 / 8."""
    p = VehicleParams(A0=0.0, A1=0.0, A2=0.0)
    B = 20e3
    d = G / 1000.0 * B / (p.mass * G)
    h = 0.05
    worst = 0.0
    for v0 in np.linspace(9.9, 10.0, 81):    # 0.1 m/s spans 1.5 steps' worth of d h: all phases
        v, x = v0, 0.0
        for _ in range(1000):
            v, x = rk4_step(v, x, h, 0.0, B, 0.0, p, LEVEL)
            assert v >= 0.0
            if v == 0.0:
                break
        assert v == 0.0
        worst = max(worst, abs(x - v0 ** 2 / (2.0 * d)))
    assert worst <= d * h * h / 8.0            # the derived bound (measured 0.124 d h^2)
    assert worst >= d * h * h / 100.0          # and the scan did hit clipped last steps


def test_departure_after_dwell_restarts_distance_only_after_full_dwell():
    """A car standing at 800 m departs: after >= station_dwell at rest the distance restarts at
    0 (a station stop is counted); after a shorter stop it keeps counting from 800 m."""
    F = 20e3
    a = G / 1000.0 * (F / (30.0 * G) - 0.89)     # breakaway acceleration at V = 0 (A1 V = A2 V^2 = 0)
    for stand, restarted in ((25.0, True), (10.0, False)):
        plant = _plant(VehicleParams(), step=0.05, dwell=20.0)
        plant.state.position = 800.0
        plant.advance(stand, 0.0, 0.0, 0.0)
        assert (plant.state.speed, plant.state.position) == (0.0, 800.0)
        assert plant.state.still_time == pytest.approx(stand, abs=1e-9)   # float sum of steps
        plant.advance(stand + 0.1, F, 0.0, 0.0)
        x0 = 0.0 if restarted else 800.0
        assert plant.state.stops == (1 if restarted else 0)
        # 0.1 s from rest: X ~ a t^2 / 2 = 3.3 mm; V's drop with speed (A1 V, A2 V^2) over
        # 0.1 s changes it by < 1e-6 m
        assert plant.state.position - x0 == pytest.approx(0.5 * a * 0.01, abs=1e-6)
        assert plant.state.still_time == 0.0 and plant.state.mode == TRACTION


# ----------------------------------------------------------------- forces

@pytest.mark.parametrize("params", [
    VehicleParams(),                                        # F_max and P_max / V bind
    VehicleParams(adhesion_factor=0.3),                     # wet rail: adhesion binds at low speed
    VehicleParams(adhesion_mass_fraction=0.25),             # few driven axles: adhesion, then power
])
def test_traction_limit_is_min_of_force_power_adhesion(params):
    """Applied traction = min(demand, F_max, P_max/V, P_adh g psi(V)) with Curtius-Kniffler
    psi = 0.161 + 7.5/(V_kmh + 44); each limit binds somewhere in the parametrised cases."""
    binding = set()
    for v in (0.0, 1.0, 5.0, 10.0, 15.0, 22.0, 30.0):
        psi = 0.161 + 7.5 / (3.6 * v + 44.0)
        adh = 1000.0 * params.mass * params.adhesion_mass_fraction * G * psi * params.adhesion_factor
        limits = {"force": params.traction_force_max, "adhesion": adh}
        if v > 0:
            limits["power"] = params.traction_power_max / v
        expected = min(limits.values())
        binding.add(min(limits, key=limits.get))
        # same arithmetic in a different order: rounding only
        assert traction_force_limit(v, params) == pytest.approx(expected, rel=1e-12)
        f, b = applied_forces(v, 1e9, 0.0, params)
        assert f == pytest.approx(expected, rel=1e-12)  # clipped demand, rounding only
        assert b == 0.0
        small = 0.5 * expected
        assert applied_forces(v, small, 0.0, params) == (small, 0.0)   # below the limit: unchanged
    assert len(binding) >= 2                   # the case really exercises more than one limit


def test_brake_demand_cuts_traction_and_brake_is_clipped():
    """Any brake demand > 0 zeroes traction (interlock); the brake is clipped to
    min(B_max, adhesion on all axles)."""
    p = VehicleParams(adhesion_mass_fraction=0.5)
    assert applied_forces(10.0, 30e3, 5e3, p) == (0.0, 5e3)
    assert applied_forces(10.0, 30e3, 1e-3, p) == (0.0, 1e-3)
    v = 10.0
    adh_all = adhesion_force_limit(v, p) / p.adhesion_mass_fraction
    f, b = applied_forces(v, 30e3, 1e9, p)
    assert f == 0.0
    assert b == min(p.brake_force_max, adh_all) == brake_force_limit(v, p)


def test_wind_moves_all_three_resistance_coefficients():
    """For V + Vw > 0, w0(V, Vw) = (A0 + A2 Vw^2) + (A1 + 2 A2 Vw) V + A2 V^2 (MODEL.md s. 2)."""
    rng = np.random.default_rng(2024)
    p = VehicleParams(A0=0.89, A1=0.0288, A2=0.010498)
    for _ in range(200):
        v = rng.uniform(0.0, 25.0)
        vw = rng.uniform(-v + 0.01, 15.0)        # head- or tailwind, V + Vw > 0
        expected = (p.A0 + p.A2 * vw ** 2) + (p.A1 + 2.0 * p.A2 * vw) * v + p.A2 * v ** 2
        # values ~1..15 N/kN, algebraically equal forms: rounding ~1e-15 relative
        assert main_resistance(v, vw, p) == pytest.approx(expected, rel=1e-12, abs=1e-12)
    # a tailwind faster than the car pushes it: the drag term is A2 (V + Vw)|V + Vw| (sign kept)
    assert main_resistance(2.0, -6.0, p) == pytest.approx(p.A0 + p.A1 * 2.0 - p.A2 * 16.0, rel=1e-12)  # rounding
    assert main_resistance(7.0, 0.0, p) == pytest.approx(p.A0 + p.A1 * 7 + p.A2 * 49, rel=1e-14)  # eq. (1), rounding


def test_rotating_mass_factor_divides_acceleration():
    """gamma divides the acceleration by (1 + gamma) for every force, grade and wind."""
    rng = np.random.default_rng(7)
    for _ in range(100):
        gamma = rng.uniform(0.0, 0.3)
        p0 = VehicleParams(gamma=0.0)
        pg = VehicleParams(gamma=gamma)
        args = (rng.uniform(0.1, 25), rng.uniform(0, 4e4), rng.uniform(0, 4e4),
                rng.uniform(-20, 20), rng.uniform(-5, 5))
        # one extra division: rounding only
        assert acceleration(*args, pg) == pytest.approx(acceleration(*args, p0) / (1 + gamma),
                                                        rel=1e-12, abs=1e-15)  # rounding


@pytest.mark.parametrize("field, value", [
    ("mass", 0.0), ("mass", -3.0), ("A0", -0.1), ("A1", -1e-3), ("A2", -1e-4), ("gamma", -0.1),
    ("length", -1.0), ("traction_force_max", 0.0), ("traction_power_max", -1.0),
    ("brake_force_max", 0.0), ("adhesion_mass_fraction", 0.0), ("adhesion_mass_fraction", 1.5),
    ("adhesion_factor", 0.0), ("adhesion_factor", 2.0), ("mass", float("nan")),
    ("A2", float("inf")),
])
def test_validate_names_the_bad_parameter(field, value):
    """VehicleParams.validate raises ValueError whose message names car.<field>."""
    p = VehicleParams(**{field: value})
    with pytest.raises(ValueError, match=rf"car\.{field}\b"):
        p.validate()
    VehicleParams().validate()                 # defaults are valid (no exception)


# ----------------------------------------------------------------- process noise

def _free_roller():
    """Zero resistance, level, no force: dV/dt = 0 exactly, so speed changes only by noise."""
    return VehicleParams(A0=0.0, A1=0.0, A2=0.0)


@pytest.mark.parametrize("h", [0.01, 0.1])
def test_process_noise_increment_is_sqrt_psd_h_times_draws(h):
    """Exact check of the scaling: with zero resistance each grid step adds
    sqrt(noise_psd * h) * (standard normal draw), so 1 s of speed change is that times the sum
    of the 1/h draws."""
    psd = 0.01
    rng = np.random.default_rng(99)
    drawn = []

    def draws():
        z = float(rng.standard_normal())
        drawn.append(z)
        return z

    plant = _plant(_free_roller(), step=h, noise_psd=psd, draws=draws)
    plant.state.speed = 50.0
    for k in range(1, 11):
        v0, n0 = plant.state.speed, len(drawn)
        plant.advance(float(k), 0.0, 0.0, 0.0)
        assert len(drawn) - n0 == round(1.0 / h)            # one draw per grid step
        expected = math.sqrt(psd * h) * sum(drawn[n0:])
        # 100 additions to a 50 m/s speed: rounding ~1e-13 m/s
        assert plant.state.speed - v0 == pytest.approx(expected, abs=1e-11)


@pytest.mark.parametrize("h", [0.01, 0.1])
def test_process_noise_variance_per_second_independent_of_step(h):
    """Var of the speed increment over 1 s = noise_psd * 1 s at both solver steps (one long
    seeded free-rolling run at 50 m/s, 1000 one-second increments)."""
    psd = 0.01
    plant = _plant(_free_roller(), step=h, noise_psd=psd,
                   draws=NormalStream(np.random.SeedSequence(5)))
    plant.state.speed = 50.0                   # random walk std over 1000 s is 3 m/s: never near 0
    speeds = [plant.state.speed]
    n = 1000
    for k in range(1, n + 1):
        plant.advance(float(k), 0.0, 0.0, 0.0)
        speeds.append(plant.state.speed)
    inc = np.diff(speeds)
    var = float(np.mean(inc ** 2))             # the mean is known to be 0: n degrees of freedom
    # Gaussian increments: the mean square has relative std sqrt(2/n) = 4.5 %; allow 5 sigma.
    # A step-size error in the scaling would be off by a factor ~10 (or 1/10).
    assert var == pytest.approx(psd * 1.0, rel=5.0 * math.sqrt(2.0 / n))
    assert abs(float(np.mean(inc))) <= 5.0 * math.sqrt(psd / n)  # zero mean, 5 sigma of the mean


def test_fast_dynamics_closures_agree_with_the_reference_functions():
    """The plant's bound closures (held_input_dynamics) compute what the readable functions
    applied_forces / acceleration / main_resistance compute (same formulas; 1e-12 relative for
    the reordered products)."""
    from models.plant.dynamics import VehicleParams, acceleration, applied_forces, held_input_dynamics
    from models.plant.track import GradeProfile
    p = VehicleParams(mass=33.0, gamma=0.07, adhesion_factor=0.4, length=20.0)
    grade = GradeProfile((0.0, 100.0, 250.0), (0.0, 12.0, -8.0))
    for f_dem, b_dem, wind in ((40e3, 0.0, 0.0), (10e3, 0.0, 8.0), (0.0, 30e3, -5.0), (0.0, 0.0, 3.0)):
        forces, accel = held_input_dynamics(p, grade, f_dem, b_dem, wind)
        for v in (0.5, 3.0, 11.0, 25.0):
            for x in (50.0, 180.0, 400.0):
                f, b = applied_forces(v, f_dem, b_dem, p)
                assert forces(v) == pytest.approx((f, b), rel=1e-12)
                a_ref = acceleration(v, f, b, grade.average(x, p.length), wind, p)
                assert accel(v, x) == pytest.approx(a_ref, rel=1e-12, abs=1e-15)


def test_the_equation_functions_are_eq1_eq2_and_their_inverse():
    """The one Python copy of eqs. (1)-(2) (issue 26): acceleration is acceleration_eq2 of
    resistance_eq1 (exactly: the same operations), specific_force_eq2 inverts acceleration_eq2
    (1e-12 relative), and acceleration_polynomial's c0 - c1 V - c2 V^2 is eq. (2) for V >= 0 in
    still air with Theta = (1/(P g), A0, A1, A2) (1e-12 relative: its products are regrouped).
    Values by hand at 60 km/h: w0 = 0.89 + 0.0288 * 16.67 + 0.010498 * 16.67^2 = 4.286 N/kN."""
    from models.plant.dynamics import (acceleration_eq2, acceleration_gain, acceleration_polynomial,
                                       resistance_eq1, specific_force_eq2)
    p = VehicleParams(mass=33.0, A0=0.89, A1=0.0288, A2=0.010498, gamma=0.07)
    assert resistance_eq1(60.0 / 3.6, p.A0, p.A1, p.A2) == pytest.approx(4.286, abs=1e-3)
    assert resistance_eq1(10.0, 1.0, 0.0, 0.01, wind=-12.0) == pytest.approx(1.0 - 0.01 * 4.0)  # tailwind pushes
    k = acceleration_gain(p.gamma)
    assert k == G / 1000.0 / 1.07
    theta = (1.0 / (p.mass * G), p.A0, p.A1, p.A2)
    for v, f, b, grade, wind in ((0.0, 30e3, 0.0, 5.0, 0.0), (12.0, 0.0, 0.0, -8.0, 4.0),
                                 (22.0, 0.0, 25e3, 12.0, -3.0), (7.5, 18e3, 0.0, 0.0, 0.0)):
        a = acceleration(v, f, b, grade, wind, p)
        w0 = resistance_eq1(v, p.A0, p.A1, p.A2, wind)
        assert a == acceleration_eq2((f - b) / (p.mass * G), w0, grade, k)
        assert main_resistance(v, wind, p) == w0
        assert specific_force_eq2(a, w0, grade, k) == pytest.approx((f - b) / (p.mass * G), rel=1e-12, abs=1e-12)
        if wind == 0.0:
            c0, c1, c2 = acceleration_polynomial(theta, f - b, grade, k)
            assert c0 - c1 * v - c2 * v * v == pytest.approx(a, rel=1e-12, abs=1e-15)
