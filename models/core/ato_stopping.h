/* ato_stopping.h -- targeted stopping for the ATO: the C twin of models/ato/stopping.py
 * (track_force, RelayBrake: Sidorenko's (1997) multi-stage relay control of the EP brake,
 * ep_deceleration). Units: s [m], V [m/s], t [s], force [N], mass [t], grade [permille]. */
#ifndef RAILCAR_ATO_STOPPING_H
#define RAILCAR_ATO_STOPPING_H

#include "ato_motion.h"

#define RC_ATO_A_PROG_MIN 0.3    /* stopping.A_PROG_MIN */

double rc_ato_track_force(const rc_ato_plancar *car, double v, double v_ref, double a_ref,
                          double grade, double gain);

/* RelayBrake's state (fields by the same names; has_stage 0 is Python's stage None). */
typedef struct {
    double stop, a_ep, stage_force;
    int n_stages;
    double hysteresis, stage_speed, dwell, creep_speed, creep_accel, stop_window;
    int has_stage, stage;
    double switched, a_prog, creep_int;
    int has_t_creep;
    double t_creep;
} rc_ato_relay;

void rc_ato_relay_init(rc_ato_relay *r, double stop, double a_ep, double stage_force,
                       int n_stages, double hysteresis, double stage_speed, double dwell,
                       double creep_speed, double creep_accel, double stop_window);
double rc_ato_relay_programmed_speed(const rc_ato_relay *r, double s);
/* RelayBrake.command: *traction, *brake [N], *stage (-1: creeping), *v_p [m/s]. RC_MATH with
 * Python's message where int() of a stage count would raise (NaN or infinite): the state is then
 * as Python leaves it. err may be NULL. */
rc_status rc_ato_relay_command(rc_ato_relay *r, double t, double s, double v,
                               const rc_ato_plancar *car, double grade, double *traction,
                               double *brake, int *stage, double *v_p, rc_error *err);

/* ep_deceleration(car, tuning, grade) with tuning's a_ep, ep_stages, mass_reserve */
double rc_ato_ep_deceleration(const rc_ato_car *car, double a_ep, int ep_stages,
                              double mass_reserve, double grade);

#endif
