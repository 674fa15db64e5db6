/* ident.c -- see ident.h; the bodies of models/estimation/identification.py's ParameterIdentifier for
 * est.method 0, expression for expression (the Python line is quoted where it is not obvious). */
#include "rc_fp_contract.h"
#include <stdlib.h>
#include <string.h>

#include "fpmath.h"
#include "ident.h"
#include "linalg4.h"

static void add_outer(double *M, const double *u)          /* plus_outer, in place */
{
    for (int i = 0; i < 4; i++) {
        double ui = u[i];
        int r = 4 * i;
        M[r] += ui * u[0];
        M[r + 1] += ui * u[1];
        M[r + 2] += ui * u[2];
        M[r + 3] += ui * u[3];
    }
}

double rc_ident_quadratic4(const double *c, const double *phi)     /* quadratic4 */
{
    double p0 = phi[0], p1 = phi[1], p2 = phi[2], p3 = phi[3];
    return (p0 * (c[0] * p0 + c[1] * p1 + c[2] * p2 + c[3] * p3)
            + p1 * (c[4] * p0 + c[5] * p1 + c[6] * p2 + c[7] * p3)
            + p2 * (c[8] * p0 + c[9] * p1 + c[10] * p2 + c[11] * p3)
            + p3 * (c[12] * p0 + c[13] * p1 + c[14] * p2 + c[15] * p3));
}

/* sandwich: Ji M Ji for symmetric flat 4x4 matrices */
static void sandwich4(const double *J, const double *M, double *c)
{
    double j00 = J[0], j01 = J[1], j02 = J[2], j03 = J[3], j11 = J[5], j12 = J[6], j13 = J[7];
    double j22 = J[10], j23 = J[11], j33 = J[15];
    double m00 = M[0], m01 = M[1], m02 = M[2], m03 = M[3], m11 = M[5], m12 = M[6], m13 = M[7];
    double m22 = M[10], m23 = M[11], m33 = M[15];
    double t00 = m00 * j00 + m01 * j01 + m02 * j02 + m03 * j03;
    double t01 = m00 * j01 + m01 * j11 + m02 * j12 + m03 * j13;
    double t02 = m00 * j02 + m01 * j12 + m02 * j22 + m03 * j23;
    double t03 = m00 * j03 + m01 * j13 + m02 * j23 + m03 * j33;
    double t10 = m01 * j00 + m11 * j01 + m12 * j02 + m13 * j03;
    double t11 = m01 * j01 + m11 * j11 + m12 * j12 + m13 * j13;
    double t12 = m01 * j02 + m11 * j12 + m12 * j22 + m13 * j23;
    double t13 = m01 * j03 + m11 * j13 + m12 * j23 + m13 * j33;
    double t20 = m02 * j00 + m12 * j01 + m22 * j02 + m23 * j03;
    double t21 = m02 * j01 + m12 * j11 + m22 * j12 + m23 * j13;
    double t22 = m02 * j02 + m12 * j12 + m22 * j22 + m23 * j23;
    double t23 = m02 * j03 + m12 * j13 + m22 * j23 + m23 * j33;
    double t30 = m03 * j00 + m13 * j01 + m23 * j02 + m33 * j03;
    double t31 = m03 * j01 + m13 * j11 + m23 * j12 + m33 * j13;
    double t32 = m03 * j02 + m13 * j12 + m23 * j22 + m33 * j23;
    double t33 = m03 * j03 + m13 * j13 + m23 * j23 + m33 * j33;
    double c00 = j00 * t00 + j01 * t10 + j02 * t20 + j03 * t30;
    double c01 = j00 * t01 + j01 * t11 + j02 * t21 + j03 * t31;
    double c02 = j00 * t02 + j01 * t12 + j02 * t22 + j03 * t32;
    double c03 = j00 * t03 + j01 * t13 + j02 * t23 + j03 * t33;
    double c11 = j01 * t01 + j11 * t11 + j12 * t21 + j13 * t31;
    double c12 = j01 * t02 + j11 * t12 + j12 * t22 + j13 * t32;
    double c13 = j01 * t03 + j11 * t13 + j12 * t23 + j13 * t33;
    double c22 = j02 * t02 + j12 * t12 + j22 * t22 + j23 * t32;
    double c23 = j02 * t03 + j12 * t13 + j22 * t23 + j23 * t33;
    double c33 = j03 * t03 + j13 * t13 + j23 * t23 + j33 * t33;
    double out[16] = {c00, c01, c02, c03, c01, c11, c12, c13, c02, c12, c22, c23, c03, c13, c23, c33};
    memcpy(c, out, sizeof out);
}

int rc_ident_init(rc_ident *id, const rc_ident_config *cfg)
{
    return rc_ident_init_rows(id, cfg, 0);
}

