/* ato_controller.c -- AtoController (models/ato/controller.py) in the C core; see ato_controller.h.
 * Each function is the Python method of the same name, in its operand order. */
#include "rc_fp_contract.h"
#include "ato_controller.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#define REPR_SIZE 40

static void set_msg(char *msg, const char *fmt, ...)
{
    if (msg == NULL)
        return;
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(msg, ATO_TEXT_SIZE, fmt, ap);
    va_end(ap);
}

/* events.append((t, text)) */
static void add_event(ato_controller *c, double t, ato_event_code code, const char *fmt, ...)
{
    ato_event *e = &c->events[c->n_events % ATO_EVENT_RING];
    va_list ap;
    e->t = t;
    e->code = code;
    va_start(ap, fmt);
    vsnprintf(e->text, ATO_TEXT_SIZE, fmt, ap);
    va_end(ap);
    c->n_events++;
}

/* _log: recorded once per episode of key */
static void log_once(ato_controller *c, double t, int key, ato_event_code code, const char *text)
{
    if (c->episodes[key])
        return;
    c->episodes[key] = 1;
    add_event(c, t, code, "%s", text);
}

static void clear_inputs(ato_controller *c)
{
    for (int k = 0; k <= ATO_KEY_CONSISTENCY; k++)
        c->episodes[k] = 0;
}

static int key_of_subject(int subject)
{
    if (subject == ATO_SUBJECT_TIME)
        return ATO_KEY_TIME;
    if (subject == ATO_SUBJECT_CONSISTENCY)
        return ATO_KEY_CONSISTENCY;
    if (subject == ATO_SUBJECT_RECOVERY)
        return ATO_KEY_RECOVERY;
    return subject;
}

static ato_command command(double traction, double brake, int mode, double planned, int stage)
{
    ato_command cmd;
    cmd.traction = traction;
    cmd.brake = brake;
    cmd.mode = mode;
    cmd.planned_speed = planned;
    cmd.ep_stage = stage;
    return cmd;
}

/* ---------------------------------------------------------------- the curves */

static double final_stretch_start(const ato_controller *c, const double *qU)
{
    int j = c->course.n - 1;
    while (j > 0 && qU[j - 1] > qU[j] * (1.0 + 1e-12))
        j -= 1;
    return c->course.s[j];
}

/* _supervision(mass) into c->sup_q; RC_MATH where fpmath.square overflows */
static rc_status supervision(ato_controller *c, double mass)
{
    const rc_ato_course *co = &c->course;
    const rc_ato_car *car = c->car;
    double *q = c->sup_q;
    c->sup_mass = mass;
    double m = 1000.0 * mass * (1.0 + c->tuning.mass_reserve) * (1.0 + car->gamma);
    q[co->n - 1] = 2.0 * (car->brake_force_max / m) * 1.0;
    double k_acc = RC_G / 1000.0 / (1.0 + car->gamma);
    for (int i = co->n - 2; i >= 0; i--) {
        double b = rc_min(car->brake_force_max, rc_ato_brake_total_max(car, sqrt(q[i + 1])));
        double a = b / m - k_acc * (-co->g[i]);
        double qb = q[i + 1] + 2.0 * rc_max(a, 0.0) * (co->s[i + 1] - co->s[i]);
        double vl = rc_ato_v_lim_at_node(c->span, co->s[i]);
        double sq = vl * vl;
        if (isinf(sq) && isfinite(vl))
            return RC_MATH;
        q[i] = rc_min(qb, sq);
    }
    return RC_OK;
}

/* _interp: q(x) on the course's nodes and its slope */
static double interp(const ato_controller *c, const double *q, double x, double *slope)
{
    const double *s = c->course.s;
    int i = rc_ato_course_cell(&c->course, x);
    double h = s[i + 1] - s[i];
    double sl = (q[i + 1] - q[i]) / h;
    double w = rc_min(rc_max(x - s[i], 0.0), h);
    *slope = sl;
    return q[i] + w * sl;
}

/* ---------------------------------------------------------------- construction */

/* len(Span.breakpoints(car_length)): the distinct limit distances (but the first), grade
 * distances and grade distances + car length within (0, stop), counted without a buffer */
