"""The innovation gate (models/filtering/motion_filter.py, MotionFilter.gate): a speed or a
distance whose innovation nu = z - x_bar exceeds GATE_SIGMAS = 6 standard deviations of nu,
sqrt(M + R) on its diagonal, is refused (filter.rejected counts it); within 6 it is taken. The
identification is pickier: a speed beyond FIT_SIGMAS = 4.5 is not identified.

Measurements are put at 5.9 and 6.1 (4.4 and 4.6) standard deviations of the innovation, both
signs, for every filter kind and through the OnlineEstimator, so that moving either threshold
by more than 0.1 fails here. The C core's copies of the two constants (models/core/filter.h)
must be the same numbers: tests/model_tests/core holds the C filter bit-identical to this one.

Speeds [m/s], distances [m], dt [s], forces [N].
"""
from __future__ import annotations

import copy
import math
import re
from pathlib import Path

import numpy as np
import pytest

from models.estimation.identification import IdentifierConfig
from models.estimation.least_squares import theta_from_params
from models.estimation.online import OnlineEstimator, StationConfig
from models.filtering.motion_filter import EKF, LINEARISED, PAPER, SINGER, FilterConfig, MotionFilter
from models.plant.track import GradeProfile, SpeedProfile

ROOT = Path(__file__).resolve().parents[3]
DT = 0.1
THETA = theta_from_params(30.0, 0.89, 0.0288, 0.010498)
LEVEL = GradeProfile((0.0,), (0.0,))
RAMP = SpeedProfile((0.0, 100.0, 700.0), (0.0, 15.0, 15.0))   # V_zad for the linearised kinds
ACCEPTED, REFUSED = 5.9, 6.1     # [innovation standard deviations] either side of GATE_SIGMAS
FIT_TAKEN, FIT_SKIPPED = 4.4, 4.6   # either side of FIT_SIGMAS


def _in_motion(kind: int) -> MotionFilter:
    """A filter of this kind 10 s into a 1 m/s^2 start (seeded sensor noise 0.05 m/s, 1 m),
    with a predicted state and covariance M of its own to gate against."""
    f = MotionFilter(FilterConfig(dt=DT, kind=kind), LEVEL, RAMP if kind in (LINEARISED, PAPER) else None)
    rng = np.random.default_rng(kind)
    for k in range(100):
        t = k * DT
        f.gate(t + 0.05 * rng.standard_normal(), 0.5 * t * t + rng.standard_normal())
        f.update(t + 0.05 * rng.standard_normal(), 0.5 * t * t + rng.standard_normal())
        f.predict(31e3, 0.0, THETA, 1e-5, DT)
    assert f.rejected == 0
    return f


def _innovation_scale(f: MotionFilter) -> tuple[float, float, float, float]:
    """(predicted speed, its innovation std, predicted distance, its innovation std): x_bar plus
    V_zad, and sqrt(M + R) on the diagonal (sensor noise independent of the reading here)."""
    (xb0, xb1), ((m00, _), (_, m11)) = f.x_bar, f.M
    return xb0 + f.vzad_bar, math.sqrt(m00 + f.R[0]), xb1, math.sqrt(m11 + f.R[1])


KINDS = [LINEARISED, EKF, PAPER, SINGER]


@pytest.fixture(scope="module")
def filters() -> dict[int, MotionFilter]:
    return {kind: _in_motion(kind) for kind in KINDS}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_speed_within_6_sigma_is_taken_and_beyond_is_refused(filters, kind, sign):
    speed, speed_scale, position, _ = _innovation_scale(filters[kind])
    accepted, refused = copy.deepcopy(filters[kind]), copy.deepcopy(filters[kind])
    assert accepted.gate(speed + sign * ACCEPTED * speed_scale, position) == (True, True)
    assert accepted.rejected == 0
    assert refused.gate(speed + sign * REFUSED * speed_scale, position) == (False, True)
    assert refused.rejected == 1 and refused.speed_run == 1 and not refused.speed_fit


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_a_distance_within_6_sigma_is_taken_and_beyond_is_refused(filters, kind, sign):
    speed, _, position, position_scale = _innovation_scale(filters[kind])
    accepted, refused = copy.deepcopy(filters[kind]), copy.deepcopy(filters[kind])
    assert accepted.gate(speed, position + sign * ACCEPTED * position_scale) == (True, True)
    assert accepted.rejected == 0
    assert refused.gate(speed, position + sign * REFUSED * position_scale) == (True, False)
    assert refused.rejected == 1 and refused.position_run == 1