int rc_ident_init_rows(rc_ident *id, const rc_ident_config *cfg, long slope_window)
{
    memset(id, 0, sizeof *id);
    memcpy(&id->cfg, cfg, sizeof id->cfg);         /* padding too: a state holds the bytes */
    long nb = cfg->batch_size;
    /* zeroed: a state saves the batch whole, before it has filled too */
    id->batch_phi = calloc((size_t)nb * 4, sizeof(double));
    id->batch_y = calloc((size_t)nb, sizeof(double));
    id->batch_contiguous = calloc((size_t)nb, sizeof(int));
    if (!id->batch_phi || !id->batch_y || !id->batch_contiguous) {
        rc_ident_free(id);
        return -1;
    }
    id->end_factor = 2.0;                                  /* the paper's differenced rows */
    id->slope_rows = slope_window != 0;
    if (id->slope_rows) {          /* 2 sum c_j^2 of centred_slope_weights([dt] * (window - 1)) */
        long m = slope_window - 1;
        double *buf = calloc((size_t)(3 * m + 1), sizeof(double));
        if (!buf) {
            rc_ident_free(id);
            return -1;
        }
        double *dts = buf, *w = buf + m, *c = buf + 2 * m + 1;
        for (long j = 0; j < m; j++)
            dts[j] = cfg->dt;
        rc_centred_slope_weights(dts, m, w, c);
        id->n_k = m + 1;
        for (long j = 0; j <= m; j++)
            id->slope_k[j] = w[j] * cfg->dt;
        double sum = 0.0;
        for (long j = 0; j < m; j++)
            sum += c[j] * c[j];
        id->end_factor = 2.0 * sum;
        free(buf);
    }
    id->end_weight = sqrt(0.5 * id->end_factor);
    id->drift_var[0] = cfg->A0_drift_std * cfg->A0_drift_std;
    id->drift_var[1] = cfg->A1_drift_std * cfg->A1_drift_std;
    id->drift = cfg->A0_drift_std > 0.0 || cfg->A1_drift_std > 0.0;
    id->theta0[0] = 1.0 / (RC_G * cfg->mass_initial);      /* theta_from_params */
    id->theta0[1] = cfg->A0_initial;
    id->theta0[2] = cfg->A1_initial;
    id->theta0[3] = cfg->A2_initial;
    id->scale = 1000.0 * (1.0 + cfg->gamma) / (RC_G * cfg->dt);
    id->s2_ref = rc_sq(id->scale) * rc_max(2.0 * rc_sq(cfg->speed_std) + cfg->sigma2_initial, 1e-12);
    double theta1_std = cfg->mass_std_initial / (RC_G * rc_sq(cfg->mass_initial));
    double prior_std[4] = {theta1_std, cfg->A0_std_initial, cfg->A1_std_initial, cfg->A2_std_initial};
    for (int i = 0; i < 4; i++)
        id->s2_prior[i] = id->s2_ref;
    id->s2_prior[0] = rc_sq(id->scale) * rc_max(cfg->sigma2_initial, 1e-12);
    if (id->slope_rows)                    /* the A's prior takes the process-noise weight too */
        for (int i = 1; i < 4; i++)
            id->s2_prior[i] = id->s2_prior[0];
    for (int i = 0; i < 4; i++)            /* s2p / prior_std ** 2: numpy squares by x * x */
        id->j0[i] = id->s2_prior[i] / (prior_std[i] * prior_std[i]);
    rc_ident_reset(id);
    return 0;
}

void rc_ident_free(rc_ident *id)
{
    free(id->batch_phi);
    free(id->batch_y);
    free(id->batch_contiguous);
    id->batch_phi = NULL;
    id->batch_y = NULL;
    id->batch_contiguous = NULL;
}

void rc_ident_reset(rc_ident *id)
{
    memcpy(id->theta, id->theta0, sizeof id->theta);
    memcpy(id->prior_mean, id->theta, sizeof id->theta);
    id->has_running = 0;
    memset(id->running_theta, 0, sizeof id->running_theta);
    memset(id->batch_info_inv, 0, sizeof id->batch_info_inv);
    memset(id->batch_j0, 0, sizeof id->batch_j0);
    memset(id->batch_s2p, 0, sizeof id->batch_s2p);
    id->has_model_cov = 0;
    id->has_S = 0;
    memset(id->S, 0, sizeof id->S);
    id->n = 0;
    id->q_e = 0.0;
    id->s2 = id->s2_ref;
    id->batch_len = 0;
    id->mass_restarts = 0;
    id->repairs = 0;
    memset(id->W, 0, sizeof id->W);
    memset(id->D, 0, sizeof id->D);
    memset(id->Dq, 0, sizeof id->Dq);
    id->has_last_phi = 0;
    memset(id->last_phi, 0, sizeof id->last_phi);
    id->rows_len = 0;
    id->rows_next = 0;
    id->row_scale = 1.0;
    id->last_scale = 1.0;
    id->has_last_err = 0;
    id->last_err = 0.0;
    id->c0 = id->s2_ref;
    id->c1 = 0.0;
    id->n_c1 = 0;
    id->window_len = 0;
    id->window_start = 0;
    id->window_sum = 0.0;
    id->has_cL = 0;
    id->cL = 0.0;
    id->n_cL = 0;
    id->cL_count = 0.0;
    id->speed_var = 0.0;
    id->n_speed_var = 0;
    id->has_cov = 0;
    id->has_sigma2 = 0;
    id->has_J = 0;
    memset(id->J, 0, sizeof id->J);
}