static double candidate(const rc_ato_span *span, double car_length, int k)
{
    int nl = span->n_limits - 1;
    if (k < nl)
        return span->limit_distances[k + 1];
    k -= nl;
    if (car_length > 0)
        return k % 2 == 0 ? span->grade.distances[k / 2]
                          : span->grade.distances[k / 2] + car_length;
    return span->grade.distances[k];
}

static int count_breakpoints(const rc_ato_span *span, double car_length)
{
    int m = span->n_limits - 1 + (car_length > 0 ? 2 : 1) * span->grade.n;
    int count = 0;
    for (int k = 0; k < m; k++) {
        double x = candidate(span, car_length, k);
        if (!(0.0 < x && x < span->stop))
            continue;
        int seen = 0;
        for (int j = 0; j < k && !seen; j++)
            seen = candidate(span, car_length, j) == x;
        count += !seen;
    }
    return count;
}

static rc_status check_grid(const rc_ato_span *span, const rc_ato_car *car,
                            const ato_tuning *tn, char *msg)
{
    int breaks = count_breakpoints(span, car->length);
    double cells = span->stop / tn->grid_step;
    if (cells + breaks > ATO_MAX_GRID_NODES) {
        int rest = ATO_MAX_GRID_NODES - breaks;
        set_msg(msg, "tuning.grid_step = %g m puts %.4g nodes on the re-planner's grid to the stop "
                "mark (span.stop = %g m, %d grade and limit changes); at most %d (initialisation "
                "~40 us and a re-plan ~5 us per node): make tuning.grid_step >= %.4g m or the span "
                "shorter", tn->grid_step, cells + breaks, span->stop, breaks, ATO_MAX_GRID_NODES,
                span->stop / (rest > 1 ? rest : 1));
        return RC_BAD_CONFIG;
    }
    return RC_OK;
}

static rc_status check_ep(const rc_ato_span *span, const rc_ato_car *car, const ato_tuning *tn,
                          char *msg)
{
    double g = rc_grade_average(&span->grade, span->stop, car->length);
    double need = 1000.0 * car->mass * (1.0 + car->gamma) * tn->a_ep
                  - car->mass * RC_G * (car->A0 + g);
    if (need > car->mech_force_max) {
        char r[REPR_SIZE];
        rc_repr(tn->a_ep, r, sizeof r);
        set_msg(msg, "tuning.a_ep = %s m/s^2 needs %.0f N of electro-pneumatic brake at the stop "
                "mark, car.mech_force_max is %.0f N", r, need, car->mech_force_max);
        return RC_BAD_CONFIG;
    }
    return RC_OK;
}

static void schedule_shown(double schedule, char *out, size_t size)
{
    if (schedule < 1e9)
        snprintf(out, size, "%.2f", schedule);
    else
        snprintf(out, size, "%.6g", schedule);
}

