/* ato_stopping.c -- the C twin of models/ato/stopping.py (Python's operand order). */
#include "rc_fp_contract.h"
#include "ato_stopping.h"

#include <stdio.h>

double rc_ato_track_force(const rc_ato_plancar *car, double v, double v_ref, double a_ref,
                          double grade, double gain)
{
    return car->m_in * (a_ref + gain * (v_ref - v)) + car->pg * (rc_ato_pc_w0(car, v) + grade);
}

void rc_ato_relay_init(rc_ato_relay *r, double stop, double a_ep, double stage_force,
                       int n_stages, double hysteresis, double stage_speed, double dwell,
                       double creep_speed, double creep_accel, double stop_window)
{
    r->stop = stop;
    r->a_ep = a_ep;
    r->stage_force = stage_force;
    r->n_stages = n_stages;
    r->hysteresis = hysteresis;
    r->stage_speed = stage_speed;
    r->dwell = dwell;
    r->creep_speed = creep_speed;
    r->creep_accel = creep_accel;
    r->stop_window = stop_window;
    r->has_stage = 0;
    r->stage = 0;
    r->switched = -INFINITY;
    r->a_prog = a_ep;
    r->creep_int = 0.0;
    r->has_t_creep = 0;
    r->t_creep = 0.0;
}

double rc_ato_relay_programmed_speed(const rc_ato_relay *r, double s)
{
    double d = r->stop - s;
    return d > 0.0 ? sqrt(2.0 * r->a_prog * d) : 0.0;
}

/* Python's int(x) of a float as a stage count, clamped to [lo, hi] afterwards by the caller's
 * min/max: only NaN and infinities fail (OverflowError / ValueError in Python). */
static rc_status int_of(double x, double *out, rc_error *err)
{
    if (isnan(x) || isinf(x)) {
        if (err)
            snprintf(err->msg, RC_MSG_SIZE, "cannot convert float %s to integer",
                     isnan(x) ? "NaN" : "infinity");
        return RC_MATH;
    }
    *out = trunc(x);
    return RC_OK;
}

/* Python's round(x) of a finite float: to the nearest integer, ties to even, whatever the
 * FPU's rounding mode (x - floor(x) is exact) */
static double round_half_even(double x)
{
    double r = floor(x), diff = x - r;
    if (diff > 0.5 || (diff == 0.5 && fmod(r, 2.0) != 0.0))
        r += 1.0;
    return r;
}

static int clamp_stage(double x, int n)
{
    /* min(max(x, 0), n) of an integer-valued x (exact in a double) */
    return x < 0.0 ? 0 : (x > (double)n ? n : (int)x);
}

rc_status rc_ato_relay_command(rc_ato_relay *r, double t, double s, double v,
                               const rc_ato_plancar *car, double grade, double *traction,
                               double *brake, int *stage, double *v_p, rc_error *err)
{
    double d = r->stop - s;
    if (err)
        err->msg[0] = '\0';
    if (!r->has_stage && d > 0.0 && v > 0.0)
        r->a_prog = rc_min(rc_max(v * v / (2.0 * d), RC_ATO_A_PROG_MIN * r->a_ep), r->a_ep);
    double vp = rc_ato_relay_programmed_speed(r, s);
    if (d <= 0.0) {
        r->has_stage = 1;
        r->stage = r->n_stages;
        *traction = 0.0;
        *brake = r->n_stages * r->stage_force;
        *stage = r->n_stages;
        *v_p = 0.0;
        return RC_OK;
    }
    double e = v - vp;
    if (!r->has_stage) {
        double a = rc_max(r->a_prog, v * v / (2.0 * d));
        double need = car->m_in * a - car->pg * (rc_ato_pc_w0(car, v) + grade);
        double k;
        double ratio = need / r->stage_force;
        if (int_of(isfinite(ratio) ? round_half_even(ratio) : ratio, &k, err) != RC_OK)
            return RC_MATH;          /* round() of NaN/inf raises too: the state is unchanged */
        r->stage = clamp_stage(k, r->n_stages);
        r->has_stage = 1;
        r->switched = t;
    } else if (fabs(e) > r->hysteresis && t - r->switched >= r->dwell - 1e-9) {
        double k;
        if (int_of((fabs(e) - r->hysteresis) / r->stage_speed, &k, err) != RC_OK)
            return RC_MATH;
        double n = 1 + k;
        int next = clamp_stage(r->stage + (e > 0.0 ? n : -n), r->n_stages);
        if (next != r->stage) {
            r->stage = next;
            r->switched = t;
        }
    }
    if (r->stage == 0 && e < -r->hysteresis && v < r->creep_speed && d > r->stop_window) {
        double target = rc_min(vp, r->creep_speed);
        double gain = r->creep_accel / r->creep_speed;
        double dt = r->has_t_creep ? t - r->t_creep : 0.0;
        r->creep_int = rc_min(rc_max(r->creep_int + gain * gain * (target - v) * dt, 0.0),
                              r->creep_accel);
        r->has_t_creep = 1;
        r->t_creep = t;
        double f = rc_ato_track_force(car, v, target, r->creep_int, grade, gain);
        *traction = rc_max(f, 0.0);
        *brake = 0.0;
        *stage = -1;
        *v_p = vp;
        return RC_OK;
    }
    r->has_t_creep = 0;
    *traction = 0.0;
    *brake = r->stage * r->stage_force;
    *stage = r->stage;
    *v_p = vp;
    return RC_OK;
}

double rc_ato_ep_deceleration(const rc_ato_car *car, double a_ep, int ep_stages,
                              double mass_reserve, double grade)
{
    double m = car->mass * (1.0 + mass_reserve);
    int n = ep_stages;
    double spare = (double)(n - 1 > 1 ? n - 1 : 1) / (double)n;
    double force = spare * car->mech_force_max + m * RC_G * (car->A0 + grade);
    double a = force / (1000.0 * m * (1.0 + car->gamma));
    return rc_min(a_ep, rc_max(a, 0.5 * a_ep));
}