void rc_ident_set_theta(rc_ident *id, const double *theta)
{
    memcpy(id->theta, theta, sizeof id->theta);
    if (!id->has_S && id->batch_len == 0)
        memcpy(id->prior_mean, id->theta, sizeof id->theta);
    id->has_cov = 0;
}

/* end_row: phi times _end_weight (phi itself for weight 1) */
static void end_row(const rc_ident *id, const double *phi, double *out)
{
    double e = id->end_weight;
    for (int i = 0; i < 4; i++)
        out[i] = e == 1.0 ? phi[i] : e * phi[i];
}

/* slope_noise_weight: g = sum_i k[i] row(newest - i), i < min(rows_len, nk) */
static void slope_noise_weight(const rc_ident *id, const double *k, long nk, double *g)
{
    long n = id->rows_len < nk ? id->rows_len : nk;
    g[0] = g[1] = g[2] = g[3] = 0.0;
    for (long i = 0; i < n; i++) {
        long at = ((id->rows_next - 1 - i) % id->n_k + id->n_k) % id->n_k;
        const double *r = id->rows + 4 * at;
        double w = k[i];
        g[0] += w * r[0];
        g[1] += w * r[1];
        g[2] += w * r[2];
        g[3] += w * r[3];
    }
}

/* slope_end_terms: M plus the terms of the samples after the newest row, times scale */
static void slope_end_terms(const rc_ident *id, double *M, double scale)
{
    double g[4];
    for (long d = 1; d < id->n_k; d++) {
        slope_noise_weight(id, id->slope_k + d, id->n_k - d, g);
        double u[4] = {scale * g[0], scale * g[1], scale * g[2], scale * g[3]};
        add_outer(M, u);
    }
}

/* forget_meats: W and D weighted by lam^2 before one more row */
static void forget_meats(double *W, double *D, double lam)
{
    if (lam < 1.0) {
        double l2 = lam * lam;
        for (int i = 0; i < 16; i++) {
            W[i] *= l2;
            D[i] *= l2;
        }
    }
}

/* _accumulate_slope: est.method 2's D (accumulate does the rest) */
static void accumulate_slope(rc_ident *id, const double *phi, int contiguous)
{
    double *D = id->D, g[4];
    if (!contiguous && id->rows_len) {
        slope_end_terms(id, D, id->last_scale);         /* close the previous run */
        id->rows_len = 0;
    }
    memcpy(id->rows + 4 * id->rows_next, phi, 4 * sizeof(double));   /* rows.append; pop(0) */
    id->rows_next = (id->rows_next + 1) % id->n_k;
    if (id->rows_len < id->n_k)
        id->rows_len += 1;
    double s = id->row_scale;
    slope_noise_weight(id, id->slope_k, id->n_k, g);
    double u[4] = {s * g[0], s * g[1], s * g[2], s * g[3]};
    add_outer(D, u);
}

/* accumulate_meats (est.method 0) or _accumulate_slope (2), then the row's W and the open run */
static void accumulate(rc_ident *id, const double *phi, int contiguous, double lam)
{
    double *D = id->D, u[4];
    if (id->drift && lam < 1.0) {                      /* the drift meat forgets with them */
        double l2 = lam * lam;
        for (int i = 0; i < 16; i++)
            id->Dq[i] *= l2;
    }
    forget_meats(id->W, D, lam);
    if (id->slope_rows)
        accumulate_slope(id, phi, contiguous);
    else if (contiguous && id->has_last_phi) {
        const double *last = id->last_phi;
        double d[4] = {phi[0] - last[0], phi[1] - last[1], phi[2] - last[2], phi[3] - last[3]};
        add_outer(D, d);
    } else {
        if (id->has_last_phi) {
            end_row(id, id->last_phi, u);              /* close the previous run */
            add_outer(D, u);
        }
        end_row(id, phi, u);                           /* open a new one */
        add_outer(D, u);
    }
    add_outer(id->W, phi);
    memcpy(id->last_phi, phi, sizeof id->last_phi);
    id->has_last_phi = 1;
    id->last_scale = id->row_scale;
}

