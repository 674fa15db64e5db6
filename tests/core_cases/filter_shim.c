/* filter_shim.c -- test-only flat functions around models/core/filter.c for ctypes
 * (tests/model_tests/core/test_core_filter.py): one heap block holds the filter and copies of its profiles. */
#include <stdlib.h>
#include <string.h>

#include "filter.h"

typedef struct {
    rc_filter f;
    rc_grade_profile grade;
    rc_speed_profile speed;
    double *buf;               /* grade distances, grades, cum, speed distances, speeds */
} shim;

/* NULL when rc_filter_validate refuses the config (its message in msg[RC_MSG_SIZE]);
 * sn == 0: no speed profile */
shim *shim_new(double dt, double speed_std, double position_std, double position_std_rel,
               double gamma, int kind, double length, const double *gd, const double *gg, long gn,
               const double *sd, const double *ss, long sn, char *msg, double speed_std_rel)
{
    rc_filter_config cfg = {dt, speed_std, position_std, position_std_rel, gamma, kind, length,
                            10.0, 0.3, 0.1, 0.1, 1.3, -1.5,    /* FilterConfig's singer_* */
                            speed_std_rel};
    rc_error err;
    shim *s;
    if (rc_filter_validate(&cfg, sn > 0, &err) != RC_OK) {
        memcpy(msg, err.msg, RC_MSG_SIZE);
        return NULL;
    }
    s = calloc(1, sizeof *s);
    if (!s)
        return NULL;
    s->buf = malloc((size_t)(3 * gn + 2 * sn + 1) * sizeof(double));
    if (!s->buf) {
        free(s);
        return NULL;
    }
    memcpy(s->buf, gd, (size_t)gn * sizeof(double));
    memcpy(s->buf + gn, gg, (size_t)gn * sizeof(double));
    rc_grade_cumulate(s->buf, s->buf + gn, gn, s->buf + 2 * gn);
    s->grade.distances = s->buf;
    s->grade.grades = s->buf + gn;
    s->grade.cum = s->buf + 2 * gn;
    s->grade.n = gn;
    if (sn > 0) {
        memcpy(s->buf + 3 * gn, sd, (size_t)sn * sizeof(double));
        memcpy(s->buf + 3 * gn + sn, ss, (size_t)sn * sizeof(double));
    }
    s->speed.distances = s->buf + 3 * gn;
    s->speed.speeds = s->buf + 3 * gn + sn;
    s->speed.n = sn;
    rc_filter_init(&s->f, &cfg, &s->grade, sn > 0 ? &s->speed : NULL);
    return s;
}

void shim_free(shim *s)
{
    if (s) {
        free(s->buf);
        free(s);
    }
}

void shim_restart(shim *s) { rc_filter_restart(&s->f); }
int shim_start(shim *s, double v, double x)
{
    return rc_filter_start_from_measurement(&s->f, v, x);
}
void shim_hold(shim *s) { rc_filter_hold(&s->f); }
int shim_update(shim *s, double v, double x) { return rc_filter_update(&s->f, v, x); }
int shim_update_speed(shim *s, double v, double var)
{
    return rc_filter_update_speed(&s->f, v, var);
}

/* out[0], out[1]: use the speed, use the distance; returns the status */
int shim_gate(shim *s, double v, double x, int *out)
{
    return rc_filter_gate(&s->f, v, x, out, out + 1);
}

int shim_predict(shim *s, double traction, double brake, const double *theta, double q, double dt)
{
    return rc_filter_predict(&s->f, traction, brake, theta, q, dt);
}

#define SHIM_NSTATE 31
int shim_nstate(void) { return SHIM_NSTATE; }

/* Every field mirroring an attribute of MotionFilter (r0, r1 its R; xb*, m* its x_bar and M's
 * upper triangle; xh*, p* x_hat and P's), then the eight properties (the order of
 * tests/model_tests/core/test_core_filter.py's FIELDS) */
void shim_state(const shim *s, double *out)
{
    const rc_filter *f = &s->f;
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
        rc_filter_predicted_position_std(f)};
    memcpy(out, v, sizeof v);
}

/* One call of the test's op records: op[0] the code, op[1..8] the arguments (see
 * tests/model_tests/core/test_core_filter.py's OPS). out[0] the status, out[1], out[2] gate's answers (0 for the
 * other calls), out[3..] shim_state after the call. */
enum { OP_RESTART, OP_START, OP_GATE, OP_HOLD, OP_UPDATE, OP_UPDATE_SPEED, OP_PREDICT };
void shim_apply(shim *s, const double *op, double *out)
{
    int status = RC_OK, use[2] = {0, 0};
    switch ((int)op[0]) {
    case OP_RESTART: shim_restart(s); break;
    case OP_START: status = shim_start(s, op[1], op[2]); break;
    case OP_GATE: status = shim_gate(s, op[1], op[2], use); break;
    case OP_HOLD: shim_hold(s); break;
    case OP_UPDATE: status = shim_update(s, op[1], op[2]); break;
    case OP_UPDATE_SPEED: status = shim_update_speed(s, op[1], op[2]); break;
    case OP_PREDICT: status = shim_predict(s, op[1], op[2], op + 3, op[7], op[8]); break;
    default: status = -1;
    }
    out[0] = status;
    out[1] = use[0];
    out[2] = use[1];
    shim_state(s, out + 3);
}

/* the config copied into the filter, and whether it holds a speed profile */
void shim_config(const shim *s, double *out)
{
    const rc_filter *f = &s->f;
    double v[9] = {f->cfg.dt, f->cfg.speed_std, f->cfg.position_std, f->cfg.position_std_rel,
                   f->cfg.gamma, f->cfg.kind, f->cfg.length, f->speed != NULL,
                   f->cfg.speed_std_rel};
    memcpy(out, v, sizeof v);
}
