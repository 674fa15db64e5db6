/* estimator.c -- see estimator.h; the bodies of models/estimation/online.py's StationDetector and
 * OnlineEstimator (est.method 0), and of models/estimation/methods.py's SlopeLS (est.method 2),
 * same expressions in the same order. */
#include "rc_fp_contract.h"
#include "estimator.h"
#include "linalg4.h"

#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "fpmath.h"
#include "rc_common.h"

/* OnlineEstimator's class constants */
#define STEADY_SPEED 0.1         /* [m/s] */
#define STEADY_FORCE 2.0         /* [N/kN] of est.mass_initial's weight */
#define STEADY_TIME 20.0         /* [s] */
#define FORCE_SMOOTHING 10.0     /* [s] */
#define MASS_RANGE 5.0
#define ACCEL_STD 0.1            /* [m/s^2] */

/* ------------------------------------------------------------------ StationDetector */

static void station_init(rc_station *s, const rc_station_config *cfg, double speed_std,
                         double position_std)
{
    s->v_thr = cfg->speed_threshold != 0.0 ? cfg->speed_threshold : rc_max(3.0 * speed_std, 0.05);
    s->x_thr = cfg->position_threshold != 0.0 ? cfg->position_threshold
                                              : rc_max(5.0 * position_std, 2.0);
    s->dwell = cfg->dwell;
    s->still_time = 0.0;
    s->fast_run = 0;
    s->moving = 0;
    s->restarted = 0;
}

/* StationDetector.observe: 1 when a station stop is confirmed at this sample */
static int station_observe(rc_station *s, double speed_meas, double position_meas, double dt)
{
    s->fast_run = speed_meas > s->v_thr ? s->fast_run + 1 : 0;
    s->moving = s->fast_run >= RC_MOVING_RUN;
    if (s->moving) {
        s->still_time = 0.0;
        s->restarted = 0;
        return 0;
    }
    s->still_time += dt;
    if (s->still_time >= s->dwell && !s->restarted && fabs(position_meas) < s->x_thr) {
        s->restarted = 1;
        return 1;
    }
    return 0;
}

/* ------------------------------------------------------------------ SlopeLS */

static void slope_free(rc_slope_ls *s)
{
    if (!s)
        return;
    free(s->v);
    free(s->i);
    free(s->dts);
    free(s->w);
    free(s->c);
    free(s);
}

static rc_slope_ls *slope_new(long size)
{
    rc_slope_ls *s = calloc(1, sizeof *s);
    if (!s)
        return NULL;
    s->size = size;
    s->v = calloc((size_t)(size + 1), sizeof(double));   /* one more before the oldest goes */
    s->i = calloc((size_t)size * 4, sizeof(double));
    s->dts = calloc((size_t)size, sizeof(double));
    s->w = calloc((size_t)size, sizeof(double));
    s->c = calloc((size_t)size, sizeof(double));
    if (!s->v || !s->i || !s->dts || !s->w || !s->c) {
        slope_free(s);
        return NULL;
    }
    return s;
}

