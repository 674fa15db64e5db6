/* singer_shim.c -- test-only flat functions around models/core/singer.c and the Singer branches
 * of models/core/filter.c (kind 4) for ctypes (tests/model_tests/core/test_core_singer.py). Built with
 * -DSINGER_SHIM_MAIN it is a program instead (the sanitizer run): it reads a configuration and
 * op records from a file of doubles and writes the shim_apply rows to another. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "filter.h"
#include "singer.h"

typedef struct {
    rc_filter f;
    rc_grade_profile grade;
    double gd[1], gg[1], gc[1];   /* a level track (kind 4 never reads it) */
} shim;

#define SHIM_NCONFIG 14           /* FilterConfig: dt, speed_std, position_std,
                                     position_std_rel, gamma, kind, length, singer_tau,
                                     singer_p0, singer_p_plus, singer_p_minus,
                                     singer_w_max_plus, singer_w_max_minus, speed_std_rel */

/* NULL when rc_filter_validate refuses the config (its message in msg[RC_MSG_SIZE]) */
shim *shim_new(const double *c, char *msg)
{
    rc_filter_config cfg;
    rc_error err;
    shim *s;
    cfg.dt = c[0];
    cfg.speed_std = c[1];
    cfg.position_std = c[2];
    cfg.position_std_rel = c[3];
    cfg.gamma = c[4];
    cfg.kind = (int)c[5];
    cfg.length = c[6];
    cfg.singer_tau = c[7];
    cfg.singer_p0 = c[8];
    cfg.singer_p_plus = c[9];
    cfg.singer_p_minus = c[10];
    cfg.singer_w_max_plus = c[11];
    cfg.singer_w_max_minus = c[12];
    cfg.speed_std_rel = c[13];
    if (rc_filter_validate(&cfg, 0, &err) != RC_OK) {
        memcpy(msg, err.msg, RC_MSG_SIZE);
        return NULL;
    }
    s = calloc(1, sizeof *s);
    if (!s)
        return NULL;
    s->gd[0] = s->gg[0] = 0.0;
    rc_grade_cumulate(s->gd, s->gg, 1, s->gc);
    s->grade.distances = s->gd;
    s->grade.grades = s->gg;
    s->grade.cum = s->gc;
    s->grade.n = 1;
    rc_filter_init(&s->f, &cfg, &s->grade, NULL);
    return s;
}

void shim_free(shim *s) { free(s); }

#define SHIM_NSTATE 50
int shim_nstate(void) { return SHIM_NSTATE; }

/* MotionFilter's mirrored attributes and properties (test_core_filter.FIELDS' order), the
 * acceleration, then the Singer filter: x[3], P[9], nis, tau, sigma_w, m_w, clip */
static void shim_state(const shim *s, double *out)
{
    const rc_filter *f = &s->f;
    const rc_singer *g = &f->singer;
    double acc = NAN;
    rc_filter_acceleration(f, &acc);
    double v[SHIM_NSTATE] = {
        f->kind, f->r0, f->r1,
        f->xb0, f->xb1, f->m00, f->m01, f->m11,
        f->xh0, f->xh1, f->p00, f->p01, f->p11,
        f->vzad_hat, f->vzad_bar,
        (double)f->rejected, (double)f->speed_run, (double)f->position_run, (double)f->reacquired,
        f->speed_fit, f->use_speed, f->use_position, f->reacquire,
        rc_filter_speed(f), rc_filter_position(f), rc_filter_speed_std(f),
        rc_filter_position_std(f), rc_filter_predicted_speed(f),
        rc_filter_predicted_position(f), rc_filter_predicted_speed_std(f),
        rc_filter_predicted_position_std(f), acc,
        g->x[0], g->x[1], g->x[2], g->P[0], g->P[1], g->P[2], g->P[3], g->P[4], g->P[5], g->P[6],
        g->P[7], g->P[8], g->nis, g->tau, g->sigma_w, g->m_w, g->clip, 0.0};
    memcpy(out, v, sizeof v);
}

/* One call: op[0] the code (test_core_filter's RESTART .. PREDICT), op[1..8] the arguments;
 * out[0] the status, out[1], out[2] gate's answers, out[3..] shim_state after the call */
