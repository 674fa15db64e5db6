/* filter.c -- see filter.h; the bodies of models/filtering/motion_filter.py's MotionFilter (kinds 1-4) with
 * models/filtering/kalman.py's pure functions (specific_net_force, linearised_model, ekf_model, gain,
 * update, update_one, forward, predict_paper, predict) inlined in the same operand order; the
 * Singer branches call singer.c. */
#include "rc_fp_contract.h"
#include <stdio.h>

#include "filter.h"
#include "fpmath.h"
#include <string.h>

/* Python's float ** 2: OverflowError when a finite base gives an infinite square */
static rc_status square(double x, double *out)
{
    double y = rc_sq(x);
    if (isinf(y) && isfinite(x))
        return RC_MATH;
    *out = y;
    return RC_OK;
}

static int has_speed_profile(const rc_filter *f)
{
    return f->speed != NULL && f->speed->n > 0;
}

static int around_vzad(const rc_filter *f)     /* self.kind in (LINEARISED, PAPER) */
{
    return f->kind == RC_LINEARISED || f->kind == RC_PAPER;
}

/* "<what>, got <repr(v)>": FilterConfig.validate's messages (f"{v}" is Python's repr) */
static rc_status bad(rc_error *err, const char *what, double v)
{
    char r[40];
    rc_repr(v, r, (int)sizeof r);
    if (err)
        snprintf(err->msg, sizeof err->msg, "%s, got %s", what, r);
    return RC_BAD_CONFIG;
}

rc_status rc_filter_validate(const rc_filter_config *cfg, int has_speed, rc_error *err)
{
    double sq;
    if (err)
        err->msg[0] = '\0';
    if (!(cfg->position_std_rel >= 0 && isfinite(cfg->position_std_rel)))
        return bad(err, "sensor.position_std_rel must be >= 0", cfg->position_std_rel);
    if (!(cfg->speed_std_rel >= 0 && isfinite(cfg->speed_std_rel)))
        return bad(err, "sensor.speed_std_rel must be >= 0", cfg->speed_std_rel);
    if (!(cfg->length >= 0 && isfinite(cfg->length)))
        return bad(err, "car.length must be >= 0", cfg->length);
    if (!(cfg->speed_std > 0 && isfinite(cfg->speed_std)))
        return bad(err, "sensor.speed_std must be > 0 for the filter", cfg->speed_std);
    if (!(cfg->position_std > 0 && isfinite(cfg->position_std)))
        return bad(err, "sensor.position_std must be > 0 for the filter",
                   cfg->position_std);
    if (!(cfg->kind >= 0 && cfg->kind <= RC_SINGER)) {
        if (err)
            snprintf(err->msg, sizeof err->msg, "filter.kind must be 0 (auto), 1 (linearised), "
                     "2 (EKF), 3 (paper verbatim) or 4 (Singer), got %d", cfg->kind);
        return RC_BAD_CONFIG;
    }
    if (cfg->kind == RC_SINGER) {             /* FilterConfig.singer_params() */
        double m_w, sigma_w;
        rc_status st = rc_singer_params(cfg->singer_tau, cfg->singer_p0, cfg->singer_p_plus,
                                        cfg->singer_p_minus, cfg->singer_w_max_plus,
                                        cfg->singer_w_max_minus, &m_w, &sigma_w, err);
        if (st != RC_OK)
            return st;
    }
    if ((cfg->kind == RC_LINEARISED || cfg->kind == RC_PAPER) && !has_speed) {
        if (err)
            snprintf(err->msg, sizeof err->msg, "filter.kind = %d (linearised around V_zad, "
                     "eq. (13)) needs track.speed_profile", cfg->kind);
        return RC_BAD_CONFIG;
    }
    if (square(cfg->speed_std, &sq) != RC_OK)
        return bad(err, "sensor.speed_std ** 2 overflows (OverflowError)",
                   cfg->speed_std);
    if (square(cfg->position_std, &sq) != RC_OK)
        return bad(err, "sensor.position_std ** 2 overflows (OverflowError)",
                   cfg->position_std);
    return RC_OK;
}

