/* script_common.h -- what the batch engine's two drivers (scenario_driver.h: a scripted run,
 * span_driver.h: the ATO drives) share in reading their flat scripts, and the wind schedule the
 * run metrics (run_metrics.h) read too: one copy of the checks of a count, of the run's timing
 * (step_s, duration_s, stop_after_last_phase, the number of steps) and of the wind schedule, and
 * Scenario.wind_at.
 *
 * Every refusal is RC_BAD_CONFIG with the message harness/run/scenario.py's checks would give
 * ("<what> <rule>, got <repr(value)>"); the drivers' messages must not change by a byte when a
 * check moves here (tests/harness_tests/run/test_batch_runs.py, test_batch_spans.py compare them).
 */
#ifndef RAILCAR_SCRIPT_COMMON_H
#define RAILCAR_SCRIPT_COMMON_H

#include "rc_common.h"

#define RC_RUN_MAX_STEPS 1000000000L   /* drive()'s steps of one run: a sanity bound */
#define RC_SCRIPT_MAX_COUNT 10000000L  /* phases, table rows, wind steps...: a sanity bound */

/* A count of a script: a whole number in 0..RC_SCRIPT_MAX_COUNT, else -1 */
long rc_script_count(double v);

/* The count v of a script into *count, else refused: "<script>: the number of <what> must be a
 * whole number in 0..10000000, got <v>" */
rc_status rc_script_read_count(double v, const char *script, const char *what, long *count,
                               rc_error *err);

/* The run's timing from v[0] step_s [s], v[1] duration_s [s], v[2] stop_after_last_phase (0 or 1),
 * checked in that order (step_s > 0 and finite, duration_s >= 0 and finite) */
rc_status rc_script_read_timing(const double *v, double *step_s, double *duration_s,
                                int *stop_after_last_phase, rc_error *err);

/* drive()'s number of steps, int(round(duration_s / step_s)) (half to even), into *steps; refused
 * above RC_RUN_MAX_STEPS (the timing read by rc_script_read_timing) */
rc_status rc_script_count_steps(double step_s, double duration_s, long *steps, rc_error *err);

/* The n (time_s, speed_mps) rows of a wind schedule checked: each value finite, else refused
 * naming it ("wind[3].speed_mps must be finite, got inf") */
rc_status rc_wind_schedule_check(const double *steps, long n, rc_error *err);

/* Scenario.wind_at: the speed [m/s] of the last of the n (time_s, speed_mps) rows of `steps` (in
 * their order) with t + 1e-9 >= time_s, 0 when none */
double rc_wind_schedule_at(const double *steps, long n, double t);

#endif
