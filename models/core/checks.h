/* checks.h -- models/chain.py's input checks (rc_check_step, rc_check_force, rc_check_finite,
 * rc_check_bounded): RC_OK, or RC_REJECTED with the Python chain's message in err (the value as
 * Python's repr() writes it, rc_repr in railcar.h). Internal to the core. */
#ifndef RAILCAR_CHECKS_H
#define RAILCAR_CHECKS_H

#include "railcar.h"

#define MAX_STEP 3600.0                /* models.chain.MAX_STEP [s] */
#define FORCE_LIMIT_FACTOR 10.0
#define MAX_WIND 100.0                 /* [m/s] */
#define MAX_MEASURED_SPEED 200.0       /* [m/s] */
#define MAX_MEASURED_DISTANCE 1e7      /* [m] */

rc_status rc_check_step(rc_error *err, double current_time, double step_size);
rc_status rc_check_force(rc_error *err, const char *name, double value);
rc_status rc_check_finite(rc_error *err, const char *name, double value, const char *unit);
rc_status rc_check_bounded(rc_error *err, const char *name, double value, double limit,
                        const char *unit, const char *why);

#endif