void rc_filter_init(rc_filter *f, const rc_filter_config *cfg, const rc_grade_profile *grade,
                    const rc_speed_profile *speed)
{
    memcpy(&f->cfg, cfg, sizeof f->cfg);            /* padding too: a state holds the bytes */
    f->grade = grade;
    f->speed = speed;
    f->kind = cfg->kind ? cfg->kind : (has_speed_profile(f) ? RC_LINEARISED : RC_EKF);
    f->r0 = rc_sq(cfg->speed_std);
    f->r1 = rc_sq(cfg->position_std);
    f->rejected = 0;
    f->speed_run = f->position_run = 0;
    f->reacquired = 0;
    f->speed_fit = 1;
    f->use_speed = f->use_position = 1;
    f->reacquire = 0;
    f->singer_m_w = f->singer_sigma_w = 0.0;
    if (f->kind == RC_SINGER)
        rc_singer_params(cfg->singer_tau, cfg->singer_p0, cfg->singer_p_plus, cfg->singer_p_minus,
                         cfg->singer_w_max_plus, cfg->singer_w_max_minus, &f->singer_m_w,
                         &f->singer_sigma_w, NULL);
    rc_filter_restart(f);
}

static double vzad_at(const rc_filter *f, double x)      /* MotionFilter._vzad */
{
    return has_speed_profile(f) ? rc_speed_at(f->speed, x) : 0.0;
}

/* SingerKind._publish (models/filtering/kinds.py): the (v, r) block of the Singer state into the posterior's
 * (posterior true) or the prediction's fields */
static void singer_copy(rc_filter *f, int posterior)
{
    const double *x = f->singer.x, *P = f->singer.P;
    if (posterior) {
        f->xh0 = x[1];
        f->xh1 = x[2];
        f->p00 = P[4];
        f->p01 = P[5];
        f->p11 = P[8];
    } else {
        f->xb0 = x[1];
        f->xb1 = x[2];
        f->m00 = P[4];
        f->m01 = P[5];
        f->m11 = P[8];
    }
}

/* MotionFilter._singer_restart: x0 = [m_w, speed, position], P0 = diag(sigma_w^2, p_v, p_x) */
static void singer_restart(rc_filter *f, double speed, double position, double p_v, double p_x)
{
    double x0[3], P0[9] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
    x0[0] = f->singer_m_w;
    x0[1] = speed;
    x0[2] = position;
    P0[0] = rc_sq(f->singer_sigma_w);
    P0[4] = p_v;
    P0[8] = p_x;
    rc_singer_init(&f->singer, f->cfg.singer_tau, f->singer_sigma_w, f->singer_m_w, x0, P0, 1);
    singer_copy(f, 1);
    singer_copy(f, 0);
}

void rc_filter_restart(rc_filter *f)
{
    f->xb0 = f->xb1 = f->m00 = f->m01 = f->m11 = 0.0;
    f->xh0 = f->xh1 = f->p00 = f->p01 = f->p11 = 0.0;
    f->speed_run = f->position_run = 0;
    f->use_speed = f->use_position = 1;
    f->reacquire = 0;
    f->vzad_hat = f->vzad_bar = around_vzad(f) ? vzad_at(f, 0.0) : 0.0;
    if (f->kind == RC_SINGER)
        singer_restart(f, 0.0, 0.0, 0.0, 0.0);
}

/* cfg.position_noise_std(x) ** 2 */
static rc_status position_noise_var(const rc_filter *f, double x, double *out)
{
    return square(f->cfg.position_std + f->cfg.position_std_rel * fabs(x), out);
}

/* SingerKind.update's std_v: speed_std + speed_std_rel * |v|, speed_std when rel is 0 */
static double speed_noise_std(const rc_filter *f, double speed_meas)
{
    if (f->cfg.speed_std_rel != 0.0)
        return f->cfg.speed_std + f->cfg.speed_std_rel * fabs(speed_meas);
    return f->cfg.speed_std;
}

/* MotionFilter.speed_variance: (speed_std + speed_std_rel * |v|) ** 2, r0 when rel is 0 */
static rc_status speed_variance(const rc_filter *f, double speed_meas, double *out)
{
    if (f->cfg.speed_std_rel != 0.0)
        return square(f->cfg.speed_std + f->cfg.speed_std_rel * fabs(speed_meas), out);
    *out = f->r0;
    return RC_OK;
}

