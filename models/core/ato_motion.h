/* ato_motion.h -- the ATO re-planner's car and its motion on the coarse grid: the C twin of
 * models/ato/motion.py (PlanCar, accel, free_step, coast_step, hold_forces, step_time, Trace,
 * q_at, resistance_margins, blend_estimates, heavier_mass, braking_mass).
 * Units: s [m], V [m/s], q [m^2/s^2], t [s], force [N], mass [t], grade [permille]. */
#ifndef RAILCAR_ATO_MOTION_H
#define RAILCAR_ATO_MOTION_H

#include "ato_span.h"

enum { RC_ATO_K_TG = 0, RC_ATO_K_COAST = 1, RC_ATO_K_BRAKE = 2 };   /* free-step force laws */

/* models.planning.engine.Mode: Meleshin's (2011) Table 2 */
enum { RC_MODE_TG = 0, RC_MODE_C = 1, RC_MODE_VB = 2, RC_MODE_SR = 3, RC_MODE_RK = 4,
       RC_MODE_ST = 5, RC_MODE_TM = 6 };

/* PlanCar: the car for one re-plan (its constants bound once). */
typedef struct {
    double mass, brake_mass, inv_pg_brake, A0, A1, A2, pg, inv_pg, m_in, k_acc;
    double f_force, f_power, k_adh, frac, r_force, r_power, v_fade, b_total, share, eta_f, eta;
} rc_ato_plancar;

void rc_ato_plancar_init(rc_ato_plancar *pc, const rc_ato_car *car, double mass, double A0,
                         double A1, double A2, double brake_share, double brake_mass);
double rc_ato_pc_adhesion(const rc_ato_plancar *c, double v);
double rc_ato_pc_f_max(const rc_ato_plancar *c, double v);
double rc_ato_pc_r_full(const rc_ato_plancar *c, double v);
double rc_ato_pc_b_service(const rc_ato_plancar *c, double v);
double rc_ato_pc_w0(const rc_ato_plancar *c, double v);
double rc_ato_pc_w_slope(const rc_ato_plancar *c, double v);
double rc_ato_pc_hold_regen_speed(const rc_ato_plancar *c, double v_c);

double rc_ato_accel(const rc_ato_plancar *c, double v, double g, int kind);
/* RK2 in distance of q = V^2 over h; *v_mid the midpoint speed. Returns q1. */
double rc_ato_free_step(const rc_ato_plancar *c, double q0, double h, double g, int kind,
                        double *v_mid);
void rc_ato_coast_step(const rc_ato_plancar *c, double q0, double p0, double h, double g,
                       double k_lam, double *q1, double *p1);
/* (F, R, M) and whether traction suffices (the return value, 0/1) */
int rc_ato_hold_forces(const rc_ato_plancar *c, double q0, double q1, double h, double g,
                       double *F, double *R, double *M);
double rc_ato_step_time(double h, double q0, double q1);

/* A run: nodes s, q, t (n of them), per segment mode and works wF, wR [J] (n - 1), within
 * the capacity cap the owner allocated; coasts (s_c, s_end) of the run that made it. */
typedef struct {
    int n, cap;
    double *s, *q, *t, *wF, *wR;
    int *mode;
    int n_coasts, coast_cap;
    double *coast_x, *coast_end;
    double hold_speed, regen_speed;   /* V_c and V_r of the run that made it [m/s] */
} rc_ato_trace;

void rc_ato_trace_start(rc_ato_trace *tr, double s, double q, double t);
/* Trace.add; RC_MATH if the capacity is exhausted (never, for the planner's sizes) */
rc_status rc_ato_trace_add(rc_ato_trace *tr, double s, double q, double dt, int mode, double wF,
                           double wR);
/* Trace.cut_at(x) into out (out->cap >= tr->n + 1) */
void rc_ato_trace_cut_at(const rc_ato_trace *tr, double x, rc_ato_trace *out);
double rc_ato_q_at(const rc_ato_trace *tr, double x);

void rc_ato_resistance_margins(double a0, double a1, double a2, double v_lo, double v_hi,
                               double out[3]);
/* blend_estimates: configured[4], estimated[4], stated[7], speeds[n_speeds];
 * out[8] = (mass, A0, A1, A2, w_m, w_r, gate factor, d) */
void rc_ato_blend_estimates(const double configured[4], const double estimated[4],
                            const double stated[7], double ramp, double config_mass_std,
                            double config_resistance_std, double gate, const double *speeds,
                            int n_speeds, double mass_band, double gate_prev, double gate_step,
                            double out[8]);

#define RC_ATO_BRAKE_MASS_STEP 0.5   /* [t] motion.BRAKE_MASS_STEP */
double rc_ato_heavier_mass(double planned, double est_mass, int identifying, double configured,
                           double mass_band);
double rc_ato_braking_mass(double mass, double configured);

#endif
