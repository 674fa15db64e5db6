/* filter.h -- models.filtering.motion_filter.MotionFilter for kinds 1-4 (linearised, EKF, paper verbatim,
 * Singer): the innovation gate, the update ((15), (17), (18) with H = I, or one measurement
 * alone), the prediction ((16), (19) or the EKF's) and the outputs. Kind 4 runs the Singer
 * filter of singer.h on [w, v, r] and copies its (v, r) block into the posterior's and the
 * prediction's fields, as SingerKind._publish (models/filtering/kinds.py) does.
 *
 * Where Python raises (ZeroDivisionError, OverflowError of x ** 2), the C function returns
 * RC_MATH and leaves the state as Python leaves it at the raise (mostly unchanged; the few
 * assignments Python makes before it are made too). Otherwise RC_OK. NaN measurements behave as
 * in Python (comparisons false, so the gate refuses them). */
#ifndef RAILCAR_FILTER_H
#define RAILCAR_FILTER_H

#include "rc_common.h"
#include "singer.h"
#include "track.h"

enum { RC_LINEARISED = 1, RC_EKF = 2, RC_PAPER = 3, RC_SINGER = 4 };   /* filter.kind */
enum { RC_REACQUIRE_BOTH = 1, RC_REACQUIRE_DISTANCE = 2 };

#define RC_GATE_SIGMAS 6.0     /* MotionFilter.GATE_SIGMAS */
#define RC_FIT_SIGMAS 4.5      /* MotionFilter.FIT_SIGMAS */
#define RC_REACQUIRE 50        /* MotionFilter.REACQUIRE [samples] */

typedef struct {               /* models.filtering.motion_filter.FilterConfig */
    double dt;                 /* [s] */
    double speed_std;          /* [m/s] */
    double position_std;       /* [m] */
    double position_std_rel;   /* [-] */
    double gamma;              /* [-] */
    int kind;                  /* 0 auto, 1, 2, 3, 4 */
    double length;             /* [m] */
    double singer_tau;         /* [s]: the Singer filter's settings (kind 4) */
    double singer_p0, singer_p_plus, singer_p_minus;   /* [-] */
    double singer_w_max_plus, singer_w_max_minus;      /* [m/s^2] */
    double speed_std_rel;      /* [-]: last, so that positional initialisers of the fields above
                                * stay valid (0 when omitted) */
} rc_filter_config;

typedef struct {               /* models.filtering.motion_filter.MotionFilter */
    rc_filter_config cfg;
    const rc_grade_profile *grade;   /* the chain's */
    const rc_speed_profile *speed;   /* the chain's; NULL or n == 0: none */
    int kind;                  /* resolved: 1, 2, 3 or 4 */
    double r0, r1;             /* speed_std^2, position_std^2 (MotionFilter.R) */
    double xb0, xb1, m00, m01, m11;   /* prediction x_bar and its covariance M (upper triangle) */
    double xh0, xh1, p00, p01, p11;   /* posterior and its covariance */
    double vzad_hat, vzad_bar; /* [m/s] */
    long rejected, speed_run, position_run, reacquired;
    int speed_fit;             /* bool */
    int use_speed, use_position;      /* bool: what the next update takes */
    int reacquire;             /* 0, RC_REACQUIRE_BOTH or RC_REACQUIRE_DISTANCE */
    double singer_m_w, singer_sigma_w;   /* kind 4: _singer_params' m_w, sigma_w [m/s^2] */
    rc_singer singer;          /* kind 4: _singer */
} rc_filter;

/* What MotionFilter.__init__ refuses: FilterConfig.validate(has_speed_profile) for kinds 0-4
 * (the filter.singer_* settings for kind 4, rc_singer_params), and speed_std ** 2 or
 * position_std ** 2 overflowing (Python's OverflowError). RC_BAD_CONFIG with the first bad one
 * named in err (Python's message, the value printed with %.17g), else RC_OK. err may be NULL. */
rc_status rc_filter_validate(const rc_filter_config *cfg, int has_speed_profile, rc_error *err);
/* MotionFilter.__init__ (config validated by the caller, e.g. with rc_filter_validate): the
 * config is copied, the profiles are the caller's and must outlive the filter. */
void rc_filter_init(rc_filter *f, const rc_filter_config *cfg, const rc_grade_profile *grade,
                    const rc_speed_profile *speed);
void rc_filter_restart(rc_filter *f);
/* RC_MATH: speed_noise_std(speed_meas) ** 2 or position_noise_std(position_meas) ** 2 overflows
 * (after the restart and the state set, p00 and p11 left at 0, as Python leaves them) */
rc_status rc_filter_start_from_measurement(rc_filter *f, double speed_meas, double position_meas);
/* MotionFilter.gate: *use_v, *use_x (bools). RC_MATH: the distance's or the speed's variance
 * overflows (nothing changed) */
rc_status rc_filter_gate(rc_filter *f, double speed_meas, double position_meas, int *use_v,
                         int *use_x);
void rc_filter_hold(rc_filter *f);
rc_status rc_filter_update(rc_filter *f, double speed_meas, double position_meas);
/* RC_MATH: p00 + variance == 0 (nothing changed); kind 4: variance < 0, or the Singer update's */
rc_status rc_filter_update_speed(rc_filter *f, double speed_meas, double variance);
/* MotionFilter.predict with theta[4] = (1/(Pg), A0, A1, A2), process noise q [(m/s)^2].
 * RC_MATH: 1 + gamma == 0 (nothing changed); kind 4 (forces and theta unused): a bad dt */
rc_status rc_filter_predict(rc_filter *f, double traction, double brake, const double *theta,
                            double q, double dt);
/* MotionFilter.cap_predicted_speed, after rc_filter_predict over dt [s]: the predicted speed at
 * most v_max [m/s] (the kinds' cap_predicted_speed: kinds 1, 2 the distance by the trapezoid
 * with the capped speed, kind 3 the speed row only, kind 4 the projection of the Singer clip; the
 * covariance unchanged) */
void rc_filter_cap_predicted_speed(rc_filter *f, double v_max, double dt);
/* MotionFilter.acceleration: 1 with the Singer filter's acceleration [m/s^2] in *out (kind 4),
 * else 0 (Python's None) and *out untouched */
int rc_filter_acceleration(const rc_filter *f, double *out);
/* The properties: speed, position, their stds, and the predicted ones */
double rc_filter_speed(const rc_filter *f);
double rc_filter_position(const rc_filter *f);
double rc_filter_speed_std(const rc_filter *f);
double rc_filter_position_std(const rc_filter *f);
double rc_filter_predicted_speed(const rc_filter *f);
double rc_filter_predicted_position(const rc_filter *f);
double rc_filter_predicted_speed_std(const rc_filter *f);
double rc_filter_predicted_position_std(const rc_filter *f);

#endif
