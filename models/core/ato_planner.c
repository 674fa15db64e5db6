/* ato_planner.c -- the ATO's fast re-planner: the C twin of models/ato/planner.py, function by
 * function and expression by expression (Python's operand order; min/max as Python's). */
#include "rc_fp_contract.h"
#include "ato_planner.h"
#include "ato_stopping.h"

#include <stdlib.h>
#include <string.h>

#define EPS_Q 1e-12          /* planner._EPS_Q: relative tolerance on q = V^2 comparisons */

static void set_ok(rc_error *err)
{
    if (err)
        err->msg[0] = '\0';
}

/* ------------------------------------------------------------------ the course */

static int cmp_double(const void *a, const void *b)
{
    double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

rc_status rc_ato_course_init(rc_ato_course *c, const rc_ato_span *span, const rc_ato_car *car,
                             double step, double limit_margin, double v_relay, double a_ep,
                             int max_nodes, rc_error *err)
{
    char a[40], b[40];
    memset(c, 0, sizeof *c);
    const char *names[2] = {"step", "a_ep"};
    double vals[2] = {step, a_ep};
    for (int k = 0; k < 2; k++) {
        if (!(isfinite(vals[k]) && vals[k] > 0.0)) {
            if (err) {
                rc_repr(vals[k], a, sizeof a);
                rc_refuse(err, RC_BAD_CONFIG, "%s must be > 0 and finite, got %s", names[k], a);
            }
            return RC_BAD_CONFIG;
        }
    }
    if (!(isfinite(limit_margin) && limit_margin >= 0.0)) {
        if (err) {
            rc_repr(limit_margin, a, sizeof a);
            rc_refuse(err, RC_BAD_CONFIG, "limit_margin must be >= 0 and finite [m/s], got %s", a);
        }
        return RC_BAD_CONFIG;
    }
    if (!(isfinite(v_relay) && v_relay > 0.0)) {
        if (err) {
            rc_repr(v_relay, a, sizeof a);
            rc_refuse(err, RC_BAD_CONFIG, "v_relay must be > 0 and finite [m/s], got %s", a);
        }
        return RC_BAD_CONFIG;
    }
    for (int k = 0; k < span->n_limits; k++) {
        double v = span->limit_speeds[k];
        if (v - limit_margin <= v_relay) {
            if (err) {
                char m[40];
                rc_repr(v, a, sizeof a);
                rc_repr(span->limit_distances[k], b, sizeof b);
                rc_repr(limit_margin, m, sizeof m);
                rc_refuse(err, RC_BAD_CONFIG,
                         "span.limit_speeds[%d] = %s m/s (from s = %s m) "
                         "cannot be met with the speed margin %s m/s: the planned limit %.3f m/s "
                         "is not above the relay speed %.3f m/s", k, a, b, m, v - limit_margin,
                         v_relay);
            }
            return RC_BAD_CONFIG;
        }
    }
    c->stop = span->stop;
    c->h = step;
    c->margin = limit_margin;
    c->v_relay = v_relay;
    c->a_ep = a_ep;
    c->n_limits = span->n_limits;
    c->d_relay = v_relay * v_relay / (2.0 * a_ep);
    if (c->d_relay >= span->stop) {
        if (err) {
            rc_repr(span->stop, a, sizeof a);
            rc_refuse(err, RC_BAD_CONFIG,
                     "span.stop = %s m is shorter than the final "
                     "electro-pneumatic braking curve (%.1f m)", a, c->d_relay);
        }
        return RC_BAD_CONFIG;
    }
    /* the grid's size is refused before anything is allocated for it (the nodes every step
     * m), then counted with the breakpoints (C only: the controller refuses more than
     * MAX_GRID_NODES first, with its own message) */
    double cells = ceil(span->stop / step);
    if (!(cells + 2.0 <= (double)max_nodes)) {
        rc_refuse(err, RC_BAD_CONFIG,
                 "the re-planner's grid would have at least %.4g nodes (span.stop = %g m, step "
            "%g m): at most %d", cells + 2.0, span->stop, step, max_nodes);
        return RC_BAD_CONFIG;
    }
    int bound = rc_ato_breakpoints_bound(span);
    int n = cells > 1.0 ? (int)cells : 1;
    int total = n + 1 + bound + 1;
    double *block = malloc(sizeof(double) * (size_t)total * 3);
    if (block == NULL) {
        rc_refuse(err, RC_BAD_CONFIG, "out of memory for the re-planner's grid");
        return RC_BAD_CONFIG;
    }
    double *s = block;
    int m = 0;
    for (int k = 0; k <= n; k++)
        s[m++] = span->stop * k / n;
    int breaks = rc_ato_breakpoints(span, car->length, s + m, bound);
    m += breaks;
    s[m++] = span->stop - c->d_relay;
    if (m > max_nodes) {
        free(block);
        rc_refuse(err, RC_BAD_CONFIG,
                 "the re-planner's grid would have %d nodes (span.stop = %g m, step %g m, %d "
            "grade and limit changes): at most %d", m, span->stop, step, breaks, max_nodes);
        return RC_BAD_CONFIG;
    }
    qsort(s, (size_t)m, sizeof *s, cmp_double);
    int kept = 1;
    for (int k = 1; k < m; k++)
        if (s[k] - s[kept - 1] > 1e-6)
            s[kept++] = s[k];
    s[kept - 1] = span->stop;
    c->s = s;
    c->n = kept;
    c->g = block + total;
    c->qlim = block + 2 * total;
    double L = car->length;
    for (int k = 0; k + 1 < kept; k++)
        c->g[k] = rc_grade_average(&span->grade, 0.5 * (s[k] + s[k + 1]), L);
    for (int k = 0; k < kept; k++) {
        double u = rc_ato_v_lim_at_node(span, s[k]) - limit_margin;
        c->qlim[k] = u * u;
    }
    double x_relay = span->stop - c->d_relay;
    int best = 0;
    for (int k = 1; k < kept; k++)
        if (fabs(s[k] - x_relay) < fabs(s[best] - x_relay))
            best = k;
    c->i_relay = best;
    set_ok(err);
    return RC_OK;
}

void rc_ato_course_free(rc_ato_course *c)
{
    free(c->s);
    c->s = c->g = c->qlim = NULL;
}

int rc_ato_course_cell(const rc_ato_course *c, double x)
{
    int i = rc_ato_bisect_right(c->s, c->n, x) - 1;
    return i < 0 ? 0 : (i > c->n - 2 ? c->n - 2 : i);
}

/* ------------------------------------------------------------------ the planner's buffers */

typedef struct {
    char *base;
    size_t used, size;
} arena;

static void *carve(arena *a, size_t bytes)
{
    size_t aligned = (bytes + 15u) & ~(size_t)15u;
    void *out = a->base ? a->base + a->used : NULL;
    a->used += aligned;
    return out;
}

/* lays the buffers out in a (size only when a->base is NULL) */
static void layout(rc_ato_planner *p, arena *a)
{
    int n = p->c->n;
    int cap = n + 2 * (p->c->n_limits + 2) + 4;
    int ccap = p->c->n_limits + 2;
    size_t dn = sizeof(double) * (size_t)n, in = sizeof(int) * (size_t)n;
    size_t dc = sizeof(double) * (size_t)cap, ic = sizeof(int) * (size_t)cap;
    size_t dcc = sizeof(double) * (size_t)ccap;
    p->hint_has = carve(a, in);
    p->hint_has_slope = carve(a, in);
    p->hint_x = carve(a, dn);
    p->hint_slope = carve(a, dn);
    p->qU = carve(a, dn);
    p->fall0 = carve(a, in);
    p->fall1 = carve(a, in);
    for (int k = 0; k < 3; k++) {
        rc_ato_trace *tr = &p->bufs[k];
        tr->cap = cap;
        tr->coast_cap = ccap;
        tr->s = carve(a, dc);
        tr->q = carve(a, dc);
        tr->t = carve(a, dc);
        tr->wF = carve(a, dc);
        tr->wR = carve(a, dc);
        tr->mode = carve(a, ic);
        tr->coast_x = carve(a, dcc);
        tr->coast_end = carve(a, dcc);
    }
    p->coast_cap = ccap;
    p->coast_x = carve(a, dcc);
    p->coast_end = carve(a, dcc);
    p->plan.coast_x = carve(a, dcc);
    p->plan.coast_end = carve(a, dcc);
    p->plan.s = carve(a, dc);
    p->plan.v = carve(a, dc);
    p->plan.t = carve(a, dc);
    p->plan.mode = carve(a, ic);
}

rc_status rc_ato_planner_init(rc_ato_planner *p, const rc_ato_course *course, double tol,
                              double v_min, rc_error *err)
{
    memset(p, 0, sizeof *p);
    p->c = course;
    p->tol = tol;
    p->v_min = v_min;
    arena a = {NULL, 0, 0};
    layout(p, &a);
    p->block = calloc(1, a.used);
    if (p->block == NULL) {
        if (err)
            rc_refuse(err, RC_BAD_CONFIG, "out of memory for the re-planner's buffers");
        return RC_BAD_CONFIG;
    }
    a.base = p->block;
    a.size = a.used;
    a.used = 0;
    layout(p, &a);
    p->work = &p->bufs[0];
    p->spare = &p->bufs[1];
    p->best = &p->bufs[2];
    set_ok(err);
    return RC_OK;
}

void rc_ato_planner_free(rc_ato_planner *p)
{
    free(p->block);
    p->block = NULL;
}

static void add(rc_ato_planner *p, rc_ato_trace *tr, double s, double q, double dt, int mode,
                double wF, double wR)
{
    if (rc_ato_trace_add(tr, s, q, dt, mode, wF, wR) != RC_OK)
        p->overflow = 1;
}

static void swap(rc_ato_trace **a, rc_ato_trace **b)
{
    rc_ato_trace *t = *a;
    *a = *b;
    *b = t;
}

/* ------------------------------------------------------------------ the envelope */

rc_status rc_ato_envelope(const rc_ato_planner *p, const rc_ato_plancar *car, double *qU,
                          rc_error *err)
{
    const rc_ato_course *c = p->c;
    const double *s = c->s, *g = c->g, *qlim = c->qlim;
    for (int i = 0; i < c->n; i++)
        qU[i] = 0.0;
    double a2 = 2.0 * c->a_ep;
    for (int i = c->n - 2; i >= 0; i--) {
        double qb, vm;
        if (i >= c->i_relay)
            qb = a2 * (c->stop - s[i]);
        else
            qb = rc_ato_free_step(car, qU[i + 1], s[i] - s[i + 1], g[i], RC_ATO_K_BRAKE, &vm);
        qU[i] = qb > 0.0 ? rc_min(qb, qlim[i]) : 0.0;
        if (qU[i] <= 0.0 && i > 0) {
            if (err) {
                char gr[40], st[40];
                rc_repr(g[i], gr, sizeof gr);
                rc_repr(c->stop, st, sizeof st);
                rc_refuse(err, RC_BAD_CONFIG,
                         "the span cannot be run: at s = %.1f m (grade %s "
                         "permille) the service brake (%g of the electric brake) cannot keep a "
                         "%.1f t car within the speed limit / stop it at span.stop = %s m", s[i],
                         gr, car->share, car->brake_mass, st);
            }
            return RC_BAD_CONFIG;
        }
    }
    set_ok(err);
    return RC_OK;
}

/* _stretches: for each cell, the falling stretch of U it lies on (fall0, fall1) or -1 */
static void stretches(rc_ato_planner *p, const double *qU)
{
    int n = p->c->n;
    for (int k = 0; k < n - 1; k++)
        p->fall0[k] = p->fall1[k] = -1;
    int i = 0;
    while (i < n - 1) {
        if (qU[i + 1] < qU[i] * (1.0 - EPS_Q)) {
            int j = i;
            while (j < n - 1 && qU[j + 1] < qU[j] * (1.0 - EPS_Q))
                j++;
            for (int k = i; k < j; k++) {
                p->fall0[k] = i;
                p->fall1[k] = j;
            }
            i = j;
        } else {
            i++;
        }
    }
}

/* ------------------------------------------------------------------ runs */

static double u_at(const rc_ato_planner *p, const double *qU, double x, int i)
{
    const double *s = p->c->s;
    if (x <= s[i])
        return qU[i];
    if (x >= s[i + 1])
        return qU[i + 1];
    return qU[i] + (x - s[i]) / (s[i + 1] - s[i]) * (qU[i + 1] - qU[i]);
}

typedef struct {
    double q1, dt, wF, wR;
    int mode, on_u;
} step_out;

/* _step: one step [a, b] in cell i under kind, below the ceiling ca..cb, above floor */
static void step(const rc_ato_planner *p, const rc_ato_plancar *car, double q0, double a,
                 double b, int i, int kind, double floor, double ca, double cb, const double *qU,
                 step_out *o)
{
    double g = p->c->g[i];
    double h = b - a;
    double vm;
    double q1 = rc_ato_free_step(car, q0, h, g, kind, &vm);
    int over = q1 > cb;
    double w, qx, bound;
    if (over) {
        double g0 = q0 - ca, g1 = q1 - cb;
        w = g0 < 0.0 ? g0 / (g0 - g1) : 0.0;
        qx = w > 0.0 ? ca + w * (cb - ca) : q0;
        bound = cb;
    } else if (q1 < floor) {
        double g0 = q0 - floor, g1 = q1 - floor;
        w = g0 > 0.0 ? g0 / (g0 - g1) : 0.0;
        qx = w > 0.0 ? floor : q0;
        bound = floor;
    } else {
        o->q1 = q1;
        o->dt = rc_ato_step_time(h, q0, q1);
        o->mode = kind == RC_ATO_K_TG ? RC_MODE_TG : RC_MODE_VB;
        o->wF = kind == RC_ATO_K_TG ? h * rc_ato_pc_f_max(car, vm) : 0.0;
        o->wR = 0.0;
        o->on_u = 0;
        return;
    }
    double sx = a + w * h;
    double rest = b - sx;
    double wF1 = kind == RC_ATO_K_TG ? w * h * rc_ato_pc_f_max(car, vm) : 0.0;
    double dt1 = w > 0.0 ? rc_ato_step_time(sx - a, q0, qx) : 0.0;
    double F, R, M;
    int ok;
    if (rest > 1e-9) {
        ok = rc_ato_hold_forces(car, qx, bound, rest, g, &F, &R, &M);
    } else {
        F = R = M = 0.0;
        ok = 1;
    }
    if (!(ok || over)) {          /* the floor needs more than f_max: full traction */
        q1 = rc_ato_free_step(car, q0, h, g, RC_ATO_K_TG, &vm);
        o->q1 = q1;
        o->dt = rc_ato_step_time(h, q0, q1);
        o->mode = RC_MODE_TG;
        o->wF = h * rc_ato_pc_f_max(car, vm);
        o->wR = 0.0;
        o->on_u = 0;
        return;
    }
    int decel = bound < qx * (1.0 - 1e-9);
    int mode;
    if (F > 0.0)
        mode = F >= rc_ato_pc_f_max(car, sqrt(bound)) * (1 - 1e-9) ? RC_MODE_TG : RC_MODE_C;
    else if (M > 0.0)
        mode = decel ? RC_MODE_TM : RC_MODE_ST;
    else
        mode = decel ? RC_MODE_RK : RC_MODE_SR;
    o->on_u = over && decel && p->fall0[i] >= 0 && cb >= qU[i + 1] * (1.0 - 1e-12);
    o->q1 = bound;
    o->dt = dt1 + rc_ato_step_time(rest, qx, bound);
    o->mode = mode;
    o->wF = wF1 + F * rest;
    o->wR = R * rest;
}

enum { CRUISE_DONE = 0, CRUISE_EVENT = 1, CRUISE_STALL = 2 };

/* _cruise: extends tr to the stop mark, or until it runs onto a falling braking curve of U
 * ending beyond handled (*k_b, *j0, *j1); a stall at *stall_at */
static int cruise(rc_ato_planner *p, const rc_ato_plancar *car, rc_ato_trace *tr, double qc,
                  double qr, const double *qU, double handled, int *k_b, int *j0, int *j1,
                  double *stall_at)
{
    const rc_ato_course *c = p->c;
    const double *s = c->s;
    double a = tr->s[tr->n - 1], q0 = tr->q[tr->n - 1];
    int i = rc_ato_course_cell(c, a);
    if (a >= s[i + 1] - 1e-9)
        i++;
    while (a < c->stop - 1e-9 && i < c->n - 1) {
        double b = s[i + 1];
        double ua = u_at(p, qU, a, i), ub = qU[i + 1];
        int kind;
        double floor, ca, cb;
        if (q0 < qc * (1.0 - EPS_Q)) {
            kind = RC_ATO_K_TG;
            floor = -INFINITY;
            cb = rc_min(ub, qc);
            ca = rc_min(ua, qc);
        } else {
            kind = RC_ATO_K_COAST;
            floor = qc;
            cb = rc_min(ub, qr);
            ca = rc_min(ua, qr);
        }
        step_out o;
        step(p, car, q0, a, b, i, kind, floor, ca, cb, qU, &o);
        if (o.on_u && p->fall0[i] >= 0 && s[p->fall1[i]] > handled + 1e-9) {
            *k_b = tr->n - 1;
            *j0 = p->fall0[i];
            *j1 = p->fall1[i];
            return CRUISE_EVENT;
        }
        if (o.q1 <= 0.0 && b < c->stop - 1e-9) {
            *stall_at = b;
            return CRUISE_STALL;
        }
        add(p, tr, b, o.q1, o.dt, o.mode, o.wF, o.wR);
        a = b;
        q0 = o.q1;
        i++;
    }
    return CRUISE_DONE;
}

/* _coast: from x on tr with p = 1 until the curve (j0, j1) is met; the residual p - eta eta_f
 * there (-inf on a stall), *met; with keep, the trace from x on in out */
static double coast(rc_ato_planner *p, const rc_ato_plancar *car, const rc_ato_trace *tr,
                    double x, int j0, int j1, double k_lam, const double *qU, int keep,
                    rc_ato_trace *out, int *met)
{
    const rc_ato_course *c = p->c;
    const double *s = c->s;
    double pe = car->eta * car->eta_f;
    if (keep)
        rc_ato_trace_cut_at(tr, x, out);
    double a = x, q0 = rc_ato_q_at(tr, x);
    double s_start = s[j0], s_end = s[j1];
    int i = rc_ato_course_cell(c, a);
    if (a >= s[i + 1] - 1e-9)
        i++;
    double pc = 1.0;
    *met = 0;
    if (q0 <= 0.0)
        return -INFINITY;
    while (a < s_end - 1e-9) {
        double b = s[i + 1];
        double g = c->g[i];
        double h = b - a;
        double q1, p1;
        rc_ato_coast_step(car, q0, pc, h, g, k_lam, &q1, &p1);
        double ub = qU[i + 1];
        if (q1 > ub) {
            double ua = u_at(p, qU, a, i);
            double g0 = q0 - ua, g1 = q1 - ub;
            double w = g0 < 0.0 ? g0 / (g0 - g1) : 0.0;
            if (b > s_start + 1e-9 && p->fall0[i] >= 0) {
                if (keep) {
                    double sx = a + w * h;
                    double qx = w > 0 ? ua + w * (ub - ua) : q0;
                    if (w > 0.0)
                        add(p, out, sx, qx, rc_ato_step_time(sx - a, q0, qx), RC_MODE_VB, 0.0, 0.0);
                }
                *met = 1;
                return pc + w * (p1 - pc) - pe;
            }
            /* a limit or another curve on the way: follow U (regen / mech), coast on */
            double sx = a + w * h;
            double qx = w > 0 ? ua + w * (ub - ua) : q0;
            double F, R, M;
            if (b - sx > 1e-9)
                rc_ato_hold_forces(car, qx, ub, b - sx, g, &F, &R, &M);
            else
                F = R = M = 0.0;
            if (keep) {
                int mode = M > 0 ? RC_MODE_TM : (ub < qx ? RC_MODE_RK : RC_MODE_SR);
                double dt = (w > 0 ? rc_ato_step_time(sx - a, q0, qx) : 0.0)
                            + rc_ato_step_time(b - sx, qx, ub);
                add(p, out, b, ub, dt, mode, F * (b - sx), R * (b - sx));
            }
            q1 = ub;
        } else {
            if (q1 <= 0.0)
                return -INFINITY;
            if (keep)
                add(p, out, b, q1, rc_ato_step_time(h, q0, q1), RC_MODE_VB, 0.0, 0.0);
        }
        a = b;
        q0 = q1;
        pc = p1;
        i++;
    }
    return pc - pe;
}

/* ------------------------------------------------------------------ _solve */

typedef double (*solve_fn)(void *ctx, double x);

typedef struct {
    int has;
    double x, g;
} solve_pt;

typedef struct {
    double sg;
    int has_best, last_side;
    double best_x, best_y;
    solve_pt below, above;
} solve_state;

static void take(solve_state *st, double x, double y)
{
    double g = st->sg * y;
    if (!st->has_best || fabs(y) < fabs(st->best_y)) {
        st->has_best = 1;
        st->best_x = x;
        st->best_y = y;
    }
    if (g < 0.0) {
        if (!st->below.has || x > st->below.x) {
            st->below.has = 1;
            st->below.x = x;
            st->below.g = g;
        }
        if (st->last_side == -1 && st->above.has)        /* Illinois */
            st->above.g = 0.5 * st->above.g;
        st->last_side = -1;
    } else {
        if (!st->above.has || x < st->above.x) {
            st->above.has = 1;
            st->above.x = x;
            st->above.g = g;
        }
        if (st->last_side == 1 && st->below.has && isfinite(st->below.g))
            st->below.g = 0.5 * st->below.g;
        st->last_side = 1;
    }
}

/* _solve(f, x0, dx, slope, lo, hi, xtol, ftol, rising, upper, max_flat); *has_slope / *slope
 * in: the last solve's slope, out: the last secant slope */
static void solve(solve_fn f, void *ctx, double x0, double dx, int *has_slope, double *slope_io,
                  double lo, double hi, double xtol, double ftol, int rising, int has_upper,
                  double ux, double uy, int max_flat, solve_state *st)
{
    int hs = *has_slope;
    double slope = *slope_io;
    memset(st, 0, sizeof *st);
    st->sg = rising ? 1.0 : -1.0;
    if (has_upper) {
        double g = st->sg * uy;
        solve_pt pt = {1, ux, g};
        if (g < 0.0)
            st->below = pt;
        else
            st->above = pt;
    }
    double x = x0, y = f(ctx, x0);
    take(st, x, y);
    double stp = fabs(dx);
    int flat = 0;
    for (int it = 0; it < 60; it++) {
        if (fabs(y) <= ftol)
            break;
        if (st->below.has && st->above.has) {
            double xa = st->below.x, ga = st->below.g, xb = st->above.x, gb = st->above.g;
            if (xb - xa <= xtol)
                break;
            double nx;
            if (isfinite(ga) && ga != gb) {
                nx = xa + (xb - xa) * (-ga) / (gb - ga);
                nx = rc_min(rc_max(nx, xa + 0.02 * (xb - xa)), xb - 0.02 * (xb - xa));
            } else {
                nx = 0.5 * (xa + xb);
            }
            double ny = f(ctx, nx);
            if (isfinite(y) && isfinite(ny) && nx != x && ny != y) {
                slope = (ny - y) / (nx - x);
                hs = 1;
            }
            x = nx;
            y = ny;
            take(st, x, y);
            continue;
        }
        int up = st->sg * y < 0.0;
        double d;
        if (hs && isfinite(y) && st->sg * slope > 0.0) {
            d = rc_min(rc_max(fabs(y / slope), 0.05 * stp), 8.0 * stp);
        } else {
            d = stp;
            stp *= 2.0;
        }
        double nx = rc_min(rc_max(x + (up ? d : -d), lo), hi);
        if (nx == x)
            break;
        double ny = f(ctx, nx);
        if (ny == y) {
            flat += 1;
            hs = 0;
            if (flat >= max_flat)
                break;
        } else if (isfinite(y) && isfinite(ny)) {
            slope = (ny - y) / (nx - x);
            hs = 1;
        }
        x = nx;
        y = ny;
        take(st, x, y);
    }
    *has_slope = hs;
    *slope_io = slope;
}

/* ------------------------------------------------------------------ coast points and runs */

typedef struct {
    rc_ato_planner *p;
    const rc_ato_trace *tr;
    int j0, j1, final;
    double k_lam;
    const double *qU;
} coast_ctx;

static double coast_residual(void *ctx, double x)
{
    coast_ctx *cc = ctx;
    int met;
    cc->p->coast_runs += 1;
    double res = coast(cc->p, cc->p->car, cc->tr, x, cc->j0, cc->j1, cc->k_lam, cc->qU, 0, NULL,
                       &met);
    return (met || cc->final) ? res : -INFINITY;
}

/* _coast_point: the coast point in [s(k_lo), s(k_b)] for the curve (j0, j1) */
static double coast_point(rc_ato_planner *p, const rc_ato_plancar *car, const rc_ato_trace *tr,
                          int k_lo, int k_b, int j0, int j1, int final, double k_lam,
                          const double *qU)
{
    double lo_bound = tr->s[k_lo], hi = tr->s[k_b];
    if (hi - lo_bound <= 1.0)
        return lo_bound;
    coast_ctx cc = {p, tr, j0, j1, final, k_lam, qU};
    int key = j1;
    int hs = p->hint_has[key] ? p->hint_has_slope[key] : 0;
    double slope = hs ? p->hint_slope[key] : 0.0;
    double x0;
    if (p->hint_has[key] && lo_bound < p->hint_x[key] && p->hint_x[key] < hi)
        x0 = p->hint_x[key];
    else
        x0 = rc_max(lo_bound, hi - 100.0);
    solve_state st;
    solve(coast_residual, &cc, x0, 20.0, &hs, &slope, lo_bound, hi, 1.0, 1e-4, 1, 1, hi,
          1.0 - car->eta * car->eta_f, 2, &st);
    double x;
    if (fabs(st.best_y) <= 1e-4) {
        x = st.best_x;
    } else if (!st.below.has) {
        return lo_bound;                 /* p stays above eta eta_f: coast from the start */
    } else {
        double xa = st.below.x, ga = st.below.g, xb = st.above.x, gb = st.above.g;
        x = isfinite(ga) && gb != ga ? xa + (xb - xa) * (-ga) / (gb - ga) : xb;
    }
    p->hint_has[key] = 1;
    p->hint_x[key] = x;
    p->hint_has_slope[key] = hs;
    p->hint_slope[key] = slope;
    return x;
}

/* _run: the whole policy for V_c from (s0, q0, t0) into p->work; 1 on a stall */
static int run(rc_ato_planner *p, const rc_ato_plancar *car, double v_c, const double *qU)
{
    const rc_ato_course *c = p->c;
    double qc = v_c * v_c;
    double vr = rc_ato_pc_hold_regen_speed(car, v_c);
    double qr = isfinite(vr) ? vr * vr : INFINITY;
    double k_lam = qc * rc_ato_pc_w_slope(car, v_c);
    rc_ato_trace *tr = p->work, *other = p->spare;
    rc_ato_trace_start(tr, p->s0, p->q0, p->t0);
    double handled = p->s0 - 1.0;
    int k_lo = 0, n_coasts = 0, stalled = 0;
    for (int it = 0; it < c->n_limits + 2; it++) {
        int k_b, j0, j1;
        double stall_at;
        int ev = cruise(p, car, tr, qc, qr, qU, handled, &k_b, &j0, &j1, &stall_at);
        if (ev == CRUISE_STALL) {
            stalled = 1;
            break;
        }
        if (ev == CRUISE_DONE)
            break;
        double end = c->s[j1];
        int final = j1 == c->n - 1;
        double x = coast_point(p, car, tr, k_lo, k_b, j0, j1, final, k_lam, qU);
        int met;
        coast(p, car, tr, x, j0, j1, k_lam, qU, 1, other, &met);
        if (n_coasts < p->coast_cap) {
            p->coast_x[n_coasts] = x;
            p->coast_end[n_coasts] = end;
            n_coasts++;
        } else {
            p->overflow = 1;
        }
        swap(&tr, &other);
        handled = end;
        k_lo = tr->n - 1;
    }
    p->work = tr;
    p->spare = other;
    tr->n_coasts = n_coasts;
    for (int k = 0; k < n_coasts; k++) {
        tr->coast_x[k] = p->coast_x[k];
        tr->coast_end[k] = p->coast_end[k];
    }
    tr->hold_speed = v_c;
    tr->regen_speed = vr;
    return stalled;
}

/* _capped_run into p->work; 1 on a stall (*stall_at) */
static int capped_run(rc_ato_planner *p, const rc_ato_plancar *car, double v_cap,
                      const double *qU, double *stall_at)
{
    double qc = v_cap * v_cap;
    double vr = rc_ato_pc_hold_regen_speed(car, v_cap);
    double qr = isfinite(vr) ? vr * vr : INFINITY;
    rc_ato_trace *tr = p->work;
    rc_ato_trace_start(tr, p->s0, p->q0, p->t0);
    int k_b, j0, j1;
    int ev = cruise(p, car, tr, qc, qr, qU, INFINITY, &k_b, &j0, &j1, stall_at);
    tr->n_coasts = 0;
    tr->hold_speed = v_cap;
    tr->regen_speed = vr;
    return ev == CRUISE_STALL;
}

/* ------------------------------------------------------------------ the plan */

static rc_ato_trial *find_trial(rc_ato_planner *p, double x)
{
    for (int k = 0; k < p->n_trials; k++)
        if (p->trials[k].x == x)
            return &p->trials[k];
    return NULL;
}

static rc_ato_trial *new_trial(rc_ato_planner *p, double x, double y, int stalled)
{
    if (p->n_trials >= RC_ATO_MAX_TRIALS) {
        p->overflow = 1;
        return NULL;
    }
    rc_ato_trial *t = &p->trials[p->n_trials++];
    t->x = x;
    t->y = y;
    t->stalled = stalled;
    return t;
}

/* plan()'s trial(v_c): memoised; the best run so far (as _solve's best) kept in p->best */
static double energy_trial(void *ctx, double v_c)
{
    rc_ato_planner *p = ctx;
    rc_ato_trial *t = find_trial(p, v_c);
    if (t != NULL)
        return t->stalled ? INFINITY : t->y;
    int stalled = run(p, p->car, v_c, p->qU);
    double y = stalled ? INFINITY : p->work->t[p->work->n - 1] - p->arrival;
    new_trial(p, v_c, y, stalled);
    if (!p->has_best || fabs(y) < fabs(p->best_y)) {
        swap(&p->work, &p->best);
        p->has_best = 1;
        p->best_x = v_c;
        p->best_y = y;
        p->best_stalled = stalled;
    }
    return y;
}

static void plan_of(rc_ato_planner *p, const rc_ato_plancar *car, const rc_ato_trace *tr,
                    const double *qU, int status, int trials, int policy)
{
    rc_ato_plan *pl = &p->plan;
    double wF = 0.0, wR = 0.0;
    for (int k = 0; k < tr->n - 1; k++)
        wF += tr->wF[k];
    for (int k = 0; k < tr->n - 1; k++)
        wR += tr->wR[k];
    double traction = wF / car->eta_f / 3.6e6;
    double regen = car->eta * wR / 3.6e6;
    pl->hold_speed = tr->hold_speed;
    pl->regen_speed = tr->regen_speed;
    pl->n_coasts = tr->n_coasts;
    for (int k = 0; k < tr->n_coasts; k++) {
        pl->coast_x[k] = tr->coast_x[k];
        pl->coast_end[k] = tr->coast_end[k];
    }
    pl->n = tr->n;
    for (int k = 0; k < tr->n; k++) {
        pl->s[k] = tr->s[k];
        pl->v[k] = tr->q[k] > 0 ? sqrt(tr->q[k]) : 0.0;
        pl->t[k] = tr->t[k];
    }
    for (int k = 0; k < tr->n - 1; k++)
        pl->mode[k] = tr->mode[k];
    pl->qU = qU;
    pl->arrival = tr->t[tr->n - 1];
    pl->energy_kwh = traction - regen;
    pl->traction_kwh = traction;
    pl->regen_kwh = regen;
    pl->status = status;
    pl->trials = trials;
    pl->policy = policy;
}

/* _plan_capped's trial(v_cap): memoised; *fresh: the run is in p->work */
static double capped_trial(rc_ato_planner *p, double v_cap, int *fresh)
{
    rc_ato_trial *t = find_trial(p, v_cap);
    *fresh = t == NULL;
    if (t != NULL)
        return t->y;
    double stall_at;
    int stalled = capped_run(p, p->car, v_cap, p->qU, &stall_at);
    double y = stalled ? INFINITY : p->work->t[p->work->n - 1] - p->arrival;
    new_trial(p, v_cap, y, stalled);
    return y;
}

static rc_status capped_result(rc_ato_planner *p, const rc_ato_trace *tr, int stalled,
                               int status, int trials, rc_error *err)
{
    if (stalled) {
        if (err)
            rc_refuse(err, RC_BAD_CONFIG,
                     "no holding speed runs the rest of the span from "
                     "s = %.1f m, V = %.2f m/s: the car would stall", p->s0, sqrt(p->q0));
        return RC_BAD_CONFIG;
    }
    plan_of(p, p->car, tr, p->qU, status, trials, RC_ATO_POLICY_CAPPED);
    return RC_OK;
}

static rc_status plan_capped(rc_ato_planner *p, int trials0, rc_error *err)
{
    const double tol = p->tol;
    double vmax = p->qU[0];
    for (int k = 1; k < p->c->n; k++)
        vmax = rc_max(vmax, p->qU[k]);
    p->n_trials = 0;
    double v_top = rc_max(sqrt(vmax), sqrt(p->q0));
    double v_free = 4.0 * v_top;
    int fresh;
    double e_fast = capped_trial(p, v_free, &fresh);
    int fast_stalled = p->trials[p->n_trials - 1].stalled;
    if (e_fast >= -tol)
        return capped_result(p, p->work, fast_stalled,
                             e_fast <= tol ? RC_ATO_PLAN_OK : RC_ATO_PLAN_LATE,
                             trials0 + p->n_trials, err);
    swap(&p->work, &p->best);          /* best = v_free, its run kept */
    double best = v_free, best_f = e_fast;
    double e_slow = capped_trial(p, p->v_min, &fresh);
    rc_ato_trial *slow = find_trial(p, p->v_min);
    if (e_slow <= tol)
        return capped_result(p, fresh ? p->work : p->best, slow->stalled,
                             e_slow >= -tol ? RC_ATO_PLAN_OK : RC_ATO_PLAN_EARLY,
                             trials0 + p->n_trials, err);
    swap(&p->work, &p->spare);         /* the v_min run kept (a revisit may need it) */
    double lo = p->v_min, f_lo = e_slow, hi = v_free, f_hi = e_fast;
    int side = 0;
    int has_x = p->has_last_cap && lo < p->last_cap && p->last_cap < hi;
    double x = has_x ? p->last_cap : 0.0;
    for (int it = 0; it < 100; it++) {
        if (!has_x) {
            if (isfinite(f_lo)) {
                x = lo + (hi - lo) * f_lo / (f_lo - f_hi);
                x = rc_min(rc_max(x, lo + 0.01 * (hi - lo)), hi - 0.01 * (hi - lo));
            } else {
                x = 0.5 * (lo + hi);
            }
        }
        double f = capped_trial(p, x, &fresh);
        if (fabs(f) < fabs(best_f)) {
            if (fresh)
                swap(&p->work, &p->best);
            else if (x == p->v_min)
                swap(&p->spare, &p->best);
            else
                p->overflow = 1;   /* a revisited point cannot beat the best (never met) */
            best = x;
            best_f = f;
        }
        if (fabs(f) <= tol || hi - lo <= 1e-9)
            break;
        if (f > 0.0) {
            lo = x;
            f_lo = f;
            if (side == 1)
                f_hi *= 0.5;           /* Illinois: the stale end's value halved */
            side = 1;
        } else {
            hi = x;
            f_hi = f;
            if (side == -1 && isfinite(f_lo))
                f_lo *= 0.5;
            side = -1;
        }
        has_x = 0;
    }
    p->has_last_cap = 1;
    p->last_cap = best;
    rc_ato_trial *bt = find_trial(p, best);
    int status = fabs(best_f) <= tol ? RC_ATO_PLAN_OK
                                     : (best_f > 0.0 ? RC_ATO_PLAN_LATE : RC_ATO_PLAN_EARLY);
    return capped_result(p, p->best, bt != NULL && bt->stalled, status, trials0 + p->n_trials,
                         err);
}

static rc_status use_envelope(rc_ato_planner *p, const rc_ato_plancar *car, const double *qU,
                              rc_error *err)
{
    if (qU == NULL) {
        rc_status rc = rc_ato_envelope(p, car, p->qU, err);
        if (rc != RC_OK)
            return rc;
    } else if (qU != p->qU) {
        memcpy(p->qU, qU, sizeof(double) * (size_t)p->c->n);
    }
    stretches(p, p->qU);
    return RC_OK;
}

static rc_status internal(rc_ato_planner *p, rc_status rc, rc_error *err)
{
    if (p->overflow) {
        if (err)
            rc_refuse(err, RC_ATO_INTERNAL, "internal: a re-planner buffer was too small");
        return RC_ATO_INTERNAL;
    }
    return rc;
}

rc_status rc_ato_plan_run(rc_ato_planner *p, const rc_ato_plancar *car, double s0, double v0,
                          double t0, double arrival, const double *qU, rc_error *err)
{
    const rc_ato_course *c = p->c;
    set_ok(err);
    p->overflow = 0;
    rc_status rc = use_envelope(p, car, qU, err);
    if (rc != RC_OK)
        return rc;
    p->car = car;
    p->s0 = rc_min(rc_max(s0, 0.0), c->stop);
    double v0c = rc_max(v0, 0.0);
    p->q0 = v0c * v0c;
    if (isinf(p->q0) && isfinite(v0c)) {
        if (err)
            rc_refuse(err, RC_MATH, "(34, 'Numerical result out of range')");
        return RC_MATH;          /* fpmath.square's OverflowError */
    }
    p->t0 = t0;
    p->arrival = arrival;
    p->n_trials = 0;
    p->has_best = 0;
    double qmax = p->qU[0];
    for (int k = 1; k < c->n; k++)
        qmax = rc_max(qmax, p->qU[k]);
    double v_top = sqrt(qmax);
    double v_hi = 4.0 * rc_max(v_top, v0);
    double guess = p->has_last_vc ? p->last_vc : 0.8 * v_top;
    guess = rc_min(rc_max(guess, p->v_min), v_hi);
    solve_state st;
    solve(energy_trial, p, guess, 0.03 * guess, &p->has_vc_slope, &p->vc_slope, p->v_min, v_hi,
          1e-4, p->tol, 0, 0, 0.0, 0.0, 8, &st);
    if (st.best_x != p->best_x && st.best_x == st.best_x)
        p->overflow = 1;         /* the kept run must be _solve's best (never met) */
    if (fabs(st.best_y) <= p->tol && !p->best_stalled) {
        p->has_last_vc = 1;
        p->last_vc = p->best->hold_speed;
        plan_of(p, car, p->best, p->qU, RC_ATO_PLAN_OK, p->n_trials, RC_ATO_POLICY_ENERGY);
        return internal(p, RC_OK, err);
    }
    return internal(p, plan_capped(p, p->n_trials, err), err);
}

rc_status rc_ato_min_time(rc_ato_planner *p, const rc_ato_plancar *car, const double *qU,
                          double *t_min, rc_error *err)
{
    set_ok(err);
    p->overflow = 0;
    rc_status rc = use_envelope(p, car, qU, err);
    if (rc != RC_OK)
        return rc;
    double qmax = p->qU[0];
    for (int k = 1; k < p->c->n; k++)
        qmax = rc_max(qmax, p->qU[k]);
    double v_free = 4.0 * sqrt(qmax);
    p->s0 = p->q0 = p->t0 = 0.0;
    double stall_at;
    if (capped_run(p, car, v_free, p->qU, &stall_at)) {
        if (err) {
            char at[40], st[40];
            rc_repr(stall_at, at, sizeof at);
            rc_repr(p->c->stop, st, sizeof st);
            rc_refuse(err, RC_BAD_CONFIG,
                     "the span cannot be run: at full traction from rest the %.1f t car comes "
                     "to rest at s = %s m, before span.stop = %s m (a climb beyond its traction)",
                car->mass, at, st);
        }
        return RC_BAD_CONFIG;
    }
    *t_min = p->work->t[p->work->n - 1];
    return internal(p, RC_OK, err);
}

double rc_ato_plan_speed_at(const rc_ato_plan *plan, double x)
{
    int k = rc_ato_bisect_right(plan->s, plan->n, x) - 1;
    if (k < 0)
        return plan->v[0];
    if (k >= plan->n - 1)
        return plan->v[plan->n - 1];
    double w = (x - plan->s[k]) / (plan->s[k + 1] - plan->s[k]);
    return plan->v[k] + w * (plan->v[k + 1] - plan->v[k]);
}

/* ------------------------------------------------------------------ set-up */

rc_status rc_ato_plan_setup(rc_ato_course *course, rc_ato_planner *planner,
                            rc_ato_plancar *configured, const rc_ato_span *span,
                            const rc_ato_car *car, double grid_step, double limit_margin,
                            double time_tol, double a_ep, int ep_stages, double mass_reserve,
                            double brake_share, int max_nodes, rc_error *err)
{
    double g = rc_grade_average(&span->grade, span->stop, car->length);
    double a = rc_ato_ep_deceleration(car, a_ep, ep_stages, mass_reserve, g);
    rc_status rc = rc_ato_course_init(course, span, car, grid_step, limit_margin,
                                      car->regen_fade_speed, a, max_nodes, err);
    if (rc != RC_OK)
        return rc;
    rc = rc_ato_planner_init(planner, course, time_tol, 1.0, err);
    if (rc != RC_OK) {
        rc_ato_course_free(course);
        return rc;
    }
    rc_ato_plancar_init(configured, car, car->mass, car->A0, car->A1, car->A2, brake_share,
                        car->mass);
    return RC_OK;
}

rc_status rc_ato_fastest_run(const rc_ato_span *span, const rc_ato_car *car, double grid_step,
                             double limit_margin, double time_tol, double a_ep, int ep_stages,
                             double mass_reserve, double brake_share, int max_nodes,
                             double *t_min, rc_error *err)
{
    rc_ato_course course;
    rc_ato_planner planner;
    rc_ato_plancar configured;
    rc_status rc = rc_ato_plan_setup(&course, &planner, &configured, span, car, grid_step,
                                     limit_margin, time_tol, a_ep, ep_stages, mass_reserve,
                                     brake_share, max_nodes, err);
    if (rc != RC_OK)
        return rc;
    rc = rc_ato_envelope(&planner, &configured, planner.qU, err);
    if (rc == RC_OK)
        rc = rc_ato_min_time(&planner, &configured, planner.qU, t_min, err);
    rc_ato_planner_free(&planner);
    rc_ato_course_free(&course);
    return rc;
}

/* ------------------------------------------------------------------ FMU states */

size_t rc_ato_planner_block_size(const rc_ato_course *course)
{
    rc_ato_planner sizing;
    memset(&sizing, 0, sizeof sizing);
    sizing.c = course;
    arena a = {NULL, 0, 0};
    layout(&sizing, &a);
    return a.used;
}

void rc_ato_planner_relink(rc_ato_planner *p, const rc_ato_course *course, void *block)
{
    p->c = course;
    p->block = block;
    arena a = {block, 0, rc_ato_planner_block_size(course)};
    layout(p, &a);
}
