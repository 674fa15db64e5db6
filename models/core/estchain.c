/* estchain.c -- models.chain.EstimatorChain in C (see railcar.h), same checks and order. */
#include "rc_fp_contract.h"
#include "railcar.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "checks.h"
#include "track_sensors.h"

#define MASS_RANGE 5.0                 /* OnlineEstimator.MASS_RANGE */

rc_status rc_estchain_init(rc_estchain *c, const rc_estchain_config *cfg, rc_error *err)
{
    memset(c, 0, sizeof *c);
    if (err)
        err->msg[0] = '\0';
    const char *why = rc_estimator_not_covered(cfg->method, cfg->physical, cfg->sigma2_method,
                                               cfg->slope_window);
    if (why) {
        if (err)
            snprintf(err->msg, sizeof err->msg, "the C core does not cover %s", why);
        return RC_BAD_CONFIG;
    }
    if (rc_profiles_copy(cfg->grade_distances, cfg->grades, cfg->grade_n, cfg->speed_distances,
                         cfg->speeds, cfg->speed_n, &c->profiles, &c->grade, &c->speed) != 0) {
        if (err)
            snprintf(err->msg, sizeof err->msg, cfg->grade_n < 1 || cfg->speed_n < 0
                     ? "track.grade_profile must have at least one row"
                     : "out of memory for the profiles");
        return RC_BAD_CONFIG;
    }
    memcpy(&c->cfg, cfg, sizeof c->cfg);            /* padding too: a state holds the bytes */
    c->cfg.grade_distances = c->grade.distances;
    c->cfg.grades = c->grade.grades;
    c->cfg.speed_distances = c->speed.distances;
    c->cfg.speeds = c->speed.speeds;
    c->last_track_time = -INFINITY;
    double heaviest = MASS_RANGE * cfg->identifier.mass_initial * 1000.0;   /* [kg] */
    c->force_limit = FORCE_LIMIT_FACTOR * 0.4 * RC_G * heaviest;
    c->started = 0;
    c->has_time = 0;
    return RC_OK;
}

void rc_estchain_free(rc_estchain *c)
{
    if (c->started)
        rc_estimator_free(&c->est);
    c->started = 0;
    free(c->profiles);
    c->profiles = NULL;
}

static const char FORCE_WHY[] = "10 x the adhesion limit 0.4 g of 5 x est.mass_initial";

rc_status rc_estchain_step(rc_estchain *c, double current_time, double step_size, double traction,
                           double brake, double speed_meas, double position_meas,
                           double track_speed, double track_time, rc_error *err)
{
    rc_status s;
    if (err)
        err->msg[0] = '\0';
    if ((s = rc_check_step(err, current_time, step_size))
            || (s = rc_check_finite(err, "sensor.track_speed", track_speed, "m/s"))
            || (s = rc_check_finite(err, "sensor.track_time", track_time, "s"))
            || (s = rc_check_force(err, "traction_force", traction))
            || (s = rc_check_force(err, "brake_force", brake))
            || (s = rc_check_bounded(err, "traction_force", traction, c->force_limit, "N", FORCE_WHY))
            || (s = rc_check_bounded(err, "brake_force", brake, c->force_limit, "N", FORCE_WHY))
            || (s = rc_check_finite(err, "sensor.speed", speed_meas, "m/s"))
            || (s = rc_check_finite(err, "sensor.position", position_meas, "m"))
            || (s = rc_check_bounded(err, "sensor.speed", speed_meas, MAX_MEASURED_SPEED, "m/s",
                                     "no rail car is that fast"))
            || (s = rc_check_bounded(err, "sensor.position", position_meas, MAX_MEASURED_DISTANCE,
                                     "m", "no line is that long")))
        return s;
    if (c->has_time && fabs(current_time - c->time) > 1e-9 * rc_max(1.0, fabs(current_time))) {
        char a[40], b[40];
        rc_repr(current_time, a, sizeof a);
        rc_repr(c->time, b, sizeof b);
        if (err)
            snprintf(err->msg, sizeof err->msg,
                     "current time %s s does not continue the FMU's time %s s", a, b);
        return RC_REJECTED;
    }
    if (!c->started) {
        if (rc_estimator_init(&c->est, &c->cfg.identifier, &c->cfg.filter, &c->cfg.station,
                              &c->grade, c->speed.n ? &c->speed : NULL, step_size,
                              c->cfg.method == 2 ? c->cfg.slope_window : 0,
                              c->cfg.physical, c->cfg.sigma2_method) != 0) {
            if (err)
                snprintf(err->msg, sizeof err->msg, "out of memory for the identifier's batch");
            return RC_BAD_CONFIG;
        }
        c->started = 1;
    }
    rc_estimator_measure(&c->est, speed_meas, position_meas);
    if (c->last_track_time < track_time && track_time <= current_time + 1e-9 && track_speed > 0.0) {
        rc_estimator_measure_track_speed(&c->est, track_speed, current_time - track_time,
                                         rc_track_speed_std(track_speed, c->cfg.track_base,
                                                            c->cfg.track_resolution,
                                                            c->cfg.track_jitter), c->cfg.track_base);
        c->last_track_time = track_time;
    }
    rc_estimator_propagate(&c->est, traction, brake, step_size);
    c->has_time = 1;
    c->time = current_time + step_size;
    return RC_OK;
}

int rc_estchain_outputs(rc_estchain *c, double *out)
{
    if (!c->started)
        return 0;
    rc_estimator_outputs(&c->est, 1, out);
    return 1;
}
