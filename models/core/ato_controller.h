/* ato_controller.h -- the ATO for one span in the C core: the C twin of models/ato/controller.py's
 * AtoController (construction checks, the supervision curve, demands: the gate of
 * ato_supervision.h, then the RUN / BRAKE / EP / SETTLE / HOLD phases, the re-plans with the
 * blended car and the time reserve, the aim point, the speed supervisor), bit-identical to it.
 *
 * One struct: the tuning, the supervisor, the course, the planner, the plan's envelope and the
 * relay live in it (the curves on the grid as arrays of ATO_MAX_NODES, ~160 kB: allocate the struct
 * itself, not on a stack); the course and the planner allocate their grids at ato_controller_init,
 * nothing is allocated per step. The span and car structs (and their arrays) are the caller's and
 * must outlive the controller.
 *
 * Python's events list is a ring of the latest ATO_EVENT_RING (t, reason, text) with the count of
 * all events so far (a step adds a few at most: a host reads them after each step); the codes
 * ATO_EV_INPUT, _RECOVERY, _ESTIMATES, _OVERSPEED and _INTERNAL are the ones AtoController._log
 * also logs (logger models.ato.controller, "ATO at t = %.2f s: <text>"). replan_seconds
 * (wall-clock) is left out, the re-plans are counted (replans).
 *
 * One difference by design: the host gives every input as a double, NaN where it has none, so an
 * input Python's demands finds missing ("<name> is missing: safe brake") is a NaN here ("<name> =
 * nan is not finite: safe brake"); the FMU always has every input.
 * Units: s [m], V [m/s], t [s], force [N], mass [t], grade [permille].
 */
#ifndef RAILCAR_ATO_CONTROLLER_H
#define RAILCAR_ATO_CONTROLLER_H

#include "ato_planner.h"
#include "ato_stopping.h"
#include "ato_supervision.h"
#include "ato_tuning.h"

#define ATO_MAX_GRID_NODES 10000    /* controller.MAX_GRID_NODES */
#define ATO_GATE_RATE 0.2           /* [1/s] controller.GATE_RATE */
#define ATO_MAX_NODES (ATO_MAX_GRID_NODES + 3)  /* the course's nodes at most (ato_planner.h) */

/* controller.py's phases (RUN, BRAKE, STOP_EP, SETTLE, HOLD) */
typedef enum { ATO_PHASE_RUN = 0, ATO_PHASE_BRAKE = 1, ATO_PHASE_EP = 2, ATO_PHASE_SETTLE = 3,
               ATO_PHASE_HOLD = 4 } ato_phase;

/* what an event is (the text says it as Python's does) */
typedef enum {
    ATO_EV_INPUT = 0,          /* a bad input: the safe brake (once per episode of the input) */
    ATO_EV_RECOVERY = 1,       /* the safe brake held until the inputs are sane for 1 s */
    ATO_EV_RELEASED = 2,       /* ... and released */
    ATO_EV_ESTIMATES = 3,      /* est.* not usable / gated out (once per episode) */
    ATO_EV_EST_USABLE = 4,     /* est.* get weight for the first time */
    ATO_EV_REPLAN_FAILED = 5,  /* a re-plan's ValueError: the last plan is kept (once per episode) */
    ATO_EV_REPLAN_STATUS = 6,  /* a re-plan's status changed */
    ATO_EV_ONE_STOP = 7,       /* _refine_aim: no settling after all */
    ATO_EV_SETTLED = 8,
    ATO_EV_STOPPED = 9,        /* stopped (short of the mark: settling, or finished) */
    ATO_EV_OVERSPEED = 10,     /* the supervisor's full brake (once per episode) */
    ATO_EV_INTERNAL = 11       /* an error Python raises inside the step: the safe brake */
} ato_event_code;

#define ATO_EVENT_RING 32
typedef struct {
    double t;                  /* [s] as Python records it (tau for the re-plan events) */
    ato_event_code code;
    char text[ATO_TEXT_SIZE];
} ato_event;

typedef struct {
    double traction, brake;    /* [N] */
    int mode;                  /* ato_mode */
    double planned_speed;      /* [m/s] */
    int ep_stage;
} ato_command;

/* the once-per-episode keys: the inputs' subjects, then these */
enum { ATO_KEY_TIME = ATO_N_ALL_INPUTS, ATO_KEY_CONSISTENCY, ATO_KEY_RECOVERY,
       ATO_KEY_ESTIMATES, ATO_KEY_OVERSPEED, ATO_KEY_INTERNAL, ATO_KEY_REPLAN, ATO_N_KEYS };

typedef struct {
    const rc_ato_span *span;
    const rc_ato_car *car;
    ato_tuning tuning;
    rc_ato_course course;
    rc_ato_planner planner;
    rc_ato_plancar configured, car_now;
    ato_supervisor supervisor;
    rc_ato_relay relay;
    double a_ep;
    double qU[ATO_MAX_NODES];  /* the plan's envelope (a copy: a failed re-plan keeps it) */
    double sup_q[ATO_MAX_NODES]; /* the supervision curve's V^2 on the course's nodes */
    double sup_mass, final_start;
    int plan_status;           /* the plan in planner.plan (RC_ATO_PLAN_*) */
    double plan_arrival, plan_hold_speed;   /* the initial plan's (the early refusal's) */
    ato_phase phase;
    int has_departure;
    double t_departure, samples0, last_replan;
    int using_estimates, used;
    int has_last_key;
    double last_key[5];        /* (mass, A0, A1, A2, brake_mass) of car_now */
    int episodes[ATO_N_KEYS];
    int last_status;
    double last_brake;
    int has_stand_since;
    double stand_since;
    double w_m, w_r;           /* blend_estimates' weights */
    double gate;
    int has_t_gate;
    double t_gate;
    double blend_speeds[3];
    long replans;
    double aim_offset, brake_int;
    int has_t_last;
    double t_last, psd;
    int settle;                /* -1 not decided, 0 one stop, 1 stop short and settle */
    int has_settle_since;
    double settle_since;
    int settled, crept;
    int has_first_stop;
    double first_stop_t, first_stop_s;
    /* the events */
    long n_events;             /* all so far; the latest ATO_EVENT_RING are in the ring */
    ato_event events[ATO_EVENT_RING];
} ato_controller;

/* AtoController(span, car, tuning): RC_OK, or RC_BAD_CONFIG (RC_MATH where Python raises
 * another error) with the ValueError's text in msg (ATO_TEXT_SIZE chars; may be NULL); then nothing
 * is left allocated. The tuning is checked first (AtoTuning's own ValueError). */
rc_status ato_controller_init(ato_controller *c, const rc_ato_span *span, const rc_ato_car *car,
                              const ato_tuning *tuning, char *msg);
void ato_controller_free(ato_controller *c);

/* AtoController.demands(t, outputs): inputs holds ATO_N_ALL_INPUTS values in ALL_INPUTS order (NaN
 * where the host has none). Never fails: a bad input gives the safe brake. */
ato_command ato_controller_demands(ato_controller *c, double t, const double *inputs);

/* AtoController.finished: the car stands at the stop mark */
int ato_controller_finished(const ato_controller *c);

/* AtoController.plan.arrival [s]: the arrival the plan in force predicts (the FMU's
 * ato.predicted_arrival; c->replans and c->using_estimates are its ato.replans and
 * ato.using_estimates) */
double ato_controller_predicted_arrival(const ato_controller *c);

/* the event number k (0 .. n_events - 1) if still in the ring, else NULL */
const ato_event *ato_controller_event(const ato_controller *c, long k);

#endif
