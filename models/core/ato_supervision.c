/* ato_supervision.c -- see ato_supervision.h: models/ato/supervision.py's InputSupervisor and
 * the front of AtoController.demands, in Python's order, with Python's comparisons (so NaN and
 * -0.0 go the same way) and its messages. */
#include "rc_fp_contract.h"
#include "ato_supervision.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#define REPR_SIZE 40

const char *ato_subject_name(int subject)
{
    switch (subject) {
    case ATO_SUBJECT_TIME:
        return "t";
    case ATO_SUBJECT_CONSISTENCY:
        return "filter.speed vs filter.position";
    case ATO_SUBJECT_RECOVERY:
        return "recovery";
    default:
        return ato_input_name(subject);
    }
}

static void clear(ato_problem *p)
{
    p->subject = ATO_SUBJECT_NONE;
    p->reason = ATO_SANE;
    p->text[0] = '\0';
}

/* A verdict: subject, reason, the printf-formatted text; returns the reason */
static ato_reason say(ato_problem *p, int subject, ato_reason reason, const char *fmt, ...)
{
    va_list ap;
    p->subject = subject;
    p->reason = reason;
    va_start(ap, fmt);
    vsnprintf(p->text, sizeof p->text, fmt, ap);
    va_end(ap);
    return reason;
}

void ato_supervisor_init(ato_supervisor *s, double mass)
{
    memset(s, 0, sizeof *s);
    s->mass = mass;
    clear(&s->dead_problem);
    clear(&s->problem);
    clear(&s->gate);
}

void ato_supervisor_note_command(ato_supervisor *s, double traction)
{
    if (traction <= 0.0) {
        s->pushing = 0;
    } else if (!s->pushing && s->at_rest) {
        s->pushing = 1;
        s->pushing_t = s->at_rest_t;
        s->pushing_s = s->at_rest_s;
    }
}

/* _check_time (against the previous call's time, before check updates it) */
static ato_reason check_time(ato_supervisor *s, double t, ato_problem *p)
{
    if (!s->has_t_last)
        return ATO_SANE;
    double last = s->t_last;
    char rt[REPR_SIZE], rl[REPR_SIZE];
    if (!(t > last)) {
        s->has_anchor = 0;
        rc_repr(t, rt, sizeof rt);
        rc_repr(last, rl, sizeof rl);
        return say(p, ATO_SUBJECT_TIME, ATO_TIME_NOT_LATER,
                   "time t = %s s does not continue: the previous call was at t = %s s", rt, rl);
    }
    if (t - last > ATO_MAX_CALL_GAP) {
        s->has_anchor = 0;
        rc_repr(t, rt, sizeof rt);
        return say(p, ATO_SUBJECT_TIME, ATO_TIME_GAP,
                   "time t = %s s is %.6g s after the previous call (at most %g s: the inputs "
                   "cannot be checked against each other)", rt, t - last, ATO_MAX_CALL_GAP);
    }
    return ATO_SANE;
}

static ato_reason check_stds(const double *x, ato_problem *p)
{
    static const int index[2] = {ATO_IN_SPEED_STD, ATO_IN_POSITION_STD};
    static const char *const unit[2] = {"m/s", "m"};
    static const double bound[2] = {ATO_MAX_SPEED, ATO_MAX_DISTANCE};
    char r[REPR_SIZE];
    for (int k = 0; k < 2; k++) {
        const char *name = ato_input_name(index[k]);
        double sd = x[index[k]];
        if (sd < 0.0) {
            rc_repr(sd, r, sizeof r);
            return say(p, index[k], ATO_STD_NEGATIVE,
                       "%s = %s %s: a standard deviation is never negative", name, r, unit[k]);
        }
        if (sd == 0.0 && x[ATO_IN_SPEED] != 0.0) {
            rc_repr(x[ATO_IN_SPEED], r, sizeof r);
            return say(p, index[k], ATO_STD_ZERO_MOVING,
                       "%s = 0 %s while filter.speed = %s m/s: a filter is exact only at its known "
                       "start at rest", name, unit[k], r);
        }
        if (sd > bound[k]) {
            rc_repr(sd, r, sizeof r);
            return say(p, index[k], ATO_STD_BEYOND, "%s = %s %s is beyond %g %s (not physics)",
                       name, r, unit[k], bound[k], unit[k]);
        }
    }
    return ATO_SANE;
}

