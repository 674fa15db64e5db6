/* fpmath.c -- models/fpmath.py line by line (see fpmath.h): the same bits on every IEEE CPU. */
#include "rc_fp_contract.h"

#include "fpmath.h"

#include <stdint.h>
#include <string.h>

#define LN2_HI 0x1.62e42ff000000p-1       /* ln 2 in 32 significant bits: k LN2_HI is exact */
#define LN2_LO (-0x1.718432a1b0e26p-35)   /* ln 2 - LN2_HI */
#define INV_LN2 0x1.71547652b82fep+0
#define SQRT_HALF 0x1.6a09e667f3bcdp-1
#define EXP_UNDERFLOW (-745.2)

/* fpmath.EXP_TAYLOR, EXPM1_TAYLOR, LOG_TAYLOR: 1/k! and 2/(2k+1), correctly rounded divisions of
 * exact integers, as Python computes them */
static const double EXP_TAYLOR[] = {
    1.0 / 2.0, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0, 1.0 / 720.0, 1.0 / 5040.0, 1.0 / 40320.0,
    1.0 / 362880.0, 1.0 / 3628800.0, 1.0 / 39916800.0, 1.0 / 479001600.0, 1.0 / 6227020800.0};
static const double EXPM1_TAYLOR[] = {
    1.0 / 2.0, 1.0 / 6.0, 1.0 / 24.0, 1.0 / 120.0, 1.0 / 720.0, 1.0 / 5040.0, 1.0 / 40320.0,
    1.0 / 362880.0, 1.0 / 3628800.0, 1.0 / 39916800.0, 1.0 / 479001600.0, 1.0 / 6227020800.0,
    1.0 / 87178291200.0, 1.0 / 1307674368000.0, 1.0 / 20922789888000.0};
static const double LOG_TAYLOR[] = {
    2.0 / 3.0, 2.0 / 5.0, 2.0 / 7.0, 2.0 / 9.0, 2.0 / 11.0, 2.0 / 13.0, 2.0 / 15.0, 2.0 / 17.0,
    2.0 / 19.0, 2.0 / 21.0, 2.0 / 23.0};

#define COUNT(a) ((int)(sizeof(a) / sizeof((a)[0])))

/* ldexp and frexp without the library call where the result is a normal number: scaling by an
 * exact power of two and reading the exponent field are exact, so the bits are libm's (and
 * Python's math.ldexp / math.frexp); subnormals, zeros and the range's edges take libm. The
 * likelihood bank calls exp and log 27 times a step: the calls were ~6 % of a native step. */
static double scale2(double y, int k)         /* ldexp(y, k) for y in [0.5, 2) */
{
    if (k > -1021 && k < 1023) {
        uint64_t bits = (uint64_t)(k + 1023) << 52;
        double p;
        memcpy(&p, &bits, sizeof p);
        return y * p;
    }
    return ldexp(y, k);
}

static double split2(double x, int *e)        /* frexp(x, e) for finite x > 0 */
{
    uint64_t bits;
    memcpy(&bits, &x, sizeof bits);
    int field = (int)((bits >> 52) & 0x7ff);
    if (field == 0)
        return frexp(x, e);                   /* subnormal */
    *e = field - 1022;
    bits = (bits & ~((uint64_t)0x7ff << 52)) | ((uint64_t)1022 << 52);
    double m;
    memcpy(&m, &bits, sizeof m);
    return m;
}

rc_status rc_power(double x, int n, double *out)
{
    double y = n == 2 ? rc_sq(x) : n == 3 ? rc_cube(x) : n == 4 ? rc_fourth(x) : rc_fifth(x);
    if (isinf(y) && isfinite(x))
        return RC_MATH;
    *out = y;
    return RC_OK;
}

static double horner(const double *c, int n, double r)
{
    double acc = c[n - 1];
    for (int i = n - 2; i >= 0; i--)
        acc = acc * r + c[i];
    return acc;
}

static double reduce(double x, int *k)        /* x = k ln2 + r */
{
    double kf = floor(x * INV_LN2 + 0.5);
    *k = (int)kf;
    return (x - kf * LN2_HI) - kf * LN2_LO;
}

double rc_exp(double x)
{
    int k;
    if (x != x)
        return x;
    if (x > RC_EXP_OVERFLOW)
        return INFINITY;
    if (x < EXP_UNDERFLOW)
        return 0.0;
    double r = reduce(x, &k);
    return scale2(1.0 + (r + r * r * horner(EXP_TAYLOR, COUNT(EXP_TAYLOR), r)), k);
}

static double expm1_series(double x)
{
    return x + x * x * horner(EXPM1_TAYLOR, COUNT(EXPM1_TAYLOR), x);
}

double rc_expm1(double x)
{
    int k;
    if (x != x || x == 0.0)
        return x;
    if (x > RC_EXP_OVERFLOW)
        return INFINITY;
    if (x < -38.0)
        return -1.0;
    if (-LN2_HI < x && x < LN2_HI)
        return expm1_series(x);
    double r = reduce(x, &k);
    if (k > 56)
        return ldexp(1.0 + expm1_series(r), k);
    return ldexp(expm1_series(r), k) + (ldexp(1.0, k) - 1.0);
}

double rc_log(double x)
{
    int e;
    if (x != x || x == INFINITY)
        return x;
    if (x < 0.0)
        return NAN;
    if (x == 0.0)
        return -INFINITY;
    double m = split2(x, &e);
    if (m < SQRT_HALF) {
        m = m * 2.0;
        e = e - 1;
    }
    double f = m - 1.0;
    double s = f / (2.0 + f);
    double z = s * s;
    double half_f2 = 0.5 * f * f;
    double tail = z * horner(LOG_TAYLOR, COUNT(LOG_TAYLOR), z);
    double de = (double)e;
    return de * LN2_HI - ((half_f2 - (s * (half_f2 + tail) + de * LN2_LO)) - f);
}
