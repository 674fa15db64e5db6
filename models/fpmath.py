"""Elementary functions that give the same bits on every CPU, in Python and in C.

glibc picks its ``exp``, ``log``, ``expm1``, ``log1p`` and ``pow`` per CPU (an FMA and a plain
variant, chosen at load time): the same program gives different last bits on two x86-64
machines (measured here: 4e-4 to 7e-4 of arguments differ under
``GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA``), and Windows' and macOS' libraries differ again.
Only +, -, *, / and sqrt are rounded the same everywhere (IEEE 754). So the model computes:

- ``square(x)`` as ``x * x`` (CPython's ``x ** 2`` calls libm ``pow``), ``cube``, ``fourth``,
  ``fifth`` by a fixed order of products;
- ``exp``, ``expm1``, ``log`` from those operations alone, with ``floor``, ``frexp`` and
  ``ldexp``, which are exact: a reduction by ln 2 (split in a 32-bit head, so that k ln2_hi is
  exact, and a tail) and a Taylor series of fixed length, summed by Horner's rule. Accuracy
  against 50-digit decimals (tests/model_tests/test_fpmath.py): exp and log within 1 ulp, expm1
  within 1.2 ulp; 90 to 99.8 % of results correctly rounded.

models/core/fpmath.c repeats this file line by line; the C core is compiled without fused
multiply-add, so both give the very same doubles on any IEEE machine.

Overflow keeps Python's rules: ``square`` and the other powers raise OverflowError where
``x ** n`` would (a finite x with an infinite result), ``exp`` where ``math.exp`` would, and
``log`` raises ValueError for x <= 0 as ``math.log`` does (the C twins report these through a
status).
"""
from __future__ import annotations

import math

LN2_HI = float.fromhex("0x1.62e42ff000000p-1")
"""ln 2 rounded to 32 significant bits: k * LN2_HI is exact for |k| < 2^21."""
LN2_LO = float.fromhex("-0x1.718432a1b0e26p-35")
"""ln 2 - LN2_HI, rounded."""
INV_LN2 = float.fromhex("0x1.71547652b82fep+0")
"""1 / ln 2, rounded."""
SQRT_HALF = float.fromhex("0x1.6a09e667f3bcdp-1")
"""sqrt(1/2), rounded: log reduces its argument to [SQRT_HALF, 2 SQRT_HALF)."""
EXP_OVERFLOW = float.fromhex("0x1.62e42fefa39efp+9")
"""709.78...: exp(x) is inf above (the largest x with a finite exp, rounded)."""
EXP_UNDERFLOW = -745.2
"""exp(x) is 0.0 below (exp(-745.2) < the smallest subnormal / 2)."""

EXP_TAYLOR = tuple(1.0 / math.factorial(k) for k in range(2, 14))
"""1/k!, k = 2..13: exp(r) - 1 - r on |r| <= ln2/2 (the first term left out is below 2^-57)."""
EXPM1_TAYLOR = tuple(1.0 / math.factorial(k) for k in range(2, 17))
"""1/k!, k = 2..16: expm1(x) - x on |x| < ln 2, unreduced (x leads: below 2^-56 relative left out)."""
LOG_TAYLOR = tuple(2.0 / (2 * k + 1) for k in range(1, 12))
"""2/(2k+1), k = 1..11: 2 atanh(s)/s - 2 as a series in z = s^2, z <= 0.0295."""

_OVERFLOW = "(34, 'Numerical result out of range')"       # CPython's message for x ** n


def _finite_or_raise(y: float, x: float) -> float:
    if math.isinf(y) and math.isfinite(x):
        raise OverflowError(_OVERFLOW)
    return y


def square(x: float) -> float:
    """x * x, exactly rounded, with ``x ** 2``'s OverflowError."""
    return _finite_or_raise(x * x, x)


def cube(x: float) -> float:
    """(x * x) * x, with ``x ** 3``'s OverflowError."""
    return _finite_or_raise(x * x * x, x)


def fourth(x: float) -> float:
    """(x * x) * (x * x), with ``x ** 4``'s OverflowError."""
    x2 = x * x
    return _finite_or_raise(x2 * x2, x)


def fifth(x: float) -> float:
    """((x * x) * (x * x)) * x, with ``x ** 5``'s OverflowError."""
    x2 = x * x
    return _finite_or_raise(x2 * x2 * x, x)


def _horner(coeffs: tuple, r: float) -> float:
    acc = coeffs[-1]
    for c in coeffs[-2::-1]:
        acc = acc * r + c
    return acc


def _reduce(x: float) -> tuple[int, float]:
    """x = k ln2 + r, |r| <= ln2/2 (a little more by rounding)."""
    k = math.floor(x * INV_LN2 + 0.5)
    return k, (x - k * LN2_HI) - k * LN2_LO


def exp(x: float) -> float:
    """e^x, within 1 ulp; OverflowError above EXP_OVERFLOW as ``math.exp``."""
    if x != x:
        return x
    if x > EXP_OVERFLOW:
        raise OverflowError("math range error")
    if x < EXP_UNDERFLOW:
        return 0.0
    k, r = _reduce(x)
    return math.ldexp(1.0 + (r + r * r * _horner(EXP_TAYLOR, r)), k)


def _expm1_series(x: float) -> float:
    return x + x * x * _horner(EXPM1_TAYLOR, x)


def expm1(x: float) -> float:
    """e^x - 1, within 1.2 ulp, also near 0; OverflowError above EXP_OVERFLOW as ``math.expm1``."""
    if x != x or x == 0.0:              # NaN; and -0.0 keeps its sign, as math.expm1
        return x
    if x > EXP_OVERFLOW:
        raise OverflowError("math range error")
    if x < -38.0:                        # e^x below 2^-54: -1 rounds it away (and k >= -55)
        return -1.0
    if -LN2_HI < x < LN2_HI:             # unreduced: 2 expm1(r) + 1 would cancel at k = 1, r < 0
        return _expm1_series(x)
    k, r = _reduce(x)                    # |k| >= 1: 2^k - 1 outweighs 2^k expm1(r)
    if k > 56:                           # -1 is below half an ulp of e^x
        return math.ldexp(1.0 + _expm1_series(r), k)
    # e^x - 1 = 2^k expm1(r) + (2^k - 1); 2^k - 1 is exact for -57 < k <= 56
    return math.ldexp(_expm1_series(r), k) + (math.ldexp(1.0, k) - 1.0)


def log(x: float) -> float:
    """Natural logarithm, within 1 ulp; ValueError for x <= 0 as ``math.log``; log(inf) = inf."""
    if x != x or x == math.inf:
        return x
    if x <= 0.0:
        raise ValueError("math domain error")
    m, e = math.frexp(x)                 # x = m 2^e, 0.5 <= m < 1 (also for subnormal x)
    if m < SQRT_HALF:
        m, e = m * 2.0, e - 1
    f = m - 1.0                          # exact: m in [0.707, 1.414)
    s = f / (2.0 + f)                    # log(1 + f) = 2 atanh(s)
    z = s * s
    half_f2 = 0.5 * f * f
    tail = z * _horner(LOG_TAYLOR, z)
    # log(1 + f) = f - (f^2/2 - s (f^2/2 + tail)): f^2/2 - s f^2/2 = f s, and 2 s = f - f s
    return e * LN2_HI - ((half_f2 - (s * (half_f2 + tail) + e * LN2_LO)) - f)