static void residual_stats(rc_ident *id, double err, int contiguous, double mu)
{
    if (!contiguous) {
        id->window_len = 0;
        id->window_start = 0;
        id->window_sum = 0.0;
    }
    if (id->window_len < RC_LAG) {                     /* w.append(err) */
        id->window[(id->window_start + id->window_len) % RC_LAG] = err;
        id->window_len += 1;
        id->window_sum += err;
    } else {                                           /* ... and w.pop(0) */
        double first = id->window[id->window_start];
        id->window[id->window_start] = err;
        id->window_start = (id->window_start + 1) % RC_LAG;
        id->window_sum += err;
        id->window_sum -= first;
    }
    if (id->window_len == RC_LAG) {
        id->n_cL += 1;
        id->cL_count += 1.0;
        double sq = id->window_sum * id->window_sum;
        if (!id->has_cL)
            id->cL = sq;
        else if (id->cfg.forgetting > 0.0)             /* forgets as c0 and c1 do */
            id->cL += mu * (sq - id->cL);
        else
            id->cL = id->cL + (sq - id->cL) / id->cL_count;
        id->has_cL = 1;
    }
    id->c0 += mu * (err * err - id->c0);
    if (contiguous && id->has_last_err) {
        id->n_c1 += 1;
        double w = id->cfg.forgetting > 0.0 ? mu : 1.0 / (double)id->n_c1;
        id->c1 += w * (err * id->last_err - id->c1);
    }
    id->last_err = err;
    id->has_last_err = 1;
}

/* _configured_noise: (a, b) */
static void configured_noise(const rc_ident *id, double *a, double *b)
{
    double var = id->n_speed_var ? id->speed_var : rc_sq(id->cfg.speed_std);
    *a = rc_sq(id->scale) * var;
    *b = rc_sq(id->scale) * rc_max(id->cfg.sigma2_initial, 1e-12);
}

static double n_info(const rc_ident *id)
{
    double mu0 = id->cfg.forgetting;
    return mu0 > 0.0 ? 1.0 / mu0 : (double)(id->n > 1 ? id->n : 1);
}

/* Phi^T Phi + diag(j0) and Phi^T Y + j0 * prior_mean of the batch so far */
static void batch_normal_equations(const rc_ident *id, const double *j0, double *info, double *rhs)
{
    double pty[4];
    rc_la_gram(id->batch_phi, id->batch_len, 4, info);
    for (int i = 0; i < 4; i++)
        info[5 * i] += j0[i];
    rc_la_gram_t_vec(id->batch_phi, id->batch_y, id->batch_len, 4, pty);
    for (int i = 0; i < 4; i++)
        rhs[i] = pty[i] + j0[i] * id->prior_mean[i];
}

static int running_estimate(rc_ident *id)
{
    long n = id->batch_len;
    double a, b, s2p[4], j0[4], info[16], rhs[4];
    int st = RC_OK;
    configured_noise(id, &a, &b);
    memcpy(s2p, id->s2_prior, sizeof s2p);
    memcpy(j0, id->j0, sizeof j0);
    double prior_var0 = s2p[0] / j0[0];
    s2p[0] = b + id->end_factor * a / (double)n;
    j0[0] = s2p[0] / prior_var0;
    batch_normal_equations(id, j0, info, rhs);
    if (rc_la_solve(info, rhs, 4, id->running_theta))
        st = RC_MATH;
    id->has_running = 1;
    if (rc_la_inverse(info, 4, id->batch_info_inv))
        st = RC_MATH;
    memcpy(id->batch_j0, j0, sizeof j0);
    memcpy(id->batch_s2p, s2p, sizeof s2p);
    return st;
}

static int solve_batch(rc_ident *id)
{
    long n = id->batch_len;
    double info[16], rhs[4], scaled[16];
    int st = RC_OK;
    batch_normal_equations(id, id->j0, info, rhs);
    if (rc_la_solve(info, rhs, 4, id->theta))
        st = RC_MATH;
    for (int i = 0; i < 16; i++)
        scaled[i] = info[i] / (double)n;
    if (rc_la_inverse(scaled, 4, id->S))
        st = RC_MATH;
    id->has_S = 1;
    if (id->cfg.forgetting > 0.0) {
        memcpy(id->J, info, sizeof info);
        id->has_J = 1;
    }
    double q_e = 0.0, lagged_sum = 0.0, prev = 0.0, r = 0.0;
    long n_lagged = 0;
    for (long k = 0; k < n; k++) {                 /* resid = y - phi theta, in row order */
        r = id->batch_y[k] - rc_la_dot(id->batch_phi + 4 * k, id->theta, 4);
        q_e += r * r;
        if (k >= 1 && id->batch_contiguous[k]) {
            lagged_sum += r * prev;                /* resid[k] * resid[k - 1] */
            n_lagged += 1;
        }
        prev = r;
    }
    id->q_e = q_e;
    id->s2 = n > 4 ? id->q_e / (double)(n - 4) : id->s2_ref;
    id->has_running = 0;
    id->has_model_cov = 0;
    id->c0 = id->q_e / (double)(n - 4 > 1 ? n - 4 : 1);
    id->n_c1 = n_lagged;
    id->c1 = n_lagged ? lagged_sum / (double)n_lagged : 0.0;
    id->last_err = r;
    id->has_last_err = 1;
    id->n = n;
    id->batch_len = 0;
    return st;
}