static rc_status construct(ato_controller *c, char *msg)
{
    const rc_ato_span *span = c->span;
    const rc_ato_car *car = c->car;
    const ato_tuning *tn = &c->tuning;
    rc_error err;
    rc_status rc = rc_ato_check_span_for_car(span, car, &err);
    if (rc != RC_OK) {
        set_msg(msg, "%s", err.msg);
        return rc;
    }
    rc = check_grid(span, car, tn, msg);
    if (rc != RC_OK)
        return rc;
    rc = rc_ato_plan_setup(&c->course, &c->planner, &c->configured, span, car, tn->grid_step,
                           tn->limit_margin, tn->time_tol, tn->a_ep, tn->ep_stages,
                           tn->mass_reserve, tn->brake_share, ATO_MAX_NODES, &err);
    if (rc != RC_OK) {
        set_msg(msg, "%s", err.msg);
        return rc;
    }
    if (c->course.n > ATO_MAX_NODES) {   /* never: the course refuses more than this */
        set_msg(msg, "the re-planner's grid has %d nodes, the controller room for %d",
                c->course.n, ATO_MAX_NODES);
        return RC_BAD_CONFIG;
    }
    c->a_ep = c->course.a_ep;
    rc = rc_ato_envelope(&c->planner, &c->configured, c->qU, &err);
    double t_min = 0.0;
    if (rc == RC_OK)
        rc = rc_ato_min_time(&c->planner, &c->configured, c->qU, &t_min, &err);
    if (rc != RC_OK) {
        set_msg(msg, "%s", err.msg);
        return rc;
    }
    if (span->schedule < t_min - tn->time_tol) {
        char r[REPR_SIZE];
        rc_repr(tn->limit_margin, r, sizeof r);
        set_msg(msg, "span.schedule = %.2f s is infeasible: the fastest run the controller plans "
                "(limits less %s m/s) takes %.2f s", span->schedule, r, t_min);
        return RC_BAD_CONFIG;
    }
    double t_slowest = t_min + span->stop / c->planner.v_min;
    char shown[64];
    schedule_shown(span->schedule, shown, sizeof shown);
    if (span->schedule > t_slowest) {
        set_msg(msg, "span.schedule = %s s is too long: even holding %g m/s over the span.stop = "
                "%g m arrives within %.1f s", shown, c->planner.v_min, span->stop, t_slowest);
        return RC_BAD_CONFIG;
    }
    rc = check_ep(span, car, tn, msg);
    if (rc != RC_OK)
        return rc;
    rc = rc_ato_plan_run(&c->planner, &c->configured, 0.0, 0.0, 0.0, span->schedule, c->qU, &err);
    if (rc != RC_OK) {
        set_msg(msg, "%s", err.msg);
        return rc;
    }
    if (c->planner.plan.status == RC_ATO_PLAN_EARLY) {
        set_msg(msg, "span.schedule = %s s is too long: holding %.2f m/s still arrives after "
                "%.2f s", shown, c->planner.plan.hold_speed, c->planner.plan.arrival);
        return RC_BAD_CONFIG;
    }
    c->plan_status = c->planner.plan.status;
    c->plan_arrival = c->planner.plan.arrival;
    c->plan_hold_speed = c->planner.plan.hold_speed;
    double stage_force = car->mech_force_max / tn->ep_stages;
    rc_ato_relay_init(&c->relay, span->stop, c->a_ep, stage_force, tn->ep_stages,
                      tn->relay_hysteresis, tn->relay_stage_speed, tn->relay_dwell,
                      tn->creep_speed, tn->creep_accel, tn->stop_window);
    c->final_start = final_stretch_start(c, c->qU);
    rc = supervision(c, c->configured.brake_mass);
    if (rc != RC_OK) {
        set_msg(msg, "(34, 'Numerical result out of range')");
        return rc;
    }
    c->phase = ATO_PHASE_RUN;
    c->last_replan = -INFINITY;
    c->car_now = c->configured;
    c->last_status = RC_ATO_PLAN_OK;
    c->settle = -1;
    double v_lo = c->course.v_relay, v_hi = span->limit_speeds[0];
    for (int k = 1; k < span->n_limits; k++)
        v_hi = rc_max(v_hi, span->limit_speeds[k]);
    c->blend_speeds[0] = v_lo;
    c->blend_speeds[1] = 0.5 * (v_lo + v_hi);
    c->blend_speeds[2] = v_hi;
    ato_supervisor_init(&c->supervisor, car->mass);
    return RC_OK;
}

rc_status ato_controller_init(ato_controller *c, const rc_ato_span *span, const rc_ato_car *car,
                              const ato_tuning *tuning, char *msg)
{
    memset(c, 0, sizeof *c);
    c->span = span;
    c->car = car;
    memcpy(&c->tuning, tuning, sizeof c->tuning);   /* padding too: a state's bytes are written whole */
    if (msg != NULL)
        msg[0] = '\0';
    rc_error err;
    rc_status rc = ato_tuning_validate(tuning, NULL, &err);
    if (rc != RC_OK) {
        set_msg(msg, "%s", err.msg);
        return rc;
    }
    rc = construct(c, msg);
    if (rc != RC_OK)
        ato_controller_free(c);
    return rc;
}

void ato_controller_free(ato_controller *c)
{
    if (c->planner.block != NULL)
        rc_ato_planner_free(&c->planner);
    if (c->course.s != NULL)
        rc_ato_course_free(&c->course);
    c->planner.block = NULL;
    c->course.s = NULL;
}

