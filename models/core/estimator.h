/* estimator.h -- models.estimation.online: StationDetector and OnlineEstimator for est.method 0 (the
 * paper's LS) and 2 (methods.SlopeLS: the LS on Sidorenko's centred slopes), est.sigma2_method 0
 * (the LS's LAG sums) and 1 (methods.LikelihoodNoise: the likelihood bank), est.physical 0 and 1, filter kinds 1-4: per sample, measure()
 * (identification of the pair, station logic, the filter's gate and update), then propagate()
 * (the filter's prediction with the forces applied until the next sample), and the outputs with
 * finish_outputs' guarantees (every value finite, est.mass plausible, est.status). */
#ifndef RAILCAR_ESTIMATOR_H
#define RAILCAR_ESTIMATOR_H

#include "filter.h"
#include "ident.h"
#include "track.h"

#define RC_MOVING_RUN 3          /* StationDetector.MOVING_RUN */

typedef struct {                 /* models.estimation.online.StationConfig */
    double dwell;                /* [s] */
    double speed_threshold;      /* [m/s], 0 = automatic */
    double position_threshold;   /* [m], 0 = automatic */
} rc_station_config;

typedef struct {                 /* models.estimation.online.StationDetector */
    double v_thr, x_thr, dwell, still_time;
    long fast_run;
    int moving, restarted;       /* bools */
} rc_station;

enum { RC_STATUS_PRIOR = 0, RC_STATUS_IDENTIFYING = 1, RC_STATUS_HOLDING = 2, RC_STATUS_DEGRADED = 3 };

/* OnlineEstimator.outputs(): est.mass, est.mass_std, est.A0, est.A1, est.A2, est.A0_std,
 * est.A1_std, est.A2_std, est.sigma2, est.samples, est.station_stops, filter.speed,
 * filter.position, filter.speed_std, filter.position_std (RC_EST_RAW values, in this order, the
 * integers as doubles), then finish_outputs appends est.status and filter.rejected, then
 * est.cov_A0_A1, est.cov_A0_A2, est.cov_A1_A2 (RC_EST_COVARIANCES, resistance_covariances). */
#define RC_EST_RAW 15
#define RC_EST_COVARIANCES 3
#define RC_EST_OUTPUTS (RC_EST_RAW + 2 + RC_EST_COVARIANCES)
#define RC_FINISH_MAX 40         /* values finish_outputs can guard (the chain's 12 + 15) */

#define RC_BANK_SIZE 13          /* ProcessNoiseBank's n */

typedef struct {                 /* models.filtering.motion_filter.ProcessNoiseBank (est.sigma2_method 1) */
    double log_q[RC_BANK_SIZE], q[RC_BANK_SIZE], log_prior[RC_BANK_SIZE];  /* the grid [(m/s)^2] */
    double log_lik[RC_BANK_SIZE];
    double x[RC_BANK_SIZE], P[RC_BANK_SIZE];    /* members' speeds [m/s], variances [(m/s)^2] */
    int started;                 /* x is not None: the car moves */
    double R, speed_std, speed_std_rel;   /* R [(m/s)^2]; variance_at from the filter's stds */
    double estimate;             /* sigma^2 [(m/s)^2] */
} rc_noise_bank;

typedef struct {                 /* models.estimation.methods.SlopeLS (est.method 2) */
    long size;                   /* est.slope_window */
    long len;                    /* speeds held (len - 1 intervals) */
    double *v;                   /* the window's speeds [m/s], oldest first */
    double *i;                   /* its intervals' (F [N], B [N], grade [permille], dt [s]) */
    int contiguous;              /* the last row fed follows the one before */
    int has_weights;             /* dts, w, c hold centred_slope_weights(dts) */
    double *dts, *w, *c;
} rc_slope_ls;

