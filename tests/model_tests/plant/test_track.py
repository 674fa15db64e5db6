"""Tests of models.plant.track: grade averaging (exact integrals), CSV parsing errors, speed profile."""
from __future__ import annotations

import numpy as np
import pytest

from models.plant.track import (
    GRADE_COLUMNS, SPEED_COLUMNS, GradeProfile, ProfileError, SpeedProfile, parse_profile_csv,
)

# grade 2 on [0, 100), -4 on [100, 250), 6 from 250 on [permille]
PROFILE = GradeProfile((0.0, 100.0, 250.0), (2.0, -4.0, 6.0))


# ----------------------------------------------------------------- GradeProfile

@pytest.mark.parametrize("x, length, expected", [
    (300.0, 250.0, (2 * 50 - 4 * 150 + 6 * 50) / 250),   # [50, 300]: -200 / 250 = -0.8
    (200.0, 150.0, (2 * 50 - 4 * 100) / 150),            # [50, 200]: -300 / 150 = -2
    (100.0, 100.0, 2.0),                                  # [0, 100] lies on the first piece
    (260.0, 20.0, (-4 * 10 + 6 * 10) / 20),               # straddles 250: 1
    (20.0, 50.0, 2.0),                                    # [-30, 20]: first grade before 0
    (1000.0, 300.0, 6.0),                                 # beyond the last breakpoint
    (130.0, 60.0, (2 * 30 - 4 * 30) / 60),                # [70, 130]: -1
])
def test_grade_average_is_exact_integral_average(x, length, expected):
    """average(x, L) = (1/L) * integral of i over [x - L, x], hand-computed piecewise."""
    # a handful of products and sums of small integers: rounding only
    assert PROFILE.average(x, length) == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_grade_average_with_first_breakpoint_after_zero():
    """Before the first distance the first grade applies, also inside the integral."""
    prof = GradeProfile((100.0, 200.0), (3.0, 5.0))
    assert prof.average(150.0, 100.0) == pytest.approx(3.0, rel=1e-12)   # [50, 150]; rounding only
    assert prof.average(250.0, 100.0) == pytest.approx(4.0, rel=1e-12)   # (3*50 + 5*50)/100; rounding
    assert prof.average(60.0, 100.0) == pytest.approx(3.0, rel=1e-12)    # [-40, 60]; rounding only


def test_grade_average_matches_fine_riemann_sum_on_random_profile():
    """On a random (seeded) profile, average equals a midpoint sum of ``at`` on a fine grid."""
    rng = np.random.default_rng(31)
    d = np.concatenate([[0.0], np.cumsum(rng.uniform(5.0, 80.0, size=30))])
    prof = GradeProfile(tuple(d), tuple(rng.uniform(-30.0, 30.0, size=d.size)))
    for _ in range(20):
        x = rng.uniform(0.0, d[-1] + 50.0)
        length = rng.uniform(1.0, 200.0)
        m = 20000
        xs = x - length + (np.arange(m) + 0.5) * length / m
        riemann = np.mean([prof.at(s) for s in xs])
        # midpoint sum of a step function: each of <= 41 jumps in the window (spacing >= 5 m,
        # L <= 200 m; |jump| <= 60) misplaces at most one cell, so the error is <= 41 * 60 / m
        assert prof.average(x, length) == pytest.approx(riemann, abs=41 * 60 / m)


def test_grade_at_is_piecewise_constant_from_each_distance_on():
    """at(x) takes grade k on [d_k, d_{k+1}), the first grade before d_0, the last beyond."""
    assert PROFILE.at(-5.0) == 2.0
    assert PROFILE.at(0.0) == 2.0
    assert PROFILE.at(99.999) == 2.0
    assert PROFILE.at(100.0) == -4.0           # the new grade applies *from* the breakpoint on
    assert PROFILE.at(249.0) == -4.0
    assert PROFILE.at(250.0) == 6.0
    assert PROFILE.at(1e6) == 6.0
    assert PROFILE.average(100.0, 0.0) == PROFILE.at(100.0)   # length 0: point mass


