/* ato_plan_shim.c -- a ctypes face of the C re-planner (models/core/ato_*.c) for the bit-identity
 * tests (tests/model_tests/core/test_core_ato_plan.py) and benchmarks/replan_benchmark.py.
 * One handle: the span and car (copies of the caller's arrays), the course, the planner and the
 * configured PlanCar of plan_setup. */
#include "rc_fp_contract.h"
#include "ato_planner.h"
#include "ato_stopping.h"

#include <stdlib.h>
#include <string.h>

typedef struct {
    double *grade_d, *grade_g, *grade_cum, *lim_d, *lim_v;
    rc_ato_span span;
    rc_ato_car car;
    rc_ato_course course;
    rc_ato_planner planner;
    rc_ato_plancar configured, plan_car;
    rc_error err;
} shim;

static double *copy(const double *x, int n)
{
    double *out = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    if (out != NULL)
        memcpy(out, x, sizeof(double) * (size_t)n);
    return out;
}

static void car_of(rc_ato_car *c, const double *v)
{
    c->mass = v[0];
    c->A0 = v[1];
    c->A1 = v[2];
    c->A2 = v[3];
    c->gamma = v[4];
    c->length = v[5];
    c->traction_force_max = v[6];
    c->traction_power_max = v[7];
    c->brake_force_max = v[8];
    c->regen_force_max = v[9];
    c->regen_power_max = v[10];
    c->regen_fade_speed = v[11];
    c->regen_off_speed = v[12];
    c->mech_force_max = v[13];
    c->adhesion_mass_fraction = v[14];
    c->adhesion_factor = v[15];
    c->eta_f = v[16];
    c->eta = v[17];
}

static void free_arrays(shim *h)
{
    free(h->grade_d);
    free(h->grade_g);
    free(h->grade_cum);
    free(h->lim_d);
    free(h->lim_v);
}

/* span: (length, schedule, stop); car: the 18 CarTraction fields in declaration order;
 * tuning: (grid_step, limit_margin, time_tol, a_ep, ep_stages, mass_reserve, brake_share).
 * setup 0: only the span and the car (no planner). Returns the handle (NULL on an error:
 * msg then holds it) */
void *shim_new(const double *span3, const double *grade_d, const double *grade_g, int n_grade,
               const double *lim_d, const double *lim_v, int n_lim, const double *car,
               const double *tuning, int max_nodes, int setup, int *status, char *msg)
{
    shim *h = calloc(1, sizeof *h);
    if (h == NULL)
        return NULL;
    h->grade_d = copy(grade_d, n_grade);
    h->grade_g = copy(grade_g, n_grade);
    h->grade_cum = copy(grade_g, n_grade);
    h->lim_d = copy(lim_d, n_lim);
    h->lim_v = copy(lim_v, n_lim);
    h->span.length = span3[0];
    h->span.schedule = span3[1];
    h->span.stop = span3[2];
    h->span.grade.n = n_grade;
    h->span.grade.distances = h->grade_d;
    h->span.grade.grades = h->grade_g;
    rc_grade_cumulate(h->grade_d, h->grade_g, n_grade, h->grade_cum);
    h->span.grade.cum = h->grade_cum;
    h->span.n_limits = n_lim;
    h->span.limit_distances = h->lim_d;
    h->span.limit_speeds = h->lim_v;
    car_of(&h->car, car);
    *status = RC_OK;
    msg[0] = '\0';
    if (!setup)
        return h;
    *status = rc_ato_plan_setup(&h->course, &h->planner, &h->configured, &h->span, &h->car,
                                tuning[0], tuning[1], tuning[2], tuning[3], (int)tuning[4],
                                tuning[5], tuning[6], max_nodes, &h->err);
    if (*status != RC_OK) {
        strcpy(msg, h->err.msg);
        free_arrays(h);
        free(h);
        return NULL;
    }
    return h;
}

void shim_free(void *hv)
{
    shim *h = hv;
    if (h->planner.block != NULL)
        rc_ato_planner_free(&h->planner);
    if (h->course.s != NULL)
        rc_ato_course_free(&h->course);
    free_arrays(h);
    free(h);
}