int ato_controller_finished(const ato_controller *c) { return c->phase == ATO_PHASE_HOLD; }

double ato_controller_predicted_arrival(const ato_controller *c)
{
    return c->planner.plan.arrival;
}

const ato_event *ato_controller_event(const ato_controller *c, long k)
{
    if (k < 0 || k >= c->n_events || k < c->n_events - ATO_EVENT_RING)
        return NULL;
    return &c->events[k % ATO_EVENT_RING];
}

/* ---------------------------------------------------------------- the step's parts */

/* _params: the car to plan and feed forward with (c->car_now) */
static void params(ato_controller *c, double t, const double *est, const double *stated)
{
    const ato_tuning *tn = &c->tuning;
    const rc_ato_plancar *cf = &c->configured;
    char why[160];
    int usable = 0;
    double w_m = 0.0, w_r = 0.0, b[8];
    int status = (int)est[4];
    int identifying = status == 1 || status == 2;
    if (!tn->use_estimates) {
        snprintf(why, sizeof why, "use_estimates off");
    } else if (!identifying) {
        snprintf(why, sizeof why, "est.status = %d", status);
    } else if (est[5] - c->samples0 < tn->min_samples) {
        snprintf(why, sizeof why, "est.samples = %lld: %lld since departure < %d",
                 (long long)est[5], (long long)(est[5] - c->samples0), tn->min_samples);
    } else {
        usable = 1;
    }
    if (!usable) {
        if (c->using_estimates) {
            char text[ATO_TEXT_SIZE];
            snprintf(text, sizeof text, "estimates not usable (%s): configured values", why);
            log_once(c, t, ATO_KEY_ESTIMATES, ATO_EV_ESTIMATES, text);
        }
    } else {
        double ramp = rc_min(rc_max((est[5] - c->samples0 - tn->min_samples) / tn->min_samples,
                                    0.0), 1.0);
        double dt = c->has_t_gate ? t - c->t_gate : 0.0;
        double conf[4] = {cf->mass, cf->A0, cf->A1, cf->A2};
        rc_ato_blend_estimates(conf, est, stated, ramp, tn->config_mass_std * cf->mass,
                               tn->config_resistance_std, tn->est_gate, c->blend_speeds, 3,
                               tn->mass_band, c->gate, ATO_GATE_RATE * dt, b);
        w_m = b[4];
        w_r = b[5];
        c->gate = b[6];
        c->has_t_gate = 1;
        c->t_gate = t;
        if (b[6] <= 0.0 && ramp > 0.0) {
            char text[ATO_TEXT_SIZE];
            snprintf(text, sizeof text, "est.A0..A2 lie %.1f stated sigmas from the configured "
                     "resistance: no weight for est.*", b[7]);
            log_once(c, t, ATO_KEY_ESTIMATES, ATO_EV_ESTIMATES, text);
        } else if (b[6] >= 1.0) {
            c->episodes[ATO_KEY_ESTIMATES] = 0;
        }
    }
    int using = w_m > 0.0 || w_r > 0.0;
    if (using && !c->using_estimates && !c->used) {
        c->used = 1;
        c->last_replan = -INFINITY;
        add_event(c, t, ATO_EV_EST_USABLE, "est.* usable: planning with the identified values "
                  "weighed against the configured car");
    }
    c->using_estimates = using;
    c->w_m = w_m;
    c->w_r = w_r;
    double plan[4];
    if (usable && using) {
        for (int k = 0; k < 4; k++)
            plan[k] = b[k];
    } else {
        plan[0] = cf->mass;
        plan[1] = cf->A0;
        plan[2] = cf->A1;
        plan[3] = cf->A2;
    }
    if (tn->use_estimates)        /* off: the configured car alone */
        plan[0] = rc_ato_heavier_mass(plan[0], est[0], identifying, cf->mass, tn->mass_band);
    double brake_mass = rc_ato_braking_mass(plan[0], cf->mass);
    double key[5] = {plan[0], plan[1], plan[2], plan[3], brake_mass};
    int same_key = c->has_last_key;
    for (int k = 0; k < 5 && same_key; k++)
        same_key = key[k] == c->last_key[k];
    if (plan[0] == cf->mass && plan[1] == cf->A0 && plan[2] == cf->A1 && plan[3] == cf->A2
        && brake_mass == cf->brake_mass)
        c->car_now = c->configured;
    else if (!same_key)
        rc_ato_plancar_init(&c->car_now, c->car, plan[0], plan[1], plan[2], plan[3],
                            tn->brake_share, brake_mass);
    c->has_last_key = 1;
    memcpy(c->last_key, key, sizeof key);
}