static ato_reason check_motion(const double *x, ato_problem *p)
{
    double v = x[ATO_IN_SPEED], sd = x[ATO_IN_SPEED_STD];
    char r[REPR_SIZE];
    if (v < -ATO_NOISE_SIGMA * sd) {
        rc_repr(v, r, sizeof r);
        return say(p, ATO_IN_SPEED, ATO_SPEED_BACKWARDS,
                   "filter.speed = %s m/s is below -%g x filter.speed_std (%.4g m/s): the car "
                   "does not run backwards", r, ATO_NOISE_SIGMA, -ATO_NOISE_SIGMA * sd);
    }
    if (v > ATO_MAX_SPEED) {
        rc_repr(v, r, sizeof r);
        return say(p, ATO_IN_SPEED, ATO_SPEED_BEYOND,
                   "filter.speed = %s m/s is beyond %g m/s (no rail car is that fast)", r,
                   ATO_MAX_SPEED);
    }
    double s = x[ATO_IN_POSITION], psd = x[ATO_IN_POSITION_STD];
    if (s < -ATO_NOISE_SIGMA * psd) {
        rc_repr(s, r, sizeof r);
        return say(p, ATO_IN_POSITION, ATO_POSITION_BEHIND,
                   "filter.position = %s m is below -%g x filter.position_std (%.4g m): behind "
                   "the departure station", r, ATO_NOISE_SIGMA, -ATO_NOISE_SIGMA * psd);
    }
    if (s > ATO_MAX_DISTANCE) {
        rc_repr(s, r, sizeof r);
        return say(p, ATO_IN_POSITION, ATO_POSITION_BEYOND,
                   "filter.position = %s m is beyond %g m (no line is that long)", r,
                   ATO_MAX_DISTANCE);
    }
    return ATO_SANE;
}

static ato_reason check_estimates(const ato_supervisor *s, const double *x, ato_problem *p)
{
    static const int index[3] = {ATO_IN_A0, ATO_IN_A1, ATO_IN_A2};
    static const double bound[3] = {ATO_A0_MAX, ATO_A1_MAX, ATO_A2_MAX};
    static const char *const unit[3] = {"N/kN", "N/kN/(m/s)", "N/kN/(m/s)^2"};
    char r[REPR_SIZE];
    double m = x[ATO_IN_MASS];
    double lo = s->mass / ATO_MASS_FACTOR, hi = s->mass * ATO_MASS_FACTOR;
    if (!(lo <= m && m <= hi)) {
        rc_repr(m, r, sizeof r);
        return say(p, ATO_IN_MASS, ATO_MASS_OUTSIDE,
                   "est.mass = %s t is outside [%.4g, %.4g] t (a factor %g of car.mass = %g t)",
                   r, lo, hi, ATO_MASS_FACTOR, s->mass);
    }
    for (int k = 0; k < 3; k++) {
        double a = x[index[k]];
        if (fabs(a) > bound[k]) {
            rc_repr(a, r, sizeof r);
            return say(p, index[k], ATO_RESISTANCE_BEYOND,
                       "%s = %s %s is beyond +-%g %s (no resistance is that large)",
                       ato_input_name(index[k]), r, unit[k], bound[k], unit[k]);
        }
    }
    double status = x[ATO_IN_STATUS];          /* `not in (0, 1, 2, 3)`: == on each */
    if (!(status == 0.0 || status == 1.0 || status == 2.0 || status == 3.0))
        return say(p, ATO_IN_STATUS, ATO_STATUS_UNKNOWN,
                   "est.status = %g is not one of the estimator's codes 0..3", status);
    double samples = x[ATO_IN_SAMPLES];
    if (!(0.0 <= samples && samples <= ATO_MAX_SAMPLES))
        return say(p, ATO_IN_SAMPLES, ATO_SAMPLES_OUTSIDE,
                   "est.samples = %.0f is outside [0, %.0e] (a count of samples; 1e9 is 3 years "
                   "at 10 Hz)", samples, ATO_MAX_SAMPLES);
    return ATO_SANE;
}

/* _restart: a new consistency window from this call */
static void restart(ato_supervisor *s, double t, double pos, double v, double sd, double psd)
{
    s->has_anchor = 1;
    s->anchor_t = t;
    s->anchor_s = pos;
    s->anchor_psd = psd;
    s->t_prev = t;
    s->v_last = v;
    s->travel = 0.0;
    s->sd_max = sd;
}

static ato_reason check_consistency(ato_supervisor *s, double t, const double *x, ato_problem *p)
{
    double pos = x[ATO_IN_POSITION], v = x[ATO_IN_SPEED], sd = x[ATO_IN_SPEED_STD];
    double psd = x[ATO_IN_POSITION_STD];
    if (!s->has_anchor) {
        restart(s, t, pos, v, sd, psd);
        return ATO_SANE;
    }
    double t0 = s->anchor_t, s0 = s->anchor_s, psd0 = s->anchor_psd;
    s->travel += 0.5 * (s->v_last + v) * (t - s->t_prev);
    s->v_last = v;
    s->t_prev = t;
    s->sd_max = rc_max(s->sd_max, sd);
    double advance = pos - s0;
    double tol = ATO_NOISE_SIGMA * (psd0 + psd + s->sd_max * (t - t0)) + ATO_CONSISTENCY_SLACK;
    if (fabs(advance - s->travel) > tol) {
        char r[REPR_SIZE];
        rc_repr(v, r, sizeof r);
        say(p, ATO_SUBJECT_CONSISTENCY, ATO_INCONSISTENT,
            "filter.speed and filter.position disagree: filter.position advanced %.3f m "
            "in %.3g s, filter.speed (now %s m/s) accounts for %.3f m (tolerance %.3f m)",
            advance, t - t0, r, s->travel, tol);
        restart(s, t, pos, v, sd, psd);
        return p->reason;
    }
    if (t - t0 >= ATO_CONSISTENCY_WINDOW - 1e-9)
        restart(s, t, pos, v, sd, psd);
    return ATO_SANE;
}