static int restore_positive_definite(rc_ident *id)
{
    double R[16], Rs[16], w[4], V[16];
    int st = rc_la_inverse(id->S, 4, R) ? RC_MATH : RC_OK;
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            Rs[4 * i + j] = 0.5 * (R[4 * i + j] + R[4 * j + i]);
    rc_la_eigh(Rs, 4, w, V);
    double jmin = id->j0[0];                       /* min(self._j0) */
    for (int i = 1; i < 4; i++)
        jmin = rc_min(jmin, id->j0[i]);
    double floor_ = jmin / n_info(id);
    for (int i = 0; i < 4; i++)
        w[i] = rc_max(w[i], floor_);
    rc_la_inverse_from_eigen(w, V, 4, id->S);
    id->repairs += 1;
    id->has_cov = 0;
    id->has_sigma2 = 0;
    id->has_model_cov = 0;
    return st;
}

int rc_ident_update(rc_ident *id, double traction, double brake, double speed, double speed_next,
                    double grade, double dt, int contiguous)
{
    int st = RC_OK;
    if (id->cfg.frozen)
        return RC_OK;
    if (id->cfg.speed_std_rel > 0.0) {
        id->n_speed_var += 1;
        double var = rc_sq(id->cfg.speed_std + id->cfg.speed_std_rel * fabs(speed));
        id->speed_var += (var - id->speed_var) / (double)id->n_speed_var;
    }
    if (id->slope_rows)
        id->row_scale = id->scale * (id->cfg.speed_std + id->cfg.speed_std_rel * fabs(speed));
    double phi[4] = {traction - brake, -1.0, -speed, -speed * speed};                 /* (4) */
    double dtu = dt != 0.0 ? dt : id->cfg.dt;
    double y = 1000.0 * (1.0 + id->cfg.gamma) * (speed_next - speed) / (RC_G * dtu) + grade;
    id->has_cov = 0;
    id->has_sigma2 = 0;
    id->has_model_cov = 0;
    if (!id->has_S) {
        long k = id->batch_len;
        memcpy(id->batch_phi + 4 * k, phi, sizeof phi);
        id->batch_y[k] = y;
        id->batch_contiguous[k] = contiguous != 0;
        id->batch_len = k + 1;
        accumulate(id, phi, contiguous, 1.0);
        if (id->batch_len >= id->cfg.batch_size)
            return solve_batch(id);
        return running_estimate(id);
    }
    long n = id->n + 1;
    double forgetting = id->cfg.forgetting;
    double mu = forgetting > 0.0 ? forgetting : 1.0 / (double)n;
    double *S = id->S, *th = id->theta;
    double p0 = phi[0], p1 = phi[1], p2 = phi[2], p3 = phi[3];
    double Sp[4] = {S[0] * p0 + S[1] * p1 + S[2] * p2 + S[3] * p3,
                    S[4] * p0 + S[5] * p1 + S[6] * p2 + S[7] * p3,
                    S[8] * p0 + S[9] * p1 + S[10] * p2 + S[11] * p3,
                    S[12] * p0 + S[13] * p1 + S[14] * p2 + S[15] * p3};
    double pSp = p0 * Sp[0] + p1 * Sp[1] + p2 * Sp[2] + p3 * Sp[3];
    if (!(pSp > 0.0)) {                      /* S is no longer positive definite (rounding) */
        st = restore_positive_definite(id);
        Sp[0] = S[0] * p0 + S[1] * p1 + S[2] * p2 + S[3] * p3;
        Sp[1] = S[4] * p0 + S[5] * p1 + S[6] * p2 + S[7] * p3;
        Sp[2] = S[8] * p0 + S[9] * p1 + S[10] * p2 + S[11] * p3;
        Sp[3] = S[12] * p0 + S[13] * p1 + S[14] * p2 + S[15] * p3;
        pSp = p0 * Sp[0] + p1 * Sp[1] + p2 * Sp[2] + p3 * Sp[3];
    }
    double pred_err = y - (th[0] * p0 + th[1] * p1 + th[2] * p2 + th[3] * p3);
    double g = mu * pred_err / (1.0 + mu * (pSp - 1.0));                                /* (8), (9) */
    double th_new[4] = {th[0] + g * Sp[0], th[1] + g * Sp[1], th[2] + g * Sp[2], th[3] + g * Sp[3]};
    memcpy(id->theta, th_new, sizeof th_new);
    double c = 1.0 / ((1.0 - mu) / mu + pSp);                                            /* (11) */
    double inv = 1.0 / (1.0 - mu);
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            S[4 * i + j] = (S[4 * i + j] - Sp[i] * Sp[j] * c) * inv;
    double gain_den = 1.0 + mu / (1.0 - mu) * pSp;
    accumulate(id, phi, contiguous, 1.0 - forgetting);
    residual_stats(id, pred_err / sqrt(gain_den), contiguous, mu);   /* NaN where Python raises */
    if (forgetting > 0.0) {
        /* regularised forgetting: keep the prior's information (anti-windup) */
        double lam = 1.0 - forgetting, R[16];
        double *J = id->J;
        for (int i = 0; i < 4; i++)
            for (int j = 0; j < 4; j++) {
                double d = i == j ? id->j0[i] : 0.0;
                J[4 * i + j] = lam * (J[4 * i + j] - d) + d + phi[i] * phi[j];
            }
        if (rc_la_inverse(S, 4, R))
            st = RC_MATH;
        for (int i = 0; i < 4; i++)
            R[5 * i] += mu * mu * id->j0[i];
        if (rc_la_inverse(R, 4, S))
            st = RC_MATH;
        id->s2 = (1.0 - mu) * id->s2 + mu * rc_sq(pred_err) / gain_den;
    } else {
        id->q_e += rc_sq(pred_err) / gain_den;
        id->s2 = n > 4 ? id->q_e / (double)(n - 4) : id->s2_ref;
    }
    id->n = n;
    return st;
}

