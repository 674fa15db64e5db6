/* ato_supervision.h -- the ATO's input supervision for the C core: models/ato/supervision.py's
 * InputSupervisor (check, note_command) and the front of AtoController.demands
 * (models/ato/controller.py) that uses it: the finiteness of the inputs, the stated inputs'
 * priors, and the safe brake latched until the inputs have been sane for RECOVERY_TIME.
 *
 * One struct (ato_supervisor), no allocation, no globals. A verdict is an ato_problem: the
 * subject (an input index of ato_tuning.h, or the time, the position-speed consistency, the
 * recovery hold), a reason code, and the text the Python code gives, byte for byte (floats as
 * its f-strings write them: repr() by rc_repr, :g/.3g/.3f/... by printf's same conversions).
 *
 * Units: V [m/s], s [m], t [s], mass [t], A0 [N/kN], A1 [N/kN/(m/s)], A2 [N/kN/(m/s)^2].
 */
#ifndef RAILCAR_ATO_SUPERVISION_H
#define RAILCAR_ATO_SUPERVISION_H

#include "ato_tuning.h"

/* supervision.py's bounds (why: there) */
#define ATO_NOISE_SIGMA 6.0
#define ATO_RECOVERY_TIME 1.0          /* [s] */
#define ATO_MAX_CALL_GAP 10.0          /* [s] */
#define ATO_MAX_SPEED 200.0            /* [m/s] */
#define ATO_MAX_DISTANCE 1e7           /* [m] */
#define ATO_MASS_FACTOR 10.0
#define ATO_A0_MAX 1000.0              /* [N/kN] */
#define ATO_A1_MAX 100.0               /* [N/kN/(m/s)] */
#define ATO_A2_MAX 10.0                /* [N/kN/(m/s)^2] */
#define ATO_MAX_SAMPLES 1e9
#define ATO_RESPONSE_TIME 3.0          /* [s] */
#define ATO_CONSISTENCY_WINDOW 2.0     /* [s] */
#define ATO_CONSISTENCY_SLACK 1.0      /* [m] */

/* What a verdict is about: an input index (ATO_IN_*, 0 .. ATO_N_ALL_INPUTS - 1) or one of these */
enum {
    ATO_SUBJECT_NONE = -1,
    ATO_SUBJECT_TIME = 100,            /* "t" */
    ATO_SUBJECT_CONSISTENCY = 101,     /* "filter.speed vs filter.position" */
    ATO_SUBJECT_RECOVERY = 102         /* "recovery": the safe brake held after a problem */
};
/* The subject's name: InputSupervisor's problem[0] ("t", an input's name, "filter.speed vs
 * filter.position"), "recovery" for ATO_SUBJECT_RECOVERY. The controller's once-per-episode
 * log key is "input:" + this name, "recovery" for the hold. NULL for an unknown subject. */
const char *ato_subject_name(int subject);

/* Why: one code per message of supervision.py and of AtoController.demands' front */
typedef enum {
    ATO_SANE = 0,
    ATO_TIME_NOT_LATER = 1,            /* _check_time: does not continue */
    ATO_TIME_GAP = 2,                  /* _check_time: more than MAX_CALL_GAP after */
    ATO_STD_NEGATIVE = 3,              /* _check_stds */
    ATO_STD_ZERO_MOVING = 4,
    ATO_STD_BEYOND = 5,
    ATO_SPEED_BACKWARDS = 6,           /* _check_motion */
    ATO_SPEED_BEYOND = 7,
    ATO_POSITION_BEHIND = 8,
    ATO_POSITION_BEYOND = 9,
    ATO_MASS_OUTSIDE = 10,             /* _check_estimates */
    ATO_RESISTANCE_BEYOND = 11,
    ATO_STATUS_UNKNOWN = 12,
    ATO_SAMPLES_OUTSIDE = 13,
    ATO_INCONSISTENT = 14,             /* _check_consistency */
    ATO_NOT_FOLLOWING = 15,            /* _check_response (and its repetition while dead) */
    ATO_TIME_NOT_FINITE = 16,          /* AtoController.demands: t not finite */
    ATO_INPUT_NOT_FINITE = 17,         /* an INPUTS value not finite */
    ATO_RECOVERY_HOLD = 18             /* sane again, held until sane for RECOVERY_TIME */
} ato_reason;

