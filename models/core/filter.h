/* filter.h -- models.filters.MotionFilter for kinds 1-3 (linearised, EKF, paper verbatim):
 * the innovation gate, the update ((15), (17), (18) with H = I, or one measurement alone), the
 * prediction ((16), (19) or the EKF's) and the outputs. Singer (kind 4) is not here. */
#ifndef RAILCAR_FILTER_H
#define RAILCAR_FILTER_H

#include "track.h"

enum { RC_LINEARISED = 1, RC_EKF = 2, RC_PAPER = 3, RC_SINGER = 4 };   /* filter.kind */
enum { RC_REACQUIRE_BOTH = 1, RC_REACQUIRE_DISTANCE = 2 };

typedef struct {               /* models.filters.FilterConfig (the fields kinds 1-3 use) */
    double dt;                 /* [s] */
    double speed_std;          /* [m/s] */
    double position_std;       /* [m] */
    double position_std_rel;   /* [-] */
    double gamma;              /* [-] */
    int kind;                  /* 0 auto, 1, 2, 3 */
    double length;             /* [m] */
} rc_filter_config;

typedef struct {               /* models.filters.MotionFilter */
    rc_filter_config cfg;
    const rc_grade_profile *grade;   /* the chain's */
    const rc_speed_profile *speed;   /* the chain's; NULL or n == 0: none */
    int kind;                  /* resolved: 1, 2 or 3 */
    double r0, r1;             /* speed_std^2, position_std^2 */
    double xb0, xb1, m00, m01, m11;   /* prediction and its covariance */
    double xh0, xh1, p00, p01, p11;   /* posterior and its covariance */
    double vzad_hat, vzad_bar; /* [m/s] */
    long rejected, speed_run, position_run, reacquired;
    int speed_fit;             /* bool */
    int use_speed, use_position;      /* bool: what the next update takes */
    int reacquire;             /* 0, RC_REACQUIRE_BOTH or RC_REACQUIRE_DISTANCE */
} rc_filter;

/* MotionFilter.__init__ (config validated by the caller; kind 4 is refused by the chain) */
void rc_filter_init(rc_filter *f, const rc_filter_config *cfg, const rc_grade_profile *grade,
                    const rc_speed_profile *speed);
void rc_filter_restart(rc_filter *f);
void rc_filter_start_from_measurement(rc_filter *f, double speed_meas, double position_meas);
/* MotionFilter.gate: *use_v, *use_x (bools) */
void rc_filter_gate(rc_filter *f, double speed_meas, double position_meas, int *use_v, int *use_x);
void rc_filter_hold(rc_filter *f);
void rc_filter_update(rc_filter *f, double speed_meas, double position_meas);
void rc_filter_update_speed(rc_filter *f, double speed_meas, double variance);
/* MotionFilter.predict with theta[4] = (1/(Pg), A0, A1, A2), process noise q [(m/s)^2] */
void rc_filter_predict(rc_filter *f, double traction, double brake, const double *theta, double q,
                       double dt);
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
