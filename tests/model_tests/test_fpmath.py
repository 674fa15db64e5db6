"""models.fpmath: the CPU-independent exp, expm1, log and small powers, against 50-digit
decimals (accuracy), against Python's rules (special values, the errors ``math`` and ``**``
raise), and against libm where both are exact (the powers)."""
from __future__ import annotations

import math
import random
from decimal import Decimal, localcontext

import pytest

from models import fpmath


def ulps(y: float, exact: Decimal) -> float:
    """|y - exact| in units of the last place of ``exact`` rounded to a double."""
    return float(abs(Decimal(y) - exact) / Decimal(math.ulp(float(exact))))


def worst_ulps(f, reference, xs) -> float:
    with localcontext() as ctx:
        ctx.prec = 50
        return max(ulps(f(x), reference(x)) for x in xs)


rng = random.Random(20261127)
WIDE = [rng.uniform(-700.0, 700.0) for _ in range(3000)]
NEAR_ZERO = [rng.choice((-1, 1)) * 10.0 ** rng.uniform(-15, 0) for _ in range(3000)]
POSITIVE = [10.0 ** rng.uniform(-300, 300) for _ in range(3000)] + [1.0 + rng.uniform(-0.3, 0.4)
                                                                   for _ in range(3000)]


@pytest.mark.parametrize("xs", [WIDE, NEAR_ZERO], ids=["wide", "near_zero"])
def test_exp_is_within_one_ulp(xs):
    assert worst_ulps(fpmath.exp, lambda x: Decimal(x).exp(), xs) < 1.0


@pytest.mark.parametrize("xs", [[x / 17.5 for x in WIDE], NEAR_ZERO], ids=["wide", "near_zero"])
def test_expm1_is_within_1_2_ulp_also_near_zero(xs):
    # near 0 the relative accuracy is the point of expm1 (exp(x) - 1 would lose every digit)
    assert worst_ulps(fpmath.expm1, lambda x: Decimal(x).exp() - 1, xs) < 1.2


def test_log_is_within_one_ulp():
    assert worst_ulps(fpmath.log, lambda x: Decimal(x).ln(), POSITIVE) < 1.0


def test_the_functions_reach_the_ends_of_the_double_range():
    assert fpmath.exp(0.0) == 1.0 and fpmath.expm1(0.0) == 0.0 and fpmath.log(1.0) == 0.0
    assert math.copysign(1.0, fpmath.expm1(-0.0)) == -1.0        # the sign of zero kept
    assert fpmath.exp(-746.0) == 0.0 and fpmath.expm1(-50.0) == -1.0
    assert 0.0 < fpmath.exp(-745.0) <= 1e-323                      # subnormal, as math.exp
    one_ulp = 2.0 ** -52                                           # relative, libm as reference
    assert fpmath.exp(fpmath.EXP_OVERFLOW) == pytest.approx(math.exp(fpmath.EXP_OVERFLOW), rel=one_ulp)
    assert fpmath.log(5e-324) == pytest.approx(math.log(5e-324), rel=one_ulp)
    assert fpmath.log(1.7976931348623157e308) == pytest.approx(math.log(1.7976931348623157e308),
                                                               rel=one_ulp)
    assert fpmath.log(math.inf) == math.inf
    for f in (fpmath.exp, fpmath.expm1, fpmath.log):
        assert math.isnan(f(math.nan))


def test_errors_are_pythons():
    with pytest.raises(OverflowError):
        fpmath.exp(710.0)
    with pytest.raises(OverflowError):
        fpmath.expm1(710.0)
    for bad in (0.0, -1.0, -math.inf):
        with pytest.raises(ValueError, match="math domain error"):
            fpmath.log(bad)
    for power in (fpmath.square, fpmath.cube, fpmath.fourth, fpmath.fifth):
        with pytest.raises(OverflowError) as caught:
            power(1e200)
        with pytest.raises(OverflowError) as python:
            1e200 ** 5
        assert str(caught.value) == str(python.value)
        assert power(math.inf) == math.inf                           # inf in: no error, as **
        assert math.isnan(power(math.nan))


def test_the_powers_are_the_products_in_their_order():
    for x in NEAR_ZERO + WIDE:
        assert fpmath.square(x) == x * x
        assert fpmath.cube(x) == (x * x) * x
        assert fpmath.fourth(x) == (x * x) * (x * x)
        assert fpmath.fifth(x) == ((x * x) * (x * x)) * x

