/* script_common.c -- see script_common.h: the flat scripts' shared checks and Scenario.wind_at. */
#include "rc_fp_contract.h"
#include "script_common.h"

#include <math.h>
#include <stdio.h>

long rc_script_count(double v)
{
    if (!(v >= 0.0 && v <= (double)RC_SCRIPT_MAX_COUNT) || v != floor(v))
        return -1;
    return (long)v;
}

rc_status rc_script_read_count(double v, const char *script, const char *what, long *count,
                               rc_error *err)
{
    if ((*count = rc_script_count(v)) >= 0)
        return RC_OK;
    char where[64], rule[64];
    snprintf(where, sizeof where, "%s: the number of ", script);
    snprintf(rule, sizeof rule, "must be a whole number in 0..%ld", RC_SCRIPT_MAX_COUNT);
    return rc_refuse_value(err, where, what, rule, v);
}

rc_status rc_script_read_timing(const double *v, double *step_s, double *duration_s,
                                int *stop_after_last_phase, rc_error *err)
{
    *step_s = v[0];
    *duration_s = v[1];
    if (!(*step_s > 0.0 && isfinite(*step_s)))
        return rc_refuse_value(err, "", "step_s", "must be > 0 and finite", *step_s);
    if (!(*duration_s >= 0.0 && isfinite(*duration_s)))
        return rc_refuse_value(err, "", "duration_s", "must be >= 0 and finite", *duration_s);
    if (v[2] != 0.0 && v[2] != 1.0)
        return rc_refuse_value(err, "", "stop_after_last_phase", "must be 0 or 1", v[2]);
    *stop_after_last_phase = v[2] == 1.0;
    return RC_OK;
}

rc_status rc_script_count_steps(double step_s, double duration_s, long *steps, rc_error *err)
{
    double rounded = nearbyint(duration_s / step_s);        /* Python's round(): half to even */
    if (!(rounded <= (double)RC_RUN_MAX_STEPS))
        return rc_refuse_value(err, "", "duration_s / step_s", "must round to at most 1e9 steps",
                               duration_s / step_s);
    *steps = (long)rounded;
    return RC_OK;
}

rc_status rc_wind_schedule_check(const double *steps, long n, rc_error *err)
{
    static const char *const columns[] = {"time_s", "speed_mps"};
    for (long k = 0; k < n; k++)
        for (int j = 0; j < 2; j++)
            if (!isfinite(steps[2 * k + j])) {
                char where[64];
                snprintf(where, sizeof where, "wind[%ld].", k);
                return rc_refuse_value(err, where, columns[j], "must be finite", steps[2 * k + j]);
            }
    return RC_OK;
}

double rc_wind_schedule_at(const double *steps, long n, double t)
{
    double w = 0.0;
    for (long k = 0; k < n; k++)
        if (t + 1e-9 >= steps[2 * k])
            w = steps[2 * k + 1];
    return w;
}