typedef struct {                 /* models.estimation.online.OnlineEstimator (method 0 or 2) */
    rc_ident ident;
    rc_slope_ls *slope;          /* est.method 2's rows, else NULL */
    int physical;                /* est.physical: A0, A2 >= 0 reported and predicted with */
    int likelihood_noise;        /* est.sigma2_method 1: sigma^2 from `bank`, else the LS's */
    rc_noise_bank bank;
    rc_filter filter;
    rc_station station;
    const rc_grade_profile *grade;   /* the chain's */
    double length, gamma, dt_nominal;
    long station_stops, track_speeds;
    int has_prev;  double prev_speed, prev_position;   /* _prev */
    int pair_used, prev_fit;     /* bools */
    double force_traction, force_brake;  /* _forces [N] */
    double dt;                   /* _dt [s] */
    double net_force, steady_speed, steady_force, steady_time, force_band;
    double mass_initial, mass_low, mass_high, mass_std_initial;
    int has_last_good;  double last_good[RC_FINISH_MAX];   /* _last_good */
} rc_estimator;

/* models.chain.build_estimator + OnlineEstimator.__init__, sampling every dt [s] (configs
 * validated by the caller; private copies are taken); slope_window 0: est.method 0, >= 2:
 * est.method 2 with that est.slope_window; physical: est.physical; sigma2_method:
 * est.sigma2_method (0 or 1). 0, or -1 when the identifier's buffers cannot be
 * allocated. The estimator points at grade and speed: they must outlive it. */
int rc_estimator_init(rc_estimator *e, const rc_ident_config *id_cfg, const rc_filter_config *filt,
                      const rc_station_config *station, const rc_grade_profile *grade,
                      const rc_speed_profile *speed, double dt, long slope_window,
                      int physical, int sigma2_method);
void rc_estimator_free(rc_estimator *e);
/* What the core does not run, as models/compiled.py's estimator_not_covered says it */
#define RC_NOT_COVERED "est.method 1 or 3"
#define RC_NO_SLOPE_WINDOW "est.method 2 without est.slope_window (>= 2; the value after the " \
    "flat configuration)"
/* NULL when the core runs est.method, est.physical (0 or 1), est.sigma2_method and est.slope_window
 * (slope_window read with method 2 only), else what it does not cover */
const char *rc_estimator_not_covered(int method, int physical, int sigma2_method,
                                     long slope_window);
void rc_estimator_measure(rc_estimator *e, double speed_meas, double position_meas);
/* OnlineEstimator.propagate: the filter's prediction with the forces [N] over dt [s], capped at
 * the filtered speed while the car stands and traction <= 0 (OnlineEstimator.holding: a
 * virtual holding brake) */
void rc_estimator_propagate(rc_estimator *e, double traction, double brake, double dt);
/* OnlineEstimator.measure_track_speed */
void rc_estimator_measure_track_speed(rc_estimator *e, double speed_meas, double age,
                                      double speed_std, double base);
/* OnlineEstimator.outputs(predicted) without finish_outputs: out[RC_EST_RAW] */
void rc_estimator_raw_outputs(rc_estimator *e, int predicted, double *out);
/* OnlineEstimator.finish_outputs on out[n] (n <= RC_FINISH_MAX; est.mass at out[mass_index],
 * est.mass_std right after it): writes est.status at out[n] and filter.rejected at out[n + 1] */
void rc_estimator_finish_outputs(rc_estimator *e, double *out, int n, int mass_index);
/* identification.project_physical: th[4] moved onto A0, A2 >= 0 in the metric of the flat 4x4
 * covariance cov (in place; th unchanged when A0, A2 >= 0 already) */
void rc_project_physical(double *th, const double *cov);
/* OnlineEstimator.resistance_covariances (method 0: the LS's covariance): est.cov_A0_A1,
 * est.cov_A0_A2, est.cov_A1_A2 -> out[RC_EST_COVARIANCES], 0 where a variance is not > 0 or
 * the covariance is not finite */
void rc_estimator_resistance_covariances(rc_estimator *e, double *out);
/* OnlineEstimator.outputs(predicted): all three above -> out[RC_EST_OUTPUTS] */
void rc_estimator_outputs(rc_estimator *e, int predicted, double *out);

#endif