rc_status rc_filter_start_from_measurement(rc_filter *f, double speed_meas, double position_meas)
{
    double vzad, p00, p11;
    rc_filter_restart(f);
    if (f->kind == RC_SINGER) {
        double speed = rc_max(speed_meas, 0.0), p_v, p_x;
        if (speed_variance(f, speed_meas, &p_v) != RC_OK
                || position_noise_var(f, position_meas, &p_x) != RC_OK)
            return RC_MATH;
        singer_restart(f, speed, position_meas, p_v, p_x);
        return RC_OK;
    }
    vzad = around_vzad(f) ? vzad_at(f, position_meas) : 0.0;
    f->vzad_hat = f->vzad_bar = vzad;
    f->xh0 = rc_max(speed_meas, 0.0) - vzad;
    f->xh1 = position_meas;
    if (speed_variance(f, speed_meas, &p00) != RC_OK
            || position_noise_var(f, position_meas, &p11) != RC_OK)
        return RC_MATH;
    f->p00 = p00;
    f->p11 = p11;
    return RC_OK;
}

static double vzad_predicted(const rc_filter *f)        /* MotionFilter._vzad_predicted */
{
    return around_vzad(f) ? f->vzad_bar : 0.0;
}

static rc_status position_variance(const rc_filter *f, double position_meas, double *out)
{                                                        /* MotionFilter._position_variance */
    if (f->cfg.position_std_rel != 0.0)
        return position_noise_var(f, position_meas, out);
    *out = f->r1;
    return RC_OK;
}

rc_status rc_filter_gate(rc_filter *f, double speed_meas, double position_meas, int *use_v,
                         int *use_x)
{
    double vzad = vzad_predicted(f), r0, r1, e0, e1, s00, s11, g2;
    int v, x;
    if (position_variance(f, position_meas, &r1) != RC_OK
            || speed_variance(f, speed_meas, &r0) != RC_OK)
        return RC_MATH;
    e0 = speed_meas - vzad - f->xb0;
    e1 = position_meas - f->xb1;
    s00 = f->m00 + r0;
    s11 = f->m11 + r1;
    g2 = RC_GATE_SIGMAS * RC_GATE_SIGMAS;
    v = e0 * e0 <= g2 * s00;                             /* false for NaN */
    x = e1 * e1 <= g2 * s11;
    f->speed_fit = v && e0 * e0 <= RC_FIT_SIGMAS * RC_FIT_SIGMAS * s00;
    f->speed_run = v ? 0 : f->speed_run + 1;
    f->position_run = x ? 0 : f->position_run + 1;
    if (f->position_run >= RC_REACQUIRE) {
        f->position_run = 0;
        if (v) {
            f->reacquire = RC_REACQUIRE_DISTANCE;
        } else {
            f->speed_run = 0;
            f->reacquire = RC_REACQUIRE_BOTH;
            f->speed_fit = 0;
        }
        *use_v = *use_x = 1;
        return RC_OK;
    }
    f->rejected += (long)!v + (long)!x;
    f->use_speed = v;
    f->use_position = x;
    *use_v = v;
    *use_x = x;
    return RC_OK;
}

void rc_filter_hold(rc_filter *f)
{
    if (f->kind == RC_SINGER) {
        singer_copy(f, 1);
        return;
    }
    f->xh0 = f->xb0;
    f->xh1 = f->xb1;
    f->p00 = f->m00;
    f->p01 = f->m01;
    f->p11 = f->m11;
    f->vzad_hat = vzad_predicted(f);
}