/* SlopeLS.identify: one regression row per new sample once the window is full */
static void slope_identify(rc_estimator *e, double traction, double brake, double speed,
                           double speed_next, double grade, double dt, int contiguous)
{
    rc_slope_ls *s = e->slope;
    if (!contiguous) {           /* a new contiguous stretch starts at the previous sample */
        s->v[0] = speed;
        s->len = 1;
        s->contiguous = 0;
    }
    double *row = &s->i[4 * (s->len - 1)];
    s->v[s->len] = speed_next;
    row[0] = traction;
    row[1] = brake;
    row[2] = grade;
    row[3] = dt;
    s->len += 1;
    if (s->len > s->size) {      /* del self.v[0], self.i[0] */
        memmove(s->v, s->v + 1, (size_t)(s->len - 1) * sizeof(double));
        memmove(s->i, s->i + 4, (size_t)(s->len - 2) * 4 * sizeof(double));
        s->len -= 1;
    }
    if (s->len < s->size)
        return;
    long m = s->size - 1;        /* intervals */
    int same = s->has_weights;   /* constant at a fixed sampling period: computed once */
    for (long j = 0; j < m && same; j++)
        same = s->i[4 * j + 3] == s->dts[j];
    if (!same) {
        for (long j = 0; j < m; j++)
            s->dts[j] = s->i[4 * j + 3];
        rc_centred_slope_weights(s->dts, m, s->w, s->c);
        s->has_weights = 1;
    }
    double v_sum = 0.0, a_c = 0.0, f = 0.0, b = 0.0, g = 0.0;
    for (long k = 0; k < s->size; k++)
        v_sum += s->v[k];
    double v_c = v_sum / (double)s->size;
    for (long k = 0; k < s->size; k++)
        a_c += s->w[k] * s->v[k];
    for (long j = 0; j < m; j++)
        f += s->c[j] * s->i[4 * j];
    for (long j = 0; j < m; j++)
        b += s->c[j] * s->i[4 * j + 1];
    for (long j = 0; j < m; j++)
        g += s->c[j] * s->i[4 * j + 2];
    double step = e->dt_nominal;
    rc_ident_update(&e->ident, f, b, v_c, v_c + a_c * step, g, step, s->contiguous);
    s->contiguous = 1;
}

/* ------------------------------------------------------------------ ProcessNoiseBank */

/* ProcessNoiseBank.__init__ with its defaults (decades -2..1, n 13, prior_decades 1) */
static void bank_init(rc_noise_bank *b, double q0, double speed_std, double speed_std_rel)
{
    const int n = RC_BANK_SIZE;
    const double lo = -2.0, hi = 1.0, prior_decades = 1.0;
    double ln10 = rc_log(10.0), log_q0 = rc_log(q0);
    double width = prior_decades * ln10;
    for (int j = 0; j < n; j++) {
        b->log_q[j] = log_q0 + ln10 * (lo + (hi - lo) * (double)j / (double)(n - 1));
        b->q[j] = rc_exp(b->log_q[j]);
        b->log_prior[j] = -0.5 * rc_sq((b->log_q[j] - log_q0) / width);
        b->log_lik[j] = 0.0;
        b->x[j] = 0.0;
        b->P[j] = 0.0;
    }
    b->started = 0;
    b->R = rc_sq(speed_std);                      /* LikelihoodNoise.from_config */
    b->speed_std = speed_std;
    b->speed_std_rel = speed_std_rel;
    b->estimate = q0;
}

static void bank_predict(rc_noise_bank *b, double dv, double q_param)
{
    if (!b->started)
        return;
    for (int j = 0; j < RC_BANK_SIZE; j++) {
        b->x[j] = b->x[j] + dv;
        b->P[j] = b->P[j] + b->q[j] + q_param;
    }
}

#define BANK_NEGLIGIBLE (-45.0)   /* ProcessNoiseBank.NEGLIGIBLE */

static void bank_update(rc_noise_bank *b, double z)
{
    const int n = RC_BANK_SIZE;
    /* variance_at: square(speed_noise_std(z)) with sensor.speed_std_rel, else R */
    double R = b->speed_std_rel != 0.0 ? rc_sq(b->speed_std + b->speed_std_rel * fabs(z)) : b->R;
    double w[RC_BANK_SIZE];
    if (!b->started) {
        for (int j = 0; j < n; j++) {
            b->x[j] = z;
            b->P[j] = R;
        }
        b->started = 1;
        return;
    }
    for (int j = 0; j < n; j++) {
        double S = b->P[j] + R;
        double nu = z - b->x[j];
        b->log_lik[j] += -0.5 * (rc_log(S) + nu * nu / S);
        double K = b->P[j] / S;
        b->x[j] = b->x[j] + K * nu;
        b->P[j] = b->P[j] * (1.0 - K);
    }
    for (int j = 0; j < n; j++)
        w[j] = b->log_lik[j] + b->log_prior[j];
    double top = w[0];
    for (int j = 1; j < n; j++)
        top = rc_max(top, w[j]);
    double num = 0.0, den = 0.0;
    for (int j = 0; j < n; j++) {
        if (w[j] - top < BANK_NEGLIGIBLE)
            continue;
        double e = rc_exp(w[j] - top);
        num += e * b->log_q[j];
        den += e;
    }
    b->estimate = rc_exp(num / den);
}