def test_grade_from_csv_text_round_trip():
    """A well-formed CSV (with comments, blanks and quotes) parses to the listed breakpoints."""
    text = "# demo\n\ndistance_m,grade_permille\n0,0\n300, 15\n\"800\",-10\n# end\n1100,0\n"
    prof = GradeProfile.from_csv_text(text, "demo.csv")
    assert prof.distances == (0.0, 300.0, 800.0, 1100.0)
    assert prof.grades == (0.0, 15.0, -10.0, 0.0)


# ----------------------------------------------------------------- parse errors

@pytest.mark.parametrize("text, line, what", [
    ("distance,grade\n0,0\n", 1, "header"),
    ("# comment\n\ndistance_m,speed_mps\n0,0\n", 3, "header"),               # wrong columns
    ("distance_m,grade_permille\n0,0\n100,abc\n", 3, "not a number"),
    ("distance_m,grade_permille\n0,0\n\n# c\nx,1\n", 5, "not a number"),
    ("distance_m,grade_permille\n0,0\n100,1\n100,2\n", 4, "must increase"),  # equal distance
    ("distance_m,grade_permille\n0,0\n100,1\n\n50,2\n", 5, "must increase"),  # decreasing
    ("distance_m,grade_permille\n0,0\n100,1,7\n", 3, "expected 2 values"),
    ("distance_m,grade_permille\n-1,0\n", 2, ">= 0"),
    ("distance_m,grade_permille\n0,nan\n", 2, "non-finite"),
    ("", 1, "empty file"),
    ("# only a comment\n\n", 1, "empty file"),
])
def test_parse_errors_name_source_and_line(text, line, what):
    """Malformed profiles raise ProfileError starting with '<source>: line <n>:' (1-based,
    counting comment and blank lines) and saying what is wrong."""
    with pytest.raises(ProfileError) as exc:
        parse_profile_csv(text, "tracks/line7.csv", GRADE_COLUMNS)
    msg = str(exc.value)
    assert msg.startswith(f"tracks/line7.csv: line {line}:"), msg
    assert what in msg
    assert isinstance(exc.value, ValueError)


def test_parse_header_only_names_source():
    """A header without data rows is an error naming the source."""
    with pytest.raises(ProfileError, match=r"^speed\.csv: .*no data rows"):
        parse_profile_csv("distance_m,speed_mps\n", "speed.csv", SPEED_COLUMNS)


def test_speed_profile_rejects_negative_speed_with_line():
    """Speed profiles require V_zad >= 0 and say on which line it is not."""
    with pytest.raises(ProfileError, match=r"^v\.csv: line 3: speed_mps must be >= 0"):
        SpeedProfile.from_csv_text("distance_m,speed_mps\n0,0\n10,-1\n", "v.csv")


# ----------------------------------------------------------------- SpeedProfile

def test_speed_profile_interpolates_linearly_and_holds_beyond_ends():
    """V_zad(X) is piecewise linear between breakpoints and constant outside them."""
    sp = SpeedProfile((50.0, 150.0, 400.0), (0.0, 20.0, 10.0))
    assert sp.at(0.0) == 0.0                   # held before the first point
    assert sp.at(-10.0) == 0.0
    assert sp.at(1e5) == 10.0                  # held after the last point
    assert sp.at(400.0) == 10.0
    assert sp.at(150.0) == 20.0
    # linear pieces: slope 0.2 on [50, 150], -0.04 on [150, 400]; rounding only
    assert sp.at(75.0) == pytest.approx(5.0, rel=1e-12)
    assert sp.at(100.0) == pytest.approx(10.0, rel=1e-12)    # rounding only
    assert sp.at(275.0) == pytest.approx(15.0, rel=1e-12)    # rounding only
    rng = np.random.default_rng(5)
    xs = rng.uniform(-100.0, 600.0, size=200)
    # numpy.interp holds the end values too: same definition, rounding only
    np.testing.assert_allclose([sp.at(x) for x in xs],
                               np.interp(xs, sp.distances, sp.speeds), rtol=1e-12, atol=1e-12)  # rounding


def test_speed_profile_single_point_is_constant():
    """A one-row profile is a constant reference speed."""
    sp = SpeedProfile.from_csv_text("distance_m,speed_mps\n0,12.5\n", "c.csv")
    assert [sp.at(x) for x in (-1.0, 0.0, 3.0, 1e4)] == [12.5] * 4