/* MotionFilter._update_one: the speed alone (speed true, H = [1 0]) or the distance alone */
static rc_status update_one(rc_filter *f, double speed_meas, double position_meas, int speed)
{
    double vzad = vzad_predicted(f);
    double m00 = f->m00, m01 = f->m01, m11 = f->m11;
    double s, e, k0, k1, r0, r1, xh0;
    if (speed) {
        if (speed_variance(f, speed_meas, &r0) != RC_OK)
            return RC_MATH;
        s = m00 + r0;
        e = speed_meas - vzad - f->xb0;
        if (s == 0.0)
            return RC_MATH;
        k0 = m00 / s;
        k1 = m01 / s;
        f->p00 = m00 - k0 * m00;
        f->p01 = m01 - k0 * m01;
        f->p11 = m11 - k1 * m01;
    } else {
        if (position_variance(f, position_meas, &r1) != RC_OK)
            return RC_MATH;
        s = m11 + r1;
        e = position_meas - f->xb1;
        if (s == 0.0)
            return RC_MATH;
        k0 = m01 / s;
        k1 = m11 / s;
        f->p00 = m00 - k0 * m01;
        f->p01 = m01 - k0 * m11;
        f->p11 = m11 - k1 * m11;
    }
    xh0 = f->xb0 + k0 * e;
    f->xh1 = f->xb1 + k1 * e;
    f->xh0 = xh0 + vzad < 0.0 ? -vzad : xh0;            /* a car never moves backwards */
    f->vzad_hat = vzad;
    return RC_OK;
}

rc_status rc_filter_update(rc_filter *f, double speed_meas, double position_meas)
{
    double vzad, r0, r1, m00, m01, m11, s00, s11, det, i00, i01, i11, a00, a01, a10, a11;
    double p00, p01, p11, e0, e1, k00, k01, k10, k11, xh0;
    int use_v, use_x;
    if (f->reacquire) {
        int what = f->reacquire;
        f->reacquire = 0;
        f->reacquired += 1;
        if (what == RC_REACQUIRE_BOTH || f->kind == RC_SINGER)
            return rc_filter_start_from_measurement(f, speed_meas, position_meas);
        /* the distance alone: the update with the speed, then the distance restarted */
        if (update_one(f, speed_meas, position_meas, 1) != RC_OK)
            return RC_MATH;
        f->xh1 = position_meas;
        f->p01 = 0.0;
        return position_variance(f, position_meas, &f->p11);
    }
    use_v = f->use_speed;
    use_x = f->use_position;
    if (!(use_v && use_x)) {
        f->use_speed = f->use_position = 1;
        if (f->kind == RC_SINGER) {
            if (use_v) {
                if (rc_singer_update_speed(&f->singer, speed_meas, speed_noise_std(f, speed_meas))
                        != RC_OK)
                    return RC_MATH;
            } else if (use_x) {
                double std = f->cfg.position_std + f->cfg.position_std_rel * fabs(position_meas);
                if (rc_singer_update_distance(&f->singer, position_meas, std) != RC_OK)
                    return RC_MATH;
            }
            singer_copy(f, 1);
            return RC_OK;
        }
        if (use_v || use_x)
            return update_one(f, speed_meas, position_meas, use_v);
        rc_filter_hold(f);
        return RC_OK;
    }
    if (f->kind == RC_SINGER) {
        double std_v = speed_noise_std(f, speed_meas);
        double std = f->cfg.position_std + f->cfg.position_std_rel * fabs(position_meas);
        if (rc_singer_update_speed_distance(&f->singer, speed_meas, position_meas,
                                            std_v, std) != RC_OK)
            return RC_MATH;
        singer_copy(f, 1);
        return RC_OK;
    }
    vzad = vzad_predicted(f);
    if (speed_variance(f, speed_meas, &r0) != RC_OK
            || position_variance(f, position_meas, &r1) != RC_OK)
        return RC_MATH;
    m00 = f->m00;
    m01 = f->m01;
    m11 = f->m11;
    s00 = m00 + r0;                                      /* M + R and its inverse */
    s11 = m11 + r1;
    det = s00 * s11 - m01 * m01;
    if (det == 0.0)
        return RC_MATH;
    i00 = s11 / det;
    i01 = -m01 / det;
    i11 = s00 / det;
    a00 = m00 * i00 + m01 * i01;                         /* A = M (M + R)^-1 */
    a01 = m00 * i01 + m01 * i11;
    a10 = m01 * i00 + m11 * i01;
    a11 = m01 * i01 + m11 * i11;
    p00 = m00 - (a00 * m00 + a01 * m01);                 /* (18) P = M - A M */
    p01 = m01 - 0.5 * ((a00 * m01 + a01 * m11) + (a10 * m00 + a11 * m01));
    p11 = m11 - (a10 * m01 + a11 * m11);
    e0 = speed_meas - vzad - f->xb0;
    e1 = position_meas - f->xb1;
    if (r0 == 0.0 || r1 == 0.0)
        return RC_MATH;
    k00 = p00 / r0;                                      /* (17) K = P R^-1 */
    k01 = p01 / r1;
    k10 = p01 / r0;
    k11 = p11 / r1;
    xh0 = f->xb0 + k00 * e0 + k01 * e1;                  /* (15) */
    f->xh1 = f->xb1 + k10 * e0 + k11 * e1;
    f->xh0 = xh0 + vzad < 0.0 ? -vzad : xh0;            /* a car never moves backwards */
    f->p00 = p00;
    f->p01 = p01;
    f->p11 = p11;
    f->vzad_hat = vzad;
    return RC_OK;
}