const char *shim_msg(void *hv) { return ((shim *)hv)->err.msg; }

/* the course: n, i_relay, and s, g, qlim into the caller's arrays (cap) */
int shim_course(void *hv, double *s, double *g, double *qlim, double *scalars, int cap)
{
    shim *h = hv;
    const rc_ato_course *c = &h->course;
    if (c->n > cap)
        return -1;
    memcpy(s, c->s, sizeof(double) * (size_t)c->n);
    memcpy(g, c->g, sizeof(double) * (size_t)(c->n - 1));
    memcpy(qlim, c->qlim, sizeof(double) * (size_t)c->n);
    scalars[0] = c->d_relay;
    scalars[1] = c->a_ep;
    scalars[2] = c->i_relay;
    return c->n;
}

/* the PlanCar of the next plans: (mass, A0, A1, A2, brake_share, brake_mass); NULL: configured */
void shim_set_car(void *hv, const double *pc)
{
    shim *h = hv;
    if (pc == NULL)
        h->plan_car = h->configured;
    else
        rc_ato_plancar_init(&h->plan_car, &h->car, pc[0], pc[1], pc[2], pc[3], pc[4], pc[5]);
}

int shim_envelope(void *hv, double *qU)
{
    shim *h = hv;
    return rc_ato_envelope(&h->planner, &h->plan_car, qU, &h->err);
}

int shim_min_time(void *hv, const double *qU, double *t_min)
{
    shim *h = hv;
    return rc_ato_min_time(&h->planner, &h->plan_car, qU, t_min, &h->err);
}

/* plan(); scalars: hold, regen, arrival, energy, traction, regen_kwh, status, trials, policy,
 * n, n_coasts, coast_runs, last_vc (nan: None), vc_slope (nan: None), last_cap (nan: None) */
int shim_plan(void *hv, double s0, double v0, double t0, double arrival, const double *qU,
              double *scalars)
{
    shim *h = hv;
    rc_ato_planner *p = &h->planner;
    int rc = rc_ato_plan_run(p, &h->plan_car, s0, v0, t0, arrival, qU, &h->err);
    const rc_ato_plan *pl = &p->plan;
    if (rc == RC_OK) {
        double out[11] = {pl->hold_speed, pl->regen_speed, pl->arrival, pl->energy_kwh,
                          pl->traction_kwh, pl->regen_kwh, pl->status, pl->trials, pl->policy,
                          pl->n, pl->n_coasts};
        memcpy(scalars, out, sizeof out);
    }
    scalars[11] = (double)p->coast_runs;
    scalars[12] = p->has_last_vc ? p->last_vc : NAN;
    scalars[13] = p->has_vc_slope ? p->vc_slope : NAN;
    scalars[14] = p->has_last_cap ? p->last_cap : NAN;
    return rc;
}

/* the last plan's arrays: s, v, t, qU (n_qU = course n), mode (as doubles), coasts (x, end) */
void shim_plan_arrays(void *hv, double *s, double *v, double *t, double *qU, double *mode,
                      double *coasts)
{
    shim *h = hv;
    const rc_ato_plan *pl = &h->planner.plan;
    for (int k = 0; k < pl->n; k++) {
        s[k] = pl->s[k];
        v[k] = pl->v[k];
        t[k] = pl->t[k];
    }
    for (int k = 0; k + 1 < pl->n; k++)
        mode[k] = pl->mode[k];
    for (int k = 0; k < h->course.n; k++)
        qU[k] = pl->qU[k];
    for (int k = 0; k < pl->n_coasts; k++) {
        coasts[2 * k] = pl->coast_x[k];
        coasts[2 * k + 1] = pl->coast_end[k];
    }
}

double shim_speed_at(void *hv, double x)
{
    return rc_ato_plan_speed_at(&((shim *)hv)->planner.plan, x);
}

/* ---------------------------------------------------------------- the span and the car */

