/* checks.c -- models.chain's input checks and their messages (see checks.h). */
#include "rc_fp_contract.h"
#include "checks.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ------------------------------------------------------------------ messages */

static rc_status reject(rc_error *err, const char *fmt, const char *name, double value,
                        const char *extra)
{
    char v[40];
    rc_repr(value, v, sizeof v);
    if (err)
        snprintf(err->msg, sizeof err->msg, fmt, name, v, extra);
    return RC_REJECTED;
}

/* models.chain.rc_check_force, rc_check_finite, rc_check_bounded: RC_OK or RC_REJECTED */
rc_status rc_check_force(rc_error *err, const char *name, double value)
{
    if (!isfinite(value) || value < 0.0)
        return reject(err, "%s must be finite and >= 0 [N], got %s%s", name, value, "");
    return RC_OK;
}

rc_status rc_check_finite(rc_error *err, const char *name, double value, const char *unit)
{
    if (!isfinite(value)) {
        char v[40];
        rc_repr(value, v, sizeof v);
        if (err)
            snprintf(err->msg, sizeof err->msg, "%s must be finite [%s], got %s", name, unit, v);
        return RC_REJECTED;
    }
    return RC_OK;
}

rc_status rc_check_bounded(rc_error *err, const char *name, double value, double limit,
                               const char *unit, const char *why)
{
    if (!(fabs(value) <= limit)) {
        char v[40];
        rc_repr(value, v, sizeof v);
        if (err)
            snprintf(err->msg, sizeof err->msg, "%s = %s %s is beyond %g %s (%s)", name, v, unit,
                     limit, unit, why);
        return RC_REJECTED;
    }
    return RC_OK;
}

/* models.chain.rc_check_step */
rc_status rc_check_step(rc_error *err, double current_time, double step_size)
{
    if (!(isfinite(step_size) && step_size > 0.0))
        return reject(err, "%s must be > 0 [s], got %s%s", "communication step size", step_size, "");
    if (step_size > MAX_STEP)
        return reject(err, "%s must be <= 3600 s, got %s%s", "communication step size", step_size, "");
    if (!isfinite(current_time))
        return reject(err, "%s must be finite [s], got %s%s", "current time", current_time, "");
    return RC_OK;
}