rc_status rc_filter_update_speed(rc_filter *f, double speed_meas, double variance)
{
    double p00 = f->p00, p01 = f->p01, p11 = f->p11;
    double s = p00 + variance, k0, k1, e, xh0;
    if (f->kind == RC_SINGER) {               /* math.sqrt(variance): ValueError below 0 */
        if (variance < 0.0
                || rc_singer_update_speed(&f->singer, speed_meas, sqrt(variance)) != RC_OK)
            return RC_MATH;
        singer_copy(f, 1);
        return RC_OK;
    }
    if (s == 0.0)
        return RC_MATH;
    k0 = p00 / s;
    k1 = p01 / s;
    e = speed_meas - f->vzad_hat - f->xh0;
    xh0 = f->xh0 + k0 * e;
    f->xh0 = xh0 + f->vzad_hat < 0.0 ? -f->vzad_hat : xh0;
    f->xh1 += k1 * e;
    f->p00 = p00 - k0 * p00;
    f->p01 = p01 - k0 * p01;
    f->p11 = p11 - k1 * p01;
    return RC_OK;
}

/* specific_net_force: (F-B)/(Pg) - A0 - A1 V - A2 V^2 - i [N/kN] */
static double specific_net_force(double traction, double brake, double speed, double grade,
                                 const double *theta)
{
    return theta[0] * (traction - brake) - theta[1] - theta[2] * speed - theta[3] * speed * speed
           - grade;
}

int rc_filter_acceleration(const rc_filter *f, double *out)
{
    if (f->kind != RC_SINGER)
        return 0;
    *out = f->singer.x[0];
    return 1;
}

static rc_status singer_predict(rc_filter *f, double dt)
{
    if (rc_singer_predict(&f->singer, dt) != RC_OK)
        return RC_MATH;
    singer_copy(f, 0);
    return RC_OK;
}

