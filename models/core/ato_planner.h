/* ato_planner.h -- the ATO's fast re-planner: the C twin of models/ato/planner.py
 * (ReducedCourse, ReducedPlanner, ReducedPlan, _solve, plan_setup, fastest_run).
 *
 * The course (the grid) and the planner (its envelope, coast hints, run traces and the plan it
 * returns) are allocated once, at their init, sized from the grid: a re-plan allocates nothing.
 * Errors: an rc_status with the message Python's ValueError carries, word for word.
 * Units: s [m], V [m/s], t [s], force [N], mass [t], grade [permille]. */
#ifndef RAILCAR_ATO_PLANNER_H
#define RAILCAR_ATO_PLANNER_H

#include <stddef.h>

#include "ato_motion.h"

/* a status code beyond rc_status: a capacity the planner's own sizing should never miss */
#define RC_ATO_INTERNAL 11

enum { RC_ATO_PLAN_OK = 0, RC_ATO_PLAN_LATE = 1, RC_ATO_PLAN_EARLY = 2 };   /* ReducedPlan.status */
enum { RC_ATO_POLICY_ENERGY = 0, RC_ATO_POLICY_CAPPED = 1 };              /* ReducedPlan.policy */

/* ReducedCourse: the grid's nodes s, the grade of each cell g (n - 1), the planning limit
 * (V_lim - margin)^2 at each node. */
typedef struct {
    double stop, h, margin, v_relay, a_ep, d_relay;
    int n, i_relay, n_limits;
    double *s, *g, *qlim;          /* owned: rc_ato_course_free */
} rc_ato_course;

/* ReducedCourse(span, car, step=, limit_margin=, v_relay=, a_ep=): the grid's arrays allocated
 * here, once. Refuses (C only) a grid of more than max_nodes candidate nodes (the nodes every step
 * m, the breakpoints, the EP curve's start): the controller refuses stop / step + breakpoints >
 * MAX_GRID_NODES first, with its own message, so MAX_GRID_NODES + 3 here never refuses what it
 * accepts. */
rc_status rc_ato_course_init(rc_ato_course *c, const rc_ato_span *span, const rc_ato_car *car,
                             double step, double limit_margin, double v_relay, double a_ep,
                             int max_nodes, rc_error *err);
void rc_ato_course_free(rc_ato_course *c);
int rc_ato_course_cell(const rc_ato_course *c, double x);

/* ReducedPlan; its arrays are the planner's and valid until its next plan. */
typedef struct {
    double hold_speed, regen_speed;
    int n_coasts;
    double *coast_x, *coast_end;
    int n;                          /* nodes: s, v, t (n), mode (n - 1) */
    double *s, *v, *t;
    int *mode;
    const double *qU;               /* the envelope on the course's nodes (course n) */
    double arrival, energy_kwh, traction_kwh, regen_kwh;
    int status, trials, policy;
} rc_ato_plan;

typedef struct {
    double x, y;
    int stalled;
} rc_ato_trial;

#define RC_ATO_MAX_TRIALS 128       /* > _solve's 61 and _plan_capped's 102 evaluations */

/* ReducedPlanner: its warm-start state, buffers and last plan. */
typedef struct {
    const rc_ato_course *c;
    double tol, v_min;
    int has_last_vc, has_vc_slope, has_last_cap;
    double last_vc, vc_slope, last_cap;
    long coast_runs;
    /* coast hints per stretch end node. Python keys them by round(s_end, 3): the same key for
     * the same node; two nodes would share one only if they lay within 1 mm (the grid keeps
     * nodes 1e-6 m apart), which no span with limits and grades on whole metres has */
    int *hint_has, *hint_has_slope;
    double *hint_x, *hint_slope;
    double *qU;                     /* the last envelope plan/min_time used */
    int *fall0, *fall1;             /* per cell: its falling stretch (first, last node) or -1 */
    rc_ato_trace bufs[3];
    rc_ato_trace *work, *spare, *best;
    double *coast_x, *coast_end;    /* the coasts of the run being made */
    int coast_cap;
    /* one plan's bookkeeping */
    rc_ato_trial trials[RC_ATO_MAX_TRIALS];
    int n_trials, has_best, best_stalled, overflow;
    double best_x, best_y, arrival, s0, q0, t0;
    const rc_ato_plancar *car;
    rc_ato_plan plan;
    void *block;
} rc_ato_planner;

/* FMU states (fmu_src/c/native_ato_state.c): the bytes of the buffer block rc_ato_planner_init
 * allocates for `course` (the same function lays both out), and a planner restored from its
 * bytes made whole again: p->c = course, p->block = block (block_size bytes, its contents the
 * saved ones), every pointer into the block and every buffer capacity as rc_ato_planner_init
 * sets them. work, spare, best, car and plan.qU move while planning: they are the caller's. */
size_t rc_ato_planner_block_size(const rc_ato_course *course);
void rc_ato_planner_relink(rc_ato_planner *p, const rc_ato_course *course, void *block);
rc_status rc_ato_planner_init(rc_ato_planner *p, const rc_ato_course *course, double tol,
                              double v_min, rc_error *err);
void rc_ato_planner_free(rc_ato_planner *p);

/* ReducedPlanner.envelope into qU (course n doubles) */
rc_status rc_ato_envelope(const rc_ato_planner *p, const rc_ato_plancar *car, double *qU,
                          rc_error *err);
/* ReducedPlanner.min_time; qU NULL: the envelope computed here */
rc_status rc_ato_min_time(rc_ato_planner *p, const rc_ato_plancar *car, const double *qU,
                          double *t_min, rc_error *err);
/* ReducedPlanner.plan; qU NULL: the envelope computed here. The plan is p->plan. */
rc_status rc_ato_plan_run(rc_ato_planner *p, const rc_ato_plancar *car, double s0, double v0,
                          double t0, double arrival, const double *qU, rc_error *err);
/* ReducedPlan.speed_at */
double rc_ato_plan_speed_at(const rc_ato_plan *plan, double x);



/* plan_setup(span, car, tuning) with tuning's grid_step, limit_margin, time_tol, a_ep,
 * ep_stages, mass_reserve, brake_share: the course, the planner (v_min 1 m/s) and the configured
 * car. On an error nothing is left allocated. */
rc_status rc_ato_plan_setup(rc_ato_course *course, rc_ato_planner *planner,
                            rc_ato_plancar *configured, const rc_ato_span *span,
                            const rc_ato_car *car, double grid_step, double limit_margin,
                            double time_tol, double a_ep, int ep_stages, double mass_reserve,
                            double brake_share, int max_nodes, rc_error *err);
/* fastest_run: [s] the fastest run the controller plans for the span with the car */
rc_status rc_ato_fastest_run(const rc_ato_span *span, const rc_ato_car *car, double grid_step,
                             double limit_margin, double time_tol, double a_ep, int ep_stages,
                             double mass_reserve, double brake_share, int max_nodes,
                             double *t_min, rc_error *err);
#endif