int shim_span_lookups(void *hv, const double *xs, int n, double *out)
{
    /* per x: grade.at, grade.average(x, car.length), v_lim, v_lim_at_node, f_max, r_max,
     * brake_total_max, service_brake (2), hold_speed_regen */
    shim *h = hv;
    for (int k = 0; k < n; k++) {
        double x = xs[k], *o = out + 10 * k;
        o[0] = rc_grade_at(&h->span.grade, x);
        o[1] = rc_grade_average(&h->span.grade, x, h->car.length);
        o[2] = rc_ato_v_lim(&h->span, x);
        o[3] = rc_ato_v_lim_at_node(&h->span, x);
        o[4] = rc_ato_f_max(&h->car, x);
        o[5] = rc_ato_r_max(&h->car, x);
        o[6] = rc_ato_brake_total_max(&h->car, x);
        rc_ato_service_brake(&h->car, x, &o[7], &o[8]);
        o[9] = rc_ato_hold_speed_regen(&h->car, x);
    }
    return 0;
}

int shim_breakpoints(void *hv, double car_length, double *out, int cap)
{
    shim *h = hv;
    return rc_ato_breakpoints(&h->span, car_length, out, cap);
}

int shim_check_span(void *hv)
{
    shim *h = hv;
    return rc_ato_check_span_for_car(&h->span, &h->car, &h->err);
}

double shim_ep_deceleration(void *hv, double a_ep, int stages, double reserve, double grade)
{
    return rc_ato_ep_deceleration(&((shim *)hv)->car, a_ep, stages, reserve, grade);
}

/* ---------------------------------------------------------------- motion */

/* PlanCar methods at v: adhesion, f_max, r_full, b_service, w0, w_slope, hold_regen_speed,
 * accel (3 kinds at grade g) */
void shim_plancar(void *hv, double v, double g, double *out)
{
    const rc_ato_plancar *c = &((shim *)hv)->plan_car;
    out[0] = rc_ato_pc_adhesion(c, v);
    out[1] = rc_ato_pc_f_max(c, v);
    out[2] = rc_ato_pc_r_full(c, v);
    out[3] = rc_ato_pc_b_service(c, v);
    out[4] = rc_ato_pc_w0(c, v);
    out[5] = rc_ato_pc_w_slope(c, v);
    out[6] = rc_ato_pc_hold_regen_speed(c, v);
    for (int k = 0; k < 3; k++)
        out[7 + k] = rc_ato_accel(c, v, g, k);
}

/* free_step (3 kinds: q1, vm), coast_step (q1, p1), hold_forces (F, R, M, ok), step_time */
void shim_steps(void *hv, double q0, double q1, double p0, double h, double g, double k_lam,
                double *out)
{
    const rc_ato_plancar *c = &((shim *)hv)->plan_car;
    for (int k = 0; k < 3; k++)
        out[2 * k] = rc_ato_free_step(c, q0, h, g, k, &out[2 * k + 1]);
    rc_ato_coast_step(c, q0, p0, h, g, k_lam, &out[6], &out[7]);
    out[11] = rc_ato_hold_forces(c, q0, q1, h, g, &out[8], &out[9], &out[10]);
    out[12] = rc_ato_step_time(h, q0, q1);
}

void shim_blend(const double *configured, const double *estimated, const double *stated,
                const double *args, const double *speeds, int n_speeds, double *out)
{
    /* args: ramp, config_mass_std, config_resistance_std, gate, mass_band, gate_prev, gate_step */
    rc_ato_blend_estimates(configured, estimated, stated, args[0], args[1], args[2], args[3],
                           speeds, n_speeds, args[4], args[5], args[6], out);
}

void shim_masses(const double *args, double *out)
{
    /* args: planned, est_mass, identifying, configured, mass_band */
    out[0] = rc_ato_heavier_mass(args[0], args[1], (int)args[2], args[3], args[4]);
    out[1] = rc_ato_braking_mass(args[0], args[3]);
}

void shim_margins(double a0, double a1, double a2, double v_lo, double v_hi, double *out)
{
    rc_ato_resistance_margins(a0, a1, a2, v_lo, v_hi, out);
}