/* ------------------------------------------------------------------ OnlineEstimator */

int rc_estimator_init(rc_estimator *e, const rc_ident_config *id_cfg, const rc_filter_config *filt,
                      const rc_station_config *station, const rc_grade_profile *grade,
                      const rc_speed_profile *speed, double dt, long slope_window,
                      int physical, int sigma2_method)
{
    rc_ident_config ic;                    /* build_estimator's private copies, padding too */
    rc_filter_config fc;
    memcpy(&ic, id_cfg, sizeof ic);
    memcpy(&fc, filt, sizeof fc);
    ic.dt = dt;
    ic.speed_std = fc.speed_std;
    ic.speed_std_rel = fc.speed_std_rel;
    fc.dt = dt;
    fc.gamma = ic.gamma;
    e->slope = NULL;
    e->physical = physical;
    e->likelihood_noise = sigma2_method == 1;
    bank_init(&e->bank, ic.sigma2_initial, fc.speed_std, fc.speed_std_rel);
    if (rc_ident_init_rows(&e->ident, &ic, slope_window) != 0)
        return -1;
    if (slope_window != 0 && !(e->slope = slope_new(slope_window))) {
        rc_ident_free(&e->ident);
        return -1;
    }
    rc_filter_init(&e->filter, &fc, grade, speed);
    station_init(&e->station, station, fc.speed_std, fc.position_std);
    e->grade = grade;
    e->length = fc.length;
    e->gamma = ic.gamma;
    e->dt_nominal = ic.dt;
    e->station_stops = 0;
    e->track_speeds = 0;
    e->has_prev = 0;
    e->prev_speed = e->prev_position = 0.0;
    e->pair_used = 0;
    e->force_traction = e->force_brake = 0.0;
    e->dt = ic.dt;
    e->prev_fit = 1;
    e->net_force = 0.0;
    e->steady_speed = 0.0;
    e->steady_force = 0.0;
    e->steady_time = 0.0;
    e->force_band = STEADY_FORCE * ic.mass_initial * RC_G;
    e->mass_initial = ic.mass_initial;
    e->mass_low = ic.mass_initial / MASS_RANGE;
    e->mass_high = ic.mass_initial * MASS_RANGE;
    e->mass_std_initial = ic.mass_std_initial;
    e->has_last_good = 0;
    return 0;
}

const char *rc_estimator_not_covered(int method, int physical, int sigma2_method,
                                     long slope_window)
{
    if (!(method == 0 || method == 2) || !(physical == 0 || physical == 1)
            || !(sigma2_method == 0 || sigma2_method == 1))
        return RC_NOT_COVERED;
    if (method == 2 && slope_window < 2)
        return RC_NO_SLOPE_WINDOW;
    return NULL;
}

void rc_estimator_free(rc_estimator *e)
{
    rc_ident_free(&e->ident);
    slope_free(e->slope);
    e->slope = NULL;
}

