/* fpmath.h -- models/fpmath.py: elementary functions that give the same bits on every CPU.
 *
 * glibc chooses exp, log, expm1, log1p and pow per CPU (and Windows' and macOS' libraries are
 * others again), so the core never calls them for a result: squares and small powers are fixed
 * products, exp / expm1 / log are built from +, -, *, / (IEEE: the same everywhere) and the exact
 * floor, frexp and ldexp. Line by line the Python file; compiled without FMA contraction.
 *
 * Where Python raises, the C functions return what the operation gives (inf, NaN, -inf); the
 * rc_*_checked forms return RC_MATH where Python raises OverflowError. */
#ifndef RAILCAR_FPMATH_H
#define RAILCAR_FPMATH_H

#include "rc_common.h"

static inline double rc_sq(double x) { return x * x; }              /* fpmath.square */
static inline double rc_cube(double x) { return x * x * x; }        /* fpmath.cube */
static inline double rc_fourth(double x) { double x2 = x * x; return x2 * x2; }
static inline double rc_fifth(double x) { double x2 = x * x; return x2 * x2 * x; }

/* Python's x ** n (n = 2..5) as fpmath's products: RC_MATH (OverflowError) when a finite x gives
 * an infinite power; *out unchanged then */
rc_status rc_power(double x, int n, double *out);

double rc_exp(double x);        /* fpmath.exp; inf above RC_EXP_OVERFLOW (Python raises) */
double rc_expm1(double x);      /* fpmath.expm1; inf above RC_EXP_OVERFLOW (Python raises) */
double rc_log(double x);        /* fpmath.log; -inf at 0, NaN below (Python raises ValueError) */

#define RC_EXP_OVERFLOW 0x1.62e42fefa39efp+9    /* fpmath.EXP_OVERFLOW */

#endif
