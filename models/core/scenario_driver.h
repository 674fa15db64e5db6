/* scenario_driver.h -- a scripted scenario run whole in C: the C twin of harness/run/phases.py's
 * PhaseDriver and TimeTable and of harness/run/driver.py's drive() (the scenario's wind schedule,
 * the payload boarded so far, stop_after_last_phase), stepping the C chain (railcar.h) for a whole
 * run without returning to the caller per step (issue 31). Bit-identical to the Python loop: every
 * expression in Python's operand order (tests/harness_tests/run/test_batch_runs.py).
 *
 *   rc_script s;
 *   rc_script_init(&s, values, n, &err);        -- the flat description below, checked, copied
 *   rc_chain_init(chain, &cfg, &err);           -- a fresh chain (railcar.h)
 *   rc_script_run(&s, chain, outputs, inputs, &rows, &finished, &err);
 *   rc_script_free(&s);
 *
 * The flat description (doubles; models/batch.py and harness/run/batch.py write it):
 *   [0] kind: RC_SCRIPT_PHASES ([[driver]] phases) or RC_SCRIPT_TABLE ([driver_table])
 *   [1] step_s [s]  [2] duration_s [s]  [3] stop_after_last_phase (0 or 1)
 *   [4] mass_t [t]  [5] traction_force_max [N]  [6] brake_force_max [N]   (the PhaseDriver's car)
 *   [7] phases  [8] table rows  [9] wind steps   (counts)
 *   then per phase RC_PHASE_FIELDS values (rc_phase_field order; NaN: not given, Python's None),
 *   then per table row: time_s [s], traction_N [N], brake_N [N],
 *   then per wind step: time_s [s], speed_mps [m/s] (in the scenario's order).
 * Allocation happens in rc_script_init only; the run allocates nothing.
 */
#ifndef RAILCAR_SCENARIO_DRIVER_H
#define RAILCAR_SCENARIO_DRIVER_H

#include "railcar.h"
#include "rc_common.h"
#include "script_common.h"

enum { RC_SCRIPT_PHASES = 0, RC_SCRIPT_TABLE = 1 };

/* harness.run.phases.ACTIONS, in its order */
enum { RC_ACTION_TRACTION, RC_ACTION_COAST, RC_ACTION_CRUISE, RC_ACTION_BRAKE,
       RC_ACTION_BRAKE_TO_STOP, RC_ACTION_HOLD, RC_ACTIONS };

/* A phase's fields in the flat description (harness.run.phases.DriverPhase) */
enum { RC_PHASE_ACTION, RC_PHASE_FORCE, RC_PHASE_UNTIL_SPEED, RC_PHASE_UNTIL_DISTANCE,
       RC_PHASE_UNTIL_TIME, RC_PHASE_UNTIL_BRAKE_CURVE, RC_PHASE_STOP_AT, RC_PHASE_DECEL,
       RC_PHASE_MASS_CHANGE, RC_PHASE_TARGET_SPEED, RC_PHASE_FIELDS };

#define RC_SCRIPT_HEADER 10
/* A step's inputs as drive() holds them (harness.run.phases.INPUTS): traction and brake demand
 * [N], wind [m/s], payload boarded so far [t] */
#define RC_SCRIPT_INPUTS 4
#define RC_SCRIPT_MAX_STEPS RC_RUN_MAX_STEPS   /* script_common.h: rc_script_count_steps' bound */

typedef struct {                       /* harness.run.phases.DriverPhase; NaN: None */
    int action;                        /* RC_ACTION_* */
    double force_N;                    /* [N] */
    double until_speed_mps, until_distance_m, until_time_s;   /* [m/s], [m], [s] */
    int until_brake_curve;
    double stop_at_m, decel_mps2;      /* [m], [m/s^2] */
    double mass_change_t;              /* [t] */
    double target_speed_mps;           /* [m/s] */
    long next_brake;                   /* the next brake_to_stop phase after this one, -1 none */
} rc_phase;

typedef struct {
    int kind;                          /* RC_SCRIPT_PHASES or RC_SCRIPT_TABLE */
    double step_s, duration_s;         /* [s] */
    int stop_after_last_phase;
    double mass_t, traction_force_max, brake_force_max;   /* [t], [N], [N] */
    long n_phases, n_table, n_wind;
    long steps;                        /* int(round(duration_s / step_s)), as drive() */
    rc_phase *phases;                  /* owned */
    double *table;                     /* owned: n_table rows of (time_s, traction_N, brake_N) */
    double *wind;                      /* owned: n_wind rows of (time_s, speed_mps) */
} rc_script;

/* PhaseDriver's / TimeTable's state: the phase running and when it began */
typedef struct {
    const rc_script *script;
    long index;
    double phase_start;                /* [s] */
} rc_script_driver;

typedef struct {                       /* harness.run.phases.Demands */
    double traction, brake;            /* [N] */
    double payload_change_t;           /* [t] */
} rc_demands;

/* The description from n flat values (above), checked: RC_OK, or RC_BAD_CONFIG with err naming
 * the value ("phase 2 (hold).until_time_s: ...") and nothing to free */
rc_status rc_script_init(rc_script *s, const double *values, long n, rc_error *err);
void rc_script_free(rc_script *s);

/* Scenario.wind_at: the last wind step (in the given order) with t + 1e-9 >= its time [m/s] */
double rc_script_wind_at(const rc_script *s, double t);

/* A fresh driver of the script (Scenario.new_driver) */
void rc_script_driver_start(rc_script_driver *d, const rc_script *s);
/* driver.finished: all phases done (a time table never finishes) */
int rc_script_driver_finished(const rc_script_driver *d);
/* driver.demands(t, outputs) for the true speed [m/s] and distance [m] after the last step */
rc_demands rc_script_driver_demands(rc_script_driver *d, double t, double speed, double position);

/* drive(): the whole run on a freshly initialised chain. outputs gets the chain's outputs at
 * t = 0 and after every step (RC_CHAIN_OUTPUTS per row, room for s->steps + 1 rows), inputs each
 * step's RC_SCRIPT_INPUTS (room for s->steps rows); *rows: output rows written (steps + 1);
 * *finished: the run ended early, the driver done and stop_after_last_phase. RC_OK, or the
 * chain's status with err naming the step (the rows before it written, *rows counting them). */
/* One step k of a whole run (the batch engine's scripted and span drivers): the chain advanced
 * over [t, t + h] with the inputs u (traction, brake, wind, payload) held, its outputs written
 * to next_outputs; a refused step's message prefixed "step k: ". */
rc_status rc_script_advance(rc_chain *chain, long k, double t, double h, const double *u,
                            double *next_outputs, rc_error *err);

rc_status rc_script_run(const rc_script *s, rc_chain *chain, double *outputs, double *inputs,
                        long *rows, int *finished, rc_error *err);

#endif