void rc_project_physical(double *th, const double *cov)
{
    static const int comps[2] = {1, 3};               /* identification.PHYSICAL */
    if (!(th[1] < 0.0 || th[3] < 0.0))
        return;
    double C[16], best[4], best_cost = INFINITY;
    int has_best = 0;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            C[4 * i + j] = 0.5 * (cov[4 * i + j] + cov[4 * j + i]);
    for (int mask = 1; mask < 4; mask++) {
        int active[2] = {0, 0}, k = 0;            /* mask >= 1: k >= 1 (for -Wmaybe-uninitialized) */
        for (int j = 0; j < 2; j++)
            if (mask >> j & 1)
                active[k++] = comps[j];
        double A[4], b[2], lam[2], t[4];
        for (int a = 0; a < k; a++) {
            for (int c = 0; c < k; c++)
                A[k * a + c] = C[4 * active[a] + active[c]];
            b[a] = th[active[a]];
        }
        if (rc_la_solve(A, b, k, lam))                /* minus half the KKT multipliers */
            continue;
        for (int i = 0; i < 4; i++) {
            double s = C[4 * i + active[0]] * lam[0];
            for (int j = 1; j < k; j++)
                s += C[4 * i + active[j]] * lam[j];
            t[i] = th[i] - s;
        }
        for (int a = 0; a < k; a++)
            t[active[a]] = 0.0;
        int refused = 0;                              /* multipliers >= 0, feasible */
        for (int j = 0; j < k; j++)
            refused |= lam[j] > 1e-12;
        for (int j = 0; j < 2; j++)
            refused |= t[comps[j]] < -1e-12;
        if (refused)
            continue;
        double cost = th[active[0]] * lam[0];
        for (int j = 1; j < k; j++)
            cost += th[active[j]] * lam[j];
        if (cost < best_cost) {
            memcpy(best, t, sizeof best);
            best_cost = cost;
            has_best = 1;
        }
    }
    if (!has_best) {                                  /* a singular cov: clip */
        for (int j = 0; j < 2; j++)
            if (th[comps[j]] < 0.0)
                th[comps[j]] = 0.0;
        return;
    }
    memcpy(th, best, sizeof best);
}

/* OnlineEstimator.theta for methods 0 and 2: the identifier's, projected with est.physical */
static void reported_theta(rc_estimator *e, double *theta)
{
    memcpy(theta, e->ident.theta, 4 * sizeof(double));
    if (e->physical && (theta[1] < 0.0 || theta[3] < 0.0))
        rc_project_physical(theta, rc_ident_covariance(&e->ident));
}

/* OnlineEstimator.model_theta for methods 0 and 2: the identifier's, projected with est.physical */
static void model_theta(rc_estimator *e, double *theta)
{
    rc_ident_model_theta(&e->ident, theta);
    if (e->physical && (theta[1] < 0.0 || theta[3] < 0.0))
        rc_project_physical(theta, rc_ident_model_covariance(&e->ident));
}

/* OnlineEstimator.sigma2: the noise model's */
static double sigma2(rc_estimator *e)
{
    return e->likelihood_noise ? e->bank.estimate : rc_ident_sigma2(&e->ident);
}

/* OnlineEstimator.process_noise */
static double process_noise(rc_estimator *e, double traction, double brake, double dt)
{
    double v = rc_filter_speed(&e->filter);
    double k = RC_G * dt / 1000.0 / (1.0 + e->gamma);
    double phi[4] = {traction - brake, -1.0, -v, -v * v};
    double var = rc_ident_model_variance_along(&e->ident, phi);
    return sigma2(e) * dt / e->dt_nominal + k * k * var;
}

/* OnlineEstimator._excited */
static int excited(rc_estimator *e, double dt)
{
    double net = e->force_traction - e->force_brake;
    e->net_force += dt / (FORCE_SMOOTHING + dt) * (net - e->net_force);
    double v = rc_filter_speed(&e->filter);
    if (!e->station.moving || fabs(v - e->steady_speed) > STEADY_SPEED
            || fabs(e->net_force - e->steady_force) > e->force_band) {
        e->steady_speed = v;
        e->steady_force = e->net_force;
        e->steady_time = 0.0;
        return 1;
    }
    e->steady_time += dt;
    return e->steady_time <= STEADY_TIME;
}

