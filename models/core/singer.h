/* singer.h -- models/filtering/singer.py: Boynik et al.'s Singer model on z = [w, v, r]
 * (acceleration [m/s^2], speed [m/s], distance [m]) and its Kalman filter, the scalar path
 * SingerFilter runs (_predict, _update, _project), bit for bit: the exact discretisation (Phi, Q, u
 * with the Taylor series below SERIES_SWITCH and the closed forms above), the prediction, the
 * update with one or two measurements (Joseph form), the clip of a negative speed, and
 * singer_mixture_moments / SingerParams' checks for the filter.singer_* settings.
 *
 * Matrices are flat row-major: 3x3 as 9 doubles, H as m rows of 3, R as m x m (m = 1 or 2).
 * Where Python raises (ValueError of a bad step, ZeroDivisionError of a singular S,
 * OverflowError of x ** n), the call returns RC_MATH and changes nothing. */
#ifndef RAILCAR_SINGER_H
#define RAILCAR_SINGER_H

#include "rc_common.h"

#define RC_SINGER_SERIES_SWITCH 1.5   /* singer.SERIES_SWITCH */
#define RC_SINGER_SERIES_TERMS 40     /* singer._SERIES_TERMS */

/* singer._TERMS' functions, in that order (the C table follows it) */
enum { RC_SF_PHI1, RC_SF_PHI2, RC_SF_PHI3, RC_SF_WW, RC_SF_WV, RC_SF_WR, RC_SF_VV, RC_SF_VR,
       RC_SF_RR, RC_SF_COUNT };

typedef struct {               /* models.filtering.singer.SingerFilter */
    double tau, sigma_w, m_w;  /* SingerParams [s], [m/s^2], [m/s^2]; alpha = 1.0 / tau */
    int clip;                  /* bool */
    double x[3];               /* _x: w, v, r */
    double P[9];               /* _P */
    double nis;                /* NIS of the last update (NaN before one) */
    /* the discretisation at the last step (the Python side's lru_cache; not state) */
    int has_disc;
    double disc_dt, Phi[9], Q[9], u[3];
} rc_singer;

/* singer_mixture_moments + SingerParams(tau, sigma_w, m_w) as FilterConfig.singer_params does it:
 * RC_BAD_CONFIG with Python's message (prefixed "filter.singer_*: " as there; values as
 * repr()) in err, else RC_OK with *m_w, *sigma_w. Also refuses what Python would only meet
 * later: sigma_w ** 2 overflowing, 1.0 / tau overflowing. err may be NULL. */
rc_status rc_singer_params(double tau, double p0, double p_plus, double p_minus,
                           double w_max_plus, double w_max_minus, double *m_w, double *sigma_w,
                           rc_error *err);
/* SingerFilter(SingerParams(tau, sigma_w, m_w), x0, P0, clip) (x0[3], P0[9]) */
void rc_singer_init(rc_singer *s, double tau, double sigma_w, double m_w, const double *x0,
                    const double *P0, int clip);
rc_status rc_singer_predict(rc_singer *s, double dt);
/* SingerFilter.update with m = 1 or 2: z[m], H[3 m], R[m m] */
rc_status rc_singer_update(rc_singer *s, int m, const double *z, const double *H,
                           const double *R);
rc_status rc_singer_update_speed(rc_singer *s, double speed, double speed_std);
rc_status rc_singer_update_distance(rc_singer *s, double distance, double distance_std);
rc_status rc_singer_update_speed_distance(rc_singer *s, double speed, double distance,
                                          double speed_std, double distance_std);
/* singer._discretisation_flat(alpha, dt, sigma_w, m_w): Phi[9], Q[9], u[3] */
rc_status rc_singer_discretisation(double alpha, double dt, double sigma_w, double m_w,
                                   double *Phi, double *Q, double *u);
/* singer._f(name, x) (RC_MATH where x ** n overflows) and the series coefficients */
rc_status rc_singer_f(int name, double x, double *out);
const double *rc_singer_coefficients(int name);

#endif