static const char *status_name(int status)
{
    return status == RC_ATO_PLAN_OK ? "ok" : status == RC_ATO_PLAN_LATE ? "late" : "early";
}

/* _replan; RC_MATH (with err) where Python raises other than ValueError */
static rc_status replan(ato_controller *c, double t, double tau, double s, double v, rc_error *err)
{
    const rc_ato_span *span = c->span;
    const rc_ato_plancar *car = &c->car_now;
    double left = rc_max(span->schedule - tau, 0.0);
    double reserve = (c->tuning.time_reserve * (1.0 - c->gate) * left * left / span->schedule);
    rc_status rc = rc_ato_plan_run(&c->planner, car, s, v, tau, span->schedule - reserve, NULL,
                                   err);
    if (rc == RC_BAD_CONFIG) {
        char text[ATO_TEXT_SIZE];
        snprintf(text, sizeof text, "re-plan failed (%s): the last plan is kept", err->msg);
        log_once(c, t, ATO_KEY_REPLAN, ATO_EV_REPLAN_FAILED, text);
        return RC_OK;
    }
    if (rc != RC_OK)
        return rc;
    c->episodes[ATO_KEY_REPLAN] = 0;
    const rc_ato_plan *pl = &c->planner.plan;
    memcpy(c->qU, pl->qU, sizeof(double) * (size_t)c->course.n);
    c->replans++;
    if (pl->status != c->last_status) {
        add_event(c, t, ATO_EV_REPLAN_STATUS, "re-plan status %s: arrival planned %+.2f s off "
                  "schedule", status_name(pl->status), pl->arrival - span->schedule);
        c->last_status = pl->status;
    }
    c->plan_status = pl->status;
    c->final_start = final_stretch_start(c, c->qU);
    if (fabs(car->brake_mass - c->sup_mass) > 1e-3 * c->sup_mass) {
        if (supervision(c, car->brake_mass) != RC_OK) {
            snprintf(err->msg, RC_MSG_SIZE, "(34, 'Numerical result out of range')");
            return RC_MATH;
        }
    }
    return RC_OK;
}

static void set_aim(ato_controller *c, double sd)
{
    const ato_tuning *tn = &c->tuning;
    if (c->settle < 0)
        c->settle = tn->settle_time > 0.0 && c->psd > tn->settle_std;
    if (c->settle == 1 && !c->settled) {
        c->aim_offset = rc_min(tn->settle_sigma * c->psd, tn->settle_aim_max);
    } else {
        double t_ep = c->course.v_relay / c->a_ep;
        c->aim_offset = rc_min(tn->aim_sigma * sd * t_ep, tn->aim_max);
    }
    c->relay.stop = c->span->stop - c->aim_offset;
}

static void refine_aim(ato_controller *c, double t, double sd)
{
    const ato_tuning *tn = &c->tuning;
    if (c->settle == 1 && !c->settled && c->psd <= tn->settle_std) {
        c->settle = 0;
        add_event(c, t, ATO_EV_ONE_STOP, "filter.position_std %.3f m at the EP stage: one stop, "
                  "no settling", c->psd);
    }
    if (!(c->settle == 1 && !c->settled)) {
        double t_ep = c->course.v_relay / c->a_ep;
        c->aim_offset = rc_min(rc_min(c->aim_offset, tn->aim_sigma * sd * t_ep), tn->aim_max);
        c->relay.stop = c->span->stop - c->aim_offset;
    }
}

static double holding(const ato_controller *c)
{
    return rc_max(c->last_brake, c->tuning.hold_brake * c->car->brake_force_max);
}

static ato_command hold(const ato_controller *c)
{
    return command(0.0, holding(c), ATO_MODE_HOLD, 0.0, 0);
}

