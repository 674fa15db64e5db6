/* ident.h -- models.estimation.identification.ParameterIdentifier for the paper's differenced rows
 * (est.method 0) and Sidorenko's centred slopes (est.method 2: the rows come from estimator.c;
 * here their end factor, the A's prior weight, the configured noise split and the prior's
 * reweighting at a mass restart): the first batch with its prior, the
 * running estimate before it, the recursive step (8), (9), (11) with mu = 1/n or a constant
 * forgetting mu0 (J kept), the sandwich covariance, sigma^2 from LAG sums, the mass restart at a
 * station (with est.run_forgetting and the carried A's drift, est.A0_drift_std / est.A1_drift_std)
 * and the positive-definiteness repair. The rare paths use
 * linalg4.c, the twin of models/linalg4.py, so every number is bit-identical to the Python.
 *
 * Where Python raises (a singular matrix: SingularMatrixError; a division by zero; sqrt of a
 * negative: ValueError), the C code computes on with inf/NaN and the call returns RC_MATH
 * (singular matrices); divisions by zero are not reported (they need degenerate input: dt = 0,
 * theta[0] = 0 in mass_std, R[0][0] = 0 at a restart, a repaired S that stays indefinite). */
#ifndef RAILCAR_IDENT_H
#define RAILCAR_IDENT_H

#include "rc_common.h"

#define RC_LAG 50              /* ParameterIdentifier.LAG */
#define RC_MAX_SLOPE_WINDOW 1000   /* identification.MAX_SLOPE_WINDOW: est.method 2's rows held */

typedef struct {               /* models.estimation.identification.IdentifierConfig */
    double dt;                 /* [s] */
    long batch_size;           /* >= 4 */
    double forgetting;         /* mu0 in [0, 1) */
    double gamma;
    double mass_initial, mass_std_initial;             /* [t] */
    double A0_initial, A1_initial, A2_initial;
    double A0_std_initial, A1_std_initial, A2_std_initial;
    double sigma2_initial;     /* [(m/s)^2] */
    double speed_std;          /* [m/s] */
    int frozen;                /* bool */
    double run_forgetting;     /* [0, 1) */
    double speed_std_rel;      /* [-]: sensor.speed_std_rel (set by rc_estimator_init) */
    double A0_drift_std;       /* [N/kN per stop], est.method 0 and 2 (validate.c) */
    double A1_drift_std;       /* [N/kN/(m/s) per stop] */
} rc_ident_config;

typedef struct {               /* models.estimation.identification.ParameterIdentifier */
    rc_ident_config cfg;
    double theta0[4], scale, s2_ref, s2_prior[4], j0[4];
    double end_factor, end_weight;     /* 2 and 1 for the paper's rows */
    int slope_rows;                    /* _slope_rows: est.method 2 */
    long n_k;  double slope_k[RC_MAX_SLOPE_WINDOW];   /* _k: slope weights times dt */
    double theta[4], prior_mean[4];
    int has_running;  double running_theta[4];         /* _running_theta */
    double batch_info_inv[16], batch_j0[4], batch_s2p[4];   /* _batch_info_inv, _batch_prior */
    int has_model_cov;  double model_cov[16];          /* cache */
    int has_S;  double S[16];
    long n;
    double q_e, s2;
    double *batch_phi;         /* batch_size rows of 4, row-major, allocated by rc_ident_init */
    double *batch_y;
    int *batch_contiguous;
    long batch_len;
    long mass_restarts, repairs;
    double W[16], D[16];
    int drift;  double drift_var[2], Dq[16];   /* _drift, _drift_var, the drift meat _Dq */
    int has_last_phi;  double last_phi[4];
    double rows[4 * RC_MAX_SLOPE_WINDOW];  long rows_len, rows_next;   /* _rows, a ring */
    double row_scale, last_scale;      /* _row_scale, _last_scale */
    int has_last_err;  double last_err;
    double c0, c1;  long n_c1;
    double window[RC_LAG];  long window_len, window_start;  double window_sum;   /* ring */
    int has_cL;  double cL;  long n_cL;
    double cL_count;                                   /* _cL_count: n_cL forgotten with the runs */
    double speed_var;  long n_speed_var;               /* _speed_var, _n_speed_var */
    int has_cov;  double cov[16];                      /* caches */
    int has_sigma2;  double sigma2;
    int has_J;  double J[16];                          /* with forgetting */
} rc_ident;

/* ParameterIdentifier.__init__ (cfg as IdentifierConfig.validate accepts it); allocates the
 * batch buffers: 0, or -1 out of memory (nothing to free then) */
int rc_ident_init(rc_ident *id, const rc_ident_config *cfg);
/* rc_ident_init for est.method 2's rows, Sidorenko's slopes over slope_window (>= 2) samples
 * (IdentifierConfig.method 2, .slope_window); slope_window 0: the paper's rows (method 0) */
int rc_ident_init_rows(rc_ident *id, const rc_ident_config *cfg, long slope_window);
void rc_ident_free(rc_ident *id);
void rc_ident_reset(rc_ident *id);
/* update(traction, brake, speed, speed_next, grade, dt, contiguous); dt == 0 means cfg.dt
 * (Python's `dt or cfg.dt`). RC_OK, or RC_MATH where Python raises (see above) */
int rc_ident_update(rc_ident *id, double traction, double brake, double speed, double speed_next,
                    double grade, double dt, int contiguous);
int rc_ident_restart_mass(rc_ident *id);
/* the theta setter (before any data it moves the prior's centre too) */
void rc_ident_set_theta(rc_ident *id, const double *theta);
/* model_theta -> out[4]; covariance (flat 4x4), model covariance: pointers into the caches */
void rc_ident_model_theta(const rc_ident *id, double *out);
const double *rc_ident_covariance(rc_ident *id);
const double *rc_ident_model_covariance(rc_ident *id);
double rc_ident_model_variance_along(rc_ident *id, const double *phi);
void rc_ident_stds(rc_ident *id, double *out);
double rc_ident_mass(const rc_ident *id);
double rc_ident_mass_std(rc_ident *id);
double rc_ident_sigma2(rc_ident *id);
void rc_ident_noise_split(const rc_ident *id, double *a, double *b);
long rc_ident_samples(const rc_ident *id);
/* differentiation.centred_slope_weights for the n intervals dts[n]: w[n + 1], c[n] */
void rc_centred_slope_weights(const double *dts, long n, double *w, double *c);
/* _quadratic4: phi^T C phi */
double rc_ident_quadratic4(const double *c, const double *phi);

#endif