#define ATO_TEXT_SIZE 512              /* the longest text reachable is ~250 characters */

typedef struct {
    int subject;                       /* ATO_SUBJECT_NONE when sane */
    ato_reason reason;                 /* ATO_SANE when sane */
    char text[ATO_TEXT_SIZE];          /* "" when sane */
} ato_problem;

/* AtoController.demands' front: what to do with this call */
typedef enum {
    ATO_GATE_RUN = 0,                  /* step the controller, then note_command(traction) */
    ATO_GATE_RUN_RELEASED = 1,         /* the same; the latch was released now: the gate's
                                          text is the event to record */
    ATO_GATE_SAFE = 2                  /* the safe brake; the gate's problem says why (the
                                          event text, "<reason>: safe brake" for an input) and
                                          note_command(0.0) has been done */
} ato_gate_verdict;

typedef struct {
    double mass;                       /* car.mass [t] the supervisor was built for */
    /* InputSupervisor's state */
    int has_t_last;
    double t_last;                     /* [s] the latest call's time */
    int has_anchor;                    /* the consistency window: (t, s, position_std) at its start */
    double anchor_t, anchor_s, anchor_psd;
    double travel;                     /* [m] speeds integrated since the anchor */
    double v_last;                     /* [m/s] */
    double t_prev;                     /* [s] the window's latest call */
    double sd_max;                     /* [m/s] the largest filter.speed_std in the window */
    int pushing;                       /* (t, s) of the first traction command at rest */
    double pushing_t, pushing_s;
    int dead;                          /* inputs found not to follow the car: the problem, at s */
    double dead_s;
    ato_problem dead_problem;
    int at_rest;                       /* (t, s) of the last sane call with V = 0 */
    double at_rest_t, at_rest_s;
    /* AtoController's latch */
    int latched;                       /* a bad input was seen: the safe brake holds */
    int has_sane_since;
    double sane_since;                 /* [s] the first sane call since */
    /* the verdicts */
    ato_problem problem;               /* the latest ato_supervisor_check's */
    ato_problem gate;                  /* the latest ato_supervisor_gate's */
} ato_supervisor;

/* InputSupervisor(mass): mass [t] is car.mass; the latch open */
void ato_supervisor_init(ato_supervisor *s, double mass);

/* InputSupervisor.check(t, x): x holds ATO_N_INPUTS values in INPUTS order (the controller
 * passes finite ones). ATO_SANE, or the reason code with s->problem filled. */
ato_reason ato_supervisor_check(ato_supervisor *s, double t, const double *x);

/* InputSupervisor.note_command(traction [N]): after each command */
void ato_supervisor_note_command(ato_supervisor *s, double traction);

/* AtoController.demands up to its step. The controller on its verdict: ATO_GATE_SAFE: the safe
 * brake (tuning.safe_brake x car.brake_force_max), the gate's text logged once per episode of
 * its subject (key "input:<name>", or "recovery"); every verdict but a SAFE one for an input
 * (the check passed) ends the input episodes (_clear_inputs); ATO_GATE_RUN_RELEASED also ends the
 * "recovery" episode and records the gate's text as an event; then for RUN and RUN_RELEASED the
 * step from `values`, and ato_supervisor_note_command(s, its traction).
 * `inputs` holds ATO_N_ALL_INPUTS values (ALL_INPUTS order; the stated ones not finite where the
 * host has none); `values` receives them as the controller uses them (stated ones not finite
 * replaced by their prior; only written when the time and INPUTS are finite). The verdict, with s->gate filled (subject, reason, text) for
 * ATO_GATE_SAFE and ATO_GATE_RUN_RELEASED. */
ato_gate_verdict ato_supervisor_gate(ato_supervisor *s, double t, const double *inputs,
                                     double *values);

#endif
