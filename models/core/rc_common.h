/* rc_common.h -- what every part of the C model core shares: status codes, the error message
 * buffer, the constants of models/units.py, and Python's arithmetic where C's differs.
 *
 * The core is the C twin of the Python reference in models/: every expression keeps Python's
 * operand order and association, and it is compiled with -ffp-contract=off (no fused
 * multiply-add), so results are bit-identical (tests/test_core_*.py compare them exactly).
 * No Python.h, no globals, no allocation per step.
 */
#ifndef RAILCAR_COMMON_H
#define RAILCAR_COMMON_H

#include <math.h>
#include <stdarg.h>
#include <stddef.h>

#define RC_G 9.81                 /* gravity [m/s^2], models.units.G */

typedef enum {
    RC_OK = 0,
    RC_REJECTED = 1,      /* a bad input or step: nothing was changed (StepRejected) */
    RC_BAD_CONFIG = 2,    /* a configuration the core refuses (ValueError) */
    RC_MATH = 3           /* Python would raise (division by zero, sqrt of a negative) */
} rc_status;

#define RC_MSG_SIZE 256
typedef struct {
    char msg[RC_MSG_SIZE];        /* names the variable and its value; "" when status is RC_OK */
} rc_error;

/* Python's max(a, b) / min(a, b) for floats: the first unless the second is strictly
 * greater / smaller (so NaN and signed zeros come out as in Python). */
static inline double rc_max(double a, double b) { return b > a ? b : a; }
static inline double rc_min(double a, double b) { return b < a ? b : a; }

/* Python's repr() of a float into buf (shortest round-trip digits, Python's switch to an
 * exponent): messages name a value as the Python code does (repr.c) */
void rc_repr(double x, char *buf, int size);

/* err's message from a printf format (when err is not NULL); returns status: the core's one way
 * to refuse with a message (repr.c) */
#if defined(__GNUC__)
__attribute__((format(printf, 3, 4)))
#endif
rc_status rc_refuse(rc_error *err, rc_status status, const char *fmt, ...);

/* rc_refuse's va_list form, into any message buffer: msg[size] printf-formatted from ap (when
 * msg is not NULL; cut to size - 1 bytes, as vsnprintf cuts); returns status. For callers whose
 * buffer is not an rc_error's: the native AtoController's 512-byte messages) */
#if defined(__GNUC__)
__attribute__((format(printf, 4, 0)))
#endif
rc_status rc_vrefuse(char *msg, size_t size, rc_status status, const char *fmt, va_list ap);

/* err's message "<where><name> <rule>, got <repr(v)>" (where, e.g. "driver[2] (hold).", may be
 * ""); returns RC_BAD_CONFIG (repr.c) */
rc_status rc_refuse_value(rc_error *err, const char *where, const char *name, const char *rule,
                          double v);

#endif
