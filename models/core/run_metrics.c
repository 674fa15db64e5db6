/* run_metrics.c -- see run_metrics.h; harness/metrics/estimation.py's expressions, operand for
 * operand (Python's min() as rc_min's "the second only when strictly smaller"). */
#include "rc_fp_contract.h"
#include "run_metrics.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "validate.h"

/* adhesion_force_limit: 1000 P frac g psi_k(V) factor [N], Python's association */
static double adhesion_force_limit(const rc_vehicle *p, double v)
{
    double psi = 0.161 + 7.5 / (fabs(v) * 3.6 + 44.0);      /* adhesion_coefficient, mps_to_kmh */
    return 1000.0 * p->mass * p->adhesion_mass_fraction * RC_G * psi * p->adhesion_factor;
}

void rc_applied_forces(const rc_vehicle *p, double v, double traction_demand, double brake_demand,
                       double *traction, double *brake)
{
    if (brake_demand > 0.0) {                                /* brake_force_limit */
        double adh_all_axles = adhesion_force_limit(p, v) / p->adhesion_mass_fraction;
        *traction = 0.0;
        *brake = rc_min(brake_demand, rc_min(p->brake_force_max, adh_all_axles));
        return;
    }
    double f = p->traction_force_max;                        /* traction_force_limit */
    if (v > 0.0)
        f = rc_min(f, p->traction_power_max / v);
    *traction = rc_min(traction_demand, rc_min(f, adhesion_force_limit(p, v)));
    *brake = 0.0;
}

void rc_interval_forces(const rc_vehicle *car, long n, const double *speed, const double *mass,
                        const double *traction_demand, const double *brake_demand,
                        double *traction_mean, double *brake_mean)
{
    rc_vehicle p = *car;
    for (long k = 0; k + 1 < n; k++) {
        double f0, b0, f1, b1;
        p.mass = mass[k + 1];                                /* the payload of this interval */
        rc_applied_forces(&p, speed[k], traction_demand[k], brake_demand[k], &f0, &b0);
        rc_applied_forces(&p, speed[k + 1], traction_demand[k], brake_demand[k], &f1, &b1);
        traction_mean[k] = 0.5 * (f0 + f1);
        brake_mean[k] = 0.5 * (b0 + b1);
    }
}

void rc_true_theta(double mass_t, const double *A, double wind, double *theta)
{
    theta[0] = 1.0 / (RC_G * mass_t);
    theta[1] = A[0] + A[2] * wind * wind;
    theta[2] = A[1] + 2.0 * A[2] * wind;
    theta[3] = A[2];
}

rc_status rc_oracle_filter(const rc_oracle_config *cfg, long n, const double *time,
                           const double *mass, const double *speed_meas,
                           const double *position_meas, const double *traction_mean,
                           const double *brake_mean, double *v_out, double *x_out, rc_error *err)
{
    const rc_estchain_config *c = &cfg->est;
    rc_status st;
    if (err)
        err->msg[0] = '\0';
    if (!(cfg->step > 0.0 && isfinite(cfg->step))) {
        if (err)
            snprintf(err->msg, sizeof err->msg, "oracle: the step must be > 0 and finite, got %g",
                     cfg->step);
        return RC_BAD_CONFIG;
    }
    rc_ident_config ic = c->identifier;             /* OnlineEstimator's checks, in its order */
    ic.dt = cfg->step;
    if ((st = rc_ident_validate(&ic, c->method, c->physical, c->sigma2_method, c->slope_window, err)))
        return st;
    const char *why = rc_estimator_not_covered(c->method, c->physical, c->sigma2_method,
                                               c->slope_window);
    if (why) {
        if (err)
            snprintf(err->msg, sizeof err->msg, "the C core does not cover %s", why);
        return RC_BAD_CONFIG;
    }
    rc_filter_config fc = c->filter;
    fc.dt = cfg->step;
    fc.gamma = ic.gamma;
    if ((st = rc_filter_validate(&fc, c->speed_n > 0, err)) || (st = rc_station_validate(&c->station, err)))
        return st;
    double *profiles = NULL;
    rc_grade_profile grade;
    rc_speed_profile speed;
    rc_estimator *est = malloc(sizeof *est);
    if (!est || rc_profiles_copy(c->grade_distances, c->grades, c->grade_n, c->speed_distances,
                                 c->speeds, c->speed_n, &profiles, &grade, &speed) != 0) {
        free(est);
        if (err)
            snprintf(err->msg, sizeof err->msg, c->grade_n < 1 || c->speed_n < 0
                     ? "track.grade_profile must have at least one row" : "out of memory");
        return RC_BAD_CONFIG;
    }
    if (rc_estimator_init(est, &ic, &fc, &c->station, &grade, &speed, cfg->step, c->slope_window,
                          c->physical, c->sigma2_method) != 0) {
        free(profiles);
        free(est);
        if (err)
            snprintf(err->msg, sizeof err->msg, "out of memory");
        return RC_BAD_CONFIG;
    }
    for (long k = 0; k < n; k++) {
        double theta[4];
        rc_true_theta(mass[k], cfg->A, rc_wind_schedule_at(cfg->wind, cfg->wind_n, time[k]), theta);
        rc_ident_set_theta(&est->ident, theta);
        rc_estimator_measure(est, speed_meas[k], position_meas[k]);
        v_out[k] = rc_filter_speed(&est->filter);
        x_out[k] = rc_filter_position(&est->filter);
        if (k + 1 < n)
            rc_estimator_propagate(est, traction_mean[k], brake_mean[k], cfg->step);
    }
    rc_estimator_free(est);
    free(est);
    free(profiles);
    return RC_OK;
}

long rc_coast_segments(const double *mode, long n, long min_rows, long *first, long *last)
{
    long count = 0, start = -1;                     /* start -1: Python's None */
    for (long k = 0; k <= n; k++) {
        int coasting = k < n && mode[k] == RC_COASTING_MODE;   /* the row after the last: -1 */
        if (coasting && start < 0) {
            start = k;
        } else if (!coasting && start >= 0) {
            if (k - start >= min_rows) {
                first[count] = start;
                last[count] = k - 1;
                count++;
            }
            start = -1;
        }
    }
    return count;
}

double rc_coast_time(const rc_vehicle *p, const rc_grade_profile *grade, double v0, double x0,
                     double x1, const double *wind, long wind_n, double t0, double h, double t_max)
{
    double v = v0, x = x0, t = 0.0;
    while (x < x1 && t < t_max) {
        double v_new, x_new;
        rc_rk4_step(p, grade, v, x, h, 0.0, 0.0, rc_wind_schedule_at(wind, wind_n, t0 + t), &v_new,
                    &x_new);
        if (x_new >= x1)
            return t + h * (x1 - x) / (x_new - x);
        if (v_new <= 0.0)
            return INFINITY;
        v = v_new;
        x = x_new;
        t = t + h;
    }
    return INFINITY;
}