enum { OP_RESTART, OP_START, OP_GATE, OP_HOLD, OP_UPDATE, OP_UPDATE_SPEED, OP_PREDICT };
void shim_apply(shim *s, const double *op, double *out)
{
    int status = RC_OK, use[2] = {0, 0};
    rc_filter *f = &s->f;
    switch ((int)op[0]) {
    case OP_RESTART: rc_filter_restart(f); break;
    case OP_START: status = rc_filter_start_from_measurement(f, op[1], op[2]); break;
    case OP_GATE: status = rc_filter_gate(f, op[1], op[2], use, use + 1); break;
    case OP_HOLD: rc_filter_hold(f); break;
    case OP_UPDATE: status = rc_filter_update(f, op[1], op[2]); break;
    case OP_UPDATE_SPEED: status = rc_filter_update_speed(f, op[1], op[2]); break;
    case OP_PREDICT: status = rc_filter_predict(f, op[1], op[2], op + 3, op[7], op[8]); break;
    default: status = -1;
    }
    out[0] = status;
    out[1] = use[0];
    out[2] = use[1];
    shim_state(s, out + 3);
}

/* ------------------------------------------------------------ the Singer filter alone */

rc_singer *singer_new(double tau, double sigma_w, double m_w, const double *x0, const double *P0,
                      int clip)
{
    rc_singer *g = calloc(1, sizeof *g);
    if (g)
        rc_singer_init(g, tau, sigma_w, m_w, x0, P0, clip);
    return g;
}

void singer_free(rc_singer *g) { free(g); }

/* op[0]: 0 predict(op[1]); 1 update_speed(op[1], op[2]); 2 update_distance(op[1], op[2]);
 * 3 update_speed_distance(op[1..4]); 4 update(m = op[1], z = op[2..3], H = op[4..9],
 * R = op[10..13]). out: status, x[3], P[9], nis */
void singer_apply(rc_singer *g, const double *op, double *out)
{
    int status;
    switch ((int)op[0]) {
    case 0: status = rc_singer_predict(g, op[1]); break;
    case 1: status = rc_singer_update_speed(g, op[1], op[2]); break;
    case 2: status = rc_singer_update_distance(g, op[1], op[2]); break;
    case 3: status = rc_singer_update_speed_distance(g, op[1], op[2], op[3], op[4]); break;
    case 4: status = rc_singer_update(g, (int)op[1], op + 2, op + 4, op + 10); break;
    default: status = -1;
    }
    out[0] = status;
    memcpy(out + 1, g->x, sizeof g->x);
    memcpy(out + 4, g->P, sizeof g->P);
    out[13] = g->nis;
}

int singer_f(int name, double x, double *out) { return rc_singer_f(name, x, out); }

void singer_coefficients(int name, double *out)
{
    memcpy(out, rc_singer_coefficients(name), RC_SINGER_SERIES_TERMS * sizeof(double));
}

/* out: Phi[9], Q[9], u[3] */
int singer_discretisation(double alpha, double dt, double sigma_w, double m_w, double *out)
{
    return rc_singer_discretisation(alpha, dt, sigma_w, m_w, out, out + 9, out + 18);
}

/* v: tau, p0, p_plus, p_minus, w_max_plus, w_max_minus; out: m_w, sigma_w */
int singer_params(const double *v, double *out, char *msg)
{
    rc_error err;
    int st = rc_singer_params(v[0], v[1], v[2], v[3], v[4], v[5], out, out + 1, &err);
    memcpy(msg, err.msg, RC_MSG_SIZE);
    return st;
}

#ifdef SINGER_SHIM_MAIN
/* argv[1]: SHIM_NCONFIG doubles, then 9 doubles per op; argv[2]: (3 + SHIM_NSTATE) per op */
int main(int argc, char **argv)
{
    double cfg[SHIM_NCONFIG], op[9], out[3 + SHIM_NSTATE];
    char msg[RC_MSG_SIZE];
    FILE *in, *res;
    shim *s;
    if (argc != 3 || !(in = fopen(argv[1], "rb")))
        return 2;
    if (fread(cfg, sizeof(double), SHIM_NCONFIG, in) != SHIM_NCONFIG || !(s = shim_new(cfg, msg))) {
        fclose(in);
        return 3;
    }
    if (!(res = fopen(argv[2], "wb"))) {
        fclose(in);
        shim_free(s);
        return 2;
    }
    while (fread(op, sizeof(double), 9, in) == 9) {
        shim_apply(s, op, out);
        fwrite(out, sizeof(double), 3 + SHIM_NSTATE, res);
    }
    fclose(in);
    fclose(res);
    shim_free(s);
    return 0;
}
#endif