/* OnlineEstimator.restart_filter */
static void restart_filter(rc_estimator *e, double speed_meas, double position_meas)
{
    double theta[4];
    int use_v, use_x;
    rc_filter_restart(&e->filter);
    double traction = e->force_traction, brake = e->force_brake;
    model_theta(e, theta);
    double q = process_noise(e, traction, brake, e->dt);
    rc_filter_predict(&e->filter, traction, brake, theta, q, e->dt);
    rc_filter_gate(&e->filter, speed_meas, position_meas, &use_v, &use_x);
    rc_filter_update(&e->filter, speed_meas, position_meas);
}

void rc_estimator_measure(rc_estimator *e, double speed_meas, double position_meas)
{
    double dt = e->dt;
    int moving_before = e->station.moving;
    int stop = station_observe(&e->station, speed_meas, position_meas, dt);
    int use_v, use_x, fit;
    if (stop || !e->has_prev) {
        use_v = use_x = fit = 1;
    } else {
        rc_filter_gate(&e->filter, speed_meas, position_meas, &use_v, &use_x);
        fit = e->filter.speed_fit;
    }
    if (!e->has_prev && !(fabs(speed_meas) < e->station.v_thr
                          && fabs(position_meas) < e->station.x_thr)) {
        rc_filter_start_from_measurement(&e->filter, speed_meas, position_meas);
        e->has_prev = 1;
        e->prev_speed = speed_meas;
        e->prev_position = position_meas;
        return;
    }
    int exc = excited(e, dt);
    int used = e->has_prev && fit && e->prev_fit && exc && moving_before && e->station.moving
               && position_meas >= e->prev_position - 10.0 * e->filter.cfg.position_std - 1.0;
    if (used) {
        double grade = rc_grade_average(e->grade, e->prev_position, e->length);
        if (e->slope)
            slope_identify(e, e->force_traction, e->force_brake, e->prev_speed, speed_meas, grade,
                           dt, e->pair_used);
        else
            rc_ident_update(&e->ident, e->force_traction, e->force_brake, e->prev_speed,
                            speed_meas, grade, dt, e->pair_used);
    }
    e->pair_used = used;
    /* a refused distance would pick the next pair's grade: its prediction stands in */
    e->has_prev = 1;
    e->prev_speed = speed_meas;
    e->prev_position = use_x ? position_meas : rc_filter_predicted_position(&e->filter);
    e->prev_fit = fit;
    if (e->likelihood_noise) {            /* LikelihoodNoise.observe */
        if (!e->station.moving)
            e->bank.started = 0;
        else if (use_v)
            bank_update(&e->bank, speed_meas);
    }
    if (stop) {
        e->station_stops += 1;
        rc_ident_restart_mass(&e->ident);
        restart_filter(e, speed_meas, position_meas);
    } else {
        rc_filter_update(&e->filter, speed_meas, position_meas);
    }
}

void rc_estimator_propagate(rc_estimator *e, double traction, double brake, double dt)
{
    double theta[4];
    model_theta(e, theta);
    double q = process_noise(e, traction, brake, dt);
    double before = rc_filter_speed(&e->filter);
    rc_filter_predict(&e->filter, traction, brake, theta, q, dt);
    if (e->station.fast_run == 0 && traction <= 0.0)   /* holding: StationDetector.standing */
        rc_filter_cap_predicted_speed(&e->filter, before, dt);
    if (e->likelihood_noise && e->station.moving)      /* LikelihoodNoise.predicted */
        bank_predict(&e->bank, rc_filter_predicted_speed(&e->filter) - before,
                     q - sigma2(e) * dt / e->dt_nominal);
    e->force_traction = traction;
    e->force_brake = brake;
    e->dt = dt;
}

void rc_estimator_measure_track_speed(rc_estimator *e, double speed_meas, double age,
                                      double speed_std, double base)
{
    if (!(isfinite(speed_meas) && speed_meas > 0.0 && age >= 0.0))
        return;
    age += 0.5 * base / speed_meas;
    double accel;
    if (!rc_filter_acceleration(&e->filter, &accel)) {   /* the Singer filter's own, else: */
        double th[4];
        rc_ident_model_theta(&e->ident, th);
        double traction = e->force_traction, brake = e->force_brake;
        double v = rc_filter_speed(&e->filter);
        accel = RC_G / 1000.0 / (1.0 + e->gamma) * (
            th[0] * (traction - brake) - th[1] - th[2] * v - th[3] * v * v
            - rc_grade_average(e->grade, rc_filter_position(&e->filter), e->length));
    }
    double var = rc_sq(speed_std) + rc_sq(ACCEL_STD * age);
    rc_filter_update_speed(&e->filter, rc_max(speed_meas + accel * age, 0.0), var);
    e->track_speeds += 1;
}