/* a trace made of the given nodes, then cut_at(x) and q_at(x): out (s, q, t, mode, wF, wR of
 * the cut, n), q_at */
double shim_trace_cut(const double *s, const double *q, const double *t, const double *wF,
                      const double *wR, const double *mode, int n, double x, double *out,
                      int *n_out)
{
    rc_ato_trace a, b;
    int cap = n + 2;
    double *buf = calloc((size_t)(10 * cap), sizeof(double));
    int *ib = calloc((size_t)(2 * cap), sizeof(int));
    a.cap = b.cap = cap;
    a.s = buf; a.q = buf + cap; a.t = buf + 2 * cap; a.wF = buf + 3 * cap; a.wR = buf + 4 * cap;
    b.s = buf + 5 * cap; b.q = buf + 6 * cap; b.t = buf + 7 * cap; b.wF = buf + 8 * cap;
    b.wR = buf + 9 * cap;
    a.mode = ib;
    b.mode = ib + cap;
    rc_ato_trace_start(&a, s[0], q[0], t[0]);
    for (int k = 1; k < n; k++)
        rc_ato_trace_add(&a, s[k], q[k], t[k] - t[k - 1], (int)mode[k - 1], wF[k - 1], wR[k - 1]);
    for (int k = 1; k < n; k++)
        a.t[k] = t[k];                /* the caller's times exactly (add sums dt) */
    rc_ato_trace_cut_at(&a, x, &b);
    *n_out = b.n;
    for (int k = 0; k < b.n; k++) {
        out[6 * k] = b.s[k];
        out[6 * k + 1] = b.q[k];
        out[6 * k + 2] = b.t[k];
        out[6 * k + 3] = k + 1 < b.n ? b.mode[k] : 0;
        out[6 * k + 4] = k + 1 < b.n ? b.wF[k] : 0.0;
        out[6 * k + 5] = k + 1 < b.n ? b.wR[k] : 0.0;
    }
    double qa = rc_ato_q_at(&a, x);
    free(buf);
    free(ib);
    return qa;
}

/* ---------------------------------------------------------------- the relay */

void *shim_relay_new(const double *args)
{
    rc_ato_relay *r = malloc(sizeof *r);
    if (r != NULL)
        rc_ato_relay_init(r, args[0], args[1], args[2], (int)args[3], args[4], args[5], args[6],
                          args[7], args[8], args[9]);
    return r;
}

void shim_relay_free(void *r) { free(r); }

/* command at (t, s, v, grade) with the handle's plan_car: out (traction, brake, stage, v_p,
 * a_prog, creep_int) */
int shim_relay_command(void *rv, void *hv, double t, double s, double v, double grade,
                       double *out, char *msg)
{
    rc_ato_relay *r = rv;
    rc_error err;
    int stage;
    int rc = rc_ato_relay_command(r, t, s, v, &((shim *)hv)->plan_car, grade, &out[0], &out[1],
                                  &stage, &out[3], &err);
    out[2] = stage;
    out[4] = r->a_prog;
    out[5] = r->creep_int;
    strcpy(msg, err.msg);
    return rc;
}

double shim_track_force(void *hv, double v, double v_ref, double a_ref, double grade,
                        double gain)
{
    return rc_ato_track_force(&((shim *)hv)->plan_car, v, v_ref, a_ref, grade, gain);
}

/* ReducedCourse(span, car, step=, limit_margin=, v_relay=, a_ep=) on the handle's span and car:
 * its status, msg its error; the course is freed again */
int shim_course_error(void *hv, double step, double margin, double v_relay, double a_ep,
                      char *msg)
{
    shim *h = hv;
    rc_ato_course c;
    rc_error err;
    int rc = rc_ato_course_init(&c, &h->span, &h->car, step, margin, v_relay, a_ep, 10000, &err);
    strcpy(msg, err.msg);
    if (rc == RC_OK)
        rc_ato_course_free(&c);
    return rc;
}
