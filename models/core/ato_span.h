/* ato_span.h -- a span between two stations and the car's traction/brake characteristic, as the
 * ATO's re-planner sees them: the C twin of models/planning/span.py (Span, CarTraction's
 * characteristic, check_span_for_car); its grade is track.h's GradeProfile (one copy of it).
 *
 * The caller fills the structs; arrays are the caller's and must outlive every use. Units:
 * s [m], V [m/s], force [N], power [W], mass [t], grade [permille]. */
#ifndef RAILCAR_ATO_SPAN_H
#define RAILCAR_ATO_SPAN_H

#include "rc_common.h"
#include "track.h"


/* Span: the limits V_lim(s) piecewise constant from each limit distance on (the first is 0). */
typedef struct {
    double length, schedule, stop;             /* [m], [s], [m] */
    rc_grade_profile grade;                    /* track.h: the plant's GradeProfile, one copy */
    int n_limits;
    const double *limit_distances;             /* [m] */
    const double *limit_speeds;                /* [m/s] */
} rc_ato_span;

/* CarTraction's fields (models/planning/span.py). */
typedef struct {
    double mass, A0, A1, A2, gamma, length;
    double traction_force_max, traction_power_max, brake_force_max;
    double regen_force_max, regen_power_max, regen_fade_speed, regen_off_speed;
    double mech_force_max, adhesion_mass_fraction, adhesion_factor, eta_f, eta;
} rc_ato_car;


/* bisect.bisect_right(a[0:n], x) */
int rc_ato_bisect_right(const double *a, int n, double x);

double rc_ato_v_lim(const rc_ato_span *span, double s);
double rc_ato_v_lim_at_node(const rc_ato_span *span, double s);
/* Span.breakpoints into out (capacity cap): sorted distinct distances in (0, stop). Returns
 * their number, or -1 if cap is too small. rc_ato_breakpoints_bound: a capacity that suffices. */
int rc_ato_breakpoints(const rc_ato_span *span, double car_length, double *out, int cap);
int rc_ato_breakpoints_bound(const rc_ato_span *span);

/* CarTraction's characteristic (the scalar branch of each method). */
double rc_ato_adhesion_force_limit(const rc_ato_car *car, double v);
double rc_ato_f_max(const rc_ato_car *car, double v);
double rc_ato_r_max(const rc_ato_car *car, double v);
double rc_ato_brake_total_max(const rc_ato_car *car, double v);
void rc_ato_service_brake(const rc_ato_car *car, double v, double *regen, double *mech);
double rc_ato_hold_speed_regen(const rc_ato_car *car, double v_hold);

/* check_span_for_car: RC_BAD_CONFIG with ValueError's message where the car cannot run the
 * span at all, else RC_OK. err may be NULL. */
rc_status rc_ato_check_span_for_car(const rc_ato_span *span, const rc_ato_car *car, rc_error *err);

#endif