rc_status rc_filter_predict(rc_filter *f, double traction, double brake, const double *theta,
                            double q, double dt)
{
    if (f->kind == RC_SINGER)                 /* model-free: forces and theta are not used */
        return singer_predict(f, dt);
    double speed_hat = rc_filter_speed(f);
    double x_pos = f->xh1;
    double grade = rc_grade_average(f->grade, x_pos, f->cfg.length);
    double p00 = f->p00, p01 = f->p01, p11 = f->p11;
    double gamma = f->cfg.gamma;
    double k, dv, v_next_minus_dv_v, vzad_hat, vzad_bar, v_hat, v_pred, f10;
    if (around_vzad(f)) {
        double vzad = f->vzad_hat;
        double vzad_next = vzad_at(f, x_pos + speed_hat * dt);
        double a, c, C;
        if (1.0 + gamma == 0.0)
            return RC_MATH;
        k = RC_G / 1000.0 / (1.0 + gamma) * dt;          /* linearised_model */
        c = vzad - vzad_next + k * specific_net_force(traction, brake, vzad, grade, theta);
        a = 1.0 - k * (theta[2] + 2.0 * theta[3] * vzad);
        C = vzad * dt;
        f->vzad_bar = vzad_next;
        if (f->kind == RC_PAPER) {                       /* eqs. (16), (19) verbatim */
            double xb0 = c + a * f->xh0;
            f->xb0 = xb0 + vzad_next < 0.0 ? -vzad_next : xb0;
            f->xb1 = C + dt * f->xh0 + x_pos;
            f->m00 = a * a * p00 + q;
            f->m01 = a * (dt * p00 + p01);
            f->m11 = dt * dt * p00 + 2.0 * dt * p01 + p11;
            return RC_OK;
        }
        dv = a;
        v_next_minus_dv_v = c + vzad_next - a * vzad;
    } else {
        double v_next;
        if (1.0 + gamma == 0.0)
            return RC_MATH;
        k = RC_G / 1000.0 / (1.0 + gamma) * dt;          /* ekf_model */
        v_next = speed_hat + k * specific_net_force(traction, brake, speed_hat, grade, theta);
        dv = 1.0 - k * (theta[2] + 2.0 * theta[3] * speed_hat);
        v_next = rc_max(v_next, 0.0);
        v_next_minus_dv_v = v_next - dv * speed_hat;
    }
    vzad_hat = f->kind == RC_LINEARISED ? f->vzad_hat : 0.0;
    vzad_bar = f->kind == RC_LINEARISED ? f->vzad_bar : 0.0;
    v_hat = f->xh0 + vzad_hat;
    v_pred = rc_max(v_next_minus_dv_v + dv * v_hat, 0.0);
    f10 = 0.5 * dt * (1.0 + dv);                         /* Phi = [[dv, 0], [f10, 1]] */
    f->xb0 = v_pred - vzad_bar;
    f->xb1 = x_pos + 0.5 * dt * (v_hat + v_pred);
    f->m00 = dv * dv * p00 + q;
    f->m01 = dv * (f10 * p00 + p01) + q * 0.5 * dt;
    f->m11 = f10 * f10 * p00 + 2.0 * f10 * p01 + p11 + q * dt * dt / 3.0;
    return RC_OK;
}

void rc_filter_cap_predicted_speed(rc_filter *f, double v_max, double dt)
{
    if (f->kind == RC_SINGER) {                /* SingerKind.cap_predicted_speed */
        double *x = f->singer.x;
        const double *P = f->singer.P;
        double excess, pvv;
        if (!(x[1] > v_max))
            return;
        excess = x[1] - v_max;
        pvv = P[4];
        if (pvv > 0.0) {
            x[0] = x[0] - P[1] / pvv * excess;
            x[2] = x[2] - P[7] / pvv * excess;
        }
        x[1] = v_max;
        singer_copy(f, 0);
        return;
    }
    if (!(f->xb0 + f->vzad_bar > v_max))
        return;
    f->xb0 = v_max - f->vzad_bar;
    if (f->kind != RC_PAPER) {                 /* EKFKind: the trapezoid with the capped speed */
        double v_hat = f->xh0 + (f->kind == RC_LINEARISED ? f->vzad_hat : 0.0);
        f->xb1 = f->xh1 + 0.5 * dt * (v_hat + v_max);
    }                                          /* PaperKind: Euler's distance has no V' in it */
}

double rc_filter_speed(const rc_filter *f)
{
    double v = f->xh0 + f->vzad_hat;
    return v > 0.0 ? v : 0.0;
}

double rc_filter_position(const rc_filter *f)
{
    return f->xh1;
}

double rc_filter_speed_std(const rc_filter *f)
{
    return f->p00 > 0.0 ? sqrt(f->p00) : 0.0;
}

double rc_filter_position_std(const rc_filter *f)
{
    return f->p11 > 0.0 ? sqrt(f->p11) : 0.0;
}

double rc_filter_predicted_speed(const rc_filter *f)
{
    double v = f->xb0 + f->vzad_bar;
    return v > 0.0 ? v : 0.0;
}

double rc_filter_predicted_position(const rc_filter *f)
{
    return f->xb1;
}

double rc_filter_predicted_speed_std(const rc_filter *f)
{
    return f->m00 > 0.0 ? sqrt(f->m00) : 0.0;
}

double rc_filter_predicted_position_std(const rc_filter *f)
{
    return f->m11 > 0.0 ? sqrt(f->m11) : 0.0;
}
