"""Every AtoTuning number at its most absurd (issue 29: "bounds on every parameter that keep it
alive and fast, or a clear refusal naming the parameter"): 1e300 (2^31 - 1 for integers) is
either refused naming the field, or a closed loop on a 1 km span still departs, stops within
1 m of the mark and arrives; the fields of interface.UPPER_BOUNDS are also run at their bound.
Seeded closed-loop runs on the C core chain (closed_loop_line.run_span), ~10 s in all."""
from __future__ import annotations

import math
from dataclasses import fields

import pytest

from models.ato.interface import UPPER_BOUNDS, AtoTuning

from closed_loop_line import line_span, run_span

SPAN = line_span((0, 500), (0, -10), 1000.0, ((0, 70),), 80.0)   # [m], [permille], [km/h], [s]
RELAXED = line_span((0, 500), (0, -10), 1000.0, ((0, 70),), 120.0)   # a bound's slower planning fits
NUMBERS = [f.name for f in fields(AtoTuning)
           if not isinstance(f.default, bool) and isinstance(f.default, (int, float))]
STOP_M = 1.0      # [m] "stops at the mark" for an absurd tuning: the never-past bound


def _absurd(name: str):
    return 2 ** 31 - 1 if isinstance(getattr(AtoTuning(), name), int) else 1e300


def _still_drives(tuning: AtoTuning, span=SPAN) -> dict:
    out = run_span(span, 1, {}, wind=0.0, tuning=tuning)
    assert math.isfinite(out["arrival"]), out["arrival"]
    assert abs(out["stop"]) <= STOP_M, out["stop"]
    return out


@pytest.mark.parametrize("name", NUMBERS)
def test_the_most_absurd_value_is_refused_by_name_or_still_drives(name):
    value = _absurd(name)
    try:
        tuning = AtoTuning(**{name: value})
    except ValueError as e:
        assert f"tuning.{name}" in str(e), str(e)
        return
    try:
        _still_drives(tuning)
    except ValueError as e:             # refused by the controller at construction, by name
        assert f"tuning.{name}" in str(e), str(e)


@pytest.mark.parametrize("name", sorted(UPPER_BOUNDS))
def test_each_upper_bound_is_the_largest_accepted_and_still_drives(name):
    high = UPPER_BOUNDS[name][0]
    with pytest.raises(ValueError, match=rf"tuning\.{name} must be <= "):
        AtoTuning(**{name: math.nextafter(high, math.inf)})
    _still_drives(AtoTuning(**{name: high}), RELAXED)


def test_the_fields_found_absurd_at_1e300_are_refused():
    for name in ("k_sigma", "gap_sigma", "supervisor_gap", "mass_reserve", "stand_time", "time_tol",
                 "grid_step", "limit_margin"):
        with pytest.raises(ValueError, match=rf"tuning\.{name} must be <= "):
            AtoTuning(**{name: 1e300})