/* marginalise_mass, in place on a flat 4x4 information matrix */
static void marginalise_mass(double *R, double lam, const double *j0)
{
    double r00 = R[0];
    for (int i = 1; i < 4; i++)
        for (int j = 1; j < 4; j++)
            R[4 * i + j] -= R[4 * i] * R[j] / r00;
    if (lam < 1.0)
        for (int i = 1; i < 4; i++)
            for (int j = 1; j < 4; j++) {
                double d = i == j ? j0[i] : 0.0;
                R[4 * i + j] = lam * (R[4 * i + j] - d) + d;
            }
    for (int k = 1; k < 4; k++) {
        R[k] = 0.0;
        R[4 * k] = 0.0;
    }
    R[0] = j0[0];
}

static double process_share(const rc_ident *id, double a, double b);

/* drift_meat: M plus Jc diag(drift_var) Jc in its A block, Jc = info's A block symmetrised,
 * times info_scale, less the prior's j0 */
static void drift_meat(double *M, const double *info, double info_scale, const double *j0,
                       const double *drift_var)
{
    double Jc[9];
    for (int i = 1; i < 4; i++)
        for (int j = 1; j < 4; j++) {
            double d = i == j ? j0[i] : 0.0;
            Jc[3 * (i - 1) + j - 1] = 0.5 * (info[4 * i + j] + info[4 * j + i]) * info_scale - d;
        }
    double v0 = drift_var[0], v1 = drift_var[1];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            M[4 * (i + 1) + j + 1] += (Jc[3 * i] * Jc[3 * j]) * v0 + (Jc[3 * i + 1] * Jc[3 * j + 1]) * v1;
}

/* _reweight_prior (est.method 2, at a mass restart): the prior's weight follows the identified
 * process noise once the LAG sums exist; J and Theta-hat move with it */
static int reweight_prior(rc_ident *id)
{
    if (!(id->has_cL && id->n_cL >= RC_LAG))
        return RC_OK;
    double a, b, j0_new[4], d[4] = {0.0, 0.0, 0.0, 0.0};
    rc_ident_noise_split(id, &a, &b);
    double s2_new = rc_max(process_share(id, a, b), 1e-12);
    for (int i = 0; i < 4; i++) {
        double prior_var = id->s2_prior[i] / id->j0[i];  /* prior_std^2, as configured */
        j0_new[i] = s2_new / prior_var;
    }
    for (int i = 1; i < 4; i++)                           /* the mass: restart_mass */
        d[i] = j0_new[i] - id->j0[i];
    double n = n_info(id), J[16], J_new[16], Jt[4], rhs[4];
    int st = rc_la_inverse(id->S, 4, J) ? RC_MATH : RC_OK;
    for (int k = 0; k < 16; k++)
        J[k] *= n;
    memcpy(J_new, J, sizeof J);
    for (int i = 1; i < 4; i++)
        J_new[5 * i] += d[i];
    rc_la_matvec(J, id->theta, 4, Jt);
    for (int i = 0; i < 4; i++)
        rhs[i] = Jt[i] + d[i] * id->prior_mean[i];
    if (rc_la_solve(J_new, rhs, 4, id->theta))
        st = RC_MATH;
    for (int k = 0; k < 16; k++)
        J_new[k] /= n;
    if (rc_la_inverse(J_new, 4, id->S))
        st = RC_MATH;
    if (id->has_J)
        for (int i = 1; i < 4; i++)
            id->J[5 * i] += d[i];
    for (int i = 0; i < 4; i++) {
        id->j0[i] = j0_new[i];
        id->s2_prior[i] = s2_new;
    }
    id->has_cov = 0;
    id->has_sigma2 = 0;
    return st;
}

