/* ident_shim.c -- test-only flat functions around models/core/ident.c for ctypes
 * (tests/model_tests/core/test_core_ident.py). */
#include <stdlib.h>
#include <string.h>

#include "ident.h"
#include "linalg4.h"

/* c: dt, batch_size, forgetting, gamma, mass_initial, mass_std_initial, A0, A1, A2, A0_std,
 * A1_std, A2_std, sigma2_initial, speed_std, frozen, run_forgetting, speed_std_rel, A0_drift_std,
 * A1_drift_std */
rc_ident *shim_new(const double *c)
{
    rc_ident_config cfg = {c[0], (long)c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9],
                           c[10], c[11], c[12], c[13], (int)c[14], c[15], c[16], c[17], c[18]};
    rc_ident *id = malloc(sizeof *id);
    if (!id)
        return NULL;
    if (rc_ident_init(id, &cfg)) {
        free(id);
        return NULL;
    }
    return id;
}

void shim_free(rc_ident *id)
{
    rc_ident_free(id);
    free(id);
}

void shim_reset(rc_ident *id) { rc_ident_reset(id); }

int shim_update(rc_ident *id, double traction, double brake, double speed, double speed_next,
                double grade, double dt, int contiguous)
{
    return rc_ident_update(id, traction, brake, speed, speed_next, grade, dt, contiguous);
}

int shim_restart_mass(rc_ident *id) { return rc_ident_restart_mass(id); }

void shim_set_theta(rc_ident *id, const double *theta) { rc_ident_set_theta(id, theta); }

/* ident._S = S (nothing else: no cache is cleared, as in Python) */
void shim_set_S(rc_ident *id, const double *S) { memcpy(id->S, S, sizeof id->S); }

static double *put(double *o, const double *x, int n, int have)
{
    for (int i = 0; i < n; i++)
        o[i] = have ? x[i] : 0.0;
    return o + n;
}

static double *put1(double *o, double x) { *o = x; return o + 1; }

/* The state (caches excepted: their presence depends on when outputs were asked for), fields
 * absent in Python (None) as has = 0 and zeros. Layout: see STATE in tests/model_tests/core/test_core_ident.py */
long shim_state(const rc_ident *id, double *o)
{
    double *s = o, win[RC_LAG];
    s = put(s, id->theta0, 4, 1);
    s = put1(s, id->scale);
    s = put1(s, id->s2_ref);
    s = put(s, id->s2_prior, 4, 1);
    s = put(s, id->j0, 4, 1);
    s = put(s, id->theta, 4, 1);
    s = put(s, id->prior_mean, 4, 1);
    s = put1(s, id->has_running);
    s = put(s, id->running_theta, 4, id->has_running);
    s = put(s, id->batch_info_inv, 16, id->has_running);
    s = put(s, id->batch_j0, 4, 1);
    s = put(s, id->batch_s2p, 4, 1);
    s = put1(s, id->has_S);
    s = put(s, id->S, 16, id->has_S);
    s = put1(s, (double)id->n);
    s = put1(s, id->q_e);
    s = put1(s, id->s2);
    s = put1(s, (double)id->batch_len);
    s = put1(s, (double)id->mass_restarts);
    s = put1(s, (double)id->repairs);
    s = put(s, id->W, 16, 1);
    s = put(s, id->D, 16, 1);
    s = put1(s, id->has_last_phi);
    s = put(s, id->last_phi, 4, id->has_last_phi);
    s = put1(s, id->has_last_err);
    s = put1(s, id->has_last_err ? id->last_err : 0.0);
    s = put1(s, id->c0);
    s = put1(s, id->c1);
    s = put1(s, (double)id->n_c1);
    s = put1(s, (double)id->window_len);
    for (long k = 0; k < RC_LAG; k++)
        win[k] = k < id->window_len ? id->window[(id->window_start + k) % RC_LAG] : 0.0;
    s = put(s, win, RC_LAG, 1);
    s = put1(s, id->window_sum);
    s = put1(s, id->has_cL);
    s = put1(s, id->has_cL ? id->cL : 0.0);
    s = put1(s, (double)id->n_cL);
    s = put1(s, id->has_J);
    s = put(s, id->J, 16, id->has_J);
    s = put(s, id->Dq, 16, 1);
    return (long)(s - o);
}

/* The outputs, in this order (it fills the caches as Python's calls do): model_theta[4],
 * model_covariance[16], model_variance_along(phi), covariance[16], stds[4], mass, mass_std,
 * sigma2, samples, noise_split a, b */
long shim_outputs(rc_ident *id, const double *phi, double *o)
{
    double *s = o, tmp[4];
    rc_ident_model_theta(id, tmp);
    s = put(s, tmp, 4, 1);
    s = put(s, rc_ident_model_covariance(id), 16, 1);
    s = put1(s, rc_ident_model_variance_along(id, phi));
    s = put(s, rc_ident_covariance(id), 16, 1);
    rc_ident_stds(id, tmp);
    s = put(s, tmp, 4, 1);
    s = put1(s, rc_ident_mass(id));
    s = put1(s, rc_ident_mass_std(id));
    s = put1(s, rc_ident_sigma2(id));
    s = put1(s, (double)rc_ident_samples(id));
    rc_ident_noise_split(id, tmp, tmp + 1);
    s = put(s, tmp, 2, 1);
    return (long)(s - o);
}

/* linalg4 directly, for the test comparing it with models/linalg4.py */
int shim_la_solve(const double *A, const double *b, int n, double *x) { return rc_la_solve(A, b, n, x); }
int shim_la_inverse(const double *A, int n, double *out) { return rc_la_inverse(A, n, out); }
int shim_la_is_pd(const double *A, int n) { return rc_la_is_positive_definite(A, n); }
void shim_la_eigh(const double *A, int n, double *w, double *V) { rc_la_eigh(A, n, w, V); }
void shim_la_inverse_from_eigen(const double *w, const double *V, int n, double *out)
{
    rc_la_inverse_from_eigen(w, V, n, out);
}
void shim_la_gram(const double *rows, long m, int n, double *out) { rc_la_gram(rows, m, n, out); }
