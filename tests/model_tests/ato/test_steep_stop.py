"""Targeted stopping on steep marks (models/ato/controller.py ep_deceleration, issue 29): on a
descent the EP stage's programmed deceleration leaves one stage spare for a car
(1 + mass_reserve) heavier than configured, so the relay can still brake harder; stops within
+-0.3 m on +-30 permille marks under the library's disturbances.

Units: grade [permille], a [m/s^2], s [m]. Seeded closed-loop runs (~1 s each).
"""
from __future__ import annotations

import pytest

from models.ato.controller import AtoController
from models.ato.interface import AtoTuning
from models.ato.motion import BRAKE_MASS_STEP, braking_mass, heavier_mass
from models.ato.stopping import ep_deceleration
from models.planning.span import CarTraction
from models.units import G

from closed_loop_line import CAR, line_span, run_span

# 1 km, the last 500 m at -30 or +30 permille; schedules 8 % above the fastest run the
# controller planned with a_ep = 1 m/s^2 everywhere (72.3 s and 67.9 s; on the descent now 72.9 s)
DOWN = line_span((0, 500), (0, -30), 1000.0, ((0, 70),), 78.1)
UP = line_span((0, 500), (0, 30), 1000.0, ((0, 70),), 73.3)


def test_ep_deceleration_keeps_one_stage_spare_on_a_descent():
    tn = AtoTuning()
    assert ep_deceleration(CAR, tn, 0.0) == tn.a_ep          # level: the tuning's a_ep
    assert ep_deceleration(CAR, tn, 30.0) == tn.a_ep
    a = ep_deceleration(CAR, tn, -30.0)
    m = CAR.mass * (1.0 + tn.mass_reserve)
    # the stages it needs for the heavier car: five of six, exactly
    need = 1000.0 * m * a - m * G * (CAR.A0 - 30.0)
    assert need == pytest.approx(5.0 / 6.0 * CAR.mech_force_max, rel=1e-12)
    assert 0.5 * tn.a_ep <= a < tn.a_ep
    assert ep_deceleration(CAR, tn, -45.0) < a               # steeper: gentler
    assert ep_deceleration(CAR, tn, -200.0) == 0.5 * tn.a_ep  # the floor
    # the controller uses it for the course and the relay
    ctrl = AtoController(DOWN, CAR)
    assert ctrl.a_ep == a and ctrl.relay.a_ep == a and ctrl.course.a_ep == a


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_25_percent_heavier_car_stops_within_0_3_m_on_a_minus_30_mark(seed):
    """Seed 3 ran 0.44 m past with all six stages spent on the grade (the old a_ep = 1 m/s^2)."""
    r = run_span(DOWN, seed, {"sensor.speed_std": 0.01, "sensor.speed_std_rel": 0.02,
                              "car.mass": 1.25 * CAR.mass})
    assert abs(r["stop"]) <= 0.3, r["stop"]
    assert abs(r["arrival"]) <= 2.5, r["arrival"]


@pytest.mark.parametrize("span", [DOWN, UP], ids=["-30", "+30"])
@pytest.mark.parametrize("seed", [1, 2])
def test_issue_29_combination_stops_within_0_3_m_on_steep_marks(span, seed):
    """15 % more mass, a 4 m/s headwind, speed noise 0.01 m/s + 1 % of V."""
    r = run_span(span, seed, {"sensor.speed_std": 0.01, "sensor.speed_std_rel": 0.01,
                              "car.mass": 1.15 * CarTraction().mass})
    assert abs(r["stop"]) <= 0.3, r["stop"]
    assert abs(r["arrival"]) <= 2.5, r["arrival"]


# --------------------------------------------- planned for the heavier car (motion.heavier_mass)

def test_plan_and_braking_assume_the_heavier_of_the_blend_and_est_mass():
    m, band = CAR.mass, AtoTuning().mass_band
    assert heavier_mass(m - 3.0, m - 1.0, True, m, band) == m - 1.0   # est heavier than the blend
    assert heavier_mass(m - 3.0, m - 4.0, True, m, band) == m - 3.0   # lighter: the blend's
    assert heavier_mass(m, m + 6.2, True, m, band) == m + 6.2
    assert heavier_mass(m, m + 6.2, False, m, band) == m              # prior only, degraded
    assert heavier_mass(m, 1e6, True, m, band) == band * m
    assert heavier_mass(m, float("nan"), True, m, band) == m
    assert braking_mass(m - 3.0, m) == m                             # never below configured
    assert braking_mass(m + 6.2, m) == m + 6.5                       # rounded up, in steps
    assert braking_mass(m + 6.5, m) == m + 6.5
    assert BRAKE_MASS_STEP == 0.5


def test_a_much_heavier_car_under_speed_noise_stops_at_a_steep_mark():
    """The issue's combination (speed noise 0.01 m/s + 1 % of V, 4 m/s headwind) with a car
    40 % heavier than configured (passengers on a 15 % heavier car) on the -30 permille mark:
    the estimates get no weight (their resistance is sigmas off), but est.mass does for the
    braking curves and the plan. Before, braking planned for the configured 30 t ran 9.5 m past
    such a mark (studies/ato_generated_lines.py, combination, seed 11 span 5)."""
    heavy = {"car.mass": 1.4 * CAR.mass, "sensor.speed_std": 0.01, "sensor.speed_std_rel": 0.01}
    for seed in (1, 2, 3):
        out = run_span(DOWN, seed, heavy, wind=4.0)
        assert abs(out["stop"]) <= 0.3, (seed, out)