int rc_ident_restart_mass(rc_ident *id)
{
    int st = RC_OK;
    double R[16], u[4], t[3], j0n[4];
    id->mass_restarts += 1;
    if (!id->has_S || id->cfg.frozen)
        return RC_OK;
    if (!rc_la_is_positive_definite(id->S, 4))
        st = restore_positive_definite(id);
    if (id->slope_rows && reweight_prior(id) != RC_OK)
        st = RC_MATH;
    if (rc_la_inverse(id->S, 4, R))
        st = RC_MATH;
    double lam = 1.0 - id->cfg.run_forgetting;
    if (id->slope_rows) {
        if (id->rows_len) {
            slope_end_terms(id, id->D, id->last_scale);
            id->rows_len = 0;
        }
    } else if (id->has_last_phi) {
        end_row(id, id->last_phi, u);
        add_outer(id->D, u);
    }
    for (int i = 1; i < 4; i++)
        t[i - 1] = R[4 * i] / R[0];
    id->cL_count *= lam;                               /* the LAG sums forget with the A's */
    double *meats[3] = {id->W, id->D, id->Dq};
    for (int m = 0; m < (id->drift ? 3 : 2); m++) {
        double *M = meats[m], M_AA[9];
        double m00 = M[0];
        for (int i = 1; i < 4; i++)
            for (int j = 1; j < 4; j++)
                M_AA[3 * (i - 1) + j - 1] = ((M[4 * i + j] - t[i - 1] * M[j]) - M[4 * i] * t[j - 1])
                                            + t[i - 1] * t[j - 1] * m00;
        for (int i = 0; i < 3; i++)
            for (int j = 0; j < 3; j++)
                M[4 * (i + 1) + j + 1] = 0.5 * (M_AA[3 * i + j] + M_AA[3 * j + i]) * lam;
        for (int k = 0; k < 4; k++) {
            M[k] = 0.0;
            M[4 * k] = 0.0;
        }
    }
    double ni = n_info(id);
    for (int i = 0; i < 4; i++)
        j0n[i] = id->j0[i] / ni;
    marginalise_mass(R, lam, j0n);
    if (rc_la_inverse(R, 4, id->S))
        st = RC_MATH;
    if (id->has_J)
        marginalise_mass(id->J, lam, id->j0);
    if (id->drift) {                   /* the carried A's drift: see identification.py */
        if (id->has_J)
            drift_meat(id->Dq, id->J, 1.0, id->j0, id->drift_var);
        else
            drift_meat(id->Dq, R, ni, id->j0, id->drift_var);
    }
    id->has_last_phi = 0;
    id->has_cov = 0;
    return st;
}

void rc_ident_model_theta(const rc_ident *id, double *out)
{
    if (id->has_running && !id->has_S && !id->cfg.frozen)
        memcpy(out, id->running_theta, 4 * sizeof(double));
    else
        memcpy(out, id->theta, 4 * sizeof(double));
}

void rc_ident_noise_split(const rc_ident *id, double *a, double *b)
{
    if (id->slope_rows) {          /* smoothed slopes: residuals correlated over the window */
        configured_noise(id, a, b);
        return;
    }
    *a = rc_max(-id->c1, 0.0);
    *b = rc_max(id->c0 - 2.0 * *a, 1e-12 * id->c0);
}

static double process_share(const rc_ident *id, double a, double b)
{
    if (id->has_cL && id->n_cL >= RC_LAG)
        return rc_max((id->cL - id->end_factor * a) / (double)RC_LAG, 1e-3 * id->c0 / (double)RC_LAG);
    return b;
}

/* _sandwich: J^-1 M J^-1 with M = a D + b W (+ the open run's end) + diag(s2) J0 */
static void sandwich(const rc_ident *id, const double *Ji, double a, double b, const double *j0,
                     const double *s2, double *out)
{
    double M[16];
    if (id->slope_rows) {                              /* D carries each sample's a */
        for (int i = 0; i < 16; i++)
            M[i] = 1.0 * id->D[i] + b * id->W[i];
        M[0] += s2[0] * j0[0];
        M[5] += s2[1] * j0[1];
        M[10] += s2[2] * j0[2];
        M[15] += s2[3] * j0[3];
        if (id->rows_len)
            slope_end_terms(id, M, id->last_scale);
        sandwich4(Ji, M, out);
        return;
    }
    for (int i = 0; i < 16; i++)
        M[i] = a * id->D[i] + b * id->W[i];
    if (id->has_last_phi) {                            /* the open run's end */
        double sa = sqrt(a) * id->end_weight;
        const double *l = id->last_phi;
        double u[4] = {sa * l[0], sa * l[1], sa * l[2], sa * l[3]};
        add_outer(M, u);
    }
    M[0] += s2[0] * j0[0];
    M[5] += s2[1] * j0[1];
    M[10] += s2[2] * j0[2];
    M[15] += s2[3] * j0[3];
    sandwich4(Ji, M, out);
}