static ato_command settle_step(ato_controller *c, double t, double s)
{
    const ato_tuning *tn = &c->tuning;
    if (t - c->settle_since < tn->settle_time - 1e-9)
        return command(0.0, holding(c), ATO_MODE_SETTLE, 0.0, 0);
    c->settled = 1;
    c->aim_offset = tn->creep_aim;
    c->relay.stop = c->span->stop - tn->creep_aim;
    c->relay.stop_window = rc_min(tn->settle_window, tn->stop_window);
    c->has_stand_since = 0;
    add_event(c, t, ATO_EV_SETTLED, "settled: %+.3f m short of the mark (filter)",
              c->span->stop - s);
    c->phase = ATO_PHASE_EP;
    return command(0.0, holding(c), ATO_MODE_SETTLE, 0.0, 0);
}

/* _ceiling: *u [m/s] and *a_u [m/s^2] */
static void ceiling(const ato_controller *c, double s, double sd, double shift, double *u_out,
                    double *a_out)
{
    const ato_tuning *tn = &c->tuning;
    double dq, dqs;
    double qu = interp(c, c->qU, s + shift, &dq);
    double u = qu > 0.0 ? sqrt(qu) : 0.0;
    double a_u = 0.5 * dq;
    double qs = interp(c, c->sup_q, s + tn->k_sigma * c->psd, &dqs);
    double vs = qs > 0.0 ? sqrt(qs) : 0.0;
    double w = vs - (tn->k_sigma + tn->gap_sigma) * sd - tn->supervisor_gap;
    if (w < u) {
        *u_out = rc_max(w, 0.0);
        *a_out = 0.5 * dqs;
        return;
    }
    *u_out = u;
    *a_out = a_u;
}

static ato_command command_of(const ato_controller *c, const rc_ato_plancar *car, double v,
                              double f, double a_ref, double planned)
{
    if (f > 0.0) {
        double fm = rc_ato_pc_f_max(car, v);
        int mode = f >= fm ? ATO_MODE_TG : ATO_MODE_C;
        return command(rc_min(f, c->car->traction_force_max), 0.0, mode, planned, 0);
    }
    if (f == 0.0)
        return command(0.0, 0.0, ATO_MODE_VB, planned, 0);
    double b = -f;
    double regen = v >= car->v_fade ? rc_ato_pc_r_full(car, v) : 0.0;
    int decel = a_ref < 0.0;
    int mode;
    if (b <= regen)
        mode = decel ? ATO_MODE_RK : ATO_MODE_SR;
    else
        mode = decel ? ATO_MODE_TM : ATO_MODE_ST;
    return command(0.0, rc_min(b, c->car->brake_force_max), mode, planned, 0);
}

static ato_command supervised(ato_controller *c, double t, double s, double v, double sd,
                              ato_command cmd)
{
    double k = c->tuning.k_sigma;
    double s_hi = s + k * c->psd;
    double slope;
    double q = interp(c, c->sup_q, s_hi, &slope);
    double v_hi = v + k * sd;
    if (v_hi * v_hi > q) {
        char text[ATO_TEXT_SIZE];
        snprintf(text, sizeof text, "speed %.3f m/s + %g x %.3f m/s above the supervision curve "
                 "%.3f m/s at s = %.1f m + %g x %.3f m: full brake", v, k, sd,
                 sqrt(rc_max(q, 0.0)), s, k, c->psd);
        log_once(c, t, ATO_KEY_OVERSPEED, ATO_EV_OVERSPEED, text);
        return command(0.0, c->car->brake_force_max, ATO_MODE_OVERSPEED, cmd.planned_speed,
                       cmd.ep_stage);
    }
    c->episodes[ATO_KEY_OVERSPEED] = 0;
    return cmd;
}

