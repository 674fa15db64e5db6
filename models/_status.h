/* _status.h -- the Python exception of a C core refusal, one rule for both extensions
 * (models/_railcar.c, models/_batch.c): the caller's class (StepRejected) for RC_REJECTED,
 * ArithmeticError for RC_MATH (where Python raises ZeroDivisionError or OverflowError),
 * ValueError for the rest (a configuration the core refuses). Include after Python.h. */
#ifndef RAILCAR_STATUS_H
#define RAILCAR_STATUS_H

#include "core/rc_common.h"

static inline PyObject *status_exception(rc_status st, PyObject *rejected)
{
    return st == RC_REJECTED ? rejected : st == RC_MATH ? PyExc_ArithmeticError : PyExc_ValueError;
}

#endif