const double *rc_ident_covariance(rc_ident *id)
{
    double a, b, Ji[16];
    if (id->has_cov)
        return id->cov;
    id->has_cov = 1;
    if (id->cfg.frozen) {
        memset(id->cov, 0, sizeof id->cov);
        return id->cov;
    }
    if (!id->has_S) {                                  /* before the batch: s2_prior J0^-1 */
        memset(id->cov, 0, sizeof id->cov);
        for (int i = 0; i < 4; i++)
            id->cov[5 * i] = id->s2_prior[i] / id->j0[i];
        return id->cov;
    }
    rc_ident_noise_split(id, &a, &b);
    b = process_share(id, a, b);
    if (id->has_J)                                     /* forgetting: J kept explicitly */
        rc_la_inverse(id->J, 4, Ji);
    else {                                             /* mu = 1/n: J^-1 = S / n */
        double k = 1.0 / n_info(id);
        for (int i = 0; i < 16; i++)
            Ji[i] = id->S[i] * k;
    }
    sandwich(id, Ji, a, b, id->j0, id->s2_prior, id->cov);
    if (id->drift) {                   /* drift_covariance: J^-1 symmetrised, then its sandwich */
        double Js[16], c[16];
        for (int i = 0; i < 4; i++)
            for (int j = 0; j < 4; j++)
                Js[4 * i + j] = 0.5 * (Ji[4 * i + j] + Ji[4 * j + i]);
        sandwich4(Js, id->Dq, c);
        for (int i = 0; i < 16; i++)
            id->cov[i] = id->cov[i] + c[i];
    }
    return id->cov;
}

const double *rc_ident_model_covariance(rc_ident *id)
{
    if (!id->has_running || id->has_S || id->cfg.frozen)
        return rc_ident_covariance(id);
    if (!id->has_model_cov) {
        double a, b;
        configured_noise(id, &a, &b);
        sandwich(id, id->batch_info_inv, a, b, id->batch_j0, id->batch_s2p, id->model_cov);
        id->has_model_cov = 1;
    }
    return id->model_cov;
}

double rc_ident_model_variance_along(rc_ident *id, const double *phi)
{
    return rc_ident_quadratic4(rc_ident_model_covariance(id), phi);
}

void rc_ident_stds(rc_ident *id, double *out)
{
    const double *c = rc_ident_covariance(id);
    for (int i = 0; i < 4; i++)
        out[i] = c[5 * i] > 0.0 ? sqrt(c[5 * i]) : 0.0;
}

double rc_ident_mass(const rc_ident *id)
{
    double th1 = id->theta[0];
    return th1 > 0 ? 1.0 / (RC_G * th1) : INFINITY;
}

double rc_ident_mass_std(rc_ident *id)
{
    double var = rc_ident_covariance(id)[0];
    return sqrt(rc_max(var, 0.0)) / (RC_G * rc_sq(id->theta[0]));
}

double rc_ident_sigma2(rc_ident *id)
{
    if (!id->has_S)
        return id->cfg.sigma2_initial;
    if (!id->has_sigma2) {
        double a, b, a_conf, b_conf;
        rc_ident_noise_split(id, &a, &b);
        if (!(id->has_cL && id->n_cL >= RC_LAG)) {
            configured_noise(id, &a_conf, &b_conf);
            b = b_conf;
        }
        double s2 = process_share(id, a, b);                    /* sigma2_from_residual */
        id->sigma2 = RC_G * RC_G * id->cfg.dt * id->cfg.dt / 1e6 * s2 / rc_sq(1.0 + id->cfg.gamma);
        id->has_sigma2 = 1;
    }
    return id->sigma2;
}

long rc_ident_samples(const rc_ident *id)
{
    return id->has_S ? id->n : id->batch_len;
}

void rc_centred_slope_weights(const double *dts, long n, double *w, double *c)
{
    double t = 0.0, sum = 0.0;     /* w holds the times t, then tau, then the weights */
    w[0] = t;
    for (long k = 0; k < n; k++)
        w[k + 1] = t = t + dts[k];
    for (long k = 0; k <= n; k++)
        sum += w[k];
    double mean = sum / (double)(n + 1);
    double ss = 0.0;
    for (long k = 0; k <= n; k++) {
        w[k] = w[k] - mean;
        ss += w[k] * w[k];
    }
    for (long k = 0; k <= n; k++)
        w[k] = w[k] / ss;
    double tail = 0.0;
    for (long j = n - 1; j >= 0; j--) {
        tail += w[j + 1];
        c[j] = dts[j] * tail;
    }
}