static rc_status stop_ep(ato_controller *c, double t, double s, double v, double sd, double d,
                         double g, ato_command *out, rc_error *err)
{
    const ato_tuning *tn = &c->tuning;
    int settle = c->settle == 1 && !c->settled;
    int done = c->crept && (c->relay.has_stage ? c->relay.stage : 0) > 0;
    if (v <= tn->stand_speed && (d <= c->relay.stop_window || settle || done)) {
        if (!c->has_stand_since) {
            c->has_stand_since = 1;
            c->stand_since = t;
        }
        if (t - c->stand_since >= tn->stand_time - 1e-9 && settle) {
            c->phase = ATO_PHASE_SETTLE;
            c->has_settle_since = 1;
            c->settle_since = t;
            c->has_first_stop = 1;
            c->first_stop_t = t;
            c->first_stop_s = s;
            add_event(c, t, ATO_EV_STOPPED, "stopped %+.3f m short of the mark (filter; aimed "
                      "%.3f m short): standing %g s", c->span->stop - s, c->aim_offset,
                      tn->settle_time);
            *out = settle_step(c, t, s);
            return RC_OK;
        }
        if (t - c->stand_since >= tn->stand_time - 1e-9) {
            if (!c->has_first_stop) {
                c->has_first_stop = 1;
                c->first_stop_t = t;
                c->first_stop_s = s;
            }
            c->phase = ATO_PHASE_HOLD;
            add_event(c, t, ATO_EV_STOPPED, "stopped %+.3f m short of the mark (filter; aimed "
                      "%.3f m short)", c->span->stop - s, c->aim_offset);
            *out = hold(c);
            return RC_OK;
        }
        *out = command(0.0, holding(c), ATO_MODE_EP, 0.0, c->relay.n_stages);
        return RC_OK;
    }
    c->has_stand_since = 0;
    double f, b, v_p;
    int stage;
    rc_status rc = rc_ato_relay_command(&c->relay, t, s, v, &c->car_now, g, &f, &b, &stage, &v_p,
                                        err);
    if (rc != RC_OK)
        return rc;
    c->crept = c->crept || (c->settled && stage < 0);
    int mode = stage < 0 ? ATO_MODE_CREEP : ATO_MODE_EP;
    *out = supervised(c, t, s, v, sd, command(f, b, mode, v_p, stage > 0 ? stage : 0));
    return RC_OK;
}

/* _step: the command in *out, or an error Python raises (RC_MATH, its text in err) */
static rc_status step(ato_controller *c, double t, const double *vals, ato_command *out,
                      rc_error *err)
{
    const ato_tuning *tn = &c->tuning;
    double v = rc_max(vals[0], 0.0), s = vals[1], sd = vals[2];
    const double *est = vals + 3;
    c->psd = rc_max(vals[9], 0.0);
    const double *stated = vals + 10;
    if (!c->has_departure) {
        c->has_departure = 1;
        c->t_departure = t;
        c->samples0 = est[5];
    }
    double tau = t - c->t_departure;
    params(c, t, est, stated);
    const rc_ato_plancar *car = &c->car_now;
    if (c->phase == ATO_PHASE_HOLD) {
        *out = hold(c);
        return RC_OK;
    }
    if (c->phase == ATO_PHASE_SETTLE) {
        *out = settle_step(c, t, s);
        return RC_OK;
    }
    double g = rc_grade_average(&c->span->grade, s, c->car->length);
    if (c->phase == ATO_PHASE_BRAKE)
        set_aim(c, sd);
    double d = c->relay.stop - s;
    if ((c->phase == ATO_PHASE_RUN || c->phase == ATO_PHASE_BRAKE)
        && (d <= c->course.d_relay || (c->phase == ATO_PHASE_BRAKE && v <= c->course.v_relay))) {
        c->phase = ATO_PHASE_EP;
        if (c->aim_offset == 0.0)
            set_aim(c, sd);
        else
            refine_aim(c, t, sd);
    }
    if (c->phase == ATO_PHASE_EP)
        return stop_ep(c, t, s, v, sd, c->relay.stop - s, g, out, err);
    if (c->phase == ATO_PHASE_RUN && tn->replan
        && tau - c->last_replan >= tn->replan_period - 1e-9) {
        c->last_replan = tau;
        rc_status rc = replan(c, t, tau, s, v, err);
        if (rc != RC_OK)
            return rc;
    }
    const rc_ato_plan *plan = &c->planner.plan;
    double u, a_u;
    ceiling(c, s, sd, c->phase == ATO_PHASE_BRAKE ? c->aim_offset : 0.0, &u, &a_u);
    double f_ceil = rc_ato_track_force(car, v, u, a_u, g, tn->approach_gain);
    if (c->phase == ATO_PHASE_BRAKE) {
        double dt = c->has_t_last ? t - c->t_last : 0.0;
        double lim = tn->brake_integral_max;
        c->brake_int = rc_min(rc_max(c->brake_int + tn->brake_integral_gain * (u - v) * dt, -lim),
                              lim);
        double f = rc_min(f_ceil + car->m_in * c->brake_int, 0.0);
        c->has_t_last = 1;
        c->t_last = t;
        *out = supervised(c, t, s, v, sd, command_of(c, car, v, f, a_u, u));
        return RC_OK;
    }
    double f_want = 0.0;
    int coasting = 0;
    for (int k = 0; k < plan->n_coasts && !coasting; k++)
        coasting = plan->coast_x[k] <= s && s < plan->coast_end[k];
    if (!coasting) {
        double f_c = rc_ato_track_force(car, v, plan->hold_speed, 0.0, g, tn->approach_gain);
        if (f_c > 0.0)
            f_want = f_c;
        else if (v > plan->regen_speed)
            f_want = rc_ato_track_force(car, v, plan->regen_speed, 0.0, g, tn->approach_gain);
    }
    int on_ceiling = f_ceil < f_want;
    double f = on_ceiling ? f_ceil : f_want;
    if (on_ceiling && f < 0.0 && s >= c->final_start - 1e-9) {
        c->phase = ATO_PHASE_BRAKE;
        c->brake_int = 0.0;
        c->has_t_last = 1;
        c->t_last = t;
        set_aim(c, sd);
    }
    *out = supervised(c, t, s, v, sd, command_of(c, car, v, f, on_ceiling ? a_u : 0.0,
                                                 rc_ato_plan_speed_at(plan, s)));
    return RC_OK;
}