void rc_estimator_raw_outputs(rc_estimator *e, int predicted, double *out)
{
    const rc_filter *f = &e->filter;
    double th[4], sd[4];
    reported_theta(e, th);
    rc_ident_stds(&e->ident, sd);
    out[0] = rc_ident_mass(&e->ident);
    out[1] = rc_ident_mass_std(&e->ident);
    out[2] = th[1];
    out[3] = th[2];
    out[4] = th[3];
    out[5] = sd[1];
    out[6] = sd[2];
    out[7] = sd[3];
    out[8] = sigma2(e);
    out[9] = (double)rc_ident_samples(&e->ident);
    out[10] = (double)e->station_stops;
    if (predicted) {
        out[11] = rc_filter_predicted_speed(f);
        out[12] = rc_filter_predicted_position(f);
        out[13] = rc_filter_predicted_speed_std(f);
        out[14] = rc_filter_predicted_position_std(f);
    } else {
        out[11] = rc_filter_speed(f);
        out[12] = rc_filter_position(f);
        out[13] = rc_filter_speed_std(f);
        out[14] = rc_filter_position_std(f);
    }
}

void rc_estimator_finish_outputs(rc_estimator *e, double *out, int n, int mass_index)
{
    double sum = 0.0;                    /* Python's sum(out.values()), finite or not */
    for (int k = 0; k < n; k++)
        sum += out[k];
    double *mass = &out[mass_index], *mass_std = &out[mass_index + 1];
    int status;
    if (e->mass_low <= *mass && *mass <= e->mass_high && isfinite(sum)) {
        status = e->pair_used ? RC_STATUS_IDENTIFYING
                 : rc_ident_samples(&e->ident) ? RC_STATUS_HOLDING : RC_STATUS_PRIOR;
        for (int k = 0; k < n; k++)
            e->last_good[k] = out[k];
        e->has_last_good = 1;
    } else {
        const double *good = e->has_last_good ? e->last_good : NULL;
        if (!(e->mass_low <= *mass && *mass <= e->mass_high && isfinite(*mass_std))) {
            *mass = good ? good[mass_index] : e->mass_initial;
            *mass_std = rc_max(good ? good[mass_index + 1] : 0.0, e->mass_std_initial);
        }
        for (int k = 0; k < n; k++)
            if (!isfinite(out[k]))
                out[k] = good ? good[k] : 0.0;
        status = RC_STATUS_DEGRADED;
    }
    out[n] = (double)status;
    out[n + 1] = (double)e->filter.rejected;
}

void rc_estimator_resistance_covariances(rc_estimator *e, double *out)
{
    static const int rows[RC_EST_COVARIANCES][2] = {{1, 2}, {1, 3}, {2, 3}};  /* A_COVARIANCES */
    const double *c = rc_ident_covariance(&e->ident);
    for (int k = 0; k < RC_EST_COVARIANCES; k++) {
        int i = rows[k][0], j = rows[k][1];
        double cij = c[4 * i + j];
        out[k] = c[5 * i] > 0.0 && c[5 * j] > 0.0 && isfinite(cij) ? cij : 0.0;
    }
}

void rc_estimator_outputs(rc_estimator *e, int predicted, double *out)
{
    rc_estimator_raw_outputs(e, predicted, out);
    rc_estimator_finish_outputs(e, out, RC_EST_RAW, 0);
    rc_estimator_resistance_covariances(e, out + RC_EST_RAW + 2);
}