@pytest.mark.parametrize("kind", KINDS)
def test_a_speed_beyond_4_5_sigma_is_filtered_but_not_identified(filters, kind):
    speed, speed_scale, position, _ = _innovation_scale(filters[kind])
    for sigmas, fit in ((FIT_TAKEN, True), (FIT_SKIPPED, False), (ACCEPTED, False)):
        f = copy.deepcopy(filters[kind])
        assert f.gate(speed + sigmas * speed_scale, position) == (True, True)
        assert bool(f.speed_fit) == fit, sigmas


@pytest.mark.parametrize("kind", KINDS)
def test_a_refused_speed_does_not_enter_the_update(filters, kind):
    """The posterior after a speed refused at 6.1 sigma is the one after a speed refused at
    1000 sigma, bit for bit (the distance alone updated it); one taken at 5.9 sigma moves it."""
    speed, speed_scale, position, _ = _innovation_scale(filters[kind])
    posteriors = {}
    for sigmas in (ACCEPTED, REFUSED, 1000.0):
        f = copy.deepcopy(filters[kind])
        z = speed + sigmas * speed_scale
        f.gate(z, position)
        f.update(z, position)
        posteriors[sigmas] = (f.x_hat, f.P)
    assert posteriors[REFUSED] == posteriors[1000.0]
    assert posteriors[ACCEPTED][0][0] > posteriors[REFUSED][0][0]


# ------------------------------------------------------------------ through the estimator

def _estimator_in_motion() -> OnlineEstimator:
    """The estimator's filter (EKF, no speed profile) and identification 20 s into a start from
    a station, fed a car accelerating at 1 m/s^2 with seeded sensor noise."""
    est = OnlineEstimator(IdentifierConfig(dt=DT), FilterConfig(dt=DT), StationConfig(), LEVEL, None)
    rng = np.random.default_rng(5)
    for k in range(200):
        t = k * DT
        est.measure(t + 0.05 * rng.standard_normal(), 0.5 * t * t + rng.standard_normal())
        est.propagate(31e3, 0.0, DT)
    return est


@pytest.fixture(scope="module")
def moving_estimator() -> OnlineEstimator:
    """(Not named "estimator": conftest takes that name for the RailCarEstimator FMU's layer.)"""
    est = _estimator_in_motion()
    assert est.filter.rejected == 0 and est.ident.samples > 100     # it is identifying
    return est


@pytest.mark.parametrize("sigmas, rejected, identified", [
    (FIT_TAKEN, 0, True), (FIT_SKIPPED, 0, False), (ACCEPTED, 0, False), (REFUSED, 1, False),
    (-ACCEPTED, 0, False), (-REFUSED, 1, False),
])
def test_the_estimator_counts_a_speed_beyond_6_sigma_in_filter_rejected(moving_estimator, sigmas,
                                                                         rejected, identified):
    """filter.rejected (the FMU output) counts the refused speed; the identification takes
    the pair only within 4.5 sigma."""
    est = copy.deepcopy(moving_estimator)
    speed, speed_scale, position, _ = _innovation_scale(est.filter)
    samples = est.ident.samples
    est.measure(speed + sigmas * speed_scale, position)
    assert est.filter.rejected == rejected
    assert est.ident.samples == samples + identified


# ------------------------------------------------------------------ the C core's copies

@pytest.mark.parametrize("c_name, python_value", [("RC_GATE_SIGMAS", MotionFilter.GATE_SIGMAS),
                                                  ("RC_FIT_SIGMAS", MotionFilter.FIT_SIGMAS)])
def test_the_c_core_gates_at_the_same_number_of_sigmas(c_name, python_value):
    header = ROOT / "models" / "core" / "filter.h"
    found = re.findall(rf"^#define {c_name} ([0-9.eE+-]+)", header.read_text(encoding="utf-8"), re.M)
    assert len(found) == 1, f"{header}: no single #define {c_name}"
    assert float(found[0]) == python_value, f"{header}: {c_name} {found[0]} != MotionFilter's {python_value}"