/* ---------------------------------------------------------------- demands */

static ato_command safe(const ato_controller *c)
{
    return command(0.0, c->tuning.safe_brake * c->car->brake_force_max, ATO_MODE_SAFE, 0.0, 0);
}

ato_command ato_controller_demands(ato_controller *c, double t, const double *inputs)
{
    double vals[ATO_N_ALL_INPUTS];
    ato_supervisor *sup = &c->supervisor;
    ato_gate_verdict verdict = ato_supervisor_gate(sup, t, inputs, vals);
    if (verdict == ATO_GATE_SAFE) {
        int key = key_of_subject(sup->gate.subject);
        if (key == ATO_KEY_RECOVERY)
            clear_inputs(c);
        log_once(c, t, key, key == ATO_KEY_RECOVERY ? ATO_EV_RECOVERY : ATO_EV_INPUT,
                 sup->gate.text);
        return safe(c);
    }
    clear_inputs(c);
    if (verdict == ATO_GATE_RUN_RELEASED) {
        c->episodes[ATO_KEY_RECOVERY] = 0;
        add_event(c, t, ATO_EV_RELEASED, "%s", sup->gate.text);
    }
    ato_command cmd;
    rc_error err;
    rc_status rc = step(c, t, vals, &cmd, &err);
    if (rc != RC_OK) {
        /* Python's except Exception: the safe brake, the error named once. What raises: int() of
         * a NaN stage count (ValueError) or of an infinite one, fpmath.square (OverflowError);
         * RC_ATO_INTERNAL is the C planner's own (a capacity its sizing never misses). None is
         * reached by inputs the supervisor passes (speeds <= 200 m/s, finite). */
        char text[ATO_TEXT_SIZE];
        const char *kind = rc == RC_ATO_INTERNAL ? "RuntimeError"
                           : strstr(err.msg, "NaN") != NULL ? "ValueError" : "OverflowError";
        snprintf(text, sizeof text, "internal error %s: %s: safe brake", kind, err.msg);
        log_once(c, NAN, ATO_KEY_INTERNAL, ATO_EV_INTERNAL, text);
        ato_supervisor_note_command(sup, 0.0);
        return safe(c);
    }
    c->last_brake = cmd.brake;
    ato_supervisor_note_command(sup, cmd.traction);
    return cmd;
}