static ato_reason check_response(ato_supervisor *s, double t, const double *x, ato_problem *p)
{
    if (s->dead) {
        if (x[ATO_IN_SPEED] == 0.0 && x[ATO_IN_POSITION] == s->dead_s) {
            *p = s->dead_problem;
            return p->reason;
        }
        s->dead = 0;
    }
    if (!s->pushing)
        return ATO_SANE;
    double t0 = s->pushing_t, s0 = s->pushing_s;
    if (x[ATO_IN_SPEED] != 0.0 || x[ATO_IN_POSITION] != s0) {
        s->pushing = 0;                        /* the car responds */
        return ATO_SANE;
    }
    if (t - t0 >= ATO_RESPONSE_TIME - 1e-9) {
        char r[REPR_SIZE];
        s->pushing = 0;
        rc_repr(s0, r, sizeof r);
        say(p, ATO_IN_SPEED, ATO_NOT_FOLLOWING,
            "filter.speed = 0 m/s and filter.position = %s m have not moved in %.3g s of "
            "traction: the inputs do not follow the car (not connected?)", r, t - t0);
        s->dead = 1;
        s->dead_s = s0;
        s->dead_problem = *p;
        return p->reason;
    }
    return ATO_SANE;
}

ato_reason ato_supervisor_check(ato_supervisor *s, double t, const double *x)
{
    ato_problem *p = &s->problem;
    clear(p);
    ato_reason found = check_time(s, t, p);
    if (!s->has_t_last || t > s->t_last) {
        s->has_t_last = 1;
        s->t_last = t;
    }
    if (found == ATO_SANE)
        found = check_stds(x, p);
    if (found == ATO_SANE)
        found = check_motion(x, p);
    if (found == ATO_SANE)
        found = check_estimates(s, x, p);
    if (found == ATO_SANE)
        found = check_consistency(s, t, x, p);
    else
        s->has_anchor = 0;     /* a window spans sane calls only: no trapezoid over a bad episode */
    s->at_rest = found == ATO_SANE && x[ATO_IN_SPEED] == 0.0;
    if (s->at_rest) {
        s->at_rest_t = t;
        s->at_rest_s = x[ATO_IN_POSITION];
    }
    if (found == ATO_SANE)
        found = check_response(s, t, x, p);
    return found;
}

/* AtoController._bad_input: latched, the release timer stopped, _safe's note_command(0) */
static ato_gate_verdict bad_input(ato_supervisor *s)
{
    s->latched = 1;
    s->has_sane_since = 0;
    ato_supervisor_note_command(s, 0.0);
    return ATO_GATE_SAFE;
}

ato_gate_verdict ato_supervisor_gate(ato_supervisor *s, double t, const double *inputs,
                                     double *values)
{
    ato_problem *g = &s->gate;
    char r[REPR_SIZE];
    clear(g);
    if (!isfinite(t)) {
        rc_repr(t, r, sizeof r);
        say(g, ATO_SUBJECT_TIME, ATO_TIME_NOT_FINITE,
            "time t = %s is not a finite number: safe brake", r);
        return bad_input(s);
    }
    for (int i = 0; i < ATO_N_INPUTS; i++)
        if (!isfinite(inputs[i])) {
            rc_repr(inputs[i], r, sizeof r);   /* str() of inf and nan: as repr() */
            say(g, i, ATO_INPUT_NOT_FINITE, "%s = %s is not finite: safe brake",
                ato_input_name(i), r);
            return bad_input(s);
        }
    for (int i = 0; i < ATO_N_ALL_INPUTS; i++)
        values[i] = i < ATO_N_INPUTS || isfinite(inputs[i]) ? inputs[i] : ato_stated_prior(i);
    if (ato_supervisor_check(s, t, values) != ATO_SANE) {
        const ato_problem *p = &s->problem;
        say(g, p->subject, p->reason, "%s: safe brake", p->text);
        return bad_input(s);
    }
    if (s->latched) {                          /* sane again: held until sane for RECOVERY_TIME */
        if (!s->has_sane_since) {
            s->has_sane_since = 1;
            s->sane_since = t;
        }
        if (t - s->sane_since < ATO_RECOVERY_TIME - 1e-9) {
            ato_supervisor_note_command(s, 0.0);
            say(g, ATO_SUBJECT_RECOVERY, ATO_RECOVERY_HOLD, "inputs sane again: the safe brake "
                "is held until they have been sane for %g s", ATO_RECOVERY_TIME);
            return ATO_GATE_SAFE;
        }
        s->latched = 0;
        s->has_sane_since = 0;
        say(g, ATO_SUBJECT_RECOVERY, ATO_SANE, "inputs sane for %g s: the safe brake is released",
            ATO_RECOVERY_TIME);
        return ATO_GATE_RUN_RELEASED;
    }
    return ATO_GATE_RUN;
}
