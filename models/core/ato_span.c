/* ato_span.c -- the span and the car's characteristic of the ATO's re-planner: the C twin of
 * models/planning/span.py and GradeProfile's lookups (Python's operand order throughout). */
#include "rc_fp_contract.h"
#include "ato_span.h"

#include <stdio.h>
#include <stdlib.h>

#define TINY_SPEED 1e-9     /* span._TINY_SPEED: P/V at V = 0 is taken at this speed [m/s] */

int rc_ato_bisect_right(const double *a, int n, double x)
{
    int lo = 0, hi = n;
    while (lo < hi) {
        int mid = (lo + hi) / 2;
        if (x < a[mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

double rc_ato_v_lim(const rc_ato_span *span, double s)
{
    int k = rc_ato_bisect_right(span->limit_distances, span->n_limits, s) - 1;
    return span->limit_speeds[k >= 0 ? k : 0];
}

double rc_ato_v_lim_at_node(const rc_ato_span *span, double s)
{
    int k = rc_ato_bisect_right(span->limit_distances, span->n_limits, s) - 1;
    k = k >= 0 ? k : 0;
    if (k > 0 && span->limit_distances[k] == s)
        return rc_min(span->limit_speeds[k], span->limit_speeds[k - 1]);
    return span->limit_speeds[k];
}

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

int rc_ato_breakpoints_bound(const rc_ato_span *span)
{
    return span->n_limits + 2 * span->grade.n;
}

int rc_ato_breakpoints(const rc_ato_span *span, double car_length, double *out, int cap)
{
    int n = 0;
    if (cap < rc_ato_breakpoints_bound(span))
        return -1;
    /* the set {limit distances[1:], grade distances (+ the car length)} within (0, stop) */
    for (int k = 1; k < span->n_limits; k++)
        out[n++] = span->limit_distances[k];
    for (int k = 0; k < span->grade.n; k++) {
        out[n++] = span->grade.distances[k];
        if (car_length > 0)
            out[n++] = span->grade.distances[k] + car_length;
    }
    int kept = 0;
    for (int k = 0; k < n; k++)
        if (0.0 < out[k] && out[k] < span->stop)
            out[kept++] = out[k];
    qsort(out, (size_t)kept, sizeof *out, cmp_double);
    n = 0;
    for (int k = 0; k < kept; k++)
        if (n == 0 || out[k] != out[n - 1])
            out[n++] = out[k];
    return n;
}

double rc_ato_adhesion_force_limit(const rc_ato_car *car, double v)
{
    /* models.plant.dynamics.adhesion_force_limit with adhesion_coefficient inlined */
    double psi = 0.161 + 7.5 / (fabs(v) * 3.6 + 44.0);
    return 1000.0 * car->mass * car->adhesion_mass_fraction * RC_G * psi * car->adhesion_factor;
}

double rc_ato_f_max(const rc_ato_car *car, double v)
{
    double vp = rc_max(v, TINY_SPEED);
    return rc_min(rc_min(car->traction_force_max, car->traction_power_max / vp),
                  rc_ato_adhesion_force_limit(car, v));
}

double rc_ato_r_max(const rc_ato_car *car, double v)
{
    double vp = rc_max(v, TINY_SPEED);
    double full = rc_min(rc_min(car->regen_force_max, car->regen_power_max / vp),
                         rc_ato_adhesion_force_limit(car, v));
    double width = car->regen_fade_speed - car->regen_off_speed;
    double share;
    if (width > 0.0)
        share = rc_min(rc_max((v - car->regen_off_speed) / width, 0.0), 1.0);
    else
        share = (v >= car->regen_fade_speed) * 1.0;
    return full * share;
}

double rc_ato_brake_total_max(const rc_ato_car *car, double v)
{
    double adh_all_axles = rc_ato_adhesion_force_limit(car, v) / car->adhesion_mass_fraction;
    return rc_min(car->brake_force_max, adh_all_axles);
}

void rc_ato_service_brake(const rc_ato_car *car, double v, double *regen, double *mech)
{
    double r = rc_min(rc_ato_r_max(car, v), rc_ato_brake_total_max(car, v));
    double level = rc_min(rc_ato_r_max(car, car->regen_fade_speed), rc_ato_brake_total_max(car, v));
    double below = (v < car->regen_fade_speed) * 1.0;
    *regen = r;
    *mech = rc_min(rc_max(level - r, 0.0), car->mech_force_max) * below;
}

double rc_ato_hold_speed_regen(const rc_ato_car *car, double v_hold)
{
    if (car->eta == 0.0)
        return INFINITY;
    double target = v_hold * v_hold * (car->A1 + 2.0 * car->A2 * v_hold) / (car->eta * car->eta_f);
    if (car->A2 == 0.0)
        return car->A1 > 0 ? sqrt(target / car->A1) : INFINITY;
    double v = rc_max(v_hold, pow(target / (2.0 * car->A2), 1.0 / 3.0));
    for (int k = 0; k < 60; k++) {
        double fv = v * v * (car->A1 + 2.0 * car->A2 * v) - target;
        double dv = fv / (2.0 * v * car->A1 + 6.0 * car->A2 * v * v);
        v -= dv;
        if (fabs(dv) <= 1e-13 * v)
            break;
    }
    return v;
}

rc_status rc_ato_check_span_for_car(const rc_ato_span *span, const rc_ato_car *car, rc_error *err)
{
    char a[40], b[40], c[40];
    double w = car->mass * RC_G;
    double i0 = rc_grade_average(&span->grade, 0.0, car->length);
    if (rc_ato_f_max(car, 0.0) <= w * (car->A0 + i0)) {
        if (err) {
            rc_repr(i0, a, sizeof a);
            snprintf(err->msg, RC_MSG_SIZE, "the car cannot start at s = 0: f_max(0) = %.0f N <= "
                     "resistance %.0f N on span.grade %s permille", rc_ato_f_max(car, 0.0),
                     w * (car->A0 + i0), a);
        }
        return RC_BAD_CONFIG;
    }
    int cap = rc_ato_breakpoints_bound(span);
    double *pts = malloc(sizeof(double) * (size_t)(cap > 0 ? cap : 1));
    if (pts == NULL) {
        if (err)
            snprintf(err->msg, RC_MSG_SIZE, "out of memory");
        return RC_BAD_CONFIG;
    }
    int np = rc_ato_breakpoints(span, car->length, pts, cap);
    const double *d = span->limit_distances, *lim = span->limit_speeds;
    for (int k = 0; k < span->n_limits; k++) {
        double v = lim[k];
        double lo = d[k], hi = k + 1 < span->n_limits ? d[k + 1] : span->stop;
        double steepest = rc_grade_average(&span->grade, lo, car->length);
        for (int j = 0; j < np; j++)
            if (lo <= pts[j] && pts[j] < hi)
                steepest = rc_min(steepest, rc_grade_average(&span->grade, pts[j], car->length));
        double va = v + 0.0;      /* main_resistance(v, wind 0) */
        double need = -w * (car->A0 + car->A1 * v + car->A2 * va * fabs(va) + steepest);
        double have = rc_min(rc_ato_r_max(car, v) + car->mech_force_max,
                             rc_ato_brake_total_max(car, v));
        if (need > have) {
            if (err) {
                rc_repr(v, a, sizeof a);
                rc_repr(lo, b, sizeof b);
                rc_repr(steepest, c, sizeof c);
                snprintf(err->msg, RC_MSG_SIZE, "span.limit_speeds[%d] = %s m/s (from s = %s m) "
                         "cannot be met: holding it on the %s permille grade needs %.0f N of "
                         "brake, the car has %.0f N", k, a, b, c, need, have);
            }
            free(pts);
            return RC_BAD_CONFIG;
        }
    }
    free(pts);
    if (err)
        err->msg[0] = '\0';
    return RC_OK;
}
